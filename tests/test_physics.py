"""Pure physics functions against physics.md's independent checks (sections 2-5)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate as sp_integrate
from scipy import optimize, special

import bsfs_jax as bsfs
from bsfs_jax import model, physics
from bsfs_jax.solvers import SolverSettings, integrate

from .helpers import finite_difference, measured_period

E_STEEL = 206e9
NU_STEEL = 0.3


# --------------------------------------------------------------------------------------
# Fixtures
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cold_params():
    """Default preset with the thermal chain off (physics.md section 2 values)."""
    return bsfs.preset().replace("thermal.enabled", False)


@pytest.fixture(scope="module")
def cold_system(cold_params):
    return bsfs.build_system(cold_params)


@pytest.fixture(scope="module")
def warm_system():
    """Default preset, thermal chain on: equal, non-zero offsets on both halves."""
    return bsfs.build_system(bsfs.preset())


def _unit_pair(angle=jnp.pi / 2):
    """A dimensionless pair: Z = 1, K = 1, F_p = 1, so delta0 = 1 at 90 deg.

    The ball is large (d = 1000, A0 = 100) so that displacements of several delta0 stay
    small against the curvature-centre distance, as in a real joint.
    """
    return physics.preloaded_pair(1.0, 1000.0, 0.55, 0.55, angle, 1.0, 1.0)


def _contact_loss_u(pair):
    """u > 0 at which the right half's deformation delta_- is exactly zero (physics.md s1).

    sqrt((A sin b - u/cos l)^2 + (A cos b)^2) = A0 + D  =>  solve for u.
    """
    a, a0, b, cl, d = (float(x) for x in (pair.a, pair.a0, pair.contact_angle,
                                            pair.cos_helix, pair.offset))
    return cl * (a * math.sin(b) - math.sqrt((a0 + d) ** 2 - (a * math.cos(b)) ** 2))


# --------------------------------------------------------------------------------------
# 1(a). Double-nut unloading force and the loaded-half law (HIWIN F 3.6-3.7)
# --------------------------------------------------------------------------------------
PRELOAD = 1500.0


def _pair_at(angle_deg, preload=PRELOAD):
    """A nut-like pair (50 balls, K_n of the defaults, no helix) at a given contact angle."""
    return physics.preloaded_pair(50.0, 3.175e-3, 0.55, 0.55, math.radians(angle_deg),
                                  preload, 3.78e-7)


def test_unloading_force_at_90_degrees():
    pair = _pair_at(90.0)
    u_star = _contact_loss_u(pair)
    f_plus, f_minus = physics.side_forces(u_star, pair)
    f_net = physics.pair_force(u_star, pair)
    assert abs(float(f_minus)) < 1e-9 * PRELOAD
    np.testing.assert_allclose(float(f_net), 2**1.5 * PRELOAD, rtol=1e-9)
    # The loaded half then carries all of it.
    np.testing.assert_allclose(float(f_plus), 2**1.5 * PRELOAD, rtol=1e-9)
    # Just beyond, the joint is one-sided: F = F_+ and the unloaded half carries nothing.
    f_plus2, f_minus2 = physics.side_forces(1.1 * u_star, pair)
    assert float(f_minus2) == 0.0 and float(f_plus2) > 2**1.5 * PRELOAD


def test_loaded_half_law_at_90_degrees():
    """At constant angle the exact Hertz pair obeys F/F_p = (1+x)^1.5 - (1-x)^1.5 with
    x = u / delta0, and F_+ = F_p (1+x)^1.5.  HIWIN's F_b = F_p (1 + F/(2^1.5 F_p))^1.5
    is a catalogue approximation of this: exact at F = 0 and at unloading, and
    (computed here) at most 2.42 % above the exact Hertz value in between.
    """
    pair = _pair_at(90.0)
    delta0 = float(pair.a - pair.a0)
    x = np.linspace(0.0, 1.0, 201)
    u = x * delta0
    f_plus, _ = physics.side_forces(jnp.asarray(u), pair)
    f_net = physics.pair_force(jnp.asarray(u), pair)
    np.testing.assert_allclose(f_plus, PRELOAD * (1 + x) ** 1.5, rtol=1e-9)
    np.testing.assert_allclose(f_net, PRELOAD * ((1 + x) ** 1.5 - (1 - x) ** 1.5),
                               rtol=1e-9, atol=1e-9 * PRELOAD)
    hiwin = PRELOAD * (1 + np.asarray(f_net) / (2**1.5 * PRELOAD)) ** 1.5
    dev = np.asarray(f_plus) / hiwin - 1.0
    np.testing.assert_allclose(dev[[0, -1]], 0.0, atol=1e-9)  # exact at both ends
    assert np.max(np.abs(dev)) < 0.025  # the catalogue law's approximation error
    assert np.max(np.abs(dev)) > 0.02  # ...and it is an approximation, not an identity


@pytest.mark.parametrize("which,tolerance", [("nut", 0.03), ("bearing", 0.05)])
def test_default_joints_unload_near_catalogue_force(cold_system, which, tolerance):
    """With the load-dependent contact angle (45 deg nut: +2.5 %, 40 deg bearing: +4.1 %)
    the default joints unload a few percent above 2^1.5 F_p; HIWIN's law is within that.
    """
    pair = getattr(cold_system, which)
    u_star = _contact_loss_u(pair)
    d_plus, d_minus = physics.contact_deformations(u_star, pair)
    assert abs(float(d_minus)) < 1e-15  # u_star really is the contact-loss point
    f_net = float(physics.pair_force(u_star, pair))
    ratio = f_net / (2**1.5 * PRELOAD)
    assert 1.0 < ratio < 1.0 + tolerance
    # Loaded-half law at half the unloading force: also within the tolerance.
    u_half = optimize.brentq(lambda u: float(physics.pair_force(u, pair)) - f_net / 2, 0.0,
                             u_star, xtol=1e-18)
    f_plus = float(physics.side_forces(u_half, pair)[0])
    hiwin = PRELOAD * (1 + (f_net / 2) / (2**1.5 * PRELOAD)) ** 1.5
    assert abs(f_plus / hiwin - 1.0) < tolerance


# --------------------------------------------------------------------------------------
# 1(b). Backbone of the symmetric preloaded pair, measured by integration
# --------------------------------------------------------------------------------------
def _unit_pair_field(t, y, pair):
    """m x'' + k [(d0+x)^1.5 - (d0-x)^1.5] = 0 with m = k = d0 = 1 (pair at 90 deg)."""
    return jnp.stack([y[1], -physics.pair_force(y[0], pair)])


def _exact_period(amplitude):
    """Period of the unit oscillator from the energy integral (x = A sin(theta))."""

    def potential(x):
        return 0.4 * (max(1 + x, 0.0) ** 2.5 + max(1 - x, 0.0) ** 2.5)

    def integrand(theta):
        x = amplitude * math.sin(theta)
        return amplitude * math.cos(theta) / math.sqrt(2 * (potential(amplitude) - potential(x)))

    val, _ = sp_integrate.quad(integrand, 0.0, math.pi / 2, epsabs=1e-13, epsrel=1e-13,
                               limit=200)
    return 4 * val


# (A / d0, physics.md section 5 value of w / w0)
BACKBONE = [(0.2, 1 - 0.2**2 / 64), (1.0, 0.9799), (2.5, 0.9354), (5.0, 0.9728)]


def test_backbone_of_symmetric_pair():
    pair = _unit_pair()
    # The unit pair is what we think it is: delta0 = 1, so k = 1, and w0^2 = 3 k sqrt(d0)/m.
    np.testing.assert_allclose(float(pair.a - pair.a0), 1.0, rtol=1e-12)
    k_lin = float(jax.grad(physics.pair_force)(0.0, pair))
    np.testing.assert_allclose(k_lin, 3.0, rtol=1e-12)
    w0 = math.sqrt(3.0)
    t0 = 2 * math.pi / w0
    t_end = 14 * t0
    ts = jnp.linspace(0.0, t_end, 14 * 200 + 1)
    amplitudes = jnp.array([a for a, _ in BACKBONE])
    y0 = jnp.stack([amplitudes, jnp.zeros_like(amplitudes)], axis=-1)
    settings = SolverSettings(rtol=1e-12, atol=1e-14, max_steps=100_000)

    @jax.jit
    def run(y0):
        return integrate(_unit_pair_field, y0, pair, 0.0, t_end, ts, settings)

    res = jax.vmap(run)(y0)
    assert np.all(np.asarray(res.ok))
    for i, (amp, expected) in enumerate(BACKBONE):
        ys = np.asarray(res.ys[i])
        ratio = t0 / measured_period(np.asarray(ts), ys[:, 0], ys[:, 1])
        exact = t0 / _exact_period(amp)
        # Integration against the exact energy integral: tight.
        assert abs(ratio - exact) < 1e-9, (amp, ratio, exact)
        # Against physics.md's 4-digit values (half a unit of the last digit), and the
        # small-A series 1 - A^2/64 at A = 0.2 d0 (its O(A^4) remainder is 4e-6 there).
        assert abs(ratio - expected) < 5e-5, (amp, ratio, expected)
    # Amplitude A = d0 is exactly the separation amplitude; beyond it contact is lost.
    big = np.asarray(res.ys[-1])
    assert np.min(big[:, 0]) < -1.0 and np.max(big[:, 0]) > 1.0


def _one_sided_field(t, y, pair):
    """m x'' + k (d_s + x)+^1.5 = W with m = k = d_s = W = 1: one loaded half only."""
    return jnp.stack([y[1], 1.0 - physics.side_forces(y[0], pair)[0]])


def _exact_one_sided_ratio(amplitude):
    """w0 / w from the energy integral; `amplitude` is the excursion towards separation."""

    def potential(x):
        return 0.4 * max(1 + x, 0.0) ** 2.5 - x

    energy = potential(-amplitude)
    right = optimize.brentq(lambda x: potential(x) - energy, 1e-12, 10.0, xtol=1e-15)
    mid, half = 0.5 * (right - amplitude), 0.5 * (right + amplitude)

    def integrand(theta):
        x = mid + half * math.sin(theta)
        return half * math.cos(theta) / math.sqrt(2 * (energy - potential(x)))

    val, _ = sp_integrate.quad(integrand, -math.pi / 2, math.pi / 2, epsabs=1e-13,
                               epsrel=1e-13, limit=200)
    return (2 * math.pi / math.sqrt(1.5)) / (2 * val)


def test_backbone_of_one_sided_contact():
    """physics.md s5: w/w0 = 1 - (a/d_s)^2/24 for small a; 0.9531 at a = d_s."""
    pair = _unit_pair()
    w0 = math.sqrt(1.5)  # k_lin = 1.5 sqrt(d_s)
    t0 = 2 * math.pi / w0
    t_end = 12 * t0
    ts = jnp.linspace(0.0, t_end, 12 * 200 + 1)
    amplitudes = jnp.array([0.1, 1.0])
    y0 = jnp.stack([-amplitudes, jnp.zeros_like(amplitudes)], axis=-1)
    settings = SolverSettings(rtol=1e-12, atol=1e-14, max_steps=100_000)
    res = jax.vmap(jax.jit(lambda y: integrate(_one_sided_field, y, pair, 0.0, t_end, ts,
                                               settings)))(y0)
    assert np.all(np.asarray(res.ok))
    ratios = []
    for i in range(2):
        ys = np.asarray(res.ys[i])
        ratios.append(t0 / measured_period(np.asarray(ts), ys[:, 0], ys[:, 1]))
    assert abs(ratios[0] - _exact_one_sided_ratio(0.1)) < 1e-9
    assert abs(ratios[0] - (1 - 0.1**2 / 24)) < 1e-5  # leading-order series
    assert abs(ratios[1] - 0.9531) < 5e-5
    # At a = d_s the contact just reaches zero deformation at the extreme.
    np.testing.assert_allclose(np.min(np.asarray(res.ys[1])[:, 0]), -1.0, atol=1e-6)


# --------------------------------------------------------------------------------------
# 1(c) and 2. Curvature and the Hertz coefficient
# --------------------------------------------------------------------------------------
def _curvature(d, f, dm, angle, inner):
    """Harris's Sum(rho) and F(rho), written independently of the library."""
    g = d * math.cos(angle) / dm
    rho_ball = 2.0 / d
    rho_groove_circ = (2.0 / d) * g / (1 - g) if inner else -(2.0 / d) * g / (1 + g)
    rho_groove_axial = -1.0 / (f * d)
    total = 2 * rho_ball + rho_groove_circ + rho_groove_axial
    diff = (rho_ball - rho_ball + rho_groove_circ - rho_groove_axial) / total
    return total, diff


