"""Verified motion labels on textbook systems (the same code the ball screw uses).

Each label must carry its evidence: a stable orbit found by Newton from the sampled state
(period-n), an exponent whose confidence interval excludes zero plus a broadband spectrum
(chaos), or a zero exponent, an unlocked rotation number, a closed invariant curve and no
stable orbit of period <= 16 (quasi-periodic).
"""

import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.analysis import (
    SweepConfig,
    SweepProblem,
    VerifySettings,
    largest_lyapunov,
    minimum_transient,
    sweep,
    verify_sweep,
)
from bsfs_jax.analysis._evidence import (
    closed_curve_error,
    exponent_interval,
    locked_to,
    rotation_number,
)
from bsfs_jax.solvers import SolverSettings
from tests.textbook import (
    LORENZ_CLASSIC,
    LORENZ_LYAPUNOV,
    duffing,
    linear_oscillator,
    lorenz,
    van_der_pol,
)

SETTINGS = SolverSettings(rtol=1e-9, atol=1e-11, solver="dopri5-fused")


def _run(problem, values, transient, periods=16):
    cfg = SweepConfig(transient_periods=transient, periods=periods, samples_per_period=16,
                      lyapunov=False, batch_size=4, chunk_size=4, settings=SETTINGS)
    res = sweep(problem, values, config=cfg, progress=False)
    return res, verify_sweep(problem, res)


def _omega_setup(data, omega):
    return (data[0], data[1], data[2], omega), 2.0 * jnp.pi / omega


def test_lightly_damped_oscillator_far_above_resonance_is_period_1_from_a_short_run():
    # zeta = 0.01: the free vibration decays by only 0.3 % per forcing period at
    # omega = 20 w0, so 10 + 16 periods leave it nearly untouched in the samples (a
    # sample-based classifier reads a torus). The orbit engine jumps to the orbit.
    problem = SweepProblem(linear_oscillator, _omega_setup, jnp.array([0.01, 1.0, 1.0]),
                           jnp.zeros(2), "omega")
    res, v = _run(problem, [20.0, 35.0], transient=10)
    assert list(v["motion"][0]) == ["period-1", "period-1"]
    assert v["verified"][0].all()
    # The multiplier is the closed form exp(-zeta w0 T).
    mu = np.exp(-0.01 * 2 * np.pi / np.array([20.0, 35.0]))
    np.testing.assert_allclose(v["max_multiplier"][0], mu, rtol=1e-6)
    # The amplitude is that of the orbit, not of the still-decaying samples: f0/|w0^2-w^2|.
    amp = 1.0 / np.abs(1.0 - np.array([20.0, 35.0]) ** 2)
    np.testing.assert_allclose(v["amplitude"][0], amp, rtol=1e-4)
    assert np.all(v["orbit_residual"][0] < 1e-8)
    # The record itself does not repeat: the samples alone would not give period-1.
    from bsfs_jax.analysis import strobe_period

    assert strobe_period(res.strobe[0, 0], scale=res.amplitude[0, 0]) == 0


def test_host_eigvals_are_numpys_under_jit_and_vmap():
    """The checks' multipliers come from `solvers.host_eigvals` (LAPACK on the host, not
    cuSOLVER's one-matrix-at-a-time geev on a GPU): the same eigenvalues as numpy's, a
    complex pair included, traced and batched."""
    import jax

    from bsfs_jax.solvers import host_eigvals

    rng = np.random.default_rng(3)
    m = rng.normal(size=(4, 3, 6, 6))
    m[0, 0] = np.diag([0.5, 2.0, -1.0, 3.0, 0.1, 0.2])
    m[0, 0, 0, 1], m[0, 0, 1, 0] = 1.0, -1.0  # a complex pair
    got = np.asarray(jax.jit(jax.vmap(host_eigvals))(jnp.asarray(m)))
    want = np.linalg.eigvals(m)
    assert got.shape == want.shape == (4, 3, 6)
    for g, w in zip(got.reshape(-1, 6), want.reshape(-1, 6)):
        np.testing.assert_allclose(np.sort_complex(g), np.sort_complex(w), rtol=0, atol=1e-12)


