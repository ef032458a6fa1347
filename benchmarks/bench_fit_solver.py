"""Which optimistix descent the fit uses: steps to the remaining-step test, per problem.

On the paper test (maximum a posteriori, 3 starts drawn from the prior; and maximum
likelihood from the prior) and on its profile-likelihood problems (c_b and c_s held at
t = 1.96, 3, 4 and -1.96 standard errors, the others started on the conditional path), each
method of `identification.fitting.solve`'s solver runs with the fit's stopping test (remaining
Gauss-Newton step < 1e-3 of its standard error) and at most 200 steps. Reported: steps per
lane, whether the test was met at the returned point, and the rise of 2 x cost (profile).
MINPACK (scipy, `tests/minpack_fit.py`, 240 evaluations) runs on the
same held problems. Writes results/fit_solver.json and .md.

    python benchmarks/bench_fit_solver.py
"""

import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402
from _machine import machine_info  # noqa: E402
from minpack_fit import levenberg_marquardt  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402
from identification.fitting import (
    SolveOptions,
    full_used_mask,
    remaining_step,
    solve,
    start_points,
)

METHODS = ("dogleg", "lm", "indirect-lm", "gauss-newton")
TS = (1.96, 3.0, 4.0, -1.96)


def main():
    data = [idn.measurement_data(r) for r in idn.load_records(idn.bundled_records("paper-test"))]
    pb = idn.Problem(data, bsfs_jax.preset())
    ml = idn.Problem(data, bsfs_jax.preset(), priors=None)
    res = idn.fit(pb)
    unc = idn.uncertainty(res)
    rows, base = full_used_mask(pb), 2 * res.cost
    held = {}
    for name in ("c_b", "c_s"):
        i = pb.names.index(name)
        s = unc.scaled_std[i]
        starts, free = [], []
        for t in TS:
            a = res.theta + t * unc.covariance[:, i] / s
            a[i] = res.theta[i] + t * s
            f = np.ones(a.size, bool)
            f[i] = False
            starts.append(a)
            free.append(f)
        held[name] = (np.stack(starts), np.stack(free))
    out = dict(machine=machine_info(), problem="paper test (bundled), default fit set",
               methods={})
    for method in METHODS:
        opt = SolveOptions(method=method, max_steps=200, step_tol=1e-3)
        t0 = time.perf_counter()
        st = solve(np.stack(start_points(pb, 3, 0)), True, pb.fit_data, pb.structure, opt)
        row = dict(seconds_with_compile=time.perf_counter() - t0,
                   starts_steps=st["steps"].tolist(),
                   starts_converged=[bool(remaining_step(st["residual"][k], st["jacobian"][k],
                                                         np.r_[rows]) < 1e-2)
                                     for k in range(3)])
        n = rows.size - pb.n_params
        o = solve(np.zeros((1, ml.n_params)), True, ml.fit_data, ml.structure, opt)
        row["ml_steps"] = int(o["steps"][0])
        row["ml_remaining_step"] = remaining_step(o["residual"][0][:n], o["jacobian"][0][:n],
                                                  rows[:n], 1.0)
        for name, (a, f) in held.items():
            o = solve(a, f, pb.fit_data, pb.structure, opt)
            row[f"held_{name}_steps"] = o["steps"].tolist()
            row[f"held_{name}_rise"] = (2 * o["cost"] - base).tolist()
            row[f"held_{name}_remaining"] = [remaining_step(o["residual"][k], o["jacobian"][k],
                                                            rows) for k in range(len(TS))]
        out["methods"][method] = row
        print(method, row, flush=True)
    mp = {}
    for name, (a, f) in held.items():
        runs = [levenberg_marquardt(pb.rj, a[k], held=~f[k], max_steps=60, tol=1e-3,
                                    rows=rows) for k in range(len(TS))]
        mp[f"held_{name}_evaluations"] = [r.evaluations for r in runs]
        mp[f"held_{name}_rise"] = [2 * r.cost - base for r in runs]
        mp[f"held_{name}_converged"] = [r.converged for r in runs]
    out["minpack"] = mp
    (HERE / "results" / "fit_solver.json").write_text(json.dumps(out, indent=1))
    (HERE / "results" / "fit_solver.md").write_text(markdown(out))


def _fmt(steps, remaining, tol):
    return " / ".join(f"{s}" + ("" if r < tol else "✗") for s, r in zip(steps, remaining))


def markdown(out):
    m = out["machine"]
    lines = ["## F1 Fit solvers", "",
             "Command: `python benchmarks/bench_fit_solver.py`.",
             f"Machine: {m.get('cpu')}, {m.get('cores')} cores; jax {m.get('jax')}. "
             f"Date: {m.get('date_utc', '')} UTC.", "",
             "Paper test (3 records, 7 parameters). Steps of each lane to the fit's stopping "
             "test (remaining Gauss-Newton step < 1e-3 of its standard error, at most 200 "
             "steps; ✗: not met at the returned point). Held problems: c_b or c_s held at t = "
             + ", ".join(f"{t:g}" for t in TS) + " standard errors (the profile likelihood).",
             "", "| method | 3 MAP starts | ML from the prior (remaining step) | held c_b | "
             "held c_s |", "|---|---|---|---|---|"]
    for name, r in out["methods"].items():
        lines.append(
            f"| {name} | {' / '.join(map(str, r['starts_steps']))} | {r['ml_steps']} "
            f"({r['ml_remaining_step']:.2g}) | "
            f"{_fmt(r['held_c_b_steps'], r['held_c_b_remaining'], 1e-2)} | "
            f"{_fmt(r['held_c_s_steps'], r['held_c_s_remaining'], 1e-2)} |")
    mp = out["minpack"]
    best = out["methods"]["dogleg"]
    lines += ["", "MINPACK (scipy `least_squares(method='lm')`, 240 evaluations, as the "
              "profile used before): held c_b converged "
              f"{mp['held_c_b_converged']}, rise of 2 x cost "
              + ", ".join(f"{x:.4g}" for x in mp["held_c_b_rise"])
              + " (dogleg: " + ", ".join(f"{x:.4g}" for x in best["held_c_b_rise"]) + ").",
              "", "The default is `dogleg` with its Gauss-Newton point from a truncated SVD "
              "(singular values below the information floor left out): plain LM crawls along "
              "the long curved valleys of the held problems (over 100 steps), Gauss-Newton "
              "with a backtracking line search fails on one of them, and without the "
              "truncation the dogleg's Gauss-Newton point is dominated by the directions "
              "a maximum-likelihood fit has no information on.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
