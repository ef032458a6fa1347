"""Sweeps: continued up/down sweeps with jumps, checkpoint-resume, failed points, files,
sharding over devices, the ball-screw problem and the `bsfs sweep` command."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.analysis import SweepConfig, SweepProblem, bsfs_problem, load_sweep, sweep
from bsfs_jax.analysis import _sweep as sweep_module
from bsfs_jax.solvers import RESULTS, SolverSettings, result_codes, result_ok
from tests.textbook import duffing

ROOT = Path(__file__).resolve().parents[1]

# Hardening Duffing x'' + 0.1 x' + x + 0.3 x^3 = 0.5 cos(w t), swept in w.
DELTA, ALPHA, BETA, GAMMA = 0.1, 1.0, 0.3, 0.5


def duffing_omega(data, omega):
    return (data[0], data[1], data[2], data[3], omega), 2.0 * jnp.pi / omega


@pytest.fixture(scope="module")
def problem():
    return SweepProblem(duffing, duffing_omega, jnp.array([DELTA, ALPHA, BETA, GAMMA]),
                        jnp.zeros(2), "omega", unit="rad/s", observe=0,
                        state_names=("x", "v"), state_units=("1", "1"), time_unit="1")


# One configuration for all Duffing sweeps here, so the chunk function compiles once.
CFG = SweepConfig(transient_periods=150, continued_transient_periods=40, periods=16,
                  samples_per_period=16, lyapunov=False, batch_size=4, chunk_size=4,
                  settings=SolverSettings(rtol=1e-8, atol=1e-10))
OMEGAS = np.linspace(0.8, 2.4, 33)


def harmonic_balance_folds(omegas):
    """One-term harmonic balance A^2 [(a - w^2 + 3/4 b A^2)^2 + (d w)^2] = g^2: the range
    of w with three real amplitudes (between the folds)."""
    three = []
    for w in np.linspace(omegas[0], omegas[-1], 4001):
        # cubic in u = A^2
        c = [9 / 16 * BETA**2, 1.5 * BETA * (ALPHA - w * w),
             (ALPHA - w * w) ** 2 + (DELTA * w) ** 2,
             -GAMMA**2]
        roots = np.roots(c)
        real = roots[(abs(roots.imag) < 1e-9) & (roots.real > 0)]
        if real.size == 3:
            three.append(w)
    return min(three), max(three)


@pytest.fixture(scope="module")
def both(problem):
    return sweep(problem, OMEGAS, mode="continued", direction="both", config=CFG,
                 progress=False)


def test_continued_sweep_shows_hysteresis_and_jumps(both):
    assert both.directions == ("up", "down")
    assert np.all(result_ok(both.result)) and not np.any(both.failed)
    jumps = both.jumps()
    up = [j for j in jumps if j.direction == "up"]
    down = [j for j in jumps if j.direction == "down"]
    assert len(up) == 1 and len(down) == 1
    (ju,), (jd,) = up, down
    assert ju.kind == "jump-down" and jd.kind == "jump-up"
    assert ju.value_before < ju.value_after and jd.value_before > jd.value_after
    # The up sweep stays on the resonant branch longer: the jumps bracket the hysteresis.
    assert ju.value_before > jd.value_before
    lo, hi = harmonic_balance_folds(OMEGAS)
    step = OMEGAS[1] - OMEGAS[0]
    # Jumps happen at the folds of the one-term harmonic balance (within the grid step and
    # the few-percent error of one harmonic).
    assert ju.value_before <= hi * 1.03 and ju.value_after >= hi * 0.97 - step
    assert jd.value_after <= lo * 1.03 + step and jd.value_before >= lo * 0.97
    # Between the jumps the two directions sit on different branches.
    _, a_up = both.frc("up")
    _, a_down = both.frc("down")
    inside = (OMEGAS > jd.value_before) & (OMEGAS < ju.value_before)
    assert inside.any() and np.all(a_up[inside] > 1.5 * a_down[inside])
    outside = (OMEGAS < jd.value_after - 1e-9) | (OMEGAS > ju.value_after + 1e-9)
    # (continued points run 40 transient periods, e^(-delta/2 * 40 T) ~ 5e-3 of the step
    # change remains at the high end)
    np.testing.assert_allclose(a_up[outside], a_down[outside], rtol=1e-3)


def test_save_load_roundtrip(both, tmp_path):
    import dataclasses

    import xarray as xr

    path = tmp_path / "sweep.nc"
    D, N = len(both.directions), OMEGAS.size
    verdicts = {
        "motion": np.where(np.arange(N)[None, :] % 2 == 0, "period-1", "chaotic?").repeat(D, 0),
        "agrees": (np.arange(D * N).reshape(D, N) % 3 == 0),
        "margin": np.linspace(-1.0, 1.0, D * N).reshape(D, N),
    }
    verdicts["margin"][0, 1] = np.nan
    dataclasses.replace(both, verdicts=verdicts).save(path)
    assert not list(tmp_path.glob(".*.tmp"))  # the temporary file was renamed
    back = load_sweep(path)
    assert back.param == "omega" and back.unit == "rad/s" and back.directions == ("up", "down")
    assert back.state_names == ("x", "v") and back.mode == "continued"
    np.testing.assert_array_equal(back.values, both.values)
    np.testing.assert_array_equal(back.period, both.period)
    for name in ("amplitude", "strobe", "spectrum", "log_growth", "num_steps", "end_state"):
        np.testing.assert_array_equal(getattr(back, name), getattr(both, name))
    np.testing.assert_array_equal(result_codes(back.result), result_codes(both.result))
    assert back.config == both.config and back.config["settings"]["rtol"] == 1e-8
    assert back.metadata["fingerprint"] == both.metadata["fingerprint"]
    assert list(back.verdicts) == ["motion", "agrees", "margin"]
    assert back.verdicts["motion"].dtype.kind == "U" and back.verdicts["agrees"].dtype == bool
    np.testing.assert_array_equal(back.verdicts["motion"], verdicts["motion"])
    np.testing.assert_array_equal(back.verdicts["agrees"], verdicts["agrees"])
    np.testing.assert_array_equal(back.verdicts["margin"], verdicts["margin"])
    assert load_sweep(path).summary()["points"][0]["motion"] == "period-1"
    assert both.verdicts is None

    # Any NetCDF reader sees labelled, self-describing variables.
    with xr.open_dataset(path) as ds:
        assert ds.attrs["format"] == "bsfs-sweep-2" and ds.attrs["param"] == "omega"
        assert ds["omega"].attrs["units"] == "rad/s" and ds["omega"].dims == ("point",)
        assert ds["strobe"].dims == ("direction", "point", "sample", "state")
        assert ds["log_growth"].dims == ("direction", "point", "period")
        assert ds["amplitude"].attrs["units"] == "1" and "long_name" in ds["amplitude"].attrs
        assert ds["lyapunov"].attrs["units"] == "1/1"
        assert ds["spectrum_order"].dims == ("bin",)
        assert list(ds["direction"].values) == ["up", "down"]
        assert list(ds["state"].values) == ["x", "v"]
        assert ds["status"].shape == (2, N) and int(ds["status"].max()) == 0
        assert json.loads(ds.attrs["status_messages"]) == {"0": "successful"}
    xr.testing.assert_identical(back.to_xarray(),
                                dataclasses.replace(both, verdicts=verdicts).to_xarray())

    # Files that are not sweeps: one line naming the file.
    other = tmp_path / "other.nc"
    xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(other, engine="h5netcdf")
    text = tmp_path / "notes.nc"
    text.write_text("not a sweep")
    for bad in (other, text):
        with pytest.raises(ValueError, match="not a bsfs sweep file") as info:
            load_sweep(bad)
        assert str(bad) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ValueError, match="verdict 'short'"):
        dataclasses.replace(both, verdicts={"short": np.zeros(3)}).save(tmp_path / "x.nc")


def test_checkpoint_resume_recomputes_only_missing_chunks(problem, tmp_path, monkeypatch):
    values = OMEGAS[::2]  # 17 points -> 5 chunks of 4 (the last padded)
    reference = sweep(problem, values, config=CFG, progress=False)

    calls = {"n": 0}
    real_chunk = sweep_module._cold_chunk

    def interrupted(*args, **kwargs):
        if calls["n"] == 3:
            raise KeyboardInterrupt  # as if the user pressed Ctrl-C during chunk 4
        calls["n"] += 1
        return real_chunk(*args, **kwargs)

    monkeypatch.setattr(sweep_module, "_cold_chunk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sweep(problem, values, config=CFG, checkpoint_dir=tmp_path, progress=False)
    assert sorted(p.name for p in tmp_path.glob("chunk_*.npz")) == [
        "chunk_00000.npz", "chunk_00001.npz", "chunk_00002.npz"]

    counted = {"n": 0}

    def counting(*args, **kwargs):
        counted["n"] += 1
        return real_chunk(*args, **kwargs)

    monkeypatch.setattr(sweep_module, "_cold_chunk", counting)
    resumed = sweep(problem, values, config=CFG, checkpoint_dir=tmp_path, progress=False)
    assert counted["n"] == 2  # chunks 3 and 4 only
    assert resumed.metadata["chunks_computed_this_run"] == 2
    np.testing.assert_array_equal(resumed.amplitude, reference.amplitude)
    np.testing.assert_array_equal(resumed.strobe, reference.strobe)

    # A different sweep refuses to reuse the folder.
    with pytest.raises(ValueError, match="different sweep"):
        sweep(problem, values * 1.01, config=CFG, checkpoint_dir=tmp_path, progress=False)


def test_per_point_transient_in_cold_mode(problem, tmp_path):
    values = OMEGAS[::2]  # the chunk shapes of the test above: no new compile
    reference = sweep(problem, values, config=CFG, progress=False)
    same = sweep(problem, values, config=CFG, transient=np.full(values.size, 150),
                 progress=False)
    np.testing.assert_array_equal(same.amplitude, reference.amplitude)
    assert "transient_periods_per_point" not in same.metadata
    short = np.full(values.size, 150)
    short[0] = 5  # e^(-0.05 * 5 T) at omega = 0.8: the start transient is still there
    res = sweep(problem, values, config=CFG, transient=short, checkpoint_dir=tmp_path,
                progress=False)
    assert res.metadata["transient_periods_per_point"] == short.tolist()
    assert abs(res.amplitude[0, 0, 0] / reference.amplitude[0, 0, 0] - 1) > 1e-3
    np.testing.assert_allclose(res.amplitude[:, 1:], reference.amplitude[:, 1:], rtol=1e-9)
    # The transients are part of the checkpoint fingerprint.
    with pytest.raises(ValueError, match="different sweep"):
        sweep(problem, values, config=CFG, checkpoint_dir=tmp_path, progress=False)
    for bad, match in ((np.full(3, 150), "shape"), (np.full(values.size, 150.0), "int array"),
                       (np.zeros(values.size, int), ">= 1")):
        with pytest.raises(ValueError, match=match):
            sweep(problem, values, config=CFG, transient=bad, progress=False)
    with pytest.raises(ValueError, match="mode='cold'"):
        sweep(problem, values, mode="continued", config=CFG, transient=short, progress=False)


def test_continued_checkpoint_resume_carries_the_state(problem, tmp_path, monkeypatch):
    values = OMEGAS[8:20]  # 12 points, 3 chunks, across the upper branch
    reference = sweep(problem, values, mode="continued", config=CFG, progress=False)
    real_chunk = sweep_module._continued_chunk
    calls = {"n": 0}

    def interrupted(*args, **kwargs):
        if calls["n"] == 1:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real_chunk(*args, **kwargs)

    monkeypatch.setattr(sweep_module, "_continued_chunk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sweep(problem, values, mode="continued", config=CFG, checkpoint_dir=tmp_path,
              progress=False)
    monkeypatch.setattr(sweep_module, "_continued_chunk", real_chunk)
    resumed = sweep(problem, values, mode="continued", config=CFG, checkpoint_dir=tmp_path,
                    progress=False)
    assert resumed.metadata["chunks_computed_this_run"] == 2
    np.testing.assert_allclose(resumed.amplitude, reference.amplitude, rtol=1e-12)


def test_failed_point_is_marked_and_does_not_stop_the_sweep(problem):
    # With few allowed steps the long low-frequency horizons fail, the short ones do not.
    cfg = SweepConfig(transient_periods=150, continued_transient_periods=40, periods=16,
                      samples_per_period=16, lyapunov=False, batch_size=4, chunk_size=4,
                      settings=SolverSettings(rtol=1e-8, atol=1e-10, max_steps=50_000))
    values = np.array([0.05, 0.8, 2.0, 2.4])
    res = sweep(problem, values, config=cfg, progress=False)
    assert bool(res.point_result(0, 0) == RESULTS.max_steps_reached)
    assert np.all(result_ok(res.result)[0, 1:])
    assert np.all(np.isnan(res.strobe[0, 0])) and np.isnan(res.amplitude[0, 0, 0])
    assert np.all(np.isfinite(res.amplitude[0, 1:]))
    motions = res.motions()[0]
    assert motions[0].kind == "failed" and motions[1].kind == "periodic"
    summary = res.summary()
    assert summary["failed_points"] == 1
    first = summary["points"][0]
    assert first["status"] == int(result_codes(RESULTS.max_steps_reached))
    assert "maximum number of solver steps" in first["status_message"]
    assert summary["points"][1]["status_message"] == "successful"
    # In continued mode the point after a failure restarts cold and succeeds.
    cont = sweep(problem, values, mode="continued", config=cfg, progress=False)
    ok = result_ok(cont.result)[0]
    assert bool(cont.point_result(0, 0) == RESULTS.max_steps_reached) and np.all(ok[1:])


SHARD_SCRIPT = textwrap.dedent("""
    import json, os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp, numpy as np
    from bsfs_jax.analysis import SweepConfig, SweepProblem, sweep
    from bsfs_jax.solvers import SolverSettings, result_ok
    from tests.textbook import duffing

    def setup(data, omega):
        return (data[0], data[1], data[2], data[3], omega), 2 * jnp.pi / omega

    prob = SweepProblem(duffing, setup, jnp.array([0.1, 1.0, 0.3, 0.5]), jnp.zeros(2), "omega")
    cfg = SweepConfig(transient_periods=50, periods=8, samples_per_period=8, lyapunov=True,
                      batch_size=2, chunk_size=4, settings=SolverSettings(rtol=1e-8, atol=1e-10))
    values = np.linspace(0.8, 2.0, 6)
    sharded = sweep(prob, values, config=cfg, shard=True, progress=False)
    single = sweep(prob, values, config=cfg, shard=False, progress=False)
    print(json.dumps({
        "devices": len(jax.devices()),
        "sharded_over": sharded.metadata["sharded_over_devices"],
        "max_diff": float(np.nanmax(abs(sharded.amplitude - single.amplitude))),
        "lyap_diff": float(np.nanmax(abs(sharded.lyapunov - single.lyapunov))),
        "ok": np.asarray(result_ok(sharded.result)).tolist(),
    }))