def test_linear_approach_checks_every_pair_against_the_monodromy():
    """`linear_approach`: samples whose deviations from a period-2 orbit follow
    e_{j+2} = M e_j exactly show no misfit; one pair pushed off shows exactly its own
    relative misfit (computed here pair by pair); pairs already on the orbit are skipped;
    a pair that is not finite gives no verdict (infinite misfit)."""
    from bsfs_jax.analysis._evidence import linear_approach

    rng = np.random.default_rng(7)
    d, n, k = 4, 2, 21
    m = 0.5 * rng.normal(size=(d, d)) / np.sqrt(d)
    o = rng.normal(size=(n, d))
    sc = np.array([1.0, 2.0, 0.5, 1.5])
    idx = (np.arange(k) - (k - 1)) % n
    e = np.zeros((k, d))
    for start in (0, 1):  # the two phases' chains, each e_{j+2} = M e_j
        e[start] = 1e-3 * rng.normal(size=d)
        for j in range(start + n, k, n):
            e[j] = m @ e[j - n]
    s = o[idx] + e * sc
    dev, misfit = linear_approach(s, o, m, sc, near_tol=1e-12)
    assert misfit < 1e-6 and dev == pytest.approx(np.linalg.norm(e, axis=1).max())
    s2 = s.copy()
    s2[10] += 1e-5 * sc  # a sample at phase 0 (k - 1 - 10 even): two pairs change
    e2 = (s2 - o[idx]) / sc
    p0 = np.flatnonzero(idx == 0)
    want = max(np.linalg.norm(e2[b] - m @ e2[a]) / np.linalg.norm(e2[a])
               for a, b in zip(p0[:-1], p0[1:]))
    assert linear_approach(s2, o, m, sc, near_tol=1e-12)[1] == pytest.approx(want, rel=1e-9)
    assert want > 1e-4
    # Pairs whose first deviation is below near_tol are not checked.
    assert linear_approach(s2, o, m, sc, near_tol=1.0)[1] == 0.0
    s3 = s.copy()
    s3[-3] = np.nan
    assert linear_approach(s3, o, m, sc, near_tol=1e-12)[1] == np.inf


def test_a_period_1_orbit_solved_over_5_periods_is_not_period_5():
    # Newton on Phi^{5T}(y) = y from a period-1 sample converges to the period-1 orbit; its
    # five-period multipliers (mu^5) look like those of a stable period-5 orbit. It must
    # not be labelled period-5 (a false label found on the ball screw and fixed).
    from bsfs_jax.analysis._orbit_trials import OrbitTrials, scale_of

    problem = SweepProblem(linear_oscillator, _omega_setup, jnp.array([0.01, 1.0, 1.0]),
                           jnp.zeros(2), "omega")
    res, _ = _run(problem, [20.0], transient=10)
    strobe, amp = res.strobe[0, 0], res.amplitude[0, 0]
    trials = OrbitTrials(problem, VerifySettings(), observe=0)
    sc = scale_of(amp, strobe[-1])
    (chk,) = trials.orbits([(20.0, strobe[-1], sc, 5)])
    assert chk["converged"]
    mu1 = np.exp(-0.01 * 2 * np.pi / 20.0)
    assert np.max(np.abs(chk["multipliers"])) == pytest.approx(mu1 ** 5, rel=1e-6)
    verdict, why = trials.accept(chk, 5, strobe, sc, 2 * np.pi / 20.0)
    assert verdict is None and "repeats after 1 period" in why


def _gamma_setup(data, gamma):
    return (data[0], data[1], data[2], gamma, data[3]), 2.0 * jnp.pi / data[3]