def _exact_hertz_k(d, f, dm, angle, inner, e=E_STEEL, nu=NU_STEEL):
    """Exact (elliptic-integral, Harris) per-contact K [m/N^(2/3)] of physics.md s3."""
    total, diff = _curvature(d, f, dm, angle, inner)

    def f_rho(k):
        m = 1 - 1 / k**2  # scipy's parameter m = e^2
        big_k, big_e = special.ellipk(m), special.ellipe(m)
        return ((k**2 + 1) * big_e - 2 * big_k) / ((k**2 - 1) * big_e)

    kappa = optimize.brentq(lambda k: f_rho(k) - diff, 1.0 + 1e-9, 1e3, xtol=1e-14)
    m = 1 - 1 / kappa**2
    big_k, big_e = special.ellipk(m), special.ellipe(m)
    delta_star = (2 * big_k / math.pi) * (math.pi / (2 * kappa**2 * big_e)) ** (1 / 3)
    e_prime = e / (1 - nu**2)
    return delta_star * (3 / (e_prime * total)) ** (2 / 3) * total / 2


def test_harris_209_curvature():
    d, dm, f = 12.7e-3, 65e-3, 0.52
    total, diff = physics.curvature_sum_and_difference(d, f, dm, 0.0, True)
    np.testing.assert_allclose(float(total) * 1e-3, 0.2018, atol=5e-5)  # 1/mm
    np.testing.assert_allclose(float(diff), 0.9400, atol=5e-5)
    own_total, own_diff = _curvature(d, f, dm, 0.0, True)
    np.testing.assert_allclose([float(total), float(diff)], [own_total, own_diff], rtol=1e-12)
    # The outer contact (no physics.md value, but the two implementations must agree).
    total_o, diff_o = physics.curvature_sum_and_difference(d, 0.52, dm, 0.3, False)
    np.testing.assert_allclose([float(total_o), float(diff_o)],
                               _curvature(d, 0.52, dm, 0.3, False), rtol=1e-12)


