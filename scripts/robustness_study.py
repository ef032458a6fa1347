"""Robustness study of identification through the resonance (docs/ROBUSTNESS.md).

Worn drives are drawn over the prior ranges (seeded), each is tested with a through-resonance
plan, and each test is identified from a cold start as a user would (`identification.identify`,
the default preset as prior with the default priors, 3 starts, the staged multi-start fit).

- Fit sets: `preload` (PRELOAD_FIT: both preloads and the three dampers; drives with preloads
  drawn uniformly over 50-100 % of nominal and dampers log-uniformly over the central 95 % of
  their priors) and `default` (DEFAULT_FIT: Hertz coefficients, screw stiffness, dampers and
  expansion, each log-uniform over the central 95 % of its prior, preloads nominal: the truth
  must lie in the fitted family for coverage to mean anything).
- The plan, relative to the drive's own first natural frequency f1 (`bsfs_jax.modes`): 100 N
  stepped sines swept up at 0.13, 0.35, 0.62, 0.84, 0.95, 1.03, 1.24 and 1.77 f1 (two within
  +-10 % of f1), 0.5 s each; 3000 N sines at 150 and 300 Hz; a 5 N chirp 50-2500 Hz over 1 s;
  40 dB noise on both channels, the shaker's default distortion and drift; 2000 r/min.
- Per drive: converged or not (and why), the cost at the estimate against the cost at the
  truth (same problem, same models), whether each 95 % interval covers the truth, z-scores,
  seconds.

    python scripts/robustness_study.py --set preload          # 100 drives
    python scripts/robustness_study.py --set default --drives 10
    python scripts/robustness_study.py --report-only          # docs/ROBUSTNESS.md tables
    python scripts/robustness_study.py --set default --draw prior   # drives from the prior
    python scripts/robustness_study.py --set preload --noise-free --drives 30
    python scripts/robustness_study.py --set default --no-priors    # maximum likelihood
    python scripts/robustness_study.py --set default --seed-offset 10  # another realisation
    python scripts/robustness_study.py --set default --pool A.jsonl B.jsonl  # pooled summary
                                                  # the bias of model and estimator alone
    python scripts/robustness_study.py --set default --drives 545 --workers 8  # a drive a
                                                  # chunk on a local Dask cluster
    python scripts/robustness_study.py --set default --scheduler tcp://login1:8786

Each drive is appended as one JSON line to out/robustness/<set>.jsonl (fsynced); a rerun
skips the drives already there, so an interrupted study resumes. Results: docs/ROBUSTNESS.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import platform
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import numpy as np  # noqa: E402
import study_cluster  # noqa: E402
from coverage_study import (  # noqa: E402
    append_line,
    binom_ci,
    read_done,
    with_clean_values,
)

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402

FS = 10240.0
SPEED = 2000.0
RATIOS = (0.13, 0.35, 0.62, 0.84, 0.95, 1.03, 1.24, 1.77)
LOW_FORCE, HIGH = 100.0, ((150.0, 3000.0), (300.0, 3000.0))
SINE_S = 0.5
# Highest sine [Hz]: the top of the chirp's band, below the usable band (0.25 x FS = 2560
# Hz; a stiff drive's 1.77 f1 reached 2578 Hz, a record `identify` refuses).
TOP_HZ = 2500.0
CHIRP = dict(force=5.0, duration=1.0, start=50.0, stop=2500.0)
EFFECTS = idn.TestEffects(accel_snr_db=40.0, force_snr_db=40.0)
SETS = {"preload": idn.PRELOAD_FIT, "default": idn.DEFAULT_FIT}
OUT = ROOT / "out" / "robustness"
Z95 = 1.959963984540054
COST_RTOL = 1e-6  # "no higher than the cost at the truth", up to round-off


def draw_drive(kind: str, drive: int, draw: str = "uniform"):
    """The drive's truth (BallScrewParams at SPEED) and {fit name: true value}.

    `draw`: "uniform" (every parameter but the preloads log-uniform over the central 95 %
    of its prior) or "prior" (from the prior itself, log-normal with the prior's sigma:
    the population under which the intervals' Bayesian calibration is defined; seeds
    30000 + drive). The preloads are uniform over 50-100 % of nominal either way."""
    rng = np.random.default_rng((20_000 if draw == "uniform" else 30_000) + drive)
    p = bsfs_jax.preset().replace("thermal.speed_rpm", SPEED)
    names = SETS[kind]
    truth = {}
    from bsfs_jax.model import bearing_hertz_k, nut_hertz_k, screw_stiffness

    derived = {"nut_k": nut_hertz_k, "bearing_k": bearing_hertz_k,  # keys the preset leaves
               "screw_k": lambda q: screw_stiffness(q) / 1e6}  # unset: its geometry's values
    for name in names:
        fp = idn.FIT_PARAMETERS[name]
        value = p.get(fp.key)
        value = float(derived[name](p) if value is None else value)
        if name.endswith("_preload"):
            value *= rng.uniform(0.5, 1.0)
        elif draw == "prior":
            value *= float(np.exp(rng.normal() * fp.prior_sigma))
        else:
            value *= float(np.exp(rng.uniform(-Z95, Z95) * fp.prior_sigma))
        p = p.replace(fp.key, value)
        truth[name] = value
    return p, truth


def plan(params):
    """[(frequency or None for the chirp, force, sweep)] and the drive's f1 [Hz]."""
    f1 = float(np.asarray(bsfs_jax.modes(bsfs_jax.build_system(params)).frequencies_hz)[0])
    sines = [(min(round(r * f1, 1), TOP_HZ), LOW_FORCE, "up") for r in RATIOS] + [
        (f, n, None) for f, n in HIGH]
    return sines, f1