def test_duffing_period_doubling_route_is_verified():
    """x'' + 0.3 x' - x + x^3 = g cos(1.2 t): period 1, 2, 4, then chaos (Guckenheimer &
    Holmes 2.2; Thompson & Stewart)."""
    problem = SweepProblem(duffing, _gamma_setup, jnp.array([0.3, -1.0, 1.0, 1.2]),
                           jnp.array([1.0, 0.0]), "gamma")
    gammas = np.array([0.20, 0.28, 0.29, 0.50])
    n_min = minimum_transient(problem, gammas, 2 * np.pi / 1.2 * np.ones(4))
    assert np.all(n_min == n_min[0]) and n_min[0] >= 8
    _, v = _run(problem, gammas, transient=60)
    assert list(v["motion"][0]) == ["period-1", "period-2", "period-4", "chaotic"]
    assert v["verified"][0].all()
    assert list(v["period_n"][0]) == [1, 2, 4, 0]
    # The orbit's own stroboscopic points: n distinct values, NaN beyond; none for chaos.
    strobe = v["orbit_strobe"][0]
    for i, n in enumerate([1, 2, 4]):
        pts = strobe[i][np.isfinite(strobe[i])]
        assert pts.size == n and np.unique(np.round(pts, 6)).size == n
    assert np.all(np.isnan(strobe[3]))
    assert np.all(v["max_multiplier"][0, :3] < 1.0)
    lo, hi = v["lyapunov_low"][0, 3], v["lyapunov_high"][0, 3]
    assert 0.0 < lo < hi, "chaos needs a confidence interval above zero"
    assert v["line_fraction"][0, 3] < 0.99


def test_van_der_pol_torus_is_verified_quasi_periodic():
    # Weakly forced van der Pol: limit cycle (omega0 ~ 1) beside the forcing at the
    # golden-ratio frequency: an unlocked 2-torus.
    def setup(data, omega):
        return (data[0], data[1], omega), 2.0 * jnp.pi / omega

    problem = SweepProblem(van_der_pol, setup, jnp.array([0.2, 0.1]), jnp.array([2.0, 0.0]),
                           "omega")
    _, v = _run(problem, [1.618], transient=100)
    assert v["motion"][0, 0] == "quasi-periodic" and v["verified"][0, 0]
    assert v["lyapunov_low"][0, 0] <= 0.0 <= v["lyapunov_high"][0, 0]
    assert v["curve_error"][0, 0] < 0.05
    # rho ~ omega0 / omega (the free frequency seen once per forcing period).
    assert v["rotation_number"][0, 0] == pytest.approx(1.0 / 1.618, abs=0.01)


def test_lorenz_is_verified_chaotic_through_the_same_code():
    # Autonomous: "period" is the sampling interval (1 time unit); no orbit of period
    # n x 1 exists, so the exponent and the spectrum decide.
    problem = SweepProblem(lorenz, lambda data, dt: (data, dt), jnp.array(LORENZ_CLASSIC),
                           jnp.array([1.0, 1.0, 1.0]), "interval")
    _, v = _run(problem, [1.0], transient=20)
    assert v["motion"][0, 0] == "chaotic" and v["verified"][0, 0]
    assert v["lyapunov_low"][0, 0] < LORENZ_LYAPUNOV < v["lyapunov_high"][0, 0]


def test_largest_lyapunov_drops_alignment_and_gives_an_interval():
    res = largest_lyapunov(lorenz, jnp.array([1.0, 1.0, 1.0]), jnp.array(LORENZ_CLASSIC),
                           interval=1.0, n_intervals=800, transient_intervals=20,
                           align_intervals=10, settings=SolverSettings(rtol=1e-8, atol=1e-10))
    assert res.log_growth.shape == (800,)
    lo, hi = res.confidence_interval()
    assert lo < LORENZ_LYAPUNOV < hi and hi - lo < 0.2


# ---------------------------------------------------------------------------------------
# The evidence functions on exact data


def test_exponent_interval_covers_the_mean_of_noisy_growth():
    rng = np.random.default_rng(0)
    g = 0.3 + 0.5 * rng.standard_normal(4000)
    mean, lo, hi = exponent_interval(g, 8)
    assert lo < 0.3 < hi and mean == pytest.approx(np.mean(g))
    assert np.isnan(exponent_interval(g[:3], 8)[0])