CONTACTS = [
    # (name, D, f, d_m, angle_deg, inner)
    ("nut/screw", 3.175e-3, 0.55, 25.5e-3, 45.0, True),
    ("nut/nut", 3.175e-3, 0.55, 25.5e-3, 45.0, False),
    ("bearing/inner", 7.938e-3, 0.52, 38.5e-3, 40.0, True),
    ("bearing/outer", 7.938e-3, 0.53, 38.5e-3, 40.0, False),
    ("harris209/inner", 12.7e-3, 0.52, 65e-3, 0.0, True),
    ("harris209/outer", 12.7e-3, 0.52, 65e-3, 0.0, False),
]


@pytest.mark.parametrize("name,d,f,dm,angle,inner", CONTACTS)
def test_hamrock_brewe_against_exact_hertz(name, d, f, dm, angle, inner):
    hb = float(physics.contact_coefficient(d, f, dm, math.radians(angle), E_STEEL, NU_STEEL,
                                           inner))
    exact = _exact_hertz_k(d, f, dm, math.radians(angle), inner)
    assert abs(hb / exact - 1) < 0.02, (name, hb, exact)


def test_default_hertz_coefficients_and_stiffness(cold_params, cold_system):
    k_n = float(model.nut_hertz_k(cold_params))
    k_b = float(model.bearing_hertz_k(cold_params))
    np.testing.assert_allclose(k_n, 3.78e-7, rtol=2e-3)
    np.testing.assert_allclose(k_b, 2.37e-7, rtol=2e-3)
    exact_n = (_exact_hertz_k(3.175e-3, 0.55, 25.5e-3, math.pi / 4, True)
               + _exact_hertz_k(3.175e-3, 0.55, 25.5e-3, math.pi / 4, False))
    exact_b = (_exact_hertz_k(7.938e-3, 0.52, 38.5e-3, math.radians(40), True)
               + _exact_hertz_k(7.938e-3, 0.53, 38.5e-3, math.radians(40), False))
    assert abs(k_n / exact_n - 1) < 0.02 and abs(k_b / exact_b - 1) < 0.02
    k_nut = float(jax.grad(physics.pair_force)(0.0, cold_system.nut))
    k_brg = float(jax.grad(physics.pair_force)(0.0, cold_system.bearing))
    np.testing.assert_allclose(k_nut / 1e6, 699.0, rtol=2e-3)  # N/um
    np.testing.assert_allclose(k_brg / 1e6, 447.0, rtol=2e-3)
    np.testing.assert_allclose(float(cold_system.screw_stiffness) / 1e6, 279.2, rtol=2e-3)


