"""The periodic-orbit engine (shooting and harmonic balance) on systems with known answers,
on the BSFS through contact loss, and its implicit derivatives in both AD modes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.machine import bsfs_family, simulate
from bsfs_jax.params import preset
from bsfs_jax.solvers import (
    RESULTS,
    HarmonicBalance,
    ImplicitForward,
    ImplicitReverse,
    Shooting,
    SolverError,
    SolverSettings,
    classify_multipliers,
    integrate,
    periodic_orbit,
)

from .textbook import duffing, linear_oscillator_eigenvalues, linear_oscillator_response

ONES = jnp.ones(2)
# A weakly hardening Duffing oscillator away from its fold region: one stable T-orbit.
DUFFING = (0.1, 1.0, 0.05, 0.3, 1.1)  # delta, alpha, beta, gamma, omega
HB8 = HarmonicBalance(harmonics=8, error_tol=1e-8)


def _as_duffing(zeta, w0, f0, omega):
    """The linear oscillator is the Duffing field with beta = 0 (shares compiled code)."""
    return (2 * zeta * w0, w0 * w0, 0.0, f0, omega)


@pytest.mark.parametrize("method", [Shooting(), Shooting(segments=3), HB8,
                                    HarmonicBalance(harmonics=8, error_tol=1e-8,
                                                    second_order=True)],
                         ids=["single-shooting", "multiple-shooting", "harmonic-balance",
                              "harmonic-balance-second-order"])
def test_linear_oscillator_matches_closed_form(method):
    zeta, w0, f0, omega = 0.05, 1.0, 1.0, 1.3
    period = 2 * np.pi / omega
    orbit = periodic_orbit(duffing, jnp.zeros(2), _as_duffing(zeta, w0, f0, omega), period,
                           method=method, scale=ONES)
    assert bool(orbit.converged) and orbit.result == RESULTS.successful
    np.testing.assert_allclose(orbit.state, linear_oscillator_response(zeta, w0, f0, omega),
                               rtol=0, atol=1e-9)
    expected = np.exp(np.asarray(linear_oscillator_eigenvalues(zeta, w0)) * period)
    got = np.asarray(orbit.multipliers)
    np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(expected), atol=1e-7)
    h = abs(1.0 / (w0**2 - omega**2 + 2j * zeta * w0 * omega))
    amps = np.asarray(orbit.amplitudes(duffing, _as_duffing(zeta, w0, f0, omega)))
    np.testing.assert_allclose(amps, [h, h * omega], rtol=1e-7)
    if isinstance(method, HarmonicBalance):
        # One harmonic carries the whole answer: the truncation error is round-off.
        assert float(orbit.error_estimate) < 1e-12


def test_harmonic_balance_matches_shooting_on_duffing():
    period = 2 * np.pi / DUFFING[4]
    shoot = periodic_orbit(duffing, jnp.array([0.5, 0.0]), DUFFING, period, scale=ONES)
    hb = periodic_orbit(duffing, jnp.array([0.5, 0.0]), DUFFING, period, method=HB8,
                        scale=ONES)
    # The cubic term makes odd harmonics; 8 harmonics reach 1e-8 here (the error estimate
    # says so, and doubling H from the method's start was not needed).
    assert float(hb.error_estimate) < 1e-8
    np.testing.assert_allclose(hb.state, shoot.state, atol=1e-8)
    np.testing.assert_allclose(np.abs(hb.multipliers), np.abs(shoot.multipliers), atol=1e-7)
    np.testing.assert_allclose(hb.amplitudes(duffing, DUFFING),
                               shoot.amplitudes(duffing, DUFFING), rtol=1e-7)

    # Without stability: the same orbit and derivative, multipliers left out (nan), and
    # the orbit is then never called stable.
    bare = periodic_orbit(duffing, jnp.array([0.5, 0.0]), DUFFING, period, method=HB8,
                          scale=ONES, stability=False)
    assert bool(bare.converged)
    np.testing.assert_array_equal(bare.state, hb.state)
    assert np.all(np.isnan(np.asarray(bare.multipliers))) and not bool(bare.stable)
    assert bool(hb.stable)
    grad = lambda stab: jax.grad(lambda g: periodic_orbit(
        duffing, jnp.array([0.5, 0.0]), DUFFING[:3] + (g,) + DUFFING[4:], period, method=HB8,
        scale=ONES, stability=stab, adjoint=ImplicitReverse(), throw=False).state[0])(
        DUFFING[3])
    assert np.isfinite(grad(True)) and abs(float(grad(True))) > 0
    np.testing.assert_allclose(grad(False), grad(True), rtol=1e-12)


def test_subharmonic_orbit_of_period_two():
    """Double-well Duffing at gamma = 0.28: the attractor in the right well has period 2T."""
    args = (0.3, -1.0, 1.0, 0.28, 1.2)
    period = 2 * np.pi / 1.2
    from bsfs_jax.solvers import integrate

    ts = period * jnp.arange(600, 605)
    settled = integrate(duffing, jnp.array([1.0, 0.0]), args, 0.0, ts[-1], ts).ys
    orbit = periodic_orbit(duffing, settled[-1] + 0.01, args, period, n_periods=2,
                           scale=ONES)
    np.testing.assert_allclose(orbit.state, settled[-1], atol=1e-5)
    assert orbit.n_periods == 2 and bool(orbit.stable)
    assert float(jnp.abs(settled[-1, 0] - settled[-2, 0])) > 1e-2  # a genuine 2T orbit


def test_failures_are_reported_not_guessed():
    period = 2 * np.pi / 1.1
    with pytest.raises(SolverError, match="not found"):
        periodic_orbit(duffing, jnp.array([3.0, -2.0]), (0.1, 1.0, 5.0, 3.0, 1.1), period,
                       scale=ONES, max_steps=1)
    orbit = periodic_orbit(duffing, jnp.array([3.0, -2.0]), (0.1, 1.0, 5.0, 3.0, 1.1),
                           period, scale=ONES, max_steps=1, throw=False)
    assert orbit.result == RESULTS.newton_failed and not bool(orbit.converged)
    with pytest.raises(ValueError, match="finite"):
        periodic_orbit(duffing, jnp.array([np.nan, 0.0]), DUFFING, period)
    with pytest.raises(ValueError, match="n_periods"):
        periodic_orbit(duffing, jnp.zeros(2), DUFFING, period, n_periods=0)
    with pytest.raises(ValueError, match="harmonics"):
        HarmonicBalance(harmonics=0)


def test_classify_multipliers():
    assert classify_multipliers(np.array([0.5, 0.2j])) == "stable"
    assert classify_multipliers(np.array([1.2, 0.1])) == "unstable"
    assert classify_multipliers(np.array([1.0 + 1e-5, 0.3])) == "fold"
    assert classify_multipliers(np.array([-0.9999, 0.3])) == "period-doubling"
    ns = np.exp(1j * 0.7)
    assert classify_multipliers(np.array([ns, np.conj(ns)])) == "neimark-sacker"
    assert classify_multipliers(np.array([np.nan, 0.1])) == "invalid"


# -- the BSFS through contact loss ----------------------------------------------------------
F_HZ, P_N = 1000.0, 5000.0  # joint forces reach 15-21 kN: both joints lose contact


@pytest.fixture(scope="module")
def bsfs_point():
    params = preset("default")
    family = bsfs_family(params, P_N)
    args, period = family(F_HZ)
    guess = simulate(params, frequency_hz=F_HZ, force_n=P_N, transient_periods=100,
                     periods=1).final_state
    shoot = periodic_orbit(family.vector_field, guess, args, period, scale=family.scale)
    return family, args, period, guess, shoot


def test_bsfs_orbit_loses_contact(bsfs_point):
    from bsfs_jax.model import joint_forces

    family, args, period, _, shoot = bsfs_point
    ys = shoot.trajectory(family.vector_field, args, jnp.linspace(0.0, period, 256))
    forces = np.abs(np.asarray(joint_forces(args[0], ys[:, :3])))
    assert forces[:, 0].max() > 4417.0 and forces[:, 2].max() > 4349.0  # unloading forces
    assert bool(shoot.stable)


def test_harmonic_balance_matches_shooting_on_the_bsfs(bsfs_point):
    """At 5000 N the joint forces are only C^1 (contact loss): HB converges algebraically.
    Its error estimate tracks the true state error, and 128 harmonics give the amplitude
    within 1e-6 of shooting."""
    family, args, period, guess, shoot = bsfs_point
    vf = family.vector_field
    size = float(jnp.max(jnp.abs(shoot.state / shoot.scale)))
    for h in (16, 32):
        hb = periodic_orbit(vf, guess, args, period, scale=family.scale, throw=False,
                            method=HarmonicBalance(harmonics=h, max_harmonics=h))
        assert hb.result == RESULTS.harmonics_insufficient  # honest: above 1e-4
        err = float(jnp.max(jnp.abs(hb.state - shoot.state) / shoot.scale)) / size
        est = float(hb.error_estimate)
        assert err <= est <= 10 * err, (h, err, est)
    hb = periodic_orbit(vf, guess, args, period, scale=family.scale,
                        method=HarmonicBalance(harmonics=128, error_tol=1e-5))
    amp_hb = float(hb.amplitudes(vf, args)[2])
    amp_shoot = float(shoot.amplitudes(vf, args)[2])
    assert amp_hb == pytest.approx(amp_shoot, rel=1e-6)
    # Stability from the HB state (Runge-Kutta on 256 steps): the least damped multiplier
    # to 1e-6, the strongly damped higher modes' to 5e-5.
    mu_hb, mu_sh = np.abs(np.asarray(hb.multipliers)), np.abs(np.asarray(shoot.multipliers))
    assert mu_hb[0] == pytest.approx(mu_sh[0], abs=1e-6)
    np.testing.assert_allclose(mu_hb, mu_sh, atol=5e-5)


def test_harmonic_balance_jacobian_from_the_aft_equals_forward_mode(bsfs_point):
    """The corrector's assembled HB Jacobian (convolution of the field Jacobian's DFT) is
    the forward-mode Jacobian of the residual to rounding, through contact loss (5000 N),
    at the orbit and off it, for an odd and an even harmonic count."""
    from bsfs_jax.solvers._newton import residual_and_jacobian

    family, args, period, guess, _ = bsfs_point
    vf, scale = family.vector_field, family.scale
    for h in (7, 16):
        hb = HarmonicBalance(harmonics=h, max_harmonics=h)
        orbit = periodic_orbit(vf, guess, args, period, scale=scale, method=hb, throw=False)
        # each side one compiled program, as the corrector runs it (op by op, the forward
        # mode through the FFT alone compiled about 300 small programs)
        by_ad = jax.jit(lambda z, hb=hb: residual_and_jacobian(
            lambda v, _: hb.residual(vf, v, args, period, 1, scale), z, None))
        by_aft = jax.jit(lambda z, hb=hb: hb.residual_and_jacobian(vf, z, args, period, 1,
                                                                   scale))
        for z in (orbit.unknowns, orbit.unknowns + 1e-2 * jnp.sin(
                jnp.arange(orbit.unknowns.shape[0]))):
            r_ad, j_ad = by_ad(z)
            r, j = by_aft(z)
            # the same residual, fused differently: equal to rounding (unknowns are O(1))
            assert float(jnp.max(jnp.abs(r - r_ad))) <= 1e-12
            assert float(jnp.max(jnp.abs(j - j_ad))) <= 1e-13 * float(jnp.max(jnp.abs(j_ad)))


def test_second_order_harmonic_balance_is_the_first_order_one(bsfs_point):
    """Harmonic balance in the positions alone (`second_order=True`, the velocities'
    coefficients from the positions') solves the first-order method's equations with half
    the unknowns: through contact loss (5000 N) the same orbit (coefficients, state,
    multipliers, error estimate) to rounding; its assembled Jacobian is the forward-mode
    Jacobian of its residual, on the orbit and off it (the chord: the next test)."""
    from bsfs_jax.solvers import _harmonic_second as second
    from bsfs_jax.solvers._newton import residual_and_jacobian

    family, args, period, guess, _ = bsfs_point
    vf, scale = family.vector_field, family.scale
    omega = 2 * np.pi / period
    for h in (7,):  # one count: the AFT layout itself is tested for odd and even above
        one = HarmonicBalance(harmonics=h, max_harmonics=h)
        two = HarmonicBalance(harmonics=h, max_harmonics=h, second_order=True)
        o1 = periodic_orbit(vf, guess, args, period, scale=scale, method=one, throw=False)
        o2 = periodic_orbit(vf, guess, args, period, scale=scale, method=two, throw=False)
        assert o2.unknowns.shape[0] * 2 == o1.unknowns.shape[0] == 6 * (2 * h + 1)
        assert o1.result == o2.result == RESULTS.harmonics_insufficient  # at 5000 N
        full = second.expand(o2.unknowns, h, 6, omega, scale)
        np.testing.assert_allclose(full, o1.unknowns, rtol=0, atol=1e-10)
        np.testing.assert_allclose(o2.state / scale, o1.state / scale, rtol=0, atol=1e-10)
        np.testing.assert_allclose(np.asarray(o2.multipliers), np.asarray(o1.multipliers),
                                   atol=1e-10)
        assert float(o2.error_estimate) == pytest.approx(float(o1.error_estimate), rel=1e-6)
        # At the expanded coefficients the first-order residual's position rows (x' = v)
        # vanish, and its velocity rows are the second-order residual.
        r_full = np.asarray(one.residual(vf, full, args, period, 1, scale)).reshape(-1, 6)
        assert np.max(np.abs(r_full[:, :3])) < 1e-13
        np.testing.assert_allclose(
            r_full[:, 3:].reshape(-1),
            two.residual(vf, o2.unknowns, args, period, 1, scale), rtol=0, atol=1e-14)
        by_ad = jax.jit(lambda z: residual_and_jacobian(
            lambda v, _: two.residual(vf, v, args, period, 1, scale), z, None))
        by_aft = jax.jit(lambda z: two.residual_and_jacobian(vf, z, args, period, 1, scale))
        for z in (o2.unknowns, o2.unknowns + 1e-2 * jnp.sin(jnp.arange(o2.unknowns.shape[0]))):
            r_ad, j_ad = by_ad(z)
            r, j = by_aft(z)
            assert float(jnp.max(jnp.abs(r - r_ad))) <= 1e-12
            assert float(jnp.max(jnp.abs(j - j_ad))) <= 1e-13 * float(jnp.max(jnp.abs(j_ad)))


def test_harmonic_balance_amplitudes_from_its_harmonics_equal_the_samples(bsfs_point):
    """Harmonic balance's amplitudes come from its own H harmonics (`series_half_range`),
    not from the rfft of its 8 N samples (whose harmonics above H are zero): the same
    values and the same derivatives along a direction of the unknowns, to rounding,
    through contact loss (5000 N), first and second order. Against the default of every
    method (`fourier_half_range` of the samples), which sums over all 8 N / 2 + 1 terms."""
    from bsfs_jax.solvers._half_range import fourier_half_range

    family, args, period, guess, _ = bsfs_point
    vf, scale = family.vector_field, family.scale
    for second_order in (False, True):
        hb = HarmonicBalance(harmonics=16, max_harmonics=16, second_order=second_order)
        orbit = periodic_orbit(vf, guess, args, period, scale=scale, method=hb, throw=False)
        z = orbit.unknowns
        dz = 1e-2 * jnp.cos(jnp.arange(z.shape[0]))

        def by_samples(v, hb=hb):
            return fourier_half_range(hb.samples(vf, v, args, period, 1, scale)[1])

        def by_harmonics(v, hb=hb):
            return hb.amplitudes(vf, v, args, period, 1, scale)

        a_s, da_s = jax.jit(lambda v: jax.jvp(by_samples, (v,), (dz,)))(z)
        a_h, da_h = jax.jit(lambda v: jax.jvp(by_harmonics, (v,), (dz,)))(z)
        assert float(jnp.min(a_h / scale)) > 1e-3  # every coordinate moves
        np.testing.assert_allclose(np.asarray(a_h), np.asarray(a_s), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(da_h), np.asarray(da_s), rtol=1e-9,
                                   atol=1e-12 * float(jnp.max(jnp.abs(da_s))))


def test_start_from_a_period_of_samples_is_the_integrated_start():
    """`init_from_samples` (states over one period, e.g. a transient's last one: no
    program) gives harmonic balance the start `init` integrates, in both forms, and
    shooting the first (or each segment's) state."""
    period = 2 * np.pi / DUFFING[4]
    y0 = jnp.array([0.5, 0.1])
    ts = period * jnp.arange(32) / 32  # the AFT grid of 8 harmonics (4 H samples)
    ys = np.asarray(integrate(duffing, y0, DUFFING, 0.0, period, ts,
                              SolverSettings(rtol=1e-12, atol=1e-12, solver="dopri8")).ys)
    scale = jnp.array([0.5, 2.0])
    for so in (False, True):
        hb = HarmonicBalance(harmonics=8, second_order=so)
        z_int = hb.init(duffing, y0, DUFFING, period, 1, scale)
        z_smp = hb.init_from_samples(ys, scale)
        assert z_smp.shape == z_int.shape == (hb.size(2),)
        np.testing.assert_allclose(z_smp, z_int, rtol=0, atol=1e-9)
    # More harmonics than the grid holds: those beyond it start at zero.
    wide = HarmonicBalance(harmonics=40).init_from_samples(ys, scale).reshape(-1, 2)
    assert np.all(wide[1 + 15:41] == 0) and np.all(wide[41 + 15:] == 0)
    assert np.all(wide[1:16] != 0)
    np.testing.assert_allclose(Shooting().init_from_samples(ys, scale), ys[0] / scale)
    np.testing.assert_allclose(Shooting(segments=4).init_from_samples(ys, scale),
                               (ys[::8] / np.asarray(scale)[None]).reshape(-1))
    assert Shooting(segments=5).init_from_samples(ys, scale) is None
    # One state is a start for single shooting only.
    assert HarmonicBalance(harmonics=8).init_from_samples(ys[:1], scale) is None
    assert Shooting(segments=2).init_from_samples(ys[:1], scale) is None


def test_second_order_chord_converges_to_the_orbit():
    """The chord iteration in the positions (`HarmonicBalance.chord`, the linear field's
    block per harmonic) from zero: one step is the linear oscillator's closed form; on a
    weakly nonlinear Duffing oscillator it converges to the orbit Newton finds."""
    hb = HarmonicBalance(harmonics=8, error_tol=1e-10, second_order=True)
    zeta, w0, f0, omega = 0.05, 1.0, 1.0, 1.3
    lin = _as_duffing(zeta, w0, f0, omega)
    period = 2 * np.pi / omega
    jac = jnp.array([[0.0, 1.0], [-w0 * w0, -2 * zeta * w0]])
    z = hb.chord(duffing, jnp.zeros(17), lin, period, 1, ONES, jac, 1)[-1]
    np.testing.assert_allclose(hb.initial_state(z, period, 1, ONES),
                               linear_oscillator_response(zeta, w0, f0, omega), atol=1e-12)
    weak = (0.1, 1.0, 0.05, 0.3, 1.6)  # far from the fold: the chord map contracts
    period = 2 * np.pi / weak[4]
    jac = jnp.array([[0.0, 1.0], [-weak[1], -weak[0]]])
    zs = hb.chord(duffing, jnp.zeros(17), weak, period, 1, ONES, jac, 60)
    orbit = periodic_orbit(duffing, jnp.zeros(2), weak, period, method=hb, scale=ONES)
    np.testing.assert_allclose(zs[-1], orbit.unknowns, atol=1e-10)
    assert float(jnp.max(jnp.abs(zs[-1] - zs[-2]))) < 1e-12


@pytest.mark.parametrize("method,agree", [
    (Shooting(), 1e-8),
    (Shooting(settings=SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8-fused")), 1e-6),
    (HarmonicBalance(harmonics=32, max_harmonics=32), 1e-8)],
    ids=["shooting", "shooting-fused", "harmonic-balance"])
def test_implicit_gradients_through_contact_loss(bsfs_point, method, agree):
    """d(nut amplitude)/d(force, nut mass) by ImplicitReverse (grad) and ImplicitForward
    (jacfwd) against central differences of the solved orbit. The two modes agree to
    `agree`: 1e-8 where both differentiate one discretisation; the fused 8(7) loop has no
    reverse mode, so with it ImplicitReverse differentiates diffrax's Dopri8 flow at the
    same orbit, and the two differ by the integrators' error in the derivative (7e-8
    measured)."""
    family, _, period, guess, shoot = bsfs_point
    vf = family.vector_field
    start = shoot.state

    def amplitude(theta, adjoint):
        fam = bsfs_family(family.params.replace("masses.nut_kg", theta[1]), theta[0])
        args, _ = fam(F_HZ)
        orbit = periodic_orbit(vf, start, args, period, method=method, scale=family.scale,
                               adjoint=adjoint, throw=False)
        return orbit.amplitudes(vf, args, adjoint=adjoint)[2]

    theta = jnp.array([P_N, float(family.params.get("masses.nut_kg"))])
    g_rev = np.asarray(jax.grad(amplitude)(theta, ImplicitReverse()))
    # jacfwd with the amplitude as its aux output: the central differences' orbits are
    # solved by the same program (op by op, a separate primal program compiled the whole
    # orbit solve a third time: 10 s with the fused loop)
    forward = jax.jacfwd(lambda th: (amplitude(th, ImplicitForward()),) * 2, has_aux=True)
    g_fwd = np.asarray(forward(theta)[0])
    h = 1e-4 * np.asarray(theta)
    fd = np.array([(float(forward(theta.at[i].add(h[i]))[1])
                    - float(forward(theta.at[i].add(-h[i]))[1])) / (2 * h[i])
                   for i in range(2)])
    np.testing.assert_allclose(g_rev, g_fwd, rtol=agree)
    np.testing.assert_allclose(g_rev, fd, rtol=1e-4)


@pytest.mark.parametrize("adjoint,diff", [(ImplicitReverse(), jax.grad),
                                          (ImplicitForward(), jax.jacfwd)],
                         ids=["reverse", "forward"])
def test_attach_differentiates_a_jitted_function_from_outside(adjoint, diff):
    """u*(theta) = sqrt(c theta) attached by a residual that closes over `c`, a tracer of
    the jit around it: differentiating the jitted function from outside (the user's
    jax.grad of a jitted design metric) gives the closed form; a closure's tracer used to
    leak into the transposed program."""

    @jax.jit
    def root(theta, c):
        u_star = jax.lax.stop_gradient(jnp.sqrt(c * theta))
        return adjoint.attach(lambda u, th: u * u - c * th, theta, u_star,
                              2.0 * u_star[:, None])[0]

    theta, c = jnp.array([2.0]), jnp.asarray(3.0)
    assert float(diff(lambda t: root(t, c))(theta)[0]) == pytest.approx(
        0.5 * np.sqrt(3.0 / 2.0), rel=1e-12)
