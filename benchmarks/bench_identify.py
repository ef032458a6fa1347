"""Benchmark: identification from the three paper-test records (issue 4, item 9).

1. `bsfs identify` end to end on the bundled paper-test records (default 7 parameters, 3
   starts), in this fresh process, compilation included: wall and CPU seconds.
2. The same fit problem solved two ways, same records, same start, same parameters
   (screw stiffness k_s and nut damping c_n; all other parameters at the truth, so that
   the parameter error is meaningful on this quasi-static test):
   - ours: optimistix Levenberg-Marquardt, JAX forward-mode Jacobians, harmonic-domain
     measurement model (linearised FRF per harmonic);
   - baseline: scipy.optimize.least_squares ('lm', 2-point finite-difference Jacobian)
     with the steady state from scipy.integrate.solve_ivp (DOP853, rtol 1e-8): simulate
     `transient` periods from rest under the measured force harmonics, Fourier-analyse the
     last period, same noise-weighted residual. The right-hand side is the same model
     (bsfs_jax.vector_field, jit-compiled once), called from solve_ivp.

    python benchmarks/bench_identify.py [--quick]

Writes benchmarks/results/identify.md and identify.json.
"""

import argparse
import datetime
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402
from identification._measurement import harmonic_analysis  # noqa: E402

FIT = ("screw_k", "c_n")


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def machine():
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        model = next(line.split(":", 1)[1].strip() for line in out.splitlines()
                     if line.startswith("Model name"))
    except Exception:
        model = platform.processor() or "unknown"
    import os

    return f"{model}, {os.cpu_count()} cores"


def end_to_end(starts):
    t0, c0 = time.perf_counter(), cpu_seconds()
    res = idn.identify(idn.bundled_records("paper-test"), bsfs_jax.preset(), starts=starts,
                       max_steps=60)
    return dict(wall_s=time.perf_counter() - t0, cpu_s=cpu_seconds() - c0,
                iterations=res.fit.steps, converged=res.fit.converged,
                compliance=res.uncertainty.compliance)


def problem(truth):
    data = [harmonic_analysis(r) for r in idn.load_records(idn.bundled_records("paper-test"))]
    preset = bsfs_jax.preset()
    prior = truth.replace("screw.stiffness_n_per_um",
                          float(bsfs_jax.model.screw_stiffness(preset)) / 1e6)
    prior = prior.replace("damping.nut_n_s_per_m", float(preset.get("damping.nut_n_s_per_m")))
    return idn.Problem(data, prior, FIT)


def ours(pb):
    t0 = time.perf_counter()
    res = idn.fit(pb, starts=1)
    return dict(wall_s=time.perf_counter() - t0, values=res.values.tolist(),
                iterations=res.steps, converged=res.converged, cost=res.cost)