def test_default_natural_frequencies(cold_params):
    modes = bsfs.modes(cold_params)
    np.testing.assert_allclose(modes.frequencies_hz, [1165.0, 4884.0, 6360.0], rtol=5e-3)
    # Static stiffness at the nut: the three linearised springs in series.
    sys_ = bsfs.build_system(cold_params)
    k_n = float(jax.grad(physics.pair_force)(0.0, sys_.nut))
    k_b = float(jax.grad(physics.pair_force)(0.0, sys_.bearing))
    k_s = float(sys_.screw_stiffness)
    np.testing.assert_allclose(float(modes.static_stiffness), 1 / (1 / k_n + 1 / k_s + 1 / k_b),
                               rtol=1e-10)
    # Mass-normalised shapes: phi^T M phi = I.
    phi = np.asarray(modes.shapes)
    np.testing.assert_allclose(phi.T @ np.diag(np.asarray(modes.mass)) @ phi, np.eye(3),
                               atol=1e-10)


# --------------------------------------------------------------------------------------
# 3. Preload balance, symmetry and derivatives at contact loss (pure physics)
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["nut", "bearing"])
def test_preload_balance_at_zero(cold_system, warm_system, which):
    cold, warm = getattr(cold_system, which), getattr(warm_system, which)
    f_plus, f_minus = physics.side_forces(0.0, cold)
    np.testing.assert_allclose([float(f_plus), float(f_minus)], [PRELOAD, PRELOAD], rtol=1e-12)
    assert float(physics.pair_force(0.0, cold)) == 0.0
    # Thermal offsets (positive: reduce the deformation) lower the preload of both halves
    # equally; the net force at u = 0 stays exactly zero.
    assert float(warm.offset) > 0.0
    w_plus, w_minus = physics.side_forces(0.0, warm)
    assert float(w_plus) == float(w_minus) < PRELOAD
    assert float(physics.pair_force(0.0, warm)) == 0.0