def test_rotation_number_lock_and_closed_curve():
    k = np.arange(400)
    golden = (np.sqrt(5) - 1) / 2
    circle = np.stack([np.cos(2 * np.pi * golden * k), 0.5 * np.sin(2 * np.pi * golden * k),
                       0.1 * np.cos(4 * np.pi * golden * k)], axis=1)
    # A finite section's mean turn per iterate is exact to O(1/N) (the end points).
    assert rotation_number(circle) == pytest.approx(golden, abs=1.0 / len(k))
    assert locked_to(golden) is None and locked_to(0.4) == (2, 5)
    assert closed_curve_error(circle) < 0.01  # smooth: only the truncated series
    rng = np.random.default_rng(1)
    cloud = rng.standard_normal((400, 3))
    assert closed_curve_error(cloud) > 0.3


def test_settings_are_checked():
    with pytest.raises(ValueError, match="max_period"):
        VerifySettings(max_period=0)
    with pytest.raises(ValueError, match="block_periods"):
        VerifySettings(block_periods=8, segments=8)


def test_verification_resumes_from_its_checkpoint(tmp_path, monkeypatch):
    import bsfs_jax.analysis._verify as verify_module

    problem = SweepProblem(linear_oscillator, _omega_setup, jnp.array([0.01, 1.0, 1.0]),
                           jnp.zeros(2), "omega")
    cfg = SweepConfig(transient_periods=10, periods=16, samples_per_period=16, lyapunov=False,
                      batch_size=4, chunk_size=4, settings=SETTINGS)
    first = sweep(problem, [20.0, 35.0], config=cfg, verify=VerifySettings(),
                  checkpoint_dir=tmp_path, progress=False)
    assert list((tmp_path / "verdicts").glob("verdicts_*.npz"))

    def fail(*args, **kwargs):
        raise AssertionError("verified again instead of loading the checkpoint")

    monkeypatch.setattr(verify_module, "verify_points", fail)
    again = sweep(problem, [20.0, 35.0], config=cfg, verify=VerifySettings(),
                  checkpoint_dir=tmp_path, progress=False)
    for k, a in first.verdicts.items():
        np.testing.assert_array_equal(again.verdicts[k], a)
    # Other settings are not served from the checkpoint.
    with pytest.raises(AssertionError, match="verified again"):
        sweep(problem, [20.0, 35.0], config=cfg, verify=VerifySettings(near_tol=2e-4),
              checkpoint_dir=tmp_path, progress=False)


def test_prefetched_orbit_checks_compile_once_and_agree():
    # `_verified_sweep` compiles the orbit checks in the background while the sweep
    # integrates (`OrbitTrials.prefetch`); the checks then find that program in jit's
    # cache: not even traced again (with a persistent compilation cache a second
    # compilation would not show, its tracing would), and the closed-form verdicts.
    import jax

    from bsfs_jax.analysis._orbit_trials import OrbitTrials
    from bsfs_jax.solvers import _orbit_check

    problem = SweepProblem(linear_oscillator, _omega_setup, jnp.array([0.02, 1.0, 1.0]),
                           jnp.zeros(2), "omega")
    settings = VerifySettings()
    OrbitTrials(problem, settings, problem.observe).prefetch()
    (pending,) = [f for k, f in _orbit_check._PREFETCHED.items()
                  if k[0] == id(linear_oscillator)]
    pending.result(timeout=300)  # compiled in the background
    compiles = {"n": 0}

    def on_event(event, seconds, **kwargs):
        if event in ("/jax/core/compile/jaxpr_trace_duration",
                     "/jax/core/compile/backend_compile_duration") and \
                "_check_batch" in kwargs.get("fun_name", ""):
            compiles["n"] += 1

    jax.monitoring.register_event_duration_secs_listener(on_event)
    res, v = _run(problem, [20.0, 35.0], transient=10)
    assert list(v["motion"][0]) == ["period-1", "period-1"]
    mu = np.exp(-0.02 * 2 * np.pi / np.array([20.0, 35.0]))
    np.testing.assert_allclose(v["max_multiplier"][0], mu, rtol=1e-6)
    assert compiles["n"] == 0  # the prefetched program served the checks
    assert not any(k[0] == id(linear_oscillator) for k in _orbit_check._PREFETCHED)


