"""S1/S2: shooting one BSFS periodic orbit, and continuing the FRC through its folds.

S1: `shoot` of the default preset at 1100 Hz, 3000 N (Floquet multipliers included):
first call (compile + run), then the median run from the transient guess and from the
orbit at a neighbouring frequency (what a continuation step costs); compared with a
brute-force `simulate` of 200 transient + 64 saved periods at the same frequency.
S2: `continue_orbits` from 1000 to 1400 Hz (--quick: 1100-1150 Hz): points, steps, time
per point, folds found.

Usage: python benchmarks/bench_shooting.py [--quick]
Writes benchmarks/results/shooting.md and shooting.json.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine_info, machine_line  # noqa: E402

from bsfs_jax.params import preset  # noqa: E402
from bsfs_jax.solvers import bsfs_family, continue_orbits, shoot, simulate  # noqa: E402

RESULTS = Path(__file__).parent / "results"
FORCE_N = 3000.0
FREQ_HZ = 1100.0


def _timed(fn):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short continuation, 3 repeats")
    opts = ap.parse_args(argv)
    repeats = 3 if opts.quick else 7
    params = preset("default")
    family = bsfs_family(params, FORCE_N)
    vf = family.vector_field
    args, period = family(FREQ_HZ)
    args2, period2 = family(FREQ_HZ + 5.0)

    guess = simulate(params, frequency_hz=FREQ_HZ, force_n=FORCE_N, transient_periods=30,
                     periods=1).final_state
    orbit, t_first = _timed(lambda: shoot(vf, guess, args, period, scale=family.scale))
    runs = [_timed(lambda: shoot(vf, guess, args, period, scale=family.scale))[1]
            for _ in range(repeats)]
    warm = [_timed(lambda: shoot(vf, orbit.state, args2, period2, scale=family.scale))[1]
            for _ in range(repeats)]
    t_run, t_warm = float(np.median(runs)), float(np.median(warm))
    newton_cold = int(orbit.newton_steps)
    newton_warm = int(shoot(vf, orbit.state, args2, period2, scale=family.scale).newton_steps)

    def brute():
        return simulate(params, frequency_hz=FREQ_HZ, force_n=FORCE_N, transient_periods=200,
                        periods=64, samples_per_period=1).final_state

    _timed(brute)  # compile
    t_brute = float(np.median([_timed(brute)[1] for _ in range(repeats)]))

    f0, f1 = (1100.0, 1150.0) if opts.quick else (1000.0, 1400.0)
    args0, period0 = family(f0)
    g0 = shoot(vf, jnp.asarray(simulate(params, frequency_hz=f0, force_n=FORCE_N,
                                        transient_periods=30, periods=1).final_state),
               args0, period0, scale=family.scale).state
    t0 = time.perf_counter()
    branch = continue_orbits(family, g0, f0, f1, ds=0.2, amplitude_index=2)
    t_cont = time.perf_counter() - t0
    folds = [round(b.p, 2) for b in branch.bifurcations if b.kind == "fold"]

    info = machine_info()
    result = {
        "machine": info,
        "case": f"default preset, {FORCE_N:g} N, {FREQ_HZ:g} Hz; dopri8 rtol 1e-11 in scaled "
                "variables (SHOOTING_SETTINGS)",
        "shoot_first_call_s": t_first,
        "shoot_compile_s_estimate": t_first - t_run,
        "shoot_run_from_transient_guess_s": t_run,
        "shoot_run_from_neighbour_orbit_s": t_warm,
        "newton_steps_cold": newton_cold,
        "newton_steps_warm": newton_warm,
        "brute_force_simulate_264_periods_s": t_brute,
        "speedup_warm_shoot_vs_brute_force": t_brute / t_warm,
        "multipliers_abs": np.abs(np.asarray(orbit.multipliers)).tolist(),
        "continuation": {"range_hz": [f0, f1], "points": len(branch),
                         "steps": branch.info["steps"], "rejected": branch.info["rejected"],
                         "corrector_calls": branch.info["corrector_calls"],
                         "total_s_including_compile": t_cont,
                         "s_per_corrector_call": t_cont / branch.info["corrector_calls"],
                         "folds_hz": folds},
        "repeats": repeats,
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "shooting.json").write_text(json.dumps(result, indent=2) + "\n")
    c = result["continuation"]
    md = f"""# Shooting and continuation (S1, S2)

{machine_line(info)} Medians over {repeats} repeats after compilation.

Case: {result['case']}.

| S1: one periodic orbit | time |
|---|---|
| first call (compile + run) | {t_first:.2f} s |
| compile (estimate: first call - run) | {t_first - t_run:.2f} s |
| run from a 30-period transient guess ({newton_cold} Newton steps) | {t_run * 1e3:.1f} ms |
| run from the orbit at {FREQ_HZ + 5:g} Hz ({newton_warm} Newton steps) | {t_warm * 1e3:.1f} ms |
| brute force: `simulate` 200 transient + 64 periods (tsit5, rtol 1e-8) | {t_brute * 1e3:.1f} ms |
| ratio brute force / warm shoot | {t_brute / t_warm:.1f}x |

Floquet multiplier moduli at {FREQ_HZ:g} Hz: {', '.join(f'{m:.4f}' for m in result['multipliers_abs'])}.

S2: continuation {f0:g}-{f1:g} Hz (ds = 0.2): {c['points']} orbits, {c['steps']} steps
({c['rejected']} rejected), {c['corrector_calls']} corrector calls in {t_cont:.1f} s including
compilation ({c['s_per_corrector_call'] * 1e3:.0f} ms per call); folds at {folds} Hz.
"""
    (RESULTS / "shooting.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
