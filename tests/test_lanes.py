"""The per-lane integrator kernel (`solvers.integrate_lanes`, Pallas), in interpret mode.

On a CPU the kernel runs through Pallas' interpreter, the same kernel body that Triton
compiles on a GPU (the GPU figures are in BENCHMARKS.md). Checked against the fused loop
it replaces, a closed form, the solver's failure codes, and the sweep engines.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax import preset
from bsfs_jax.analysis import SweepConfig, bsfs_problem, sweep
from bsfs_jax.model import kernel_vector_field, vector_field_components
from bsfs_jax.solvers import RESULTS, SolverSettings, integrate, integrate_lanes, result_codes
from tests.conftest import use_xla_default_code

ROOT = Path(__file__).resolve().parents[1]
TOL = dict(rtol=1e-8, atol=1e-12)
# XLA's own CPU code generation for this file (tests/conftest.py otherwise turns the CPU
# compiler's newer fusion emitters off for the suite): the kernel runs here through Pallas'
# interpreter as a stand-in for the GPU kernel, on which XLA's CPU options have no effect,
# and its comparisons with the fused loop (step counts to a few per mille, the looped
# stages to rounding) were measured against XLA's default CPU code. Under the other
# emitters every program rounds differently, and the fused loop's own step count on the
# 4000 Hz lane moves by 0.5 % (1662 -> 1670 steps), the kernel's the other way (1668 ->
# 1653). Possible while jax has not started its backend: `make test` runs this file in a
# process of its own; in one pytest process with other files, one of them may have
# computed already.
XLA_DEFAULT_CODE = pytest.mark.skipif(
    not use_xla_default_code(),
    reason="measured against XLA's default CPU code: run this file in its own process "
           "(`make test` does)")


@pytest.fixture(scope="module")
def problem():
    return bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)


def _lanes_setup(problem, freqs):
    args, periods = jax.vmap(lambda v: problem.setup(problem.data, v))(jnp.asarray(freqs))
    return args, jnp.asarray(periods, dtype=float)


def _fused_point(problem, args, period, t_rec, n_samples, spp, rtol, atol):
    """The fused loop's two runs (transient, then the record), as the sweep makes them."""
    st = SolverSettings(rtol=rtol, atol=atol, max_steps=10**6, solver="dopri5-fused")
    r1 = integrate(problem.vector_field, jnp.zeros(6), args, 0.0, t_rec, jnp.stack([t_rec]), st)
    ts = t_rec + period * jnp.arange(1, n_samples + 1, dtype=float) / spp
    r2 = integrate(problem.vector_field, r1.ys[-1], args, t_rec, ts[-1], ts, st)
    return r1.ys[-1], r2.ys, int(r1.num_steps + r2.num_steps)


@XLA_DEFAULT_CODE
def test_kernel_matches_the_fused_loop_on_the_ball_screw(problem):
    """Five lanes in blocks of 4 (one block padded): the same method and controller as the
    fused loop, so the same step counts to a few per mille and samples within the
    integrator's own error; both against a run at rtol 1e-12."""
    freqs = np.array([900.0, 1500.0, 2500.0, 4000.0, 3000.0])
    args, periods = _lanes_setup(problem, freqs)
    n_tr, P, spp = 10, 4, 4
    start, samples, end, codes, steps = integrate_lanes(
        vector_field_components, jnp.zeros((5, 6)), args, n_tr * periods, periods,
        n_samples=P * spp, samples_per_period=spp, max_steps=10**6, block=4,
        backend="interpret", **TOL)
    assert np.all(np.asarray(codes) == int(result_codes(RESULTS.successful)))
    for i in range(5):
        a, per = jax.tree_util.tree_map(lambda x: x[i], (args, periods))
        y1, ys, n = _fused_point(problem, a, per, n_tr * per, P * spp, spp, **TOL)
        _, ref, _ = _fused_point(problem, a, per, n_tr * per, P * spp, spp, 1e-12, 1e-16)
        scale = np.max(np.abs(np.asarray(ref)), axis=0)
        err_kernel = np.max(np.abs(np.asarray(samples[i]) - ref) / scale)
        err_fused = np.max(np.abs(np.asarray(ys) - ref) / scale)
        assert err_kernel < 5e-6 and err_kernel < 5 * err_fused + 1e-7, (freqs[i], err_kernel,
                                                                          err_fused)
        assert np.max(np.abs(np.asarray(samples[i]) - ys) / scale) < 5e-6
        np.testing.assert_allclose(np.asarray(start[i]), np.asarray(y1),
                                   atol=5e-6 * float(np.max(scale)))
        np.testing.assert_array_equal(np.asarray(end[i]), np.asarray(samples[i, -1]))
        assert abs(int(steps[i]) - n) <= 0.01 * n, (int(steps[i]), n)