@pytest.mark.parametrize("which", ["nut", "bearing"])
def test_pair_force_is_odd(warm_system, which):
    pair = getattr(warm_system, which)
    u_star = _contact_loss_u(pair)
    u = jnp.linspace(-3 * u_star, 3 * u_star, 61)
    np.testing.assert_allclose(physics.pair_force(-u, pair), -physics.pair_force(u, pair),
                               rtol=1e-12, atol=1e-12)
    # ...and monotone (a restoring force): stiffness positive everywhere.
    k = jax.vmap(jax.grad(physics.pair_force), in_axes=(0, None))(u, pair)
    assert np.all(np.asarray(k) > 0)


def _right_side(u, pair):
    return physics.side_forces(u, pair)[1]


_CONTACT_FUNCS = {"pair_force": physics.pair_force, "right_side": _right_side,
                  "potential": physics.pair_potential}


@jax.jit
def _all_derivatives(u, pair):
    """Value, 1st-3rd derivatives in u and the gradient wrt every pair field, per law."""
    out = {}
    for name, fn in _CONTACT_FUNCS.items():
        out[name] = [fn(u, pair), jax.grad(fn)(u, pair), jax.hessian(fn)(u, pair),
                     jax.grad(jax.hessian(fn))(u, pair), jax.grad(fn, argnums=1)(u, pair)]
    return out


