"""Coverage study of the forecast's 95 % intervals (docs/COVERAGE.md).

For N seeded replicates of the bundled preload-loss test (the records of
`scripts/coverage_study.py`: synthesised afresh from the truth, data/worn.toml, with new
seeds), each replicate is identified as the README's example does it (`identification.
identify`, `PRELOAD_FIT`, the default preset as prior), its output folder is written as
`bsfs identify --out` writes it (identified.toml, report.json), and `bsfs predict`'s
forecast is run on that folder at the working force (default 100 N, where the FRC has
folds). Each quantity's interval is compared with the truth's own value: the same forecast
run on the truth (worn.toml) itself, the preloads read from it.

    python scripts/forecast_coverage.py                 # 100 replicates (~1 h, 2 cores)
    python scripts/forecast_coverage.py --quick         # 4 replicates, a check
    python scripts/forecast_coverage.py --workers 2     # a local Dask cluster of two
    python scripts/forecast_coverage.py --scheduler tcp://login1:8786  # a running one
    python scripts/forecast_coverage.py --report-only   # tables from the files
    python scripts/forecast_coverage.py --part liftoff  # the lift-off alone (~15 s each)
    python scripts/forecast_coverage.py --part modal    # modal quantities, preloads (~5 s)
    python scripts/forecast_coverage.py --first 200 --replicates 300   # seeds 200-299

Each folder holds the 200 bootstrap refits `bsfs identify --refits auto` saves for these
records (`identification.refit`, about 2 s), which the forecast's quadratic model uses
where its delta method is doubtful; BSFS_COVERAGE_NO_REFITS=1 leaves them out (the
forecast then draws from the covariance, as before 2026-11-28).

`--part liftoff` runs the same replicates (same seeds, so the same identification) through
the lift-off alone (`identification.forecast_liftoff`, the computation `forecast` does on
the same band); its rows (<force>N.liftoff.jsonl) replace the whole forecast's lift-off
quantities in the summary, so a change to the lift-off is checked without continuing
every FRC again.

Every replicate is one JSON line in out/forecast-coverage/<force>N.jsonl (or .w0.jsonl,
written by the study's own processes of at most 10 replicates each; flushed and fsynced); a
rerun skips the replicates already there, so an interrupted study resumes. With
`--workers N` or `--scheduler ADDRESS` each replicate is a chunk on a Dask cluster, run in a
fresh process of its worker, and this process writes its row. The summary (per quantity:
coverage with its Clopper-Pearson interval, mean and std of z = (estimate - truth) / stated
std, mean relative error, the methods used) is printed and written to
out/forecast-coverage/<force>N_summary.{json,md}. Results: docs/COVERAGE.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bsfs_jax.cli import setup_jax  # noqa: E402
from bsfs_jax.files import jsonable, write_text_atomic  # noqa: E402

setup_jax()  # 64-bit, the persistent compilation cache, one BLAS thread

import numpy as np  # noqa: E402
import study_cluster  # noqa: E402
from coverage_study import (  # noqa: E402
    append_line,
    binom_ci,
    read_done,
    record_seeds,
    synth_records,
    truth_params,
)

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402

OUT = ROOT / "out" / "forecast-coverage"
PER_PROCESS = 10  # replicates per worker process
PRELOADS = {"nut_preload_n": "nut.preload_n", "bearing_preload_n": "bearing.preload_n"}


def identified_folder(records, prior, folder: Path):
    """`bsfs identify --fit PRELOAD_FIT --out folder` on the records (identified.toml,
    report.json and, as `--refits auto` does for these records, refits.npz)."""
    res = idn.identify(records, prior, idn.PRELOAD_FIT)
    folder.mkdir(parents=True, exist_ok=True)
    idn.write_identified(res, folder)
    report = idn.report_dict(res)
    refits = (None if os.environ.get("BSFS_COVERAGE_NO_REFITS") else idn.refits_for(res))
    if refits is not None:
        report["refits"] = refits.as_dict()
        idn.save_refits(refits, folder, res.fit.values)
    write_json(folder / "report.json", report)
    return res


def truth_values(ident, truth, force: float) -> dict:
    """The truth's own value of every quantity: the forecast on the truth itself (its
    fitted coordinates at the truth's values; the intervals there are not used), the
    preloads read from worn.toml."""
    theta = []
    for key, lg, prior in zip(ident.keys, ident.log, ident.prior):
        v = float(np.asarray(truth.get(key)))
        theta.append(np.log(v / prior) if lg else v - prior)
    t_ident = dataclasses.replace(ident, params=truth, theta=np.asarray(theta))
    for key in ident.keys:  # the truth model is the truth
        assert np.isclose(float(np.asarray(t_ident.params_at(t_ident.theta).get(key))),
                          float(np.asarray(truth.get(key))), rtol=1e-12)
    fc = idn.forecast(t_ident, force, nominal_curve=False)
    # The model's own value at the truth: `plug_in` where the quadratic check made the
    # reported value a median of draws around it.
    out = {q.name: q.extra.get("plug_in", q.value)
           for q in list(fc["quantities"]) + list(fc["per_joint_liftoff"])}
    out.update({name: float(np.asarray(truth.get(key))) for name, key in PRELOADS.items()})
    return out


def row_of(replicate, fc, truth: dict, seconds: dict, res) -> dict:
    quantities = {}
    for q in list(fc["quantities"]) + list(fc["per_joint_liftoff"]):
        t = truth.get(q.name)
        lo, hi = (None, None) if q.ci95 is None else q.ci95
        covers = None
        if q.value is not None and t is not None and q.ci95 is not None:
            covers = bool((lo is None or lo <= t) and (hi is None or t <= hi))
        std = q.extra.get("std")
        if q.name in PRELOADS and q.ci95 is not None:  # the identification's interval
            std = (hi - lo) / (2 * 1.959963984540054)
        quantities[q.name] = dict(
            value=q.value, truth=t, ci95=q.ci95, method=q.method, covers=covers,
            std=std, z=None if covers is None or not std else (q.value - t) / std,
            dominated_by=q.dominated_by, plug_in=q.extra.get("plug_in"),
            z_plug_in=(None if covers is None or not std or "plug_in" not in q.extra
                       else (q.extra["plug_in"] - t) / std))
    return dict(replicate=replicate, seeds=record_seeds(replicate),
                converged=bool(res.fit.converged), quantities=quantities,
                health={j: h["line"] for j, h in fc.get("health", {}).items()},
                seconds=seconds)


# ----------------------------------------------------------------------------- summary


def summarize(rows: list[dict]) -> dict:
    names = list(rows[0]["quantities"])
    out = dict(replicates=len(rows), quantities={},
               liftoff_pass=sum(bool(r.get("liftoff_pass")) for r in rows),
               modal_pass=sum(bool(r.get("modal_pass")) for r in rows))
    for n in names:
        qs = [r["quantities"].get(n) for r in rows]
        judged = [q for q in qs if q is not None and q["covers"] is not None]
        k = sum(q["covers"] for q in judged)
        # A quantity the truth has but a replicate did not find (e.g. no fold) is a miss.
        missing = sum(1 for q in qs if q is None or (q["truth"] is not None and q["value"] is None))
        n_all = len(judged) + missing
        z = np.asarray([q["z"] for q in judged if q["z"] is not None], float)
        zp = np.asarray([q["z_plug_in"] for q in judged if q.get("z_plug_in") is not None],
                        float)
        rel = np.asarray([q["value"] / q["truth"] - 1 for q in judged], float)
        methods = {}
        for q in judged:
            methods[q["method"]] = methods.get(q["method"], 0) + 1
        if n_all == 0:
            out["quantities"][n] = dict(judged=0, methods=methods)
            continue
        out["quantities"][n] = dict(
            judged=n_all, covered=int(k), coverage=k / n_all,
            coverage_ci95=binom_ci(int(k), n_all), missing=missing,
            z_mean=float(z.mean()) if z.size else None,
            z_mean_se=float(z.std(ddof=1) / np.sqrt(z.size)) if z.size > 1 else None,
            z_std=float(z.std(ddof=1)) if z.size > 1 else None,
            z_plug_in_mean=float(zp.mean()) if zp.size else None,
            z_plug_in_n=int(zp.size),
            rel_error_mean=float(rel.mean()) if rel.size else None,
            rel_error_std=float(rel.std(ddof=1)) if rel.size > 1 else None,
            truth=next((q["truth"] for q in qs if q is not None), None), methods=methods)
    out["converged"] = float(np.mean([r["converged"] for r in rows]))
    out["seconds_median"] = {k: float(np.median([r["seconds"][k] for r in rows]))
                             for k in rows[0]["seconds"]}
    return out


def markdown(s: dict, force: float) -> str:
    lines = [f"Forecast at {force:g} N; {s['replicates']} replicates of the preload-loss "
             "test (worn.toml), each identified (PRELOAD_FIT) and predicted"
             + (f"; the lift-off quantities of {s['liftoff_pass']} of them from the lift-off "
                "pass (`--part liftoff`)" if s.get("liftoff_pass") else "")
             + (f"; the modal quantities and preloads of {s['modal_pass']} from the modal pass "
                "(`--part modal`)" if s.get("modal_pass") else "") + ".", "",
             "| quantity | truth | coverage | 95 % CI of coverage | mean z | std z | "
             "mean z of the plug-in value | mean rel. error | methods |",
             "|---|---|---|---|---|---|---|---|---|"]
    for n, q in s["quantities"].items():
        if not q.get("judged"):
            continue
        lo, hi = q["coverage_ci95"]
        zm = ("-" if q["z_mean"] is None else f"{q['z_mean']:+.2f}" if q["z_mean_se"] is None
              else f"{q['z_mean']:+.2f} +- {q['z_mean_se']:.2f}")
        zs = "-" if q["z_std"] is None else f"{q['z_std']:.2f}"
        rel = "-" if q["rel_error_mean"] is None else f"{100 * q['rel_error_mean']:+.3f} %"
        zp = ("-" if not q.get("z_plug_in_n") else
              f"{q['z_plug_in_mean']:+.2f} ({q['z_plug_in_n']} quadratic)")
        miss = f", {q['missing']} not found" if q["missing"] else ""
        meth = "; ".join(f"{k} {v}" for k, v in q["methods"].items())
        lines.append(f"| {n} | {q['truth']:.6g} | {100 * q['coverage']:.1f} % "
                     f"({q['covered']}/{q['judged']}{miss}) | {100 * lo:.1f}-{100 * hi:.1f} % "
                     f"| {zm} | {zs} | {zp} | {rel} | {meth} |")
    sec = ", ".join(f"{k} {v:.1f} s" for k, v in s["seconds_median"].items())
    lines += ["", f"Converged fits: {100 * s['converged']:.1f} %; median time per replicate: "
              f"{sec}."]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- main


def files(force: float, part: str = "all") -> list[Path]:
    """The rows of one part: the whole forecast (`all`: <force>N.jsonl, .w<i>.jsonl), the
    lift-off pass (`liftoff`: <force>N.liftoff.jsonl, .liftoff.w<i>.jsonl) or the modal
    pass (`modal`: <force>N.modal*.jsonl)."""
    if part in ("liftoff", "modal"):
        return sorted(OUT.glob(f"{force:g}N.{part}*.jsonl"))
    return sorted(p for p in OUT.glob(f"{force:g}N*.jsonl")
                  if ".liftoff" not in p.name and ".modal" not in p.name)


def row_path(force: float, part: str, worker: int | None = None) -> Path:
    tag = "" if part == "all" else f".{part}"
    return OUT / (f"{force:g}N{tag}.jsonl" if worker is None else
                  f"{force:g}N{tag}.w{worker}.jsonl")


def overlay(rows: list[dict], lift_rows: list[dict], tag: str = "liftoff_pass") -> list[dict]:
    """The whole forecast's rows with the quantities of a partial pass (lift-off or modal)
    replaced by that pass's, replicate by replicate (the same seeds, so the same
    identification). Without whole-forecast rows, the pass's rows alone."""
    if not rows:
        return [dict(r, **{tag: True}) for r in lift_rows]
    by_rep = {r["replicate"]: r for r in lift_rows}
    out = []
    for r in rows:
        lr = by_rep.get(r["replicate"])
        if lr is not None:
            r = dict(r, quantities={**r["quantities"], **lr["quantities"]}, **{tag: True})
        out.append(r)
    return out