def test_kernel_field_and_controller_are_the_fused_loops_to_rounding(problem):
    """What the kernel engine runs beside the fused loop's arithmetic: the vector field's
    fast form at random states (contact loss included) to a few ulp of each component's
    scale, and the controller's float32 power to 1e-6 of the next step over 28 decades of
    the error norm."""
    from bsfs_jax.solvers._fused import controller

    rng = np.random.default_rng(7)
    ys = rng.normal(size=(2000, 6)) * np.array([2e-6, 2e-6, 4e-6, 0.05, 0.05, 0.1])
    t = jnp.asarray(rng.uniform(0.0, 1.0, 2000))
    (system, forcing), _ = problem.setup(problem.data, 800.0)
    # The force law: the same forcing on both sides (its fast form is checked below).
    args = (system, lambda t: forcing(t))
    exact = np.stack(vector_field_components(t, tuple(jnp.asarray(ys).T), args))
    fast = np.stack(kernel_vector_field(t, tuple(jnp.asarray(ys).T), args))
    scale = np.max(np.abs(exact), axis=1, keepdims=True)
    assert np.max(np.abs(fast - exact) / scale) < 1e-13
    # The forcing's branch-free sine: a few ulp of the amplitude from the sine of its own
    # float64 phase in turns (f t + phase / 2 pi) in extended precision, and within the
    # rounding of the argument (f t up to 2400 turns) of jnp.sin's form.
    ts = np.concatenate([np.asarray(t), rng.uniform(0.0, 3.0, 2000)])
    turns = float(forcing.frequency) * ts + float(forcing.phase) * (0.5 / np.pi)
    ref = float(forcing.amplitude) * np.sin(2 * np.pi * np.mod(turns.astype(np.longdouble), 1))
    amp = float(forcing.amplitude)
    fast_force = np.asarray(forcing.fast(jnp.asarray(ts)))
    assert np.max(np.abs(fast_force - ref)) / amp < 1e-15
    assert np.max(np.abs(fast_force - np.asarray(forcing(jnp.asarray(ts))))) / amp < 1e-11
    # The controller: the fast form takes the squared norm; its float32 power is within
    # 1e-6 of the next step over 28 decades of the error norm.
    en = jnp.logspace(-14.0, 14.0, 2001)
    step = lambda e, fast: np.asarray(controller(e, jnp.isfinite(e), 1.0, 1.0, False,
                                                 fast)[1])
    assert np.max(np.abs(step(en * en, True) / step(en, False) - 1.0)) < 1e-6


def _oscillator(t, y, args):
    """x'' + 2 zeta w0 x' + w0^2 x = f0 cos(omega t), on components."""
    zeta, w0, f0, omega = args
    return y[1], f0 * jnp.cos(omega * t) - 2.0 * zeta * w0 * y[1] - w0 * w0 * y[0]


def test_kernel_follows_the_closed_form_steady_state_of_a_linear_oscillator():
    """Lanes started on the closed-form steady state stay on it (an independent answer)."""
    zeta = jnp.array([0.05, 0.02, 0.1])
    w0 = jnp.array([1.0, 2.0, 3.0])
    omega = jnp.array([1.3, 1.0, 2.5])
    f0 = jnp.ones(3)
    h = f0 / (w0 * w0 - omega * omega + 2j * zeta * w0 * omega)
    y0 = jnp.stack([jnp.real(h), jnp.real(1j * omega * h)], axis=1)
    period = 2 * jnp.pi / omega
    spp, P = 8, 3
    _, samples, _, codes, _ = integrate_lanes(
        _oscillator, y0, (zeta, w0, f0, omega), 5 * period, period, n_samples=P * spp,
        samples_per_period=spp, max_steps=10**5, block=32, backend="interpret",
        rtol=1e-10, atol=1e-13)
    assert np.all(np.asarray(codes) == 0)
    t = 5 * period[:, None] + period[:, None] * (jnp.arange(1, P * spp + 1) / spp)[None, :]
    x = jnp.real(h[:, None] * jnp.exp(1j * omega[:, None] * t))
    np.testing.assert_allclose(np.asarray(samples[:, :, 0]), np.asarray(x),
                               atol=1e-7 * float(jnp.max(jnp.abs(h))))


