"""Benchmark B1 on an accelerator: the per-point kernel against vmap and numba.

B1: default preset at 5000 N, N frequencies evenly over 100-4000 Hz, each a cold start
from rest, 200 transient periods then 64 stroboscopic samples, rtol 1e-8, atol 1e-12.

Cases, in this order, each written as one JSON line to OUT/gpu.jsonl as soon as it ends
(so a run stopped at its time limit keeps what it finished):

1. smoke: 64 points, 20 + 4 periods, kernel against the fused loop vmapped (agreement);
2. kernel at each of --points: first call (trace, compile, run) and a second call (run);
3. numba Dormand-Prince with prange over all CPU threads at --numba-points (the same
   method and controller; `numba_dopri.py`), and the kernel's strobe against it;
4. vmap over the fused loop (engine "map", the whole chunk one batch) at --vmap-points;
5. a verified sweep (`sweep(..., verify=VerifySettings())`, 16 recorded periods) at
   --verify-points, kernel engine for its sampling runs.

Usage: python benchmarks/bench_gpu.py --out DIR [--points 240,2048,16384,65536]
       [--numba-points 240,2048] [--vmap-points 2048] [--verify-points 2048]
       [--budget SECONDS]
Cases that would start after --budget seconds are skipped (and say so).
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))


def ints(text):
    return [int(x) for x in text.split(",") if x.strip()]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--points", type=ints, default=[240, 2048, 16384, 65536])
    p.add_argument("--numba-points", type=ints, default=[240, 2048])
    p.add_argument("--vmap-points", type=ints, default=[2048])
    p.add_argument("--verify-points", type=ints, default=[2048])
    p.add_argument("--blocks", type=ints, default=[32],
                   help="kernel lanes per program to time at the largest --points")
    p.add_argument("--budget", type=float, default=420.0)
    p.add_argument("--kernel-fast", type=int, default=1,
                   help="SweepConfig.kernel_fast for the kernel engine (1 or 0)")
    p.add_argument("--unroll", type=int, default=1,
                   help="SweepConfig.kernel_unroll for the kernel engine")
    p.add_argument("--looped", type=int, default=1,
                   help="SweepConfig.kernel_looped for the kernel engine (1 or 0)")
    p.add_argument("--smoke", type=int, default=1, help="run case 1 (1) or not (0)")
    p.add_argument("--kernel-checks", type=int, default=0,
                   help="VerifySettings.kernel_checks of the verified case (the orbit "
                   "checks on the kernel: 1; vmapped: 0)")
    p.add_argument("--settle", type=int, default=1,
                   help="VerifySettings.settle of the verified case (1: settle blocks on "
                   "the sweep's kernel program before the lockstep long runs)")
    p.add_argument("--wide", type=int, default=1,
                   help="VerifySettings.wide of the verified case (1: one lockstep batch per "
                   "chunk, the accelerator's default; 0: batches of 16)")
    p.add_argument("--variants", type=ints, default=[],
                   help="instead of the cases: time the kernel alone (integrate_lanes) at "
                   "these point counts for each block size in VARIANTS")
    args = p.parse_args()
    t_start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = open(out / "gpu.jsonl", "a")

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from bsfs_jax import preset
    from bsfs_jax.analysis import SweepConfig, VerifySettings, bsfs_problem, sweep
    from bsfs_jax.solvers import SolverSettings

    dev = jax.devices()[0]
    info = {"case": "machine", "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "kernel_fast": bool(args.kernel_fast), "kernel_unroll": args.unroll,
            "kernel_looped": bool(args.looped),
            "device": str(getattr(dev, "device_kind", dev)), "backend": jax.default_backend(),
            "jax": jax.__version__, "cpu_threads": os.cpu_count()}

    def emit(row):
        row["elapsed_s"] = round(time.perf_counter() - t_start, 2)
        log.write(json.dumps(row) + "\n")
        log.flush()
        print(json.dumps(row), flush=True)

    emit(info)
    force, n_tr, n_samp, rtol, atol = 5000.0, 200, 64, 1e-8, 1e-12
    params = preset("default")
    problem = bsfs_problem(params, "frequency_hz", force_n=force)
    settings = SolverSettings(rtol=rtol, atol=atol, max_steps=4_000_000, solver="dopri5-fused")

    def config(n, engine, **kw):
        base = dict(transient_periods=n_tr, periods=n_samp, samples_per_period=1,
                    lyapunov=False, batch_size=n, chunk_size=n, engine=engine,
                    settings=settings, kernel_fast=bool(args.kernel_fast),
                    kernel_unroll=args.unroll, kernel_looped=bool(args.looped))
        base.update(kw)
        return SweepConfig(**base)

    def timed(fn):
        t0 = time.perf_counter()
        r = fn()
        return r, time.perf_counter() - t0

    def over(name):
        if time.perf_counter() - t_start > args.budget:
            emit({"case": name, "skipped": f"budget {args.budget:g} s spent"})
            return True
        return False

    if args.variants:
        variants(args, problem, emit, timed, over, np)
        emit({"case": "done"})
        return

    # 1. smoke: agreement with the fused loop on a short horizon.
    smoke_points = 64 if args.smoke else 0
    f64 = np.linspace(500.0, 4000.0, 64)
    cfg_k = config(64, "kernel", transient_periods=20, periods=4, samples_per_period=8)
    cfg_m = config(64, "map", transient_periods=20, periods=4, samples_per_period=8)
    if smoke_points:
        rk, tk = timed(lambda: sweep(problem, f64, config=cfg_k, progress=False))
        rm, tm = timed(lambda: sweep(problem, f64, config=cfg_m, progress=False))
        amp = np.asarray(rm.amplitude)[0]
        dev_s = np.abs(np.asarray(rk.strobe) - np.asarray(rm.strobe))[0].max(axis=1)
        rel = dev_s / np.maximum(amp, 1e-300)
        emit({"case": "smoke", "points": 64, "kernel_first_s": tk, "map_first_s": tm,
              "failed_kernel": int(np.sum(rk.failed)), "failed_map": int(np.sum(rm.failed)),
              "strobe_rel_dev_median": float(np.median(rel)),
              "strobe_rel_dev_max": float(rel.max()),
              "steps_kernel": int(np.sum(rk.num_steps)),
              "steps_map": int(np.sum(rm.num_steps))})

    kernel_runs = {}
    for n in args.points:
        if over(f"kernel {n}"):
            continue
        freqs = np.linspace(100.0, 4000.0, n)
        cfg = config(n, "kernel")
        r1, first = timed(lambda: sweep(problem, freqs, config=cfg, progress=False))
        r2, second = timed(lambda: sweep(problem, freqs, config=cfg, progress=False))
        kernel_runs[n] = r2
        steps = np.asarray(r2.num_steps)[0]
        emit({"case": "kernel", "points": n, "block": 32, "first_call_s": first,
              "run_s": second, "points_per_s": n / second, "failed": int(np.sum(r2.failed)),
              "steps_total": int(steps.sum()), "steps_max": int(steps.max())})
    for b in args.blocks:
        if b == 32 or not args.points or over(f"kernel block {b}"):
            continue
        n = max(args.points)
        freqs = np.linspace(100.0, 4000.0, n)
        cfg = config(n, "kernel", kernel_block=b)
        sweep(problem, freqs, config=cfg, progress=False)
        r, t = timed(lambda: sweep(problem, freqs, config=cfg, progress=False))
        emit({"case": "kernel", "points": n, "block": b, "run_s": t, "points_per_s": n / t})

    # 3. numba on all threads.
    from numba_dopri import sweep_numba_parallel
    from scipy_model import bsfs_coefficients

    coeffs = bsfs_coefficients(params)
    numba_strobes = {}

    def against_numba(result, n):
        """(median, count within 1e-3) of max |x_n strobe difference| / amplitude."""
        strobe = numba_strobes[n]
        ours = np.asarray(result.strobe)[0][:, :, 2]
        a = 0.5 * (strobe[:, :, 2].max(axis=1) - strobe[:, :, 2].min(axis=1))
        d = np.abs(ours - strobe[:, :, 2]).max(axis=1) / np.maximum(a, 1e-300)
        return float(np.median(d)), int(np.sum(d < 1e-3))

    sweep_numba_parallel(coeffs, np.array([3900.0, 4000.0]), force, 2, 2, rtol, atol)
    for n in args.numba_points:
        if over(f"numba {n}"):
            continue
        freqs = np.linspace(100.0, 4000.0, n)
        (strobe, steps, status), t = timed(
            lambda: sweep_numba_parallel(coeffs, freqs, force, n_tr, n_samp, rtol, atol))
        row = {"case": "numba_prange", "points": n, "threads": os.cpu_count(), "run_s": t,
               "points_per_s": n / t, "failed": int(np.sum(status != 0)),
               "steps_total": int(steps.sum())}
        numba_strobes[n] = strobe
        if n in kernel_runs:
            med, within = against_numba(kernel_runs[n], n)
            row.update(kernel_vs_numba_median=med, kernel_vs_numba_within_1e3=within)
            row["kernel_speedup"] = t / next(
                json.loads(x)["run_s"] for x in open(out / "gpu.jsonl")
                if '"case": "kernel"' in x and f'"points": {n},' in x)
        emit(row)

    # 4. vmap over the fused loop (the engine the kernel replaces).
    for n in args.vmap_points:
        if over(f"vmap {n}"):
            continue
        freqs = np.linspace(100.0, 4000.0, n)
        cfg = config(n, "map")
        r, first = timed(lambda: sweep(problem, freqs, config=cfg, progress=False))
        row = {"case": "vmap", "points": n, "first_call_s": first,
               "failed": int(np.sum(r.failed))}
        if n in numba_strobes:
            med, within = against_numba(r, n)
            row.update(vmap_vs_numba_median=med, vmap_vs_numba_within_1e3=within)
        emit(row)

    # 5. a verified sweep.
    for n in args.verify_points:
        if over(f"verified {n}"):
            continue
        freqs = np.linspace(100.0, 4000.0, n)
        cfg = config(n, "kernel", periods=16, transient_periods=200)
        ver = VerifySettings(wide=bool(args.wide), kernel_checks=bool(args.kernel_checks),
                             settle=bool(args.settle))
        phases = phase_timers()
        r1, first = timed(lambda: sweep(problem, freqs, config=cfg, progress=False,
                                        verify=ver))
        first_phases = phases.take()
        if over(f"verified {n} second call"):
            emit({"case": "verified", "points": n, "first_call_s": first, "wide": ver.is_wide(),
                  "phases_first": first_phases})
            continue
        r2, second = timed(lambda: sweep(problem, freqs, config=cfg, progress=False,
                                         verify=ver))
        labels = {}
        for m in np.asarray(r2.verdicts["motion"])[0]:  # the verified labels
            labels[str(m)] = labels.get(str(m), 0) + 1
        emit({"case": "verified", "points": n, "first_call_s": first, "run_s": second,
              "wide": ver.is_wide(), "kernel_checks": ver.kernel_checks,
              "settle": ver.settle, "labels": labels, "phases_first": first_phases,
              "phases_run": phases.take()})
    emit({"case": "done"})


def phase_timers():
    """Seconds and calls of the verified sweep's phases (the verification as a whole, its
    orbit checks, its continuation blocks), by wrapping them; `take()` returns and resets."""
    from bsfs_jax.analysis import _orbit_trials, _verify

    acc = {}

    def wrap(owner, name, key):
        fn = getattr(owner, name)

        depth = [0]

        def timed_fn(*a, **k):  # the outermost call of a recursion only
            t0 = time.perf_counter()
            depth[0] += 1
            try:
                return fn(*a, **k)
            finally:
                depth[0] -= 1
                if not depth[0]:
                    s, c = acc.get(key, (0.0, 0))
                    acc[key] = (s + time.perf_counter() - t0, c + 1)

        setattr(owner, name, timed_fn)

    wrap(_verify, "verify_sweep", "verify_s")
    wrap(_verify, "run_block", "blocks_s")
    wrap(_orbit_trials.OrbitTrials, "orbits", "orbit_checks_s")

    # Each batch call of the checks (vmapped or on the kernel): its seconds, lanes, and
    # its lockstep length, the longest lane's n x (chord iterations + 2) periods (what a
    # vmapped call's time follows on an accelerator; a kernel call's lanes run apart).
    import jax
    import numpy as np

    batches = []

    def wrap_batch(name):
        fn = getattr(_orbit_trials, name)

        def timed_batch(*a, **k):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(*a, **k))
            n, steps = np.asarray(a[6]), np.asarray(out.steps)
            conv, res, vals = (np.asarray(out.converged), np.asarray(out.residual),
                               np.asarray(a[3]))
            # the points whose chord iterations reached their limit or did not converge
            # (the batch's padding repeats its last point: each (value, n) once)
            stuck = {}
            for i in np.flatnonzero((steps >= k.get("max_steps", 16)) | ~conv):
                stuck.setdefault((float(vals[i]), int(n[i])), {
                    "value": round(float(vals[i]), 4), "n": int(n[i]),
                    "chord": int(steps[i]), "residual": float(f"{res[i]:.3g}"),
                    "converged": bool(conv[i])})
            batches.append({"fn": name, "s": round(time.perf_counter() - t0, 3),
                            "lanes": int(n.size), "n_max": int(n.max()),
                            "chord_max": int(steps.max()),
                            "lockstep_periods": int(np.max(n * (steps + 2))),
                            "unconverged": int(np.sum(~conv)),
                            "stuck": list(stuck.values())[:12]})
            return out

        setattr(_orbit_trials, name, timed_batch)

    wrap_batch("check_orbits")
    wrap_batch("check_orbits_lanes")

    # Each call of the settle blocks: its seconds, the points it took on and those it
    # verified (the parameter values of up to 12 pending ones).
    settle = _orbit_trials.OrbitTrials.settle

    def timed_settle(self, run, pending, values, *rest):
        t0 = time.perf_counter()
        out = settle(self, run, pending, values, *rest)
        try:
            shown = [round(float(np.asarray(values)[k]), 4) for k in list(pending)[:12]]
        except Exception:  # noqa: BLE001 - keys that do not index the values
            shown = []
        batches.append({"fn": "settle", "s": round(time.perf_counter() - t0, 3),
                        "points": len(pending), "verified": len(out[0]), "values": shown})
        return out

    _orbit_trials.OrbitTrials.settle = timed_settle

    class Phases:
        def take(self):
            out = {k: {"s": round(v[0], 3), "calls": v[1]} for k, v in acc.items()}
            out["check_batches"] = list(batches)
            acc.clear()
            batches.clear()
            return out

    return Phases()


VARIANTS = [  # (name, block, num_warps): lanes per Triton program and the warps running them
    ("default", 32, 1),
    ("block 128, 4 warps", 128, 4),
    ("block 16", 16, 1),
]
# Measured on an H100 on 2026-11-26 and since removed from the kernel (results in
# benchmarks/results/gpu_b1.json, run "variants"): the restart and sample stores computed
# on every step and masked (5.05 s at 240 points, against 4.66 s in a `cond`), and the
# controller's power as exp(log) (4.62 s, no gain).


def variants(args, problem, emit, timed, over, np):
    """The kernel alone (no sweep around it) for each variant, first call and run."""
    import jax

    from bsfs_jax.model import kernel_vector_field
    from bsfs_jax.solvers import integrate_lanes

    for name, block, warps in VARIANTS:
        for n in args.variants:
            if over(f"variant {name} {n}"):
                continue
            freqs = jax.numpy.linspace(100.0, 4000.0, n)

            def run(v, block=block, warps=warps):
                a, per = jax.vmap(lambda x: problem.setup(problem.data, x))(v)
                return integrate_lanes(kernel_vector_field, jax.numpy.zeros((n, 6)), a,
                                       200 * per, per, n_samples=64, samples_per_period=1,
                                       rtol=1e-8, atol=1e-12, max_steps=4_000_000,
                                       block=block, num_warps=warps,
                                       fast=bool(args.kernel_fast))

            fn = jax.jit(run)
            _, first = timed(lambda: jax.block_until_ready(fn(freqs)))
            out, second = timed(lambda: jax.block_until_ready(fn(freqs)))
            steps = np.asarray(out[4])
            emit({"case": "variant", "name": name, "points": n, "block": block,
                  "num_warps": warps, "first_call_s": first, "run_s": second,
                  "failed": int(np.sum(np.asarray(out[3]) != 0)),
                  "steps_max": int(steps.max()),
                  "us_per_step_slowest": second / steps.max() * 1e6})


if __name__ == "__main__":
    main()