@pytest.mark.parametrize("which", ["nut", "bearing"])
@pytest.mark.parametrize("shift", [-1e-9, 0.0, 1e-9])
def test_derivatives_finite_at_contact_loss(warm_system, which, shift):
    pair = getattr(warm_system, which)
    u = jnp.asarray(_contact_loss_u(pair) + shift)
    derivs = _all_derivatives(u, pair)
    for name, values in derivs.items():
        for leaf in jax.tree_util.tree_leaves(values):
            assert np.all(np.isfinite(np.asarray(leaf))), (name, shift)
    value, grad_u, _, _, grad_pair = derivs["right_side"]
    if shift > 0:  # unloaded side: zero force and zero gradient (wrt u and parameters)
        assert float(value) == 0.0 and float(grad_u) == 0.0
        assert all(float(jnp.max(jnp.abs(x))) == 0.0
                   for x in jax.tree_util.tree_leaves(grad_pair))
    if shift < 0:  # still loaded: positive force
        assert float(value) > 0.0


def test_pos_pow_at_zero():
    for x in (-1e-300, 0.0, 1e-300):
        for p in (1.5, 2.5):
            f = lambda x: physics.pos_pow(x, p)
            derivs = [f(x), jax.grad(f)(x), jax.grad(jax.grad(f))(x)]
            assert all(np.isfinite(float(v)) for v in derivs)
    assert float(jax.grad(lambda x: physics.pos_pow(x, 1.5))(0.0)) == 0.0


@pytest.mark.parametrize("which", ["nut", "bearing"])
def test_pair_force_gradient_across_contact_loss(warm_system, which):
    """AD stiffness dF/du against central differences below, at and above contact loss."""
    pair = getattr(warm_system, which)
    u_star = _contact_loss_u(pair)
    delta0 = float(pair.a - pair.a0)
    grad = jax.jit(jax.grad(physics.pair_force))
    force = jax.jit(physics.pair_force)
    for u in (0.5 * u_star, u_star - 1e-8, u_star, u_star + 1e-8, 1.5 * u_star):
        ad = float(grad(u, pair))
        fd = finite_difference(lambda x: force(x[0], pair), np.array([u]), scale=delta0)[0]
        assert abs(ad - fd) <= 1e-4 * abs(fd), (u / u_star, ad, fd)
    # The stiffness is continuous (C1 law): the unloading half's contribution vanishes.
    k_minus = jax.grad(lambda u: physics.side_forces(u, pair)[1])
    assert abs(float(k_minus(u_star - 1e-15))) < 1e-3 * abs(float(k_minus(0.0)))


@pytest.mark.parametrize("which", ["nut", "bearing"])
def test_fast_pair_force_is_the_same_law(warm_system, which):
    """The GPU kernel's form (`fast=True`: reciprocal square roots and products by
    reciprocals instead of divisions and square roots) against the correctly rounded
    default, over three contact-loss displacements each way: the same force to a few ulp
    of the force scale (5e-15 measured), the same stiffness to a few ulp of its scale
    (cancellation near contact loss: 2e-13 measured), zero where a side is unloaded."""
    pair = getattr(warm_system, which)
    u_star = _contact_loss_u(pair)
    u = jnp.linspace(-3.0 * u_star, 3.0 * u_star, 4001)
    exact = np.asarray(physics.pair_force(u, pair))
    fast = np.asarray(physics.pair_force(u, pair, fast=True))
    assert np.max(np.abs(fast - exact)) <= 1e-13 * np.max(np.abs(exact))
    k = lambda fast: np.asarray(jax.vmap(jax.grad(
        lambda x: physics.pair_force(x, pair, fast=fast)))(u))
    k_exact, k_fast = k(False), k(True)
    assert np.max(np.abs(k_fast - k_exact)) <= 1e-11 * np.max(np.abs(k_exact))
    sides = [np.asarray(x) for x in physics.side_forces(u, pair, fast=True)]
    assert np.all(sides[1][np.asarray(u) > u_star] == 0.0)
    assert np.all(sides[0][np.asarray(u) < -u_star] == 0.0)