def test_kernel_unrolled_steps_give_the_same_lanes_bit_for_bit():
    """`unroll` steps per test of the loop's condition: lanes that finish inside an
    unrolled body stay put, so every output equals the plain loop's exactly (fast
    controller; lanes of different step counts in one block, one with a NaN start)."""
    args = (jnp.array([0.05, 0.02, 0.1]), jnp.array([1.0, 2.0, 3.0]), jnp.ones(3),
            jnp.array([1.3, 1.0, 2.5]))
    y0 = jnp.array([[0.1, 0.0], [0.0, 0.2], [jnp.nan, 0.0]])
    period = 2 * jnp.pi / args[3]
    run = lambda unroll: integrate_lanes(
        _oscillator, y0, args, 7 * period, period, n_samples=5, samples_per_period=2,
        max_steps=10**5, block=4, backend="interpret", fast=True, unroll=unroll, **TOL)
    one, three = run(1), run(3)
    codes, steps = np.asarray(one[3]), np.asarray(one[4])
    assert codes[0] == codes[1] == 0 and codes[2] == int(result_codes(RESULTS.invalid_input))
    assert steps[0] != steps[1]
    for a, b in zip(one, three):  # a failed lane's states are undefined: not compared
        a, b = np.asarray(a), np.asarray(b)
        keep = slice(None) if a.ndim == 1 else slice(0, 2)
        np.testing.assert_array_equal(a[keep], b[keep])


@XLA_DEFAULT_CODE
def test_kernel_looped_stages_are_the_unrolled_method_to_rounding(problem):
    """`looped=True` (the step's stages as a loop, the field inlined once; the restart
    takes the last stage, first same as last): on the ball screw the same step counts to
    a few steps and samples to within the tolerance's reach of the unrolled kernel's
    (the stages' sums are the same terms, only rounded in another order)."""
    freqs = np.array([900.0, 3000.0])
    args, periods = _lanes_setup(problem, freqs)
    run = lambda looped: integrate_lanes(
        vector_field_components, jnp.zeros((2, 6)), args, 6 * periods, periods,
        n_samples=8, samples_per_period=4, max_steps=10**6, block=2, backend="interpret",
        fast=True, looped=looped, **TOL)
    a, b = run(False), run(True)
    assert np.all(np.asarray(a[3]) == 0) and np.all(np.asarray(b[3]) == 0)
    steps_a, steps_b = np.asarray(a[4]), np.asarray(b[4])
    assert np.all(np.abs(steps_a - steps_b) <= 0.01 * steps_a), (steps_a, steps_b)
    scale = np.max(np.abs(np.asarray(a[1])), axis=1, keepdims=True)
    assert np.max(np.abs(np.asarray(b[1]) - np.asarray(a[1])) / scale) < 1e-6
    np.testing.assert_allclose(np.asarray(b[0]), np.asarray(a[0]), rtol=0,
                               atol=1e-6 * float(np.max(scale)))


def test_kernel_lanes_stop_at_their_own_sample_counts():
    """`lane_samples`: a lane stops after its own first samples, which are the full run's
    bit for bit (the same steps up to there), in fewer steps; the start is unchanged."""
    args = (jnp.array([0.05, 0.02]), jnp.array([1.0, 2.0]), jnp.ones(2),
            jnp.array([1.3, 1.0]))
    y0 = jnp.array([[0.1, 0.0], [0.0, 0.2]])
    period = 2 * jnp.pi / args[3]
    run = lambda **kw: integrate_lanes(
        _oscillator, y0, args, 3 * period, period, n_samples=6, samples_per_period=2,
        max_steps=10**5, block=2, backend="interpret", fast=True, **TOL, **kw)
    full, short = run(), run(lane_samples=jnp.array([2, 6]))
    np.testing.assert_array_equal(np.asarray(short[0]), np.asarray(full[0]))
    np.testing.assert_array_equal(np.asarray(short[1])[0, :2], np.asarray(full[1])[0, :2])
    np.testing.assert_array_equal(np.asarray(short[1])[1], np.asarray(full[1])[1])
    steps_full, steps_short = np.asarray(full[4]), np.asarray(short[4])
    assert steps_short[0] < steps_full[0] and steps_short[1] == steps_full[1]
    np.testing.assert_array_equal(np.asarray(short[3]), 0)