def test_wide_verification_gives_the_narrow_verdicts(monkeypatch):
    """A wide verification (an accelerator's: one lockstep batch per chunk, padded to a
    power of two, and the continuation blocks padded alike) gives the verdicts of narrow
    batches: the padding lanes repeat a point and are dropped. A lockstep call lasts as
    long as its longest lane, so n = 1 never shares a call with a longer candidate period
    (with no extra periods given). The Duffing route, whose chaotic point runs the
    continuation blocks (3 pending points padded to 4 lanes)."""
    from bsfs_jax.analysis import _extend

    problem = SweepProblem(duffing, _gamma_setup, jnp.array([0.3, -1.0, 1.0, 1.2]),
                           jnp.array([1.0, 0.0]), "gamma")
    cfg = SweepConfig(transient_periods=60, periods=16, samples_per_period=16,
                      lyapunov=False, batch_size=4, chunk_size=4, settings=SETTINGS)
    res = sweep(problem, np.array([0.20, 0.28, 0.29, 0.50]), config=cfg, progress=False)
    widths = []
    block = _extend._block

    def spy(*args, **kwargs):
        widths.append(int(args[3].shape[0]))
        return block(*args, **kwargs)

    monkeypatch.setattr(_extend, "_block", spy)
    from bsfs_jax.analysis import _orbit_trials

    calls = []
    check = _orbit_trials.check_orbits
    monkeypatch.setattr(_orbit_trials, "check_orbits", lambda *a, **k: calls.append(
        (len(a[3]), set(np.asarray(a[6]).tolist()))) or check(*a, **k))
    narrow = verify_sweep(problem, res, settings=VerifySettings(batch=2, wide=False))
    n_narrow, checks_narrow = len(widths), len(calls)
    wide_settings = VerifySettings(batch=2, wide=True)
    assert wide_settings.lanes_for(4) == 4 and wide_settings.lanes_for(5) == 8
    assert VerifySettings(batch=2, wide=False).lanes_for(5) == 2
    wide = verify_sweep(problem, res, settings=wide_settings)
    assert n_narrow >= 1 and set(widths[n_narrow:]) == {4}  # blocks padded to the lanes
    # One lockstep width; n = 1 in calls of its own (the candidates 2 and 4 apart).
    wide_calls = calls[checks_narrow:]
    assert {w for w, _ in wide_calls} == {4}
    assert all(ns == {1} or 1 not in ns for _, ns in wide_calls), wide_calls
    assert any(ns == {1} for _, ns in wide_calls) and any(1 not in ns for _, ns in wide_calls)
    assert list(wide["motion"][0]) == list(narrow["motion"][0]) == \
        ["period-1", "period-2", "period-4", "chaotic"]
    for f in ("max_multiplier", "orbit_residual", "lyapunov_low", "lyapunov_high",
              "amplitude"):
        np.testing.assert_allclose(wide[f], narrow[f], rtol=1e-9, atol=1e-12, err_msg=f)