def synth(params, drive: int, effects=EFFECTS, seed_offset: int = 0):
    """The drive's records, seeded 3_000_000 + 100 drive + k (k = 0 the chirp, 1.. the
    sines); `seed_offset` (below 90) draws another realisation of the same test: new
    phases, drift and noise."""
    if not 0 <= seed_offset < 90:
        raise ValueError(f"seed_offset = {seed_offset}: use 0..89 (the drive's seed block)")
    base = 3_000_000 + 100 * drive + seed_offset
    sines, f1 = plan(params)
    recs = [idn.synthesize(params, None, CHIRP["force"], duration_s=CHIRP["duration"],
                           sample_rate_hz=FS, excitation="chirp", start_hz=CHIRP["start"],
                           stop_hz=CHIRP["stop"], effects=effects, seed=base)]
    for j, (f, force, sweep) in enumerate(sines):
        recs.append(idn.synthesize(params, f, force, duration_s=SINE_S, sample_rate_hz=FS,
                                   effects=effects, sweep=sweep,
                                   seed=base + 1 + j))
    return recs, f1


def noise_free(params, drive: int, records, effects=EFFECTS, seed_offset: int = 0):
    """The drive's measurement data with the values of its noise-free records (sensor SNR
    300 dB, the same seeds: the same phases, distortion and drift) and the standard errors
    of the noisy ones: the fit's error is then model and estimator error alone, and z is
    that bias in units of the stated std (coverage means nothing here)."""
    clean, _ = synth(params, drive, dataclasses.replace(effects, accel_snr_db=300.0,
                                                        force_snr_db=300.0), seed_offset)
    return with_clean_values([idn.measurement_data(r) for r in records],
                             [idn.measurement_data(c) for c in clean])


def cost_at(problem, values: dict) -> float:
    theta = problem.theta_of(np.asarray([values[n] for n in problem.names]))
    r, _ = problem.anchored(theta).rj(theta)  # swept records on their sweep's orbit there
    r = np.where(np.isfinite(r), r, 1e6)
    return 0.5 * float(r @ r)


def failure_cause(res, cost_fit, cost_truth) -> str | None:
    fr = res.fit
    if not fr.converged:
        if fr.model_issues:  # the model's accuracy at the estimate (`FitResult.model_issues`)
            kind = fr.model_issue_kinds[0]
            return {"truncation": "model truncation error above the gate",
                    "no_steady_state": "no model at the estimate",
                    "swept_orbit": "swept record off its sweep's orbit at the estimate",
                    "record_misfit": "a record the model does not explain"}.get(
                kind, "model issue: " + fr.model_issues[0][:80])
        if fr.model_choice == "unsettled":
            return "model choice unsettled"
        if not fr.remaining_step < 0.01:
            return "remaining step (optimiser stopped short)"
        return "starts disagree"
    if cost_fit > cost_truth * (1 + COST_RTOL) + 1e-9:
        return "converged above the truth's cost"
    return None