def test_kernel_reports_failures_per_lane_and_leaves_the_others_alone():
    """A lane out of steps and a lane with a NaN start get their `RESULTS` codes; a good
    lane of the same block gives what it gives alone."""
    args = (jnp.array([0.05, 0.05, 0.05]), jnp.ones(3), jnp.ones(3), jnp.ones(3))
    y0 = jnp.array([[0.1, 0.0], [0.1, 0.0], [jnp.nan, 0.0]])
    period = jnp.full(3, 2 * jnp.pi)
    run = lambda y, a, max_steps: integrate_lanes(
        _oscillator, y, a, 50 * period[: y.shape[0]], period[: y.shape[0]], n_samples=4,
        samples_per_period=2, max_steps=max_steps, backend="interpret", **TOL)
    _, samples, _, codes, steps = run(y0, args, 10**5)
    codes = np.asarray(codes)
    assert codes[0] == int(result_codes(RESULTS.successful))
    assert codes[2] == int(result_codes(RESULTS.invalid_input))
    alone = run(y0[:1], jax.tree_util.tree_map(lambda a: a[:1], args), 10**5)
    np.testing.assert_array_equal(np.asarray(samples[0]), np.asarray(alone[1][0]))
    _, _, _, codes, steps = run(y0[:2], jax.tree_util.tree_map(lambda a: a[:2], args), 50)
    assert np.all(np.asarray(codes) == int(result_codes(RESULTS.max_steps_reached)))
    assert np.all(np.asarray(steps) == 50)


def test_kernel_refuses_args_without_a_lane_axis():
    with pytest.raises(ValueError, match="leading axis of 3 lanes"):
        integrate_lanes(_oscillator, jnp.zeros((3, 2)), (1.0, jnp.ones(3), jnp.ones(3),
                                                         jnp.ones(3)),
                        jnp.ones(3), jnp.ones(3), n_samples=1, samples_per_period=1,
                        max_steps=10, backend="interpret", **TOL)


def test_sweep_kernel_engine_gives_the_map_engines_answers(problem):
    """`SweepConfig(engine="kernel")` against the vmapped fused loop, with per-point
    transients (as the verifier's sampling runs use)."""
    freqs = np.array([800.0, 1200.0, 2000.0, 3500.0])
    kw = dict(transient_periods=20, periods=4, samples_per_period=8, lyapunov=False,
              chunk_size=8, kernel_block=4)
    out = {e: sweep(problem, freqs, config=SweepConfig(engine=e, **kw), progress=False,
                    transient=np.array([12, 20, 16, 30]))
           for e in ("map", "kernel")}
    a, b = out["map"], out["kernel"]
    amp = np.asarray(a.amplitude)
    assert np.max(np.abs(np.asarray(b.amplitude) - amp) / amp.max(axis=-2)) < 5e-6
    assert np.nanmax(np.abs(np.asarray(b.strobe) - np.asarray(a.strobe))) < \
        5e-6 * np.nanmax(np.abs(np.asarray(a.strobe)))
    np.testing.assert_array_equal(np.asarray(b.failed), False)
    steps_a, steps_b = np.asarray(a.num_steps), np.asarray(b.num_steps)
    assert np.all(np.abs(steps_b - steps_a) <= 0.01 * steps_a)


def test_engine_choice(problem):
    cfg = SweepConfig(lyapunov=False)
    assert cfg.engine == "auto"
    expected = "kernel" if jax.default_backend() == "gpu" else "map"
    assert problem.resolved_engine(cfg) == expected
    assert problem.resolved_engine(SweepConfig(lyapunov=True)) == "map"
    with pytest.raises(ValueError, match="lyapunov off"):
        problem.resolved_engine(SweepConfig(engine="kernel", lyapunov=True))
    with pytest.raises(ValueError, match="engine must be one of"):
        SweepConfig(engine="warp")


def test_cli_sweep_with_the_kernel_engine(tmp_path, capsys):
    from bsfs_jax.cli import main

    out = tmp_path / "sweep"
    rc = main(["sweep", "--start", "2000", "--stop", "3000", "--num", "2", "--engine",
               "kernel", "--transient", "20", "--periods", "4", "--no-verify",
               "--no-progress", "--out", str(out)])
    assert rc == 0 and (out / "sweep.nc").exists()
    rc = main(["sweep", "--start", "2000", "--stop", "3000", "--num", "2", "--engine",
               "kernel", "--lyapunov", "--out", str(tmp_path / "no")])
    assert rc != 0 and not (tmp_path / "no").exists()
    assert "--engine kernel does not integrate the tangent dynamics" in capsys.readouterr().err