# --------------------------------------------------------------------------------------
# 10. Thermal chain (physics.md section 4)
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("rpm,q_nut,h", [(1000, 25.0, 32.0), (2000, 50.0, 51.0),
                                         (3000, 75.0, 67.0)])
def test_heat_and_convection_examples(rpm, q_nut, h):
    torque = physics.nut_drag_torque(1500.0, 5e-3, 25.5e-3)
    np.testing.assert_allclose(float(physics.nut_heat(rpm, torque)), q_nut, rtol=0.01)
    # physics.md's h is rounded from slightly different air properties: within 3 %.
    h_forced = float(physics.shaft_convection_coefficient(rpm, 25e-3, 0.0))
    np.testing.assert_allclose(h_forced, h, rtol=0.03)


def test_drag_torque_and_palmgren_continuity():
    # K_p = 0.05 / sqrt(tan(lambda)) ~ 0.2 for 25x5 (physics.md s4); T_d ~ 0.24 N m at 1500 N.
    torque = float(physics.nut_drag_torque(1500.0, 5e-3, 25.5e-3))
    k_p = torque * 2 * math.pi / (1500.0 * 5e-3)
    assert 0.18 < k_p < 0.22
    # The Palmgren M0 branches meet at nu n = 2000 within 1 %.
    below = float(physics.palmgren_torque(2000 / 22 * (1 - 1e-9), 22.0, 38.5e-3, 0.0, 1e4, 2.0))
    above = float(physics.palmgren_torque(2000 / 22, 22.0, 38.5e-3, 0.0, 1e4, 2.0))
    assert abs(above / below - 1) < 0.01


