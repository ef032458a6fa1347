"""Where the robustness study's spread of z comes from: the linearised step at the truth.

For each drive of `robustness_study.py` (same seeds: the same truth and records), the
problem is built with its models chosen at the truth, and the Gauss-Newton step from the
truth, -C J^T r / sigma (C = (J^T J)^-1 with the prior's rows, sigma = sqrt(diag C)), is
split into the prior's rows' part and each record's part. The step is what the fit's
estimate minus the truth is to first order, in its own standard errors; with honest
weights and a truth drawn from the prior its spread is 1 (docs/ROBUSTNESS.md). Per
record it also gives the mean square of the weighted residual at the truth (1 for honest
weights; above 1: noise or model error the weights do not carry).

    python scripts/robustness_step_check.py --draw uniform              # 100 drives, ~5 min
    python scripts/robustness_step_check.py --draw uniform --no-effects # no drift, distortion
    python scripts/robustness_step_check.py --draw uniform --noise-free # model error alone
    python scripts/robustness_step_check.py --draw uniform --first 100 --drives 300  # new seeds
    python scripts/robustness_step_check.py --draw uniform --drives 160 --seed-offset 50
                          # the same drives, another realisation of each test

Rows: out/robustness/step_check.<draw>[.no_effects][.noise_free][.seedK].jsonl (a rerun skips
drives already there); the summary is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import numpy as np  # noqa: E402
import robustness_study as rs  # noqa: E402
from coverage_study import append_line, read_done  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402

DAMPERS = ("c_b", "c_s", "c_n")


def record_kind(name: str, j: int) -> str:
    """The plan's slot of a record: chirp, sine1..8 (ratios to f1, in order), 3000N."""
    return "chirp" if "chirp" in name else "3000N" if "3000N" in name else f"sine{j}"


def problem_at_truth(drive: int, draw: str, effects=rs.EFFECTS, clean: bool = False,
                     seed_offset: int = 0):
    """(problem, theta at the truth, the drive's params): the default set's problem of the
    drive's records (noise-free values with the noisy weights where `clean`), its models
    chosen and its swept records anchored at the truth."""
    params, truth = rs.draw_drive("default", drive, draw)
    recs, _ = rs.synth(params, drive, effects, seed_offset)
    data = rs.noise_free(params, drive, recs, effects, seed_offset) if clean else [
        idn.measurement_data(r) for r in recs]
    pb = idn.Problem(data, bsfs_jax.preset().replace("thermal.speed_rpm", rs.SPEED),
                     rs.SETS["default"])
    theta = pb.theta_of(np.asarray([truth[n] for n in pb.names]))
    return (pb.rechosen(theta) if pb.chooses_models else pb).anchored(theta), theta, params


def step_at_truth(drive: int, draw: str, effects, clean: bool, seed_offset: int = 0) -> dict:
    pb, theta, _ = problem_at_truth(drive, draw, effects, clean, seed_offset)
    r, jac = pb.rj(theta)
    cov = np.linalg.inv(jac.T @ jac)
    sd = np.sqrt(np.diag(cov))
    used = pb.used_mask()
    nd = used.size
    pull = lambda rows: list(-(cov @ (jac[rows].T @ r[rows])) / sd)
    records = []
    for j, (d, m, s) in enumerate(zip(pb.data, pb.models, pb.record_slices())):
        rows = np.arange(nd)[s][used[s]]
        # Its share of the information: E[pull^2] if its weighted residuals are N(0, 1).
        share = np.diag(cov @ (jac[rows].T @ jac[rows]) @ cov) / sd**2
        records.append(dict(kind=record_kind(d.name, j), model=m, n=int(rows.size),
                            ss=float(r[rows] @ r[rows]), pull=pull(rows),
                            share=list(share)))
    # Maximum likelihood (`identify --no-priors`): the step from the data rows alone, in
    # its own standard errors; no prior, so no pull towards the prior's centre.
    data_rows = np.arange(nd)[used]
    jd, rd = jac[data_rows], r[data_rows]
    cov_ml = np.linalg.inv(jd.T @ jd)
    ml_step = list(-(cov_ml @ (jd.T @ rd)) / np.sqrt(np.diag(cov_ml)))
    return dict(drive=drive, names=list(pb.names), step=pull(np.arange(r.size)),
                ml_step=ml_step,
                prior_step=pull(np.arange(nd, r.size)), records=records)