""")


def test_sharded_sweep_over_two_cpu_devices():
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", SHARD_SCRIPT], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-3000:]
    info = json.loads(out.stdout.strip().splitlines()[-1])
    assert info["devices"] == 2 and info["sharded_over"] == 2
    assert info["max_diff"] < 1e-12 and info["lyap_diff"] < 1e-9
    assert all(info["ok"][0])


# ---------------------------------------------------------------------------------------
# The ball screw and the command line


def test_bsfs_problem_parameter_names():
    from bsfs_jax import ParameterError, preset

    params = preset("default")
    p = bsfs_problem(params, "nut.balls", frequency_hz=500.0, force_n=100.0)
    assert p.unit == "" and p.state_names[2] == "x_n"
    assert bsfs_problem(params, "bearing.contact_angle_deg", frequency_hz=500.0,
                        force_n=100.0).unit == "deg"
    assert bsfs_problem(params, "frequency_hz", force_n=100.0).unit == "Hz"
    with pytest.raises(ParameterError, match="nut.balls"):
        bsfs_problem(params, "nut.ballz", frequency_hz=500.0, force_n=100.0)
    with pytest.raises(ValueError, match="needs a fixed frequency_hz"):
        bsfs_problem(params, "force_n")


def test_cli_sweep_writes_outputs_and_resumes(tmp_path):
    from bsfs_jax.cli import main

    out = tmp_path / "run"
    argv = ["sweep", "--param", "frequency_hz", "--start", "300", "--stop", "1500", "--num", "4",
            "--force", "100", "--transient", "100", "--periods", "8", "--samples-per-period", "16",
            "--rtol", "1e-6", "--atol", "1e-10", "--chunk", "2", "--batch", "2", "--no-progress",
            "--out", str(out)]
    assert main(argv) == 0
    for name in ("bifurcation.png", "frc.png", "waterfall.png", "sweep.nc", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["points"]) == 4 and summary["param"] == "frequency_hz"
    p0 = summary["points"][0]
    assert p0["frequency_hz"] == 300.0 and p0["motion"] == "period-1"
    # 100 N well below resonance: nearly linear, sub-micrometre to micrometre amplitudes
    assert 1e-8 < p0["amplitude"] < 1e-5
    # Verified: an orbit from the sampled state with its residual and multipliers.
    assert all(p["verified"] for p in summary["points"]) and summary["verified"]
    ev = p0["evidence"]
    assert ev["orbit_residual"] < 1e-6 and 0 < ev["max_multiplier"] < 1
    assert ev["lyapunov_per_period"] < 0 and ev["transient_s"] > 0
    assert "stable period-1 orbit" in p0["reason"]
    # The verifier's orbit (solvers.check_orbits, 32 samples per period) is the engine's:
    # the period-1 orbit by shooting (the design metric's, its maximum polished on the
    # interpolant) has the same amplitude, within what 32 samples can miss of a sinusoid's
    # crest, 1 - cos(pi / 32) = 0.5 %.
    from bsfs_jax import preset
    from bsfs_jax.design import OperatingPoint
    from bsfs_jax.design._metrics import orbit_amplitude

    engine = float(orbit_amplitude(preset(), OperatingPoint(300.0, 100.0)))
    assert p0["amplitude"] == pytest.approx(engine, rel=5e-3)
    assert p0["amplitude"] <= engine * (1 + 1e-6)
    # Rerun with the same --out: nothing recomputed.
    assert main(argv) == 0
    summary2 = json.loads((out / "summary.json").read_text())
    assert summary2["metadata"]["chunks_computed_this_run"] == 0
    assert summary2["points"][0]["amplitude"] == p0["amplitude"]
    # Another sweep into the same --out is refused in one line, and nothing is overwritten.
    before = (out / "summary.json").read_bytes()
    other = [a if a != "1500" else "1400" for a in argv]
    assert main(other) == 1
    assert (out / "summary.json").read_bytes() == before


def test_jumps_use_the_verified_amplitude(both):
    # Just after a jump a short continued transient still holds the old branch's motion:
    # the record's amplitude lags by a point. The verified orbit's amplitude does not.
    import dataclasses

    c = both.observe
    (j,) = [j for j in both.jumps() if j.direction == "up"]
    lagging = both.amplitude.copy()
    lagging[0, j.index_after, c] = j.amplitude_before
    stale = dataclasses.replace(both, amplitude=lagging, verdicts=None)
    (j_stale,) = [k for k in stale.jumps() if k.direction == "up"]
    assert j_stale.index_before == j.index_after  # the record alone puts it one point late
    verdicts = {"verified": np.ones(both.amplitude.shape[:2], bool),
                "amplitude": both.amplitude[..., c]}
    fixed = dataclasses.replace(stale, verdicts=verdicts)
    np.testing.assert_array_equal(fixed.steady_amplitude(), both.amplitude[..., c])
    (j_fixed,) = [k for k in fixed.jumps() if k.direction == "up"]
    assert (j_fixed.index_before, j_fixed.index_after) == (j.index_before, j.index_after)


def test_jumps_are_located_at_their_folds(problem, both):
    # The branch left behind by each jump ends at a fold between the two grid points;
    # continuation (shooting) from the orbit before the jump locates it.
    from bsfs_jax.analysis import locate_jump_folds

    jumps = [j for j in both.jumps() if j.hysteresis is not False]
    assert {j.direction for j in jumps} == {"up", "down"}
    locate_jump_folds(problem, both, jumps)
    for j in jumps:
        lo, hi = sorted((j.value_before, j.value_after))
        assert j.fold_located and lo < j.fold_value < hi, j
        # The fold's amplitude continues the branch before the jump (same side).
        assert abs(j.fold_amplitude - j.amplitude_before) < abs(
            j.fold_amplitude - j.amplitude_after)


def test_continued_segments_run_side_by_side(problem, both):
    # Two cost-balanced segments (vmapped lanes, same compiled chunk as the up+down run).
    seg = sweep(problem, OMEGAS, mode="continued", direction="up", config=CFG,
                segments=2, progress=False)
    starts = seg.metadata["segment_starts"]
    assert len(starts) == 2 and starts[0] == OMEGAS[0]
    # Outside the hysteresis band (where a cold start at a segment boundary may land on
    # either branch) the segmented sweep reproduces the single continuation. The first
    # point after a jump is excluded: 40 continued transient periods leave ~2 % of the
    # jump's transient there in the reference (a cold start has 150).
    (ju,) = [j for j in both.jumps() if j.direction == "up"]
    (jd,) = [j for j in both.jumps() if j.direction == "down"]
    outside = (OMEGAS <= jd.value_after) | (OMEGAS > ju.value_after + 1e-9)
    _, a_ref = both.frc("up")
    _, a_seg = seg.frc("up")
    np.testing.assert_allclose(a_seg[outside], a_ref[outside], rtol=2e-3)


def test_queue_engine_matches_lockstep_map(problem):
    # The work-queue engine (equal time slices, lanes pick up the next point) must give the
    # same steady responses as the plain lockstep batches.
    import dataclasses

    values = OMEGAS[::2]
    reference = sweep(problem, values, config=CFG, progress=False)
    queued = sweep(problem, values, config=dataclasses.replace(CFG, engine="queue",
                                                               max_slice_periods=4),
                   progress=False)
    assert np.all(result_ok(queued.result))
    np.testing.assert_allclose(queued.amplitude, reference.amplitude, rtol=1e-5)
    np.testing.assert_allclose(queued.strobe, reference.strobe, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(queued.spectrum, reference.spectrum, rtol=1e-3, atol=1e-7)


def test_waterfall_axis_ends_at_the_content(both):
    from bsfs_jax.plotting import plot_waterfall

    fig = plot_waterfall(both, direction="up")
    ax = fig.axes[0]
    keep = (both.spectrum_order > 0) & (both.spectrum_order <= 8)
    spec, freq = both.spectrum[0][:, keep], both.spectrum_hz()[:, keep]
    strong = spec > 1e-3 * np.nanmax(spec)
    assert ax.get_xlim()[1] == pytest.approx(1.1 * freq[strong].max())
    assert ax.get_xlim()[1] < freq.max()  # not to the end of the spectrum
    assert ax.get_xlabel().startswith("Response frequency") and "amplitude" in ax.get_zlabel()
    log = plot_waterfall(both, direction="up", log_amplitude=True).axes[0]
    assert log.get_zlabel().startswith("log10 amplitude")
