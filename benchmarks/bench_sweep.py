"""Benchmark B1: a cold frequency sweep of the BSFS, JAX vs numba Dormand-Prince vs scipy.

B1: default preset at 5000 N; 240 frequencies evenly over 100-4000 Hz; a cold
start from rest at each; 200 transient periods, then 64 stroboscopic samples;
rtol 1e-8, atol 1e-12. Side by side in one run:

- ours: `bsfs_jax.analysis.sweep` (cold mode, Tsit5 + PID, lockstep batches), timed
  after a warm-up that compiles the chunk function;
- numba: `numba_dopri.dopri5_strobe`, Dormand-Prince 5(4) with diffrax's error norm and
  controller, one point after the other on one core, over all points;
- scipy: `solve_ivp(method="RK45")` per-step cost measured on a subset (short horizons),
  extrapolated with the step counts scipy needs for the full horizon (estimated from the
  numba step counts, scaled by scipy/numba's step ratio on one complete point);
- continued mode (20 transient periods per point after the first) producing the same
  diagram, checked point by point against the cold sweep;
- ours, verified: `sweep(..., verify=VerifySettings())` with 16 recorded
  periods: per-point minimum transient from the slowest linear decay rate, shooting
  checks of the periodic orbit and its Floquet multipliers, continuation blocks where no
  orbit is found; timed after a warm-up run on the same values (compile listed apart);
- numba brute force "long enough": each point from rest with 2 s of transient
  (ceil(2 s x f) periods), then 16 periods at 64 samples per period, on one core and
  with prange, on every `--brute-stride`-th point, scaled to all points by the simulated
  time; its x_n amplitude checks the verified amplitudes, and the 200-period sweep's
  sample-based labels are compared with the verified ones.

Usage: python benchmarks/bench_sweep.py [--quick] [--devices 2] [--brute-stride 6]
Writes benchmarks/results/b1_sweep.md and .json (or b1_sweep_quick.* with --quick).
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

NOTES = """
Notes:
- Our sweep uses the fused Dormand-Prince 5(4) loop (`solver="dopri5-fused"`, the same
  method and controller as diffrax's Dopri5 + PID, written as one `lax.scan` over save
  times around a `lax.while_loop` of steps; cross-checked against diffrax in
  tests/test_fused.py). The diffrax Tsit5 path costs 3-4 us/step inside a vmapped sweep on
  this CPU (`--solver tsit5` to measure it): its general loop's bookkeeping dominates on a
  6-state system, and vmap turns its internal `cond`s into `select`s.
- Lockstep waste: low frequencies need far more steps (the horizon is 264 periods); a
  batch waits for its slowest member. The "queue" engine (`SweepConfig(engine="queue")`)
  gives lanes equal time slices instead; it was no faster here.
- Continued mode is not 5x faster and does not give "the same diagram": each point depends
  on its neighbour, so points run one after another (no batching), and with 20 transient
  periods per point the first mode (decay rate ~81 1/s, zeta 0.011 at 1.14 kHz) leaves
  transients of 1e-2 or more; near the resonance the continued branch also legitimately
  sits on a different coexisting attractor than a start from rest. Even the cold
  200-period diagram is ~2 % unconverged at 4 kHz (200 periods = 50 ms, e^(-81 x 0.05)).
  With the 64 recorded periods counted, no transient length can make continuation more
  than (200+64)/64 = 4.1x cheaper per point anyway. Shooting (`bsfs continue`) is the
  route to converged periodic branches, stable and unstable.
- Memory stays bounded (strobe, spectra and amplitudes only).
- Verified run: its time includes everything `sweep(..., verify=...)` does after
  compilation (decay rates, the sampling sweep with the per-point minimum transient,
  batched shooting checks, continuation blocks); the warm-up is one complete run on the
  same values, so every shape the verifier meets is compiled before timing (compile =
  warm-up minus the median run). The verifier's amplitude is half the peak-to-peak of
  x_n over the orbit's samples (32 per period, `check_orbits`); the numba amplitude is
  compared at the same phases (every other of its 64 samples per period), and also at
  all 64 (that difference is mostly the coarser sampling of the orbit).