def _over() -> dict:
    """Diagnosis: the test's imperfections changed from `identification.TestEffects` by the
    environment variable BSFS_COVERAGE_EFFECTS (JSON, e.g. '{"force_snr_db": 200}'; the
    worker processes inherit it). Empty: the study as documented."""
    text = os.environ.get("BSFS_COVERAGE_EFFECTS", "")
    return {"effects": json.loads(text)} if text else {}


def one_replicate(k: int, force: float, part: str, tv: dict | None) -> tuple[dict, dict]:
    """(row, truth values) of replicate k: its records synthesised, identified into a
    temporary folder as `bsfs identify` writes it, and forecast from that folder. `tv`:
    the truth's values (`truth_values`), or None: computed here from this replicate's
    identification (the study's first replicate)."""
    truth, prior = truth_params(), bsfs_jax.preset()
    t0 = time.perf_counter()
    recs = synth_records(truth, k, _over())
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=f"bsfs-fc{k}-") as tmp:
        res = identified_folder(recs, prior, Path(tmp))
        t2 = time.perf_counter()
        ident = idn.load_identified(tmp)
        if tv is None:  # as read back from the truth file
            tv = json.loads(json.dumps(jsonable(truth_values(ident, truth, force))))
        t_truth = time.perf_counter()
        fc = (idn.forecast(ident, force, nominal_curve=False) if part == "all"
              else idn.forecast_liftoff(ident) if part == "liftoff"
              else idn.forecast_modal(ident))
    t3 = time.perf_counter()
    return row_of(k, fc, tv, dict(synth=t1 - t0, identify=t2 - t1,
                                  forecast=t3 - t_truth), res), tv