def run_drive(kind: str, drive: int, clean: bool = False, draw: str = "uniform",
              priors="default", seed_offset: int = 0) -> dict:
    params, truth = draw_drive(kind, drive, draw)
    t0 = time.perf_counter()
    row = dict(drive=drive, truth=truth)
    if seed_offset:
        row["seed_offset"] = seed_offset
    try:
        recs, f1 = synth(params, drive, seed_offset=seed_offset)
        if clean:
            recs = noise_free(params, drive, recs, seed_offset=seed_offset)
    except Exception as exc:  # noqa: BLE001 - a drive the simulation cannot run
        return dict(row, cause=f"synthesis failed: {exc}".splitlines()[0], converged=False)
    t1 = time.perf_counter()
    try:
        res = idn.identify(recs, bsfs_jax.preset().replace("thermal.speed_rpm", SPEED),
                           SETS[kind], priors=priors)
    except Exception as exc:  # noqa: BLE001 - recorded as a failure cause
        traceback.print_exc()
        return dict(row, f1_hz=f1, cause=f"exception: {type(exc).__name__}: {exc}"
                    .splitlines()[0], converged=False)
    t2 = time.perf_counter()
    pb, u = res.problem, res.uncertainty
    cost_fit = float(res.fit.cost)
    cost_truth = cost_at(pb, truth)
    params_out = {}
    for i, name in enumerate(pb.names):
        lo, hi = u.ci95[i]
        z = (np.log(u.values[i] / truth[name]) / u.scaled_std[i]
             if np.isfinite(u.scaled_std[i]) and u.scaled_std[i] > 0 else None)
        params_out[name] = dict(value=float(u.values[i]), covered=bool(lo <= truth[name] <= hi),
                                z=None if z is None else float(z),
                                determined=bool(u.determined[i]))
    return dict(row, f1_hz=f1, converged=bool(res.fit.converged),
                cause=failure_cause(res, cost_fit, cost_truth),
                cost_fit=cost_fit, cost_truth=cost_truth,
                starts_agreeing=res.fit.starts_agreeing, starts_total=res.fit.starts_total,
                branches={res.data[i].name: b["branch"] for i, b in res.branches.items()},
                models=list(pb.models), params=params_out,
                synth_s=t1 - t0, fit_s=t2 - t1)


def drive_row(kind: str, clean: bool, draw: str, priors, seed_offset: int, drive: int):
    """`run_drive` with the drive last: a unit of work (`study_cluster.run_units`)."""
    return run_drive(kind, drive, clean, draw, priors, seed_offset)


def summarize(rows: list[dict], kind: str) -> dict:
    n = len(rows)
    conv = [r for r in rows if r.get("converged")]
    ok = [r for r in conv if r.get("cause") is None]
    causes = {}
    for r in rows:
        if r.get("cause"):
            causes[r["cause"]] = causes.get(r["cause"], 0) + 1
    per = {}
    for name in SETS[kind]:
        cov = [r["params"][name]["covered"] for r in conv]
        zs = [r["params"][name]["z"] for r in conv if r["params"][name]["z"] is not None]
        k = int(sum(cov))
        per[name] = dict(covered=k, n=len(cov), coverage=k / len(cov) if cov else None,
                         ci=binom_ci(k, len(cov)) if cov else None,
                         z_mean=float(np.mean(zs)) if zs else None,
                         z_std=float(np.std(zs)) if zs else None)
    branches = {}
    for r in rows:
        for b in (r.get("branches") or {}).values():
            branches[b] = branches.get(b, 0) + 1
    return dict(set=kind, drives=n, converged=len(conv),
                converged_ci=binom_ci(len(conv), n) if n else None,
                converged_at_or_below_truth=len(ok), causes=causes, params=per,
                branches=branches,
                fit_s_median=float(np.median([r["fit_s"] for r in rows if "fit_s" in r]))
                if any("fit_s" in r for r in rows) else None)


def markdown(s: dict) -> str:
    n = s["drives"]
    lines = [f"### Fit set `{s['set']}`: {n} drives", "",
             f"- converged: {s['converged']} of {n} "
             + (f"({100 * s['converged'] / n:.1f} %, 95 % CI {100 * s['converged_ci'][0]:.1f}"
                f"-{100 * s['converged_ci'][1]:.1f} %)" if n else ""),
             f"- converged at a cost no higher than the truth's: "
             f"{s['converged_at_or_below_truth']} of {s['converged']}",
             f"- code: {', '.join(s.get('commits', []))}",
             f"- median fit time {s['fit_s_median']:.1f} s" if s["fit_s_median"] else "",
             "- orbit records by branch: " + (", ".join(f"{k} {v}" for k, v in
                                                        sorted(s["branches"].items()))
                                              or "none"),
             "", "| parameter | covered | coverage | 95 % CI | mean z | std z |",
             "|---|---|---|---|---|---|"]
    for name, p in s["params"].items():
        if not p["n"]:
            continue
        lines.append(f"| {name} | {p['covered']}/{p['n']} | {100 * p['coverage']:.1f} % | "
                     f"{100 * p['ci'][0]:.1f}-{100 * p['ci'][1]:.1f} % | "
                     f"{p['z_mean']:+.2f} | {p['z_std']:.2f} |")
    lines += ["", "Failures by cause:", ""]
    lines += [f"- {c}: {k}" for c, k in sorted(s["causes"].items(), key=lambda x: -x[1])] or [
        "- none"]
    return "\n".join(lines) + "\n"