- numba brute force: 2 s is ~160 time constants of the slowest linear mode (~81 1/s),
  so its 16 recorded periods sit on the attractor; its time is measured on an evenly
  spread subset and scaled by the total simulated time ((ceil(2 s x f) + 16) / f per
  point); 64 samples per period add under 0.2 % steps to the stroboscopic-only run.
"""


def parse():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true",
                   help="24 frequencies instead of 240 (same horizon and tolerances)")
    p.add_argument("--num", type=int, default=None, help="number of frequencies")
    p.add_argument("--batch", type=int, default=8,
                   help="lockstep batch of our sweep (on this CPU a vmapped adaptive step "
                   "costs nearly as much per member as a single one; 8 measured best)")
    p.add_argument("--chunk", type=int, default=40, help="points per jit call/checkpoint")
    p.add_argument("--segments", type=int, default=1,
                   help="continued mode: parallel continuation segments")
    p.add_argument("--devices", type=int, default=2,
                   help="host CPU devices; with > 1 the cold sweep is also timed sharded "
                   "over them (jax.shard_map)")
    p.add_argument("--repeats", type=int, default=None,
                   help="timed repeats of the fast runs (default 3 quick, 1 full)")
    p.add_argument("--scipy-points", type=int, default=3)
    p.add_argument("--solver", default="dopri5-fused",
                   help="our integrator: 'dopri5-fused' (fast forward path) or a diffrax "
                   "solver name such as 'tsit5'")
    p.add_argument("--engine", choices=("map", "queue", "both"), default="map",
                   help="cold-sweep engine(s) to time (see SweepConfig.engine)")
    p.add_argument("--brute-stride", type=int, default=None,
                   help="numba 2 s brute force on every k-th frequency, scaled to all "
                   "(default 6, quick 2)")
    p.add_argument("--brute-seconds", type=float, default=2.0,
                   help="transient of the numba brute force [s]")
    p.add_argument("--samples-per-period", type=int, default=1,
                   help="samples per period kept by our sweep (1 = stroboscopic only, "
                   "like the references)")
    return p.parse_args()


def machine() -> dict:
    model = "unknown"
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name"):
                model = line.split(":", 1)[1].strip()
    except OSError:
        pass
    return {"cpu": model, "cores": os.cpu_count(), "python": platform.python_version(),
            "load_average_at_start": os.getloadavg()}


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def median(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2] if len(xs) % 2 else 0.5 * (xs[len(xs) // 2 - 1] + xs[len(xs) // 2])


def main():
    args = parse()
    if args.devices > 1:
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                                   + f" --xla_force_host_platform_device_count={args.devices}")
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    sys.path.insert(0, str(HERE))
    from numba_dopri import brute_force_numba, dopri5_strobe
    from scipy_model import bsfs_coefficients, solve_ivp_strobe

    from bsfs_jax import preset
    from bsfs_jax.analysis import SweepConfig, VerifySettings, bsfs_problem, sweep
    from bsfs_jax.solvers import SolverSettings

    num = args.num or (24 if args.quick else 240)
    repeats = args.repeats or (3 if args.quick else 1)
    freqs = np.linspace(100.0, 4000.0, num)
    force, n_tr, n_samp, rtol, atol = 5000.0, 200, 64, 1e-8, 1e-12
    params = preset("default")
    coeffs = bsfs_coefficients(params)
    info = {"benchmark": "B1", "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "machine": machine(), "points": num, "frequencies_hz": [100.0, 4000.0],
            "force_n": force, "transient_periods": n_tr, "samples": n_samp,
            "rtol": rtol, "atol": atol, "repeats": repeats}
    print(f"B1: {num} points, {repeats} repeat(s); {info['machine']}", flush=True)

    # --- ours: cold sweep -------------------------------------------------------------
    problem = bsfs_problem(params, "frequency_hz", force_n=force)
    settings = SolverSettings(rtol=rtol, atol=atol, max_steps=4_000_000, solver=args.solver)
    spp = args.samples_per_period
    engines = ("map", "queue") if args.engine == "both" else (args.engine,)
    variants = [(e, False) for e in engines]
    if args.devices > 1:
        variants.append((engines[0], True))
    runs = {}
    for engine, shard in variants:
        label = f"{engine}{' sharded' if shard else ''}"
        cfg = SweepConfig(transient_periods=n_tr, periods=n_samp, samples_per_period=spp,
                          lyapunov=False, batch_size=args.batch, chunk_size=args.chunk,
                          engine=engine, max_slice_periods=8, settings=settings)
        t0 = time.perf_counter()
        # Warm-up = compile: cheap (high-frequency) points with the same shapes.
        sweep(problem, np.linspace(3900.0, 4000.0, min(args.chunk, num)), config=cfg,
              progress=False, shard=shard)
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            result = sweep(problem, freqs, config=cfg, progress=False, shard=shard)
            times.append(time.perf_counter() - t0)
        ndev = result.metadata["sharded_over_devices"] or 1
        runs[label] = dict(result=result, seconds=median(times), runs=times,
                           compile_s=compile_s, steps=int(np.sum(result.num_steps)),
                           devices=ndev)
        print(f"ours (cold, {label}, batch {args.batch}, {ndev} device(s)): "
              f"{median(times):.2f} s (runs {['%.2f' % t for t in times]}), "
              f"compile+warm-up {compile_s:.1f} s, {runs[label]['steps']} steps, failed "
              f"{int(np.sum(result.failed))}", flush=True)
    best = min(runs, key=lambda e: runs[e]["seconds"])
    cold = runs[best]["result"]
    ours_s, ours_steps, compile_s = (runs[best]["seconds"], runs[best]["steps"],
                                     runs[best]["compile_s"])
    times = runs[best]["runs"]

    # --- numba Dormand-Prince ---------------------------------------------------------
    dopri5_strobe(coeffs, 2000.0, force, np.zeros(6), 2, 2, rtol, atol, 10**8)  # compile
    nb_times = []
    for rep in range(repeats):
        t0 = time.perf_counter()
        nb_strobe = np.empty((num, n_samp + 1, 6))
        nb_steps = np.zeros(num, dtype=np.int64)
        nb_status = np.zeros(num, dtype=np.int64)
        for i, f in enumerate(freqs):
            nb_strobe[i], nb_steps[i], nb_status[i] = dopri5_strobe(
                coeffs, float(f), force, np.zeros(6), n_tr, n_samp, rtol, atol, 10**8)
        nb_times.append(time.perf_counter() - t0)
    numba_s = median(nb_times)
    # The same loop on all cores (numba prange), for the multi-device comparison.
    par_s = None
    if args.devices > 1:
        from numba_dopri import sweep_numba_parallel

        sweep_numba_parallel(coeffs, freqs[-2:], force, 2, 2, rtol, atol)  # compile
        t0 = time.perf_counter()
        sweep_numba_parallel(coeffs, freqs, force, n_tr, n_samp, rtol, atol)
        par_s = time.perf_counter() - t0
        print(f"numba DOPRI5 (prange, all cores): {par_s:.2f} s", flush=True)
    print(f"numba DOPRI5 (1 core): {numba_s:.2f} s, {int(nb_steps.sum())} steps "
          f"({numba_s / nb_steps.sum() * 1e6:.2f} us/step)", flush=True)

    # --- scipy RK45: per-step cost on a subset, extrapolated --------------------------
    sub = np.linspace(0, num - 1, args.scipy_points).round().astype(int)
    sp_cost, sp_steps_short = [], []
    for i in sub:
        t0 = time.perf_counter()
        _, st, _ = solve_ivp_strobe(coeffs, float(freqs[i]), force, 10, 4, rtol, atol)
        sp_cost.append((time.perf_counter() - t0) / st)
        sp_steps_short.append(st)
    us_per_step = median(sp_cost) * 1e6
    # One complete high-frequency point: scipy's step count against numba's.
    t0 = time.perf_counter()
    sp_strobe, sp_full_steps, _ = solve_ivp_strobe(coeffs, float(freqs[-1]), force, n_tr,
                                                   n_samp, rtol, atol)
    sp_full_s = time.perf_counter() - t0
    step_ratio = sp_full_steps / nb_steps[-1]
    scipy_est_s = us_per_step * 1e-6 * step_ratio * float(nb_steps.sum())
    print(f"scipy RK45: {us_per_step:.1f} us/step on {len(sub)} short runs; steps "
          f"scipy/numba {step_ratio:.3f} on the {freqs[-1]:.0f} Hz point "
          f"({sp_full_s:.1f} s); extrapolated {scipy_est_s:.0f} s", flush=True)

    # --- agreement of the diagrams ----------------------------------------------------
    # Normalise deviations by each point's stroboscopic magnitude (floored at 1e-3 of the
    # largest), as the strobe-only runs carry no within-period amplitude.
    mag = np.nanmax(np.abs(nb_strobe[:, :, 2]), axis=1)
    amp = np.maximum(mag, 1e-3 * np.nanmax(mag))
    dev = np.abs(cold.strobe[0, :, :, 2] - nb_strobe[:, :, 2]).max(axis=1) / amp
    sp_dev = float(np.abs(sp_strobe[:, 2] - nb_strobe[-1, :, 2]).max() / amp[-1])
    motions = cold.motions()[0]
    periodic = np.array([m.kind == "periodic" for m in motions])
    agree = dev < 1e-3
    print(f"ours vs numba: strobe x_n max deviation / amplitude: median {np.median(dev):.2e}, "
          f"{int(agree.sum())}/{num} points < 1e-3 ({int(periodic.sum())} periodic)",
          flush=True)

    # --- continued mode: the same diagram with fewer transient periods ----------------
    cfg_c = SweepConfig(transient_periods=n_tr, continued_transient_periods=20, periods=n_samp,
                        samples_per_period=spp, lyapunov=False, batch_size=args.batch,
                        chunk_size=args.chunk, settings=settings)
    t0 = time.perf_counter()
    sweep(problem, np.linspace(3000.0, 4000.0, 2 * args.segments), mode="continued",
          config=cfg_c, progress=False, segments=args.segments)
    compile_c = time.perf_counter() - t0
    ctimes = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cont = sweep(problem, freqs, mode="continued", config=cfg_c, progress=False,
                     segments=args.segments)
        ctimes.append(time.perf_counter() - t0)
    cont_s = median(ctimes)
    cdev = np.abs(cont.strobe[0, :, :, 2] - cold.strobe[0, :, :, 2]).max(axis=1) / amp
    same = cdev < 1e-3
    close = cdev < 1e-2
    labels_same = sum(a.label == b.label for a, b in zip(motions, cont.motions()[0]))
    print(f"continued ({args.segments} segments, 20 transient periods): {cont_s:.2f} s; "
          f"vs cold: {int(same.sum())}/{num} points within 1e-3, {int(close.sum())} within 1e-2, "
          f"same class at {labels_same}",
          flush=True)

    # --- ours, verified: minimum transient + orbit checks, 16 periods --------
    import inspect
    from collections import Counter

    from bsfs_jax.analysis import minimum_transient
    from bsfs_jax.solvers import check_orbits

    vset = VerifySettings()
    n_rec = 16
    cfg_v = SweepConfig(periods=n_rec, samples_per_period=1, lyapunov=False,
                        batch_size=args.batch, chunk_size=args.chunk, settings=settings)
    t0 = time.perf_counter()
    # Warm-up: one complete run on the same values (every shape the verifier meets).
    sweep(problem, freqs, config=cfg_v, progress=False, verify=vset)
    warm_v = time.perf_counter() - t0
    vtimes = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        ver = sweep(problem, freqs, config=cfg_v, progress=False, verify=vset)
        vtimes.append(time.perf_counter() - t0)
    ver_s = median(vtimes)
    compile_v = max(warm_v - ver_s, 0.0)
    # Its sampling sweep alone (same per-point transients), to split the time.
    n_tr_v = minimum_transient(problem, freqs, 1.0 / freqs, vset,
                               fallback=cfg_v.transient_periods)
    t0 = time.perf_counter()
    sweep(problem, freqs, config=cfg_v, progress=False, transient=n_tr_v)
    ver_sweep_s = time.perf_counter() - t0
    vd = {k: np.asarray(a)[0] for k, a in ver.verdicts.items()}
    v_motion = [str(m) for m in vd["motion"]]
    v_ok = np.asarray(vd["verified"], dtype=bool)
    v_counts = dict(sorted(Counter(m for m, ok in zip(v_motion, v_ok) if ok).items()))
    v_unresolved = int(sum(m == "unresolved" for m in v_motion))
    v_failed = int(sum(m == "failed" for m in v_motion))
    unver = runs[engines[0]]  # unsharded, 1 device
    unver_s = unver["seconds"]
    print(f"ours, verified (1 device): {ver_s:.2f} s (runs {['%.2f' % t for t in vtimes]}), "
          f"warm-up run {warm_v:.1f} s, of which the sampling sweep {ver_sweep_s:.2f} s; "
          f"transients {int(n_tr_v.min())}-{int(n_tr_v.max())} periods; verified "
          f"{v_counts}, unresolved {v_unresolved}, failed {v_failed}", flush=True)

    # Labels: the 200-period sweep's sample-based candidates vs the verified ones.
    cand = [m.label for m in unver["result"].motions()[0]]
    cross = Counter(zip(cand, (m if ok else m + " (unverified)"
                               for m, ok in zip(v_motion, v_ok))))
    cand_counts = dict(sorted(Counter(cand).items()))

    def _other(lbl):
        return ((lbl.startswith("period-") and not lbl.startswith("period-1"))
                or lbl in ("quasi-periodic", "chaotic"))

    wrong = [i for i, (c, m, ok) in enumerate(zip(cand, v_motion, v_ok))
             if _other(c) and ok and m == "period-1"]
    wrong_by = dict(sorted(Counter(cand[i] for i in wrong).items()))
    print(f"200-period candidates {cand_counts}; labelled period-n (n > 1), quasi-periodic "
          f"or chaotic but verified period-1: {len(wrong)} {wrong_by}", flush=True)

    # --- numba brute force long enough: 2 s of transient, 16 periods x 64 samples ------
    stride = args.brute_stride or (2 if args.quick else 6)
    bsub = np.arange(0, num, stride)
    spp_nb = 64
    n_tr_b = np.ceil(args.brute_seconds * freqs).astype(np.int64)
    sim_t = (n_tr_b + n_rec) / freqs
    scale_b = float(sim_t.sum() / sim_t[bsub].sum())
    brute_force_numba(coeffs, freqs[-1:], force, np.array([2]), 2, 4, rtol, atol)  # compile
    b_times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        b_samp, b_steps, b_status = brute_force_numba(coeffs, freqs[bsub], force, n_tr_b[bsub],
                                                      n_rec, spp_nb, rtol, atol)
        b_times.append(time.perf_counter() - t0)
    brute_sub_s = median(b_times)
    brute_s = brute_sub_s * scale_b
    bpar_sub_s = bpar_s = None
    if args.devices > 1:
        brute_force_numba(coeffs, freqs[-2:], force, np.array([2, 2]), 2, 4, rtol, atol,
                          parallel=True)  # compile
        t0 = time.perf_counter()
        brute_force_numba(coeffs, freqs[bsub], force, n_tr_b[bsub], n_rec, spp_nb, rtol,
                          atol, parallel=True)
        bpar_sub_s = time.perf_counter() - t0
        bpar_s = bpar_sub_s * scale_b
    print(f"numba brute force ({args.brute_seconds:g} s transient, {len(bsub)}/{num} points, "
          f"scaled x{scale_b:.2f}): 1 core {brute_sub_s:.2f} s -> {brute_s:.1f} s, "
          f"{int(b_steps.sum())} steps on the subset"
          + ("" if bpar_s is None else f"; prange {bpar_sub_s:.2f} s -> {bpar_s:.1f} s"),
          flush=True)

    # --- accuracy: verified amplitudes vs the 2 s runs' ---------------------------------
    spp_v = int(inspect.signature(check_orbits).parameters["samples_per_period"].default)
    xb = b_samp[:, :, 2]
    amp_b64 = 0.5 * (xb.max(axis=1) - xb.min(axis=1))
    step = spp_nb // spp_v if spp_nb % spp_v == 0 else 1
    amp_bv = 0.5 * (xb[:, ::step].max(axis=1) - xb[:, ::step].min(axis=1))
    amp_v = np.asarray(vd["amplitude"], dtype=float)[bsub]
    periodic_v = np.array([v_ok[i] and v_motion[i].startswith("period-") for i in bsub])
    cmp_ok = periodic_v & (b_status == 0) & np.isfinite(amp_v)
    rel_v = np.abs(amp_v - amp_bv) / amp_bv
    rel_64 = np.abs(amp_v - amp_b64) / amp_b64
    # The 200-period (unverified) sweep's last strobe vs the 2 s run's, per amplitude.
    sb = b_samp[:, ::spp_nb, 2]
    rel_200 = np.abs(unver["result"].strobe[0, bsub, -1, 2] - sb[:, -1]) / amp_b64
    # The 2 s runs' own period-1 check: strobe repetition relative to the amplitude.
    rep_b = np.abs(np.diff(sb, axis=1)).max(axis=1) / amp_b64

    def _stat(x):
        x = x[cmp_ok]
        return (float(np.median(x)), float(np.max(x))) if x.size else (float("nan"),) * 2

    acc = {"compared_points": int(cmp_ok.sum()), "subset_points": int(len(bsub)),
           "verifier_samples_per_period": spp_v, "numba_samples_per_period": spp_nb,
           "rel_diff_same_phases": _stat(rel_v), "rel_diff_numba_64": _stat(rel_64),
           "rel_diff_200_period_strobe": _stat(rel_200),
           "numba_strobe_repetition": _stat(rep_b),
           "non_periodic_in_subset": int(len(bsub) - periodic_v.sum()),
           "numba_failed": int(np.sum(b_status != 0))}
    print(f"amplitude x_n, verified vs numba {args.brute_seconds:g} s on {acc['compared_points']}"
          f" points: same phases ({spp_v}/period) median {acc['rel_diff_same_phases'][0]:.1e}, "
          f"max {acc['rel_diff_same_phases'][1]:.1e}; vs 64/period median "
          f"{acc['rel_diff_numba_64'][0]:.1e}, max {acc['rel_diff_numba_64'][1]:.1e}; "
          f"200-period strobe vs 2 s: median {acc['rel_diff_200_period_strobe'][0]:.1e}, max "
          f"{acc['rel_diff_200_period_strobe'][1]:.1e}", flush=True)
    verified = {"seconds": ver_s, "runs": vtimes, "warmup_run_s": warm_v,
                "compile_s": compile_v, "sampling_sweep_s": ver_sweep_s,
                "periods": n_rec, "devices": 1, "batch": args.batch, "chunk": args.chunk,
                "transient_periods_min_max": [int(n_tr_v.min()), int(n_tr_v.max())],
                "sweep_steps": int(np.sum(ver.num_steps)),
                "verified_by_label": v_counts, "unresolved": v_unresolved,
                "failed": v_failed, "verify_settings": "VerifySettings() defaults"}
    labels = {"candidates_200_periods": cand_counts,
              "candidate_vs_verified": {f"{a} -> {b}": n for (a, b), n in
                                        sorted(cross.items())},
              "other_labels_verified_period_1": len(wrong),
              "other_labels_verified_period_1_by_candidate": wrong_by,
              "other_labels_verified_period_1_hz": [float(freqs[i]) for i in wrong]}
    brute = {"seconds_scaled": brute_s, "subset_seconds": brute_sub_s, "runs": b_times,
             "parallel_all_cores_seconds_scaled": bpar_s,
             "parallel_subset_seconds": bpar_sub_s, "transient_s": args.brute_seconds,
             "periods": n_rec, "samples_per_period": spp_nb, "stride": stride,
             "subset_points": int(len(bsub)), "scale_factor_simulated_time": scale_b,
             "subset_steps": int(b_steps.sum()),
             "us_per_step": brute_sub_s / b_steps.sum() * 1e6}

    rss = peak_rss_mb()
    res = dict(info)
    res.update({
        "ours": {"seconds": ours_s, "runs": times, "compile_and_warmup_s": compile_s,
                 "engine": best, "samples_per_period": spp,
                 "engines": {e: {k: v for k, v in r.items() if k != "result"}
                             for e, r in runs.items()},
                 "steps": ours_steps, "batch": args.batch, "chunk": args.chunk,
                 "devices": jax.device_count(), "solver": args.solver,
                 "failed_points": int(np.sum(cold.failed))},
        "numba": {"seconds": numba_s, "runs": nb_times, "steps": int(nb_steps.sum()),
                  "parallel_all_cores_seconds": par_s,
                  "us_per_step": numba_s / nb_steps.sum() * 1e6,
                  "failed_points": int(np.sum(nb_status != 0))},
        "scipy": {"extrapolated_seconds": scipy_est_s, "us_per_step": us_per_step,
                  "subset": [float(freqs[i]) for i in sub],
                  "full_point_hz": float(freqs[-1]), "full_point_seconds": sp_full_s,
                  "steps_ratio_scipy_over_numba": step_ratio,
                  "full_point_deviation_vs_numba": sp_dev},
        "continued": {"seconds": cont_s, "runs": ctimes, "compile_and_warmup_s": compile_c,
                      "segments": args.segments, "transient_periods": 20,
                      "points_within_1e-3_of_cold": int(same.sum()),
                      "points_within_1e-2_of_cold": int(close.sum()),
                      "same_motion_class": int(labels_same),
                      "median_deviation": float(np.median(cdev))},
        "verified": verified,
        "numba_brute_force_2s": brute,
        "verified_accuracy": acc,
        "verified_labels": labels,
        "agreement_ours_vs_numba": {"median_rel_deviation": float(np.median(dev)),
                                    "points_within_1e-3": int(agree.sum()),
                                    "periodic_points": int(periodic.sum())},
        "ratios": {"scipy_over_ours": scipy_est_s / ours_s, "numba_over_ours": numba_s / ours_s,
                   "cold_over_continued": ours_s / cont_s,
                   "numba_over_continued": numba_s / cont_s,
                   "unverified_1dev_over_verified": unver_s / ver_s,
                   "numba_brute_1core_over_verified": brute_s / ver_s,
                   "numba_brute_prange_over_verified": (None if bpar_s is None
                                                        else bpar_s / ver_s)},
        "peak_rss_mb": rss,
        "targets": {"100x_vs_scipy": scipy_est_s / ours_s >= 100,
                    "not_slower_than_numba": ours_s <= numba_s,
                    "continued_5x_vs_cold_brute_force": ours_s / cont_s >= 5,
                    "continued_5x_vs_numba_brute_force": numba_s / cont_s >= 5,
                    "rss_below_2gb": rss < 2048,
                    "verified_not_slower_than_unverified_200": ver_s <= unver_s,
                    "verified_5x_vs_numba_brute_force_2s": brute_s / ver_s >= 5},
    })
    name = "b1_sweep_quick" if args.quick else "b1_sweep"
    out = HERE / "results"
    out.mkdir(exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(res, indent=2, default=bool) + "\n")
    r = res["ratios"]
    t = res["targets"]

    def met(x):
        return "met" if x else "not met"

    def fmt_counts(d):
        return ", ".join(f"{k} {v}" for k, v in d.items()) or "none"

    par_row = ("" if bpar_s is None else
               f"\n| numba, 2 s brute force, prange over all cores (scaled) | {bpar_s:.1f} | "
               f"| | numba prange/verified = {r['numba_brute_prange_over_verified']:.1f} |")
    ver_rows = (
        f"| ours, verified ({args.solver}, batch {args.batch}, 1 device; minimum transient "
        f"{verified['transient_periods_min_max'][0]}-{verified['transient_periods_min_max'][1]}"
        f" periods + {n_rec} recorded, then orbit checks) | {ver_s:.2f} | | | unverified "
        f"200-period (1 device)/verified = {r['unverified_1dev_over_verified']:.2f} |\n"
        f"| numba, 2 s brute force (ceil(2 s x f) periods + {n_rec} x {spp_nb} samples), 1 core "
        f"(scaled: {len(bsub)}/{num} points took {brute_sub_s:.2f} s, x{scale_b:.2f}) | "
        f"{brute_s:.1f} | ~{int(b_steps.sum() * scale_b)} | {brute['us_per_step']:.2f} | "
        f"numba 2 s/verified = {r['numba_brute_1core_over_verified']:.1f} |" + par_row)
    a = acc
    engine_rows = "\n".join(
        f"| ours, cold, {e} ({args.solver}, batch {args.batch}, {r['devices']} device(s)) "
        f"| {r['seconds']:.2f} | {r['steps']} | {r['seconds'] / r['steps'] * 1e6:.2f} | "
        f"{'1 (best)' if e == best else '%.2f x best' % (r['seconds'] / ours_s)} |"
        for e, r in runs.items())
    md = f"""## B1 Cold frequency sweep