def replicate_row(force: float, part: str, tv: dict, k: int) -> dict:
    """`one_replicate`'s row, the replicate last: a unit of work on a cluster."""
    return one_replicate(k, force, part, tv)[0]


def _progress(j: int, n: int, row: dict, t_start: float) -> None:
    el = time.perf_counter() - t_start
    cov = [q["covers"] for q in row["quantities"].values() if q["covers"] is not None]
    s = row["seconds"]
    print(f"[{j}/{n}] replicate {row['replicate']}: covered {sum(cov)}/{len(cov)}  identify "
          f"{s['identify']:.1f} s forecast {s['forecast']:.1f} s  (elapsed {el:.0f} s, ETA "
          f"{el / j * (n - j):.0f} s)", flush=True)


def run(todo: list[int], path: Path, force: float, part: str = "all") -> None:
    """The replicates `todo` one after another in this process, their rows appended to
    `path`; the truth's values from the truth file, or written there by the first."""
    truth_file = OUT / f"{force:g}N_truth.json"
    t_start = time.perf_counter()
    for j, k in enumerate(todo):
        tv = json.loads(truth_file.read_text()) if truth_file.exists() else None
        row, tv = one_replicate(k, force, part, tv)
        if not truth_file.exists():  # once per study (the first worker to get here)
            write_json(truth_file, tv)
        append_line(path, row)
        _progress(j + 1, len(todo), row, t_start)