def test_thermal_chain_speed_dependence():
    params = bsfs.preset()
    speeds = [0.0, 500.0, 1000.0, 2000.0, 3000.0]
    states = [model.thermal_state(params.replace("thermal.speed_rpm", n)) for n in speeds]
    rises = np.array([np.asarray(s.temperature_rise_k) for s in states])
    offsets = np.array([[float(s.nut_offset), float(s.bearing_offset)] for s in states])
    np.testing.assert_allclose(rises[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(offsets[0], 0.0, atol=1e-18)
    np.testing.assert_allclose(np.asarray(states[0].heat_w), 0.0, atol=1e-12)
    assert np.all(np.diff(rises, axis=0) > 0)
    assert np.all(np.diff(offsets, axis=0) > 0)
    # Offsets follow D = gamma d (T - T0) (Eqs. 11, 23).
    np.testing.assert_allclose(offsets[3], [11.6e-6 * 3.175e-3 * rises[3, 2],
                                            11.6e-6 * 7.938e-3 * rises[3, 0]], rtol=1e-12)
    # physics.md: reported rises about 5-20 K; a lumped upper estimate 9-28 K.
    assert 3.0 < rises[2].max() < 30.0 and rises[4].max() < 40.0
    # Thermal off: offsets zero, temperatures still reported.
    cold = model.thermal_state(params.replace("thermal.enabled", False))
    assert float(cold.nut_offset) == 0.0 and float(cold.bearing_offset) == 0.0
    np.testing.assert_allclose(cold.temperature_rise_k, rises[3], rtol=1e-12)
    # Explicit offsets override the thermal model.
    fixed = model.thermal_state(params.replace("thermal.nut_offset_um", 0.3671))
    np.testing.assert_allclose(float(fixed.nut_offset), 0.3671e-6, rtol=1e-12)


def test_thermal_chain_gradients_finite_at_rest():
    """d(offsets)/d(speed) is finite at standstill and positive when running."""
    params = bsfs.preset()

    @jax.jit
    def offsets(rpm):
        state = model.thermal_state(params.replace("thermal.speed_rpm", rpm))
        return jnp.stack([state.nut_offset, state.bearing_offset])

    jac = jax.jacfwd(offsets)
    at_rest = np.asarray(jac(jnp.asarray(0.0)))
    running = np.asarray(jac(jnp.asarray(1000.0)))
    assert np.all(np.isfinite(at_rest)) and np.all(running > 0)
    fd = (np.asarray(offsets(jnp.asarray(1000.0 + 1e-3)))
          - np.asarray(offsets(jnp.asarray(1000.0 - 1e-3)))) / 2e-3
    np.testing.assert_allclose(running, fd, rtol=1e-6)


def test_transient_temperature_rise():
    state = model.thermal_state(bsfs.preset())
    g, c = state.conductance, state.capacity
    heat = jnp.stack([state.heat_w[0], 0.0, state.heat_w[1]])
    steady = physics.steady_temperature_rise(g, heat)
    np.testing.assert_allclose(steady, state.temperature_rise_k, rtol=1e-12)
    slowest = float(1.0 / jnp.min(jnp.linalg.eigvals(jnp.linalg.solve(jnp.diag(c), g)).real))
    times = jnp.linspace(0.0, 30 * slowest, 301)
    rise = physics.transient_temperature_rise(times, g, c, heat)
    np.testing.assert_allclose(rise[0], 0.0, atol=1e-10)
    np.testing.assert_allclose(rise[-1], steady, rtol=1e-9)
    # Heating from ambient: every node rises monotonically towards the steady state.
    assert np.all(np.diff(np.asarray(rise), axis=0) >= -1e-12)
    # It solves C dT/dt = Q - G T (checked by AD in time at a few instants).
    one = lambda t: physics.transient_temperature_rise(t[None], g, c, heat)[0]
    for t in (0.0, slowest, 5 * slowest):
        t = jnp.asarray(t)
        lhs = c * jax.jacfwd(one)(t)
        rhs = heat - g @ one(t)
        np.testing.assert_allclose(lhs, rhs, atol=1e-9 * float(jnp.max(heat)))


def test_eqx_module_pair_is_pytree():
    """PreloadedPair is a pytree of arrays, so it can cross jit/vmap boundaries."""
    pair = _pair_at(45.0)
    leaves = jax.tree_util.tree_leaves(pair)
    assert len(leaves) >= 7 and all(eqx.is_array(x) for x in leaves)
    batched = jax.vmap(lambda p: physics.pair_force(1e-6, p))(
        jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), pair))
    np.testing.assert_allclose(batched, physics.pair_force(1e-6, pair), rtol=1e-14)


def test_closed_form_3x3_solve_equals_lapack():
    """The thermal network and the static stiffness use Cramer's rule (`_numerics`), not an
    LU: it must equal numpy's LAPACK solve and inverse on well-conditioned 3 x 3 systems,
    the thermal conductance matrix among them."""
    from bsfs_jax._numerics import cofactors_3x3, solve_3x3
    from bsfs_jax.physics import conductance_matrix

    rng = np.random.default_rng(3)
    mats = [rng.normal(size=(3, 3)) + 3 * np.eye(3) for _ in range(20)]
    mats.append(np.asarray(conductance_matrix(0.8, 1.3, 0.2, 0.5, 0.4)))
    for a in mats:
        b = rng.normal(size=3)
        x = np.asarray(solve_3x3(a, b))
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-12, atol=1e-14)
        c, det = cofactors_3x3(a)
        np.testing.assert_allclose(float(det), np.linalg.det(a), rtol=1e-12)
        np.testing.assert_allclose(np.asarray(c).T / float(det), np.linalg.inv(a), rtol=1e-11,
                                   atol=1e-14)