Command: `python benchmarks/bench_sweep.py`.
Machine: {res['machine']['cpu']}, {res['machine']['cores']} cores. Date: {res['date']}
(shared machine; load average at start {', '.join('%.1f' % x for x in res['machine']['load_average_at_start'])}).
Default preset, {force:g} N, {num} frequencies evenly over 100-4000 Hz, cold start from rest,
{n_tr} transient periods + {n_samp} stroboscopic samples, rtol {rtol:g}, atol {atol:g}.
Median of {repeats} run(s); compile/warm-up excluded and listed.

| run | time [s] | steps | us/step | ratio |
|---|---|---|---|---|
{engine_rows}
| numba Dormand-Prince 5(4), 1 core | {numba_s:.2f} | {int(nb_steps.sum())} | {res['numba']['us_per_step']:.2f} | numba/ours = {r['numba_over_ours']:.2f} |
| numba Dormand-Prince 5(4), prange over all cores | {par_s if par_s is None else round(par_s, 2)} | | | |
| scipy RK45 (extrapolated) | {scipy_est_s:.0f} | ~{int(step_ratio * nb_steps.sum())} | {us_per_step:.1f} | scipy/ours = {r['scipy_over_ours']:.0f} |
| ours, continued ({args.segments} segments, 20 transient periods) | {cont_s:.2f} | {int(np.sum(cont.num_steps))} | | cold/continued = {r['cold_over_continued']:.2f}; numba/continued = {r['numba_over_continued']:.2f} |
{ver_rows}