def test_orbit_checks_find_the_orbit_to_their_newton_tolerance():
    """The checks' state-only runs (chord steps, samples) are accurate enough for their
    Newton tolerance (`STATE_TIGHTER`): on B1's 620 Hz point (5000 N), sampled after the
    verifier's minimum transient, the orbit found is a fixed point of a reference period
    map (rtol 1e-12) to the tolerance, and checking again from it converges at once. At
    the checks' own tolerances a state-only period was 2.9e-6 off, the orbit found 2.6e-6
    from the reference's, and the check from it stalled at 2.7e-6 for 16 chord steps."""
    from bsfs_jax.analysis import bsfs_problem
    from bsfs_jax.analysis._orbit_trials import scale_of
    from bsfs_jax.params import preset
    from bsfs_jax.solvers import check_orbits, integrate

    p = bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)
    v = 620.0
    args, period = p.setup(p.data, v)
    n_tr = float(np.ravel(minimum_transient(p, np.array([v]), np.array([float(period)]),
                                            VerifySettings(), fallback=200))[0])
    st = SolverSettings(rtol=1e-8, atol=1e-12, max_steps=10**7, solver="dopri5-fused")
    ts = period * (n_tr + jnp.arange(1, 17))
    rec = np.asarray(integrate(p.vector_field, jnp.zeros(6), args, 0.0, ts[-1], ts, st,
                               throw=False).ys)
    y, sc = rec[-1], scale_of((rec.max(0) - rec.min(0)) / 2, rec[-1])
    one = np.array([1])
    first = check_orbits(p.vector_field, p.setup, p.data, np.array([v]), y[None], sc[None],
                         one, max_period=2)
    assert bool(np.asarray(first.converged)[0])
    orbit = np.asarray(first.state)[0]
    tight = SolverSettings(rtol=1e-12, atol=1e-18, max_steps=10**7, solver="dopri5-fused")
    end = np.asarray(integrate(p.vector_field, jnp.asarray(orbit), args, 0.0, period,
                               jnp.asarray(period)[None], tight, throw=False).ys[-1])
    assert np.max(np.abs(end - orbit) / sc) <= 1e-6 * max(1.0, np.max(np.abs(orbit / sc)))
    again = check_orbits(p.vector_field, p.setup, p.data, np.array([v]), orbit[None],
                         sc[None], one, max_period=2)
    assert bool(np.asarray(again.converged)[0]) and int(np.asarray(again.steps)[0]) == 0


def test_settle_blocks_verify_on_the_sweeps_program(monkeypatch):
    """Settle blocks (the accelerator's default): a point without an orbit after the
    sweep is run on by the sweep's own program (same chunk shape, so no new program)
    and verified from that record, without the long runs; the same orbit as the long
    runs find. B1's 1262.35 Hz point at 5000 N (of the 256-point B1 sweep: 3 time
    constants of transient leave it too far from its orbit for the first trial; 620 Hz
    was such a point until the checks' state-only runs took a quarter of their
    tolerances, `STATE_TIGHTER`, and is verified at once since)."""
    from bsfs_jax.analysis import _sweep_engines, _verify, bsfs_problem
    from bsfs_jax.params import preset

    problem = bsfs_problem(preset("default"), "frequency_hz", force_n=5000.0)
    cfg = SweepConfig(transient_periods=200, periods=16, samples_per_period=1,
                      lyapunov=False, batch_size=1, chunk_size=1,
                      settings=SolverSettings(rtol=1e-8, atol=1e-12, solver="dopri5-fused"))
    blocks, chunks = [], []
    run_block, cold_chunk = _verify.run_block, _sweep_engines._cold_chunk
    monkeypatch.setattr(_verify, "run_block",
                        lambda *a, **k: blocks.append(len(a[1])) or run_block(*a, **k))

    def spy(problem, values, y0s, n_transient, *rest):
        chunks.append((values.shape, y0s.shape, None if n_transient is None else
                       n_transient.shape))
        return cold_chunk(problem, values, y0s, n_transient, *rest)

    monkeypatch.setattr(_sweep_engines, "_cold_chunk", spy)
    monkeypatch.setattr("bsfs_jax.analysis._sweep._cold_chunk", spy)
    out = {}
    for settle in (False, True):
        blocks.clear(), chunks.clear()
        out[settle] = sweep(problem, [1262.3529], config=cfg, progress=False,
                            verify=VerifySettings(settle=settle)).verdicts
        assert out[settle]["motion"][0, 0] == "period-1" and out[settle]["verified"][0, 0]
        assert (blocks == []) == settle  # the long runs only without settle blocks
        assert len(chunks) == 1 + settle and len(set(chunks)) == 1  # one program
    np.testing.assert_allclose(out[True]["max_multiplier"], out[False]["max_multiplier"],
                               rtol=1e-6)
    np.testing.assert_allclose(out[True]["amplitude"], out[False]["amplitude"], rtol=1e-6)
    # The time before the evidence: the long run's block starts where the sweep ended;
    # the settle block's record is its last 16 of 256 periods.
    np.testing.assert_allclose(out[True]["transient"],
                               out[False]["transient"] + (256 - 16) / 1262.3529, rtol=1e-9)