def summary(rows: list[dict]) -> str:
    names = rows[0]["names"]
    di = [names.index(n) for n in DAMPERS]
    step = np.array([r["step"] for r in rows])
    prior = np.array([r["prior_step"] for r in rows])
    ml = np.array([r.get("ml_step", [np.nan] * len(names)) for r in rows])
    lines = [f"{len(rows)} drives", "| parameter | step std | step mean | noise part std | "
             "prior part rms | |step| < 1.96 | no priors: step std | |step| < 1.96 |",
             "|---|---|---|---|---|---|---|---|"]
    for i, n in enumerate(names):
        s, p, m = step[:, i], prior[:, i], ml[:, i]
        lines.append(f"| {n} | {s.std():.2f} | {s.mean():+.2f} | {(s - p).std():.2f} | "
                     f"{np.sqrt(np.mean(p ** 2)):.2f} | {np.mean(np.abs(s) < rs.Z95):.2f} | "
                     f"{m.std():.2f} | {np.mean(np.abs(m) < rs.Z95):.2f} |")
    agg = {}
    for r in rows:
        for q in r["records"]:
            a = agg.setdefault(q["kind"], dict(ss=0.0, n=0, pull=[], share=[], models={}))
            a["ss"] += q["ss"]
            a["n"] += q["n"]
            a["pull"].append([q["pull"][i] for i in di])
            a["share"].append([q["share"][i] for i in di] if "share" in q else [np.nan] * 3)
            a["models"][q["model"]] = a["models"].get(q["model"], 0) + 1
    lines += ["", "| record | rows | mean z^2 at the truth | part of the step, rms "
              "(c_b, c_s, c_n) | its information share, rms | models |",
              "|---|---|---|---|---|---|"]
    for k, a in agg.items():
        rms = np.sqrt(np.mean(np.square(a["pull"]), axis=0))
        share = np.sqrt(np.mean(a["share"], axis=0))
        lines.append(f"| {k} | {a['n']} | {a['ss'] / max(a['n'], 1):.3f} | "
                     f"{', '.join(f'{x:.2f}' for x in rms)} | "
                     f"{', '.join(f'{x:.2f}' for x in share)} | "
                     f"{', '.join(f'{m} {c}' for m, c in sorted(a['models'].items()))} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draw", choices=("uniform", "prior"), default="uniform")
    ap.add_argument("--drives", type=int, default=100, help="drives [first, drives)")
    ap.add_argument("--first", type=int, default=0,
                    help="first drive (new seeds: a population the study has not seen)")
    ap.add_argument("--no-effects", action="store_true",
                    help="records without the shaker's drift and distortion")
    ap.add_argument("--no-filter", action="store_true",
                    help="records without the anti-alias filter")
    ap.add_argument("--noise-free", action="store_true",
                    help="noise-free values weighted as the noisy ones (model error alone)")
    ap.add_argument("--seed-offset", type=int, default=0,
                    help="another realisation of each drive's test (new phases, drift and "
                         "noise; 1..89), to tell the population's luck from the weights'")
    ap.add_argument("--out", type=Path, default=rs.OUT)
    args = ap.parse_args(argv)
    effects = (dataclasses.replace(rs.EFFECTS, drift=0.0, h2=0.0, h3=0.0)
               if args.no_effects else rs.EFFECTS)
    if args.no_filter:
        effects = dataclasses.replace(effects, antialias_order=0)
    tag = (args.draw + (".no_effects" if args.no_effects else "")
           + (".no_filter" if args.no_filter else "")
           + (".noise_free" if args.noise_free else "")
           + (f".seed{args.seed_offset}" if args.seed_offset else ""))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"step_check.{tag}.jsonl"
    done = {r["drive"] for r in read_done(path)}
    for drive in range(args.first, args.drives):
        if drive not in done:
            try:
                row = step_at_truth(drive, args.draw, effects, args.noise_free,
                                    args.seed_offset)
            except ValueError as exc:  # a drive that cannot be synthesised (as in the study)
                row = dict(drive=drive, error=str(exc).splitlines()[0])
            append_line(path, row)
            print(f"[{tag} {drive + 1}/{args.drives}]", flush=True)
    rows = [r for r in read_done(path) if args.first <= r["drive"] < args.drives]
    for r in rows:
        if "error" in r:
            print(f"drive {r['drive']}: {r['error']}")
    print(summary([r for r in rows if "error" not in r]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