- Compile + warm-up: cold {compile_s:.1f} s, continued {compile_c:.1f} s (cached on disk by the CLI).
- Agreement: ours vs numba, max |x_n strobe difference| / amplitude: median {np.median(dev):.1e};
  {int(agree.sum())}/{num} points within 1e-3 ({int(periodic.sum())} points periodic; chaotic
  points diverge by nature). scipy vs numba on the {freqs[-1]:.0f} Hz point: {sp_dev:.1e}.
- Continued vs cold: {int(same.sum())}/{num} points within 1e-3 and {int(close.sum())} within
  1e-2 of the cold diagram,
  same motion class at {labels_same}/{num}.
- Peak RSS: {rss:.0f} MB.
- Targets: >=100x scipy: {res['targets']['100x_vs_scipy']}; not slower than numba:
  {res['targets']['not_slower_than_numba']}; continued >=5x cold brute force:
  {res['targets']['continued_5x_vs_cold_brute_force']}; < 2 GB: {res['targets']['rss_below_2gb']}.

Verified labels:
- Verified run: {ver_s:.2f} s (median of {repeats}); compile ~{compile_v:.1f} s (warm-up run
  {warm_v:.1f} s); its sampling sweep alone {ver_sweep_s:.2f} s, the rest is verification.
- Verified points by label: {fmt_counts(v_counts)}; unresolved {v_unresolved}; failed {v_failed}.
- The 200-period sweep's sample-based labels: {fmt_counts(cand_counts)}. Labelled
  period-n (n > 1), quasi-periodic or chaotic there but verified period-1:
  {len(wrong)}/{num} ({fmt_counts(wrong_by)}).
- Amplitude of x_n, verified vs the numba 2 s runs, over the {a['compared_points']} points
  verified periodic among the {a['subset_points']} run with numba: relative difference at the
  same phases
  ({a['verifier_samples_per_period']} samples/period) median {a['rel_diff_same_phases'][0]:.1e},
  max {a['rel_diff_same_phases'][1]:.1e}; against the numba {spp_nb} samples/period median
  {a['rel_diff_numba_64'][0]:.1e}, max {a['rel_diff_numba_64'][1]:.1e}. (The 200-period
  sweep's last x_n strobe vs the 2 s run's, per amplitude: median
  {a['rel_diff_200_period_strobe'][0]:.1e}, max {a['rel_diff_200_period_strobe'][1]:.1e};
  the 2 s runs' strobe repeats to {a['numba_strobe_repetition'][1]:.1e} of the amplitude.)
- Targets: verified <= unverified 200-period sweep (1 device, {unver_s:.2f} s):
  {met(t['verified_not_slower_than_unverified_200'])}; verified >= 5x faster than the numba
  2 s brute force (1 core): {met(t['verified_5x_vs_numba_brute_force_2s'])}
  ({r['numba_brute_1core_over_verified']:.1f}x).""" + NOTES
    (out / f"{name}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