def write_json(path, data) -> None:
    """JSON written atomically (numpy values as plain numbers)."""
    write_text_atomic(path, json.dumps(jsonable(data), indent=2) + "\n")


def _use_out(path: Path) -> None:
    """Every path of the study (rows, truth, summary) under `path` (`--out`)."""
    global OUT
    OUT = path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=100)
    ap.add_argument("--first", type=int, default=0,
                    help="first replicate (seeds first..replicates-1; default 0)")
    ap.add_argument("--quick", action="store_true", help="4 replicates (a check)")
    ap.add_argument("--force", type=float, default=100.0, help="working force [N]")
    ap.add_argument("--shard", default=None, help=argparse.SUPPRESS)  # "i/n" (a worker)
    ap.add_argument("--report-only", action="store_true", help="summarise the files")
    ap.add_argument("--out", type=Path, default=OUT,
                    help=f"results folder (default {OUT.relative_to(ROOT)})")
    ap.add_argument("--part", choices=("all", "liftoff", "modal"), default="all",
                    help="the whole forecast, or the lift-off alone, or the modal quantities "
                         "and preloads alone (their rows then replace the whole forecast's "
                         "quantities of the same names in the summary)")
    study_cluster.add_args(ap)
    args = ap.parse_args(argv)
    _use_out(args.out)
    n = 4 if args.quick else args.replicates
    part = args.part
    OUT.mkdir(parents=True, exist_ok=True)
    rows = [r for f in files(args.force, part) for r in read_done(f)]
    done = {r["replicate"] for r in rows}
    todo = [k for k in range(args.first, n) if k not in done]
    if args.shard:
        i, m = (int(x) for x in args.shard.split("/"))
        run(todo[i::m][:PER_PROCESS], row_path(args.force, part, i), args.force, part)
        return 0
    print(f"{len(done)} replicate(s) done, {len(todo)} to run at {args.force:g} N "
          f"(part: {part})", flush=True)
    if todo and not args.report_only:
        cluster = study_cluster.open_from(args)  # (an unreachable one: before any work)
        if not (OUT / f"{args.force:g}N_truth.json").exists():
            # The truth's values first (the whole forecast at the truth, in `run`), so the
            # workers do not both compute them.
            run(todo[:1], row_path(args.force, part), args.force, part)
        if cluster is not None:
            # A replicate a chunk, each in a fresh process of its worker (the memory of
            # its continuations goes with it), with the truth's values computed above.
            tv = json.loads((OUT / f"{args.force:g}N_truth.json").read_text())
            done = {r["replicate"] for f in files(args.force, part) for r in read_done(f)}
            rest = [k for k in todo if k not in done]
            path, t_start, count = row_path(args.force, part), time.perf_counter(), [0]

            def keep(_, row):
                append_line(path, row)
                count[0] += 1
                _progress(count[0], len(rest), row, t_start)

            with cluster:
                study_cluster.run_units(functools.partial(replicate_row, args.force, part, tv),
                                        rest, keep, cluster, modules=("coverage_study",),
                                        fresh_process=True)
        # Without a cluster: processes of at most PER_PROCESS replicates, one after another
        # (every continuation leaves compiled programs behind, and a process that ran 13
        # forecasts beside another ran out of the machine's 24 GB).
        while cluster is None:
            done = {r["replicate"] for f in files(args.force, part) for r in read_done(f)}
            if all(k in done for k in range(args.first, n)):
                break
            proc = subprocess.run([sys.executable, __file__, "--replicates", str(n), "--first",
                                   str(args.first), "--force", str(args.force), "--part",
                                   part, "--out", str(OUT), "--shard", "0/1"])
            if proc.returncode:
                print("the study's process failed; rerun to resume", file=sys.stderr)
                return 1

    def read(which):
        return sorted({r["replicate"]: r for f in files(args.force, which)
                       for r in read_done(f) if args.first <= r["replicate"] < n}.values(),
                      key=lambda r: r["replicate"])

    rows = overlay(overlay(read("all"), read("liftoff")), read("modal"), "modal_pass")
    if not rows:
        return 0
    s = summarize(rows)
    md = markdown(s, args.force)
    print(md)
    write_json(OUT / f"{args.force:g}N_summary.json", s)
    write_text_atomic(OUT / f"{args.force:g}N_summary.md", md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