def test_kernel_engine_sharded_over_host_devices():
    """A sharded cold sweep (two CPU devices, `jax.shard_map`) runs the kernel on each
    device's points and gives the unsharded answer."""
    code = textwrap.dedent("""
        import numpy as np, jax
        jax.config.update("jax_enable_x64", True)
        from bsfs_jax import preset
        from bsfs_jax.analysis import SweepConfig, bsfs_problem, sweep
        assert len(jax.devices()) == 2
        p = bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)
        cfg = SweepConfig(transient_periods=10, periods=2, samples_per_period=4,
                          lyapunov=False, engine="kernel", chunk_size=4, kernel_block=2)
        f = np.array([1500.0, 2000.0, 2500.0, 3000.0])
        a = sweep(p, f, config=cfg, progress=False, shard=True)
        b = sweep(p, f, config=cfg, progress=False)
        assert a.metadata["sharded_over_devices"] == 2, a.metadata["sharded_over_devices"]
        # Not bit-equal: the two programs round differently (XLA fuses them differently),
        # and the step-size controller amplifies rounding to the integrator's error level.
        sa, sb = np.asarray(a.strobe), np.asarray(b.strobe)
        assert np.max(np.abs(sa - sb)) < 5e-6 * np.max(np.abs(sb)), np.max(np.abs(sa - sb))
        na, nb = np.asarray(a.num_steps), np.asarray(b.num_steps)
        assert np.all(np.abs(na - nb) <= 0.02 * nb), (na, nb)
        print("OK")
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=600)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]


def _duffing_components(t, y, args):
    """x'' + delta x' + alpha x + beta x^3 = gamma cos(omega t) on components."""
    delta, alpha, beta, gamma, omega = args
    x, v = y
    return v, gamma * jnp.cos(omega * t) - delta * v - alpha * x - beta * x * x * x


def _gamma_setup(data, gamma):
    return (data[0], data[1], data[2], gamma, data[3]), 2.0 * jnp.pi / data[3]


@pytest.fixture(scope="module")
def duffing_problem():
    from bsfs_jax.analysis import SweepProblem
    from tests.textbook import duffing

    return SweepProblem(duffing, _gamma_setup, jnp.array([0.3, -1.0, 1.0, 1.2]),
                        jnp.array([1.0, 0.0]), "gamma", component_field=_duffing_components)


#: Holmes-Duffing at gamma 0.20 (period 1) and 0.28 (period 2), after 60 periods.
_GAMMAS = np.array([0.20, 0.28])
_DUFFING_CFG = dict(transient_periods=60, periods=8, samples_per_period=16, lyapunov=False,
                    chunk_size=2, kernel_block=2)


def test_orbit_checks_on_the_kernel_are_the_vmapped_checks(duffing_problem):
    """`check_orbits_lanes` (every integration on the per-lane kernel: the variational
    equations one column of the monodromy matrix per lane, chord iterations, samples)
    against `check_orbits` (vmapped fused loops) from the same sampled states, n = 1 and
    2: the same orbits, iterations and multipliers to the checks' accuracy (~1e-6), and a
    monodromy matrix no further from one integrated at rtol 1e-12 than the vmapped
    checks' (at the checks' own tolerances the columns' lanes were 2.4x further)."""
    import dataclasses

    from bsfs_jax.analysis._orbit_trials import scale_of
    from bsfs_jax.solvers import CHECK_SETTINGS, check_orbits, check_orbits_lanes

    p = duffing_problem
    res = sweep(p, _GAMMAS, config=SweepConfig(
        settings=SolverSettings(solver="dopri5-fused", **TOL), **_DUFFING_CFG),
        progress=False)
    y = np.asarray(res.strobe)[0, :, -1]
    scale = np.array([scale_of(a, s) for a, s in zip(np.asarray(res.amplitude)[0], y)])
    n = np.array([1, 2])
    # The layout the verifier's call in the next test uses (2 lanes, blocks of 2, 32
    # samples a period, the kernel engine's fast controller): one program for both.
    kw = dict(max_period=2, samples_per_period=32)
    a = check_orbits(p.vector_field, p.setup, p.data, _GAMMAS, y, scale, n, **kw)
    b = check_orbits_lanes(p.component_field, p.setup, p.data, _GAMMAS, y, scale, n,
                           block=2, fast=True, **kw)
    assert np.asarray(b.converged).all() and np.asarray(a.converged).all()
    np.testing.assert_array_equal(np.asarray(b.steps), np.asarray(a.steps))
    amp = np.nanmax(np.abs(np.asarray(a.samples)), axis=1)  # (B, d); NaN past n T
    np.testing.assert_allclose(np.asarray(b.state), np.asarray(a.state), rtol=0,
                               atol=1e-6 * amp.max())
    np.testing.assert_allclose(np.asarray(b.multipliers), np.asarray(a.multipliers),
                               rtol=0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(b.monodromy), np.asarray(a.monodromy), rtol=0,
                               atol=1e-5 * np.abs(np.asarray(a.monodromy)).max())
    for f in ("strobe", "samples"):
        x, z = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        np.testing.assert_array_equal(np.isnan(z), np.isnan(x))
        assert np.nanmax(np.abs(z - x)) < 1e-6 * amp.max(), f
    tight = dataclasses.replace(CHECK_SETTINGS, rtol=1e-12, atol=1e-14)
    ref = np.asarray(check_orbits(p.vector_field, p.setup, p.data, _GAMMAS, y, scale, n,
                                  settings=tight, **kw).monodromy)
    err = {k: np.abs(np.asarray(c.monodromy) - ref).max() for k, c in (("vmap", a),
                                                                       ("lanes", b))}
    assert err["lanes"] <= err["vmap"], err
    # The same checks with the kernel's stages unrolled (`looped=False`; looped is the
    # default): the same orbits.
    c = check_orbits_lanes(p.component_field, p.setup, p.data, _GAMMAS, y, scale, n,
                           block=2, fast=True, looped=False, **kw)
    assert np.asarray(c.converged).all()
    np.testing.assert_array_equal(np.asarray(c.steps), np.asarray(b.steps))
    np.testing.assert_allclose(np.asarray(c.state), np.asarray(b.state), rtol=0,
                               atol=1e-6 * amp.max())
    np.testing.assert_allclose(np.asarray(c.multipliers), np.asarray(b.multipliers),
                               rtol=0, atol=1e-5)


def test_verifier_runs_its_checks_on_the_kernel_where_asked(duffing_problem, monkeypatch):
    """`VerifySettings(kernel_checks=True)` sends the verifier's orbit checks to
    `check_orbits_lanes`, and the verdicts are those of the vmapped checks (period 1, and
    period 2 from the samples' candidate period). Where the kernel's compiler refuses
    them, they run vmapped with a warning. Refused for a problem without a component
    field."""
    from bsfs_jax.analysis import SweepProblem, VerifySettings, _orbit_trials

    p = duffing_problem
    calls = []
    lanes = _orbit_trials.check_orbits_lanes
    monkeypatch.setattr(_orbit_trials, "check_orbits_lanes",
                        lambda *a, **k: calls.append(len(a[3])) or lanes(*a, **k))
    cfg = SweepConfig(settings=SolverSettings(solver="dopri5-fused", **TOL), **_DUFFING_CFG)
    ver = {k: VerifySettings(max_period=2, batch=2, kernel_checks=k, settle=False)
           for k in (False, True)}
    out = {k: sweep(p, _GAMMAS, config=cfg, progress=False, verify=ver[k]).verdicts
           for k in (False, True)}
    assert calls and set(calls) == {2}  # the checks' lanes (VerifySettings.batch)
    assert list(out[True]["motion"][0]) == list(out[False]["motion"][0]) == \
        ["period-1", "period-2"]
    np.testing.assert_allclose(out[True]["max_multiplier"], out[False]["max_multiplier"],
                               atol=1e-5)
    np.testing.assert_allclose(out[True]["amplitude"], out[False]["amplitude"], rtol=1e-5)

    def refuse(*a, **k):
        raise RuntimeError("no Triton here")

    monkeypatch.setattr(_orbit_trials, "check_orbits_lanes", refuse)
    with pytest.warns(RuntimeWarning, match="checking them vmapped instead"):
        again = sweep(p, _GAMMAS, config=cfg, progress=False, verify=ver[True]).verdicts
    np.testing.assert_array_equal(again["max_multiplier"], out[False]["max_multiplier"])
    plain = SweepProblem(p.vector_field, p.setup, p.data, p.y0, p.param)
    with pytest.raises(ValueError, match="component_field"):
        sweep(plain, _GAMMAS, config=cfg, progress=False,
              verify=VerifySettings(kernel_checks=True))