def baseline(pb, transient, max_nfev):
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    rhs_jit = jax.jit(lambda t, y, system, forcing: bsfs_jax.vector_field(t, y, (system,
                                                                                  forcing)))
    build = eqx.filter_jit(bsfs_jax.build_system)
    speed = pb.speeds[0]
    data = [pb.data[i] for i in pb.order]
    scale = np.asarray(pb.groups[0].lin_scale)
    meas = np.asarray(pb.groups[0].lin_acc)
    n = 64
    evals = [0]

    def steady_harmonics(system, d):
        f = d.frequency_hz
        forcing = bsfs_jax.HarmonicForcing(f, d.force.real, -d.force.imag)
        period = 1.0 / f
        t_eval = transient * period + period * np.arange(n) / n
        sol = solve_ivp(lambda t, y: np.asarray(rhs_jit(t, y, system, forcing)),
                        (0.0, (transient + 1) * period), np.zeros(6), method="DOP853",
                        rtol=1e-8, atol=1e-12, t_eval=t_eval)
        acc = np.array([np.asarray(rhs_jit(t, y, system, forcing))[5]
                        for t, y in zip(sol.t, sol.y.T)])
        k = np.arange(1, d.harmonics.size + 1)
        return 2.0 / n * np.exp(-2j * np.pi * np.outer(k, np.arange(n)) / n) @ acc

    def residual(theta):
        evals[0] += 1
        system = build(pb.params_at(np.asarray(theta), speed))
        model = np.stack([steady_harmonics(system, d) for d in data])
        diff = meas - model
        r = np.concatenate([(diff.real / scale[..., 0]).ravel(),
                            (diff.imag / scale[..., 1]).ravel()])
        return r

    t0 = time.perf_counter()
    sol = least_squares(residual, np.zeros(pb.n_params), jac="2-point", method="lm",
                        xtol=1e-10, ftol=1e-10, max_nfev=max_nfev)
    wall = time.perf_counter() - t0
    return dict(wall_s=wall, values=pb.values(sol.x).tolist(), nfev=evals[0],
                status=int(sol.status), message=sol.message, cost=float(sol.cost),
                seconds_per_residual=wall / max(evals[0], 1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="baseline capped at 3 residual "
                    "evaluations (its time to convergence is then extrapolated)")
    args = ap.parse_args()
    truth = bsfs_jax.load_params(idn.DATA_DIR / "truth.toml")
    e2e = end_to_end(starts=3)
    print(f"end-to-end bsfs identify (7 params, 3 starts): {e2e['wall_s']:.1f} s wall, "
          f"{e2e['cpu_s']:.1f} s CPU", flush=True)
    pb = problem(truth)
    truth_vals = np.array([float(truth.get("screw.stiffness_n_per_um")),
                           float(truth.get("damping.nut_n_s_per_m"))])
    t0 = time.perf_counter()
    jx = ours(pb)
    jx["wall_s_including_setup"] = time.perf_counter() - t0
    print(f"ours: {jx['wall_s']:.2f} s, values {jx['values']}", flush=True)
    sp = baseline(pb, transient=20, max_nfev=3 if args.quick else 200)
    print(f"scipy: {sp['wall_s']:.1f} s, {sp['nfev']} residuals, values {sp['values']}",
          flush=True)
    err = lambda v: (np.abs(np.asarray(v) - truth_vals) / truth_vals).tolist()
    jx["relative_error"], sp["relative_error"] = err(jx["values"]), err(sp["values"])
    # Baseline time to convergence: measured (full run) or extrapolated from its cost per
    # residual and the number of residual evaluations LM with a 2-point Jacobian needs for
    # the iterations our LM took ((p + 1) per iteration).
    if args.quick:
        sp["extrapolated_wall_s"] = sp["seconds_per_residual"] * (pb.n_params + 1) * max(
            jx["iterations"], 1)
        base_time = sp["extrapolated_wall_s"]
    else:
        base_time = sp["wall_s"]
    speedup = base_time / jx["wall_s"]
    result = dict(date=datetime.date.today().isoformat(), machine=machine(),
                  quick=args.quick, end_to_end=e2e, fit_parameters=FIT, ours=jx, scipy=sp,
                  speedup=speedup, truth=truth_vals.tolist())
    out = ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "identify.json").write_text(json.dumps(result, indent=2, default=str) + "\n")
    md = [
        "# Identification benchmark (issue 4)", "",
        f"Machine: {result['machine']}; date {result['date']}; "
        f"{'quick mode (baseline extrapolated)' if args.quick else 'full run'}.", "",
        "Single runs (one fresh process; the shared 2-core machine was loaded by other jobs, "
        "so wall time is noisy: CPU time is given too).", "",
        "| what | wall [s] | notes |", "|---|---|---|",
        f"| `bsfs identify` paper-test end to end, 7 params, 3 starts, compile included | "
        f"{e2e['wall_s']:.1f} | CPU {e2e['cpu_s']:.1f} s; {e2e['iterations']} LM iterations |",
        f"| ours: LM + JAX forward-mode, harmonic domain (k_s, c_n) | {jx['wall_s']:.2f} | "
        f"{jx['iterations']} iterations, compile included; rel. error "
        f"{', '.join(f'{e:.2e}' for e in jx['relative_error'])} |",
        f"| scipy least_squares + solve_ivp, 2-point FD (k_s, c_n) | {sp['wall_s']:.1f} | "
        f"{sp['nfev']} residual evaluations at {sp['seconds_per_residual']:.2f} s; rel. error "
        f"{', '.join(f'{e:.2e}' for e in sp['relative_error'])}; {sp['message']} |",
        "",
        f"Speed-up (baseline time to convergence / ours): **{speedup:.0f}x**"
        + (" (baseline extrapolated from its measured cost per residual)" if args.quick
           else ""), "",
    ]
    (out / "identify.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
