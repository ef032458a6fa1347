"""The fused Dormand-Prince fast path agrees with diffrax and reports failures the same way."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax as bsfs
from bsfs_jax.solvers import RESULTS, SolverError, SolverSettings, integrate


def _duffing(t, y, args):
    delta, alpha, beta, gamma, omega = args
    x, v = y[0], y[1]
    return jnp.stack([v, gamma * jnp.cos(omega * t) - delta * v - alpha * x - beta * x**3])


ARGS = (0.2, 1.0, 1.0, 0.5, 1.2)


def test_fused_matches_diffrax_on_duffing():
    ts = jnp.linspace(0.0, 30.0, 61)
    tight = SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8")
    ref = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts, tight)
    fused = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts,
                      SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri5-fused"))
    assert bool(fused.result == RESULTS.successful) and bool(fused.ok)
    np.testing.assert_allclose(fused.ys, ref.ys, rtol=0, atol=1e-8)
    # save times are hit exactly, including t0
    np.testing.assert_allclose(fused.ys[0], [0.1, 0.0])


def test_fused_matches_diffrax_on_bsfs_with_contact_loss():
    params = bsfs.preset("default")
    kw = dict(frequency_hz=900.0, force_n=5000.0, periods=3, transient_periods=5,
              samples_per_period=16, rtol=1e-10, atol=1e-14)
    a = bsfs.simulate(params, solver="dopri5-fused", **kw)
    b = bsfs.simulate(params, solver="tsit5", **kw)
    scale = float(jnp.max(jnp.abs(b.displacement)))
    assert float(jnp.max(jnp.abs(a.displacement - b.displacement))) < 1e-6 * scale
    assert float(jnp.max(jnp.abs(b.joint_force[:, 2]))) > 4243.0  # a nut half unloads


def test_fused_forward_mode_and_vmap():
    ts = jnp.linspace(0.0, 5.0, 6)
    settings = SolverSettings(rtol=1e-10, atol=1e-12, solver="dopri5-fused")

    def final_x(gamma, solver_settings):
        args = (0.2, 1.0, 1.0, gamma, 1.2)
        return integrate(_duffing, jnp.array([0.0, 0.0]), args, 0.0, 5.0, ts,
                         solver_settings).ys[-1, 0]

    g = jax.jacfwd(final_x)(0.5, settings)
    ref = jax.grad(final_x)(0.5, SolverSettings(rtol=1e-10, atol=1e-12, solver="tsit5"))
    assert float(g) == pytest.approx(float(ref), rel=1e-6)
    batch = jax.vmap(lambda gm: final_x(gm, settings))(jnp.array([0.3, 0.5, 0.7]))
    assert float(batch[1]) == pytest.approx(float(final_x(0.5, settings)), rel=1e-12)


def test_fused_reports_max_steps_and_nan():
    ts = jnp.linspace(0.0, 30.0, 4)
    res = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts,
                    SolverSettings(max_steps=10, solver="dopri5-fused"), throw=False)
    assert bool(res.result == RESULTS.max_steps_reached) and not bool(res.ok)
    assert bool(jnp.all(jnp.isnan(res.ys)))
    ref = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts,
                    SolverSettings(max_steps=10, solver="tsit5"), throw=False)
    assert bool(ref.result == RESULTS.max_steps_reached)


@pytest.mark.parametrize("solver", ["dopri5-fused", "tsit5"])
def test_concrete_failure_raises_with_cause_and_settings(solver):
    """throw=True (the default) raises on a concrete failure; under jit nothing is raised."""
    ts = jnp.linspace(0.0, 30.0, 4)
    settings = SolverSettings(max_steps=10, solver=solver)
    with pytest.raises(SolverError, match=f"maximum number of solver steps.*solver={solver}"):
        integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts, settings)
    with pytest.raises(SolverError, match="not finite"):
        integrate(_duffing, jnp.array([jnp.nan, 0.0]), ARGS, 0.0, 30.0, ts,
                  SolverSettings(max_steps=100, solver=solver))
    traced = jax.jit(lambda y0: integrate(_duffing, y0, ARGS, 0.0, 30.0, ts, settings))
    assert bool(traced(jnp.array([0.1, 0.0])).result == RESULTS.max_steps_reached)


def test_fused_dopri8_matches_diffrax_and_a_closed_form():
    """The 8(7) loop (shooting's integrator) takes diffrax's Dopri8 steps: the same states
    to the tolerance, about as many steps, and the damped oscillator's closed form."""
    ts = jnp.linspace(0.0, 30.0, 61)
    tight = dict(rtol=1e-11, atol=1e-13)
    ref = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts,
                    SolverSettings(solver="dopri8", **tight))
    fused = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts[-1:],
                      SolverSettings(solver="dopri8-fused", **tight))
    assert bool(fused.ok)
    np.testing.assert_allclose(fused.ys[-1], ref.ys[-1], rtol=0, atol=1e-9)
    one = integrate(_duffing, jnp.array([0.1, 0.0]), ARGS, 0.0, 30.0, ts[-1:],
                    SolverSettings(solver="dopri8", **tight))
    assert abs(int(fused.num_steps) - int(one.num_steps)) <= 0.1 * int(one.num_steps)

    zeta, wn = 0.05, 3.0  # x'' + 2 zeta wn x' + wn^2 x = 0, x(0) = 1, x'(0) = 0
    wd = wn * np.sqrt(1 - zeta**2)
    t = np.linspace(0.0, 10.0, 11)
    lin = integrate(lambda t, y, a: jnp.stack([y[1], -2 * zeta * wn * y[1] - wn**2 * y[0]]),
                    jnp.array([1.0, 0.0]), None, 0.0, 10.0, jnp.asarray(t),
                    SolverSettings(solver="dopri8-fused", **tight))
    exact = np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    np.testing.assert_allclose(lin.ys[:, 0], exact, rtol=0, atol=1e-10)


def test_fused_dopri8_derivatives():
    """jvp through the 8(7) loop gives the flow's Jacobian (the variational equations
    integrated tightly by diffrax), with the step sizes held; reverse mode runs diffrax's
    Dopri8 instead of the loop (which has no reverse mode)."""
    import diffrax as dfx

    from bsfs_jax.solvers._shooting import variational_monodromy

    y0 = jnp.array([0.1, 0.0])
    fused = SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8-fused")

    def end(y):
        return integrate(_duffing, y, ARGS, 0.0, 10.0, jnp.array([10.0]), fused).ys[0]

    jac = jax.jacfwd(end)(y0)
    ref = variational_monodromy(_duffing, y0, ARGS, 10.0, 1,
                                SolverSettings(rtol=1e-13, atol=1e-15, solver="dopri8"))
    np.testing.assert_allclose(jac, ref, rtol=0, atol=1e-8 * float(jnp.max(jnp.abs(ref))))

    def end_x(gamma):
        args = (0.2, 1.0, 1.0, gamma, 1.2)
        return integrate(_duffing, y0, args, 0.0, 10.0, jnp.array([10.0]), fused,
                         adjoint=dfx.RecursiveCheckpointAdjoint()).ys[0, 0]

    g_rev = jax.grad(end_x)(0.5)
    g_fwd = jax.jacfwd(lambda gm: integrate(_duffing, y0, (0.2, 1.0, 1.0, gm, 1.2), 0.0, 10.0,
                                            jnp.array([10.0]), fused).ys[0, 0])(0.5)
    assert float(g_rev) == pytest.approx(float(g_fwd), rel=1e-7)
