"""Benchmark S1: `simulate` vs scipy solve_ivp (RK45), and the cold/warm CLI.

S1: 200 periods at 500 Hz and 5000 N on the default preset, rtol 1e-8, atol 1e-12, both
saving the same 64 points per period. JAX is timed after compilation (median of repeats);
scipy runs the same model written in numpy (what a scipy user would write), once.
S2: `bsfs simulate --frequency 500 --force 5000` as a fresh process: cold (empty
compilation cache) and warm (cache filled by the previous run).

Usage: python benchmarks/bench_simulate.py [--quick]
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_info, machine_line  # noqa: E402
from scipy_model import bsfs_coefficients, rhs  # noqa: E402

import bsfs_jax as bsfs  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def bench_s1(repeats: int, periods: int) -> dict:
    params = bsfs.preset("default")
    system = bsfs.build_system(params)
    freq, force = 500.0, 5000.0
    kw = dict(frequency_hz=freq, force_n=force, periods=periods, transient_periods=0,
              samples_per_period=64, rtol=1e-8, atol=1e-12)
    timings = {}
    for solver in ("tsit5", "dopri5-fused"):
        t0 = time.perf_counter()
        traj = bsfs.simulate(system, solver=solver, **kw)
        jax.block_until_ready(traj.t)
        first = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            traj = bsfs.simulate(system, solver=solver, **kw)
            jax.block_until_ready(traj.t)
            times.append(time.perf_counter() - t0)
        timings[solver] = (first, statistics.median(times), times, int(traj.num_steps))
    first, jax_s, times, _ = timings["tsit5"]
    fused_first, fused_s, fused_times, fused_steps = timings["dopri5-fused"]
    # The same model in plain numpy/scipy (benchmarks/scipy_model.py, shared with B1).
    coeffs = bsfs_coefficients(params)
    t_eval = np.asarray(traj.t)
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.zeros(6), method="RK45", t_eval=t_eval,
                    rtol=1e-8, atol=1e-12, args=(coeffs, freq, force))
    scipy_s = time.perf_counter() - t0
    diff = np.max(np.abs(sol.y[2] - np.asarray(traj.displacement[:, 2])))
    amp = float(traj.amplitude())
    return {
        "case": f"default preset, {freq:g} Hz, {force:g} N, {periods} periods, rtol 1e-8, "
                "atol 1e-12, 64 samples/period",
        "jax_first_call_s": first, "jax_median_s": jax_s, "jax_runs_s": times,
        "jax_steps": int(traj.num_steps), "scipy_rk45_s": scipy_s, "scipy_nfev": int(sol.nfev),
        "speedup": scipy_s / jax_s, "max_abs_diff_x_n_um": diff * 1e6,
        "fused_first_call_s": fused_first, "fused_median_s": fused_s, "fused_runs_s": fused_times,
        "fused_steps": fused_steps, "fused_speedup": scipy_s / fused_s,
        "amplitude_um": amp * 1e6,
    }


def bench_s2(repeats: int) -> dict:
    exe = shutil.which("bsfs") or str(Path(sys.executable).parent / "bsfs")
    cmd = [exe, "simulate", "--frequency", "500", "--force", "5000"]
    cold, warm = [], []
    for _ in range(repeats):
        cache = tempfile.mkdtemp(prefix="bsfs-cache-")
        out = tempfile.mkdtemp(prefix="bsfs-out-")
        env = {**os.environ, "BSFS_CACHE_DIR": cache}
        for bucket in (cold, warm):
            t0 = time.perf_counter()
            subprocess.run(cmd + ["--out", out], env=env, check=True, capture_output=True)
            bucket.append(time.perf_counter() - t0)
        shutil.rmtree(cache, ignore_errors=True)
        shutil.rmtree(out, ignore_errors=True)
    return {"command": " ".join(["bsfs"] + cmd[1:]) + " --out DIR", "cold_runs_s": cold,
            "warm_runs_s": warm, "cold_median_s": statistics.median(cold),
            "warm_median_s": statistics.median(warm)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    info = machine_info()
    s1 = bench_s1(repeats=3 if args.quick else 7, periods=200)
    s2 = bench_s2(repeats=1 if args.quick else 3)
    result = {"machine": info, "S1": s1, "S2": s2}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "simulate.json").write_text(json.dumps(result, indent=2))
    md = [
        "## S1 One simulation",
        "",
        "Command: `python benchmarks/bench_simulate.py`.",
        machine_line(info),
        "",
        f"S1: {s1['case']}.",
        "",
        "| implementation | time [s] | ratio |",
        "|---|---|---|",
        f"| bsfs `simulate(..., solver=\"dopri5-fused\")` (fused loop, the CLI's default) | "
        f"{s1['fused_median_s']:.3f} | 1 |",
        f"| bsfs `simulate` (diffrax Tsit5, the library default) | "
        f"{s1['jax_median_s']:.3f} | {s1['jax_median_s'] / s1['fused_median_s']:.1f}x slower |",
        f"| scipy `solve_ivp` RK45, numpy right-hand side | {s1['scipy_rk45_s']:.2f} | "
        f"{s1['fused_speedup']:.0f}x slower (Tsit5: {s1['speedup']:.0f}x) |",
        "",
        f"First call (compile + run): {s1['jax_first_call_s']:.2f} s; {s1['jax_steps']} steps; "
        f"scipy {s1['scipy_nfev']} RHS evaluations. Max |x_n difference| between the two: "
        f"{s1['max_abs_diff_x_n_um']:.2e} um on an amplitude of {s1['amplitude_um']:.2f} um. "
        f"Target: at least 50x: **{'met' if s1['fused_speedup'] >= 50 else 'NOT met'}** with the "
        f"fused loop, **{'met' if s1['speedup'] >= 50 else 'NOT met'}** with diffrax Tsit5.",
        "",
        f"S2: `{s2['command']}` as a fresh process (import, compile or cache load, 250 periods, "
        "figure and files):",
        "",
        "| run | median [s] | runs [s] |",
        "|---|---|---|",
        f"| cold (empty compilation cache) | {s2['cold_median_s']:.2f} | "
        + ", ".join(f"{x:.2f}" for x in s2["cold_runs_s"]) + " |",
        f"| warm (persistent cache filled) | {s2['warm_median_s']:.2f} | "
        + ", ".join(f"{x:.2f}" for x in s2["warm_runs_s"]) + " |",
        "",
        f"Targets: at most 15 s cold: **{'met' if s2['cold_median_s'] <= 15 else 'NOT met'}**; "
        f"at most 5 s warm: **{'met' if s2['warm_median_s'] <= 5 else 'NOT met'}**.",
        "",
    ]
    (RESULTS / "simulate.md").write_text("\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
