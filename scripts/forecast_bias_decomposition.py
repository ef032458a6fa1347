"""Which record moves the damping ratio's estimate off the truth (docs/COVERAGE.md, "The
chirp's flank lines").

For replicates of the bundled preload-loss design (the coverage studies' records, same
seeds), each identified as `bsfs identify` does (PRELOAD_FIT, default prior), the estimate's
offset zeta(theta_hat) - zeta(theta_true) is split by the linearised fit,
theta_hat - theta_true = -(J^T J)^-1 J^T r(theta_true), into one term per record (its rows of
the weighted residual at the truth) and one for the prior, each in units of the damping
ratio's delta-method standard deviation. The mean of each term over the replicates is that
record's share of the estimate's bias; "actual" and "linear" check that the linearisation
holds. `--chirp-bound B` screens the chirp's lines with bound B instead of the package's
(`identification._choice.FRF_LINE_ERROR`); `--window-at-truth` decides the left-out lines
at the truth instead of at the estimate.

    python scripts/forecast_bias_decomposition.py --replicates 100        # ~2.5 min
    python scripts/forecast_bias_decomposition.py --replicates 100 --chirp-bound 0.1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bsfs_jax.cli._common import setup_jax  # noqa: E402

setup_jax()

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from coverage_study import synth_records, truth_params  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402
import identification._choice as choice  # noqa: E402
from identification._forecast import identified_from_result  # noqa: E402
from identification._forecast_modal import _modal_program  # noqa: E402


def decompose(truth, prior, k: int) -> dict:
    res = idn.identify(synth_records(truth, k, {}), prior, idn.PRELOAD_FIT, profile=False)
    pb, ident = res.problem, identified_from_result(res)
    th_hat = np.asarray(res.fit.theta, float)
    th_true = np.array([np.log(float(np.asarray(truth.get(key))) / p) if lg
                        else float(np.asarray(truth.get(key))) - p
                        for key, lg, p in zip(ident.keys, ident.log, ident.prior)])
    r = np.asarray(pb.residual(th_true))
    n_data = np.asarray(pb.data_residual(th_true)).size
    jac = np.asarray(res.fit.jacobian)
    z_true = np.asarray(_modal_program(ident.coordinates, jnp.asarray(th_true))[0])[1]
    z_hat, g = (np.asarray(a) for a in _modal_program(ident.coordinates,
                                                      jnp.asarray(th_hat))[:2])
    g = g[1]
    sd = float(np.sqrt(g @ ident.covariance @ g))
    w = -(g @ np.linalg.solve(jac.T @ jac, jac.T)) / sd  # each row's weight on zeta
    row = {"replicate": k, "actual": float(z_hat[1] - z_true) / sd, "linear": float(w @ r)}
    for i in range(len(pb.data)):
        idx = pb.layout[i][2]
        row[f"{i} {pb.data[i].name} ({pb.models[i]})"] = float(w[idx] @ r[idx])
    row["prior"] = float(w[n_data:] @ r[n_data:])
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--replicates", type=int, default=20)
    ap.add_argument("--chirp-bound", type=float, default=None)
    ap.add_argument("--window-at-truth", action="store_true")
    args = ap.parse_args(argv)
    truth, prior = truth_params(), bsfs_jax.preset()
    screen = choice.chirp_line_z
    if args.window_at_truth:
        at_truth = bsfs_jax.build_system(truth)
        choice.chirp_line_z = lambda system, data: screen(at_truth, data)
    if args.chirp_bound is not None:  # z rescaled: the package's bound then acts as B
        factor = choice.FRF_LINE_ERROR / args.chirp_bound
        inner = choice.chirp_line_z
        choice.chirp_line_z = lambda system, data: inner(system, data) * factor
    rows = []
    for k in range(args.replicates):
        rows.append(decompose(truth, prior, k))
        print(f"replicate {k}: actual {rows[-1]['actual']:+.3f}", flush=True)
    print(f"\nmean over {len(rows)} replicates, in standard deviations of the damping ratio")
    for key in rows[0]:
        if key == "replicate":
            continue
        v = np.array([r[key] for r in rows])
        print(f"  {key:45s} {v.mean():+.3f} +- {v.std(ddof=1) / np.sqrt(v.size):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