def _commit() -> str:
    """The code's git commit (with "+changes" where the work tree differs), for the record."""
    import subprocess

    def git(*a):
        return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout
    head = git("rev-parse", "--short", "HEAD").strip() or "unknown"
    return head + ("+changes" if git("status", "--porcelain", "--", "bsfs_jax",
                                      "identification").strip() else "")


def _summary(rows: list[dict], kind: str) -> dict:
    """`summarize` with the code commits the rows came from."""
    return dict(summarize(rows, kind),
                commits=sorted({r.get("commit", "unrecorded") for r in rows}))


def _pooled(paths, kinds) -> int:
    """Print the summary of several row files' drives together (one fit set)."""
    if len(kinds) != 1:
        raise SystemExit("--pool needs one --set")
    rows = [r for p in paths for r in read_done(p)]
    if not rows:
        raise SystemExit(f"no rows in {', '.join(map(str, paths))}")
    s = _summary(rows, kinds[0])
    print(f"Pooled: {', '.join(str(p) for p in paths)}\n")
    print(markdown(s))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=sorted(SETS), action="append",
                    help="fit set (repeatable; default both)")
    ap.add_argument("--drives", type=int, default=100)
    ap.add_argument("--first", type=int, default=0,
                    help="first drive to run (drives FIRST..DRIVES-1; the summary reads "
                         "every drive below DRIVES in the file): split a study between "
                         "processes with their own --out, then merge the files")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--draw", choices=("uniform", "prior"), default="uniform",
                    help="the drives' dampers (and the default set's other parameters): "
                         "log-uniform over the prior's central 95 %% (default) or from the "
                         "prior itself; rows in <set>.prior.jsonl")
    ap.add_argument("--noise-free", action="store_true",
                    help="fit noise-free records weighted as the noisy ones (z = the bias of "
                         "model and estimator in stated stds); rows in <set>.noise_free.jsonl")
    ap.add_argument("--no-priors", action="store_true",
                    help="maximum likelihood (`identify --no-priors`): intervals from the "
                         "data alone, no pull towards the prior; rows in "
                         "<set>[...].no_priors.jsonl")
    ap.add_argument("--seed-offset", type=int, default=0,
                    help="another realisation of every drive's test (new phases, drift and "
                         "noise; 1..89; the same truths): the study's coverage is one draw "
                         "of the tests, this measures how much it varies; rows in "
                         "<set>[...].seedK.jsonl")
    ap.add_argument("--pool", type=Path, nargs="+", metavar="ROWS",
                    help="summarise these row files together (realisations of the same "
                         "drives, e.g. the study's rows and --seed-offset runs) and stop")
    ap.add_argument("--out", type=Path, default=OUT,
                    help=f"results folder (default {OUT.relative_to(ROOT)})")
    study_cluster.add_args(ap)
    args = ap.parse_args(argv)
    kinds = args.set or ["preload", "default"]
    if args.pool:
        return _pooled(args.pool, kinds)
    cluster = None if args.report_only else study_cluster.open_from(args)
    try:
        return _run_sets(args, kinds, cluster)
    finally:
        if cluster is not None:
            cluster.close()


def _run_sets(args, kinds, cluster) -> int:
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    commit = _commit()
    for kind in kinds:
        tag = ((".prior" if args.draw == "prior" else "")
               + (".noise_free" if args.noise_free else "")
               + (".no_priors" if args.no_priors else "")
               + (f".seed{args.seed_offset}" if args.seed_offset else ""))
        path = out / f"{kind}{tag}.jsonl"
        done = {r["drive"] for r in read_done(path)}
        if not args.report_only:
            todo = [d for d in range(args.first, args.drives) if d not in done]
            one = functools.partial(drive_row, kind, args.noise_free, args.draw,
                                    None if args.no_priors else "default", args.seed_offset)

            def keep(drive, row, kind=kind, path=path):
                row = dict(row, commit=commit)
                append_line(path, row)
                print(f"[{kind} {drive + 1}/{args.drives}] converged={row.get('converged')} "
                      f"cause={row.get('cause')} fit {row.get('fit_s', 0):.1f} s", flush=True)

            study_cluster.run_units(one, todo, keep, cluster, modules=("coverage_study",))
        rows = sorted((r for r in read_done(path) if r["drive"] < args.drives),
                      key=lambda r: r["drive"])
        if not rows:
            continue
        s = _summary(rows, kind)
        s["machine"] = f"{platform.machine()}, {platform.python_version()}"
        (out / f"{kind}{tag}_summary.json").write_text(json.dumps(s, indent=1))
        md = markdown(s)
        (out / f"{kind}{tag}_summary.md").write_text(md)
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
