"""Identification's long jobs on a local Dask cluster: plain against `--workers 2`.

Three jobs, each configuration in a fresh process after a warm-up run of the same
configuration (the plain run's compilation cache and the workers' CPU folder of it both
filled), so the times are those of a repeated study, not of compiling:

- `bsfs identify --refits 200` on the bundled worn drive (batches of 32 refits a chunk);
- `bsfs predict --force 100` on that identification (a batch of draws a chunk);
- the robustness study, `scripts/robustness_study.py --set preload --drives 4` (a drive a
  chunk).

Per job: wall seconds, speed-up against the plain run, the chunks' mean and max seconds,
and whether the outputs are the plain run's (refits.npz, prediction.json's numbers, the
study's rows; largest relative difference). From the study's seconds per drive, the
estimated wall time of the 545-drive study on 8 and 64 workers.

    python benchmarks/bench_cluster_jobs.py

writes benchmarks/results/cluster_jobs.json and .md (a section of BENCHMARKS.md).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from _cli import env, run_cli, write_result  # noqa: E402
from _machine import machine_info, machine_line  # noqa: E402
from bench_cluster import _fmt  # noqa: E402

FIT = "nut_preload,bearing_preload,c_b,c_s,c_n"
IDENTIFY = ["identify", "--data", "preload-loss", "--fit", FIT, "--refits", "200"]
CONFIGS = [("plain", []), ("2 workers", ["--workers", "2"])]
DRIVES = 4
STUDY_DRIVES = 545  # the robustness study's size (docs/ROBUSTNESS.md)
COMMAND = "python benchmarks/bench_cluster_jobs.py"


def _worst(a, b) -> float:
    """Largest relative difference between two JSON trees (times, the cluster's account
    and printed text left out)."""
    if isinstance(a, dict):
        return max([_worst(a[k], b[k]) for k in a if k not in ("cluster", "summary", "note")
                    and not k.endswith(("seconds", "_s"))], default=0.0)
    if isinstance(a, list):
        return max([_worst(x, y) for x, y in zip(a, b)], default=0.0)
    if isinstance(a, float):
        return abs(a - b) / max(abs(a), 1e-300)
    return 0.0 if a == b else float("inf")


def _chunks(account: dict | None) -> dict:
    if not account:
        return {}
    c = account["chunk_seconds"]
    return {"chunks": account["chunks_done"], "chunk_s_mean": c["mean"],
            "chunk_s_max": c["max"], "failed": len(account["failed_chunks"])}


def identify_and_predict(tmp: Path, cache: Path) -> dict:
    out = {"identify": {}, "predict": {}}
    for name, extra in CONFIGS:  # warm-ups
        run_cli([*IDENTIFY, *extra, "--out", str(tmp / f"iw{len(extra)}")], cache)
    for name, extra in CONFIGS:
        folder = tmp / f"identify_{len(extra)}"
        _, wall, _ = run_cli([*IDENTIFY, *extra, "--out", str(folder)], cache)
        rep = json.loads((folder / "report.json").read_text())["refits"]
        out["identify"][name] = {"wall_s": wall, "refits_s": rep["seconds"],
                                 **_chunks(rep.get("cluster"))}
        print(f"  identify {name}: {wall:.1f} s {out['identify'][name]}", flush=True)
    a = np.load(tmp / "identify_0" / "refits.npz")["samples"]
    b = np.load(tmp / "identify_2" / "refits.npz")["samples"]
    out["identify"]["2 workers"]["max_relative_difference"] = float(
        np.max(np.abs(a - b) / np.abs(a)))
    source = str(tmp / "identify_0")
    for name, extra in CONFIGS:  # warm-ups
        run_cli(["predict", "--from", source, *extra, "--out", str(tmp / f"pw{len(extra)}")],
                cache)
    for name, extra in CONFIGS:
        folder = tmp / f"predict_{len(extra)}"
        _, wall, _ = run_cli(["predict", "--from", source, *extra, "--out", str(folder)], cache)
        pred = json.loads((folder / "prediction.json").read_text())
        out["predict"][name] = {"wall_s": wall, **_chunks(pred.get("cluster"))}
        print(f"  predict {name}: {wall:.1f} s {out['predict'][name]}", flush=True)
    here, there = (json.loads((tmp / f"predict_{k}" / "prediction.json").read_text())
                   for k in (0, 2))
    out["predict"]["2 workers"]["max_relative_difference"] = _worst(here, there)
    return out


def _study(drives: int, extra: list, folder: Path, cache: Path) -> float:
    cmd = [sys.executable, str(ROOT / "scripts" / "robustness_study.py"), "--set", "preload",
           "--drives", str(drives), "--out", str(folder), *extra]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env(cache), cwd=ROOT)
    if proc.returncode:
        raise SystemExit(f"robustness study failed:\n{proc.stderr[-3000:]}")
    return time.perf_counter() - t0


def _rows(folder: Path) -> list:
    rows = [json.loads(line) for line in (folder / "preload.jsonl").read_text().splitlines()]
    return sorted(rows, key=lambda r: r["drive"])


def study(tmp: Path, cache: Path) -> dict:
    out = {}
    for name, extra in CONFIGS:  # warm-ups: one drive each
        _study(1, extra, tmp / f"sw{len(extra)}", cache)
    for name, extra in CONFIGS:
        wall = _study(DRIVES, extra, tmp / f"study_{len(extra)}", cache)
        rows = _rows(tmp / f"study_{len(extra)}")
        per = [r["synth_s"] + r["fit_s"] for r in rows]
        out[name] = {"wall_s": wall, "drives": len(rows), "drive_s_mean": float(np.mean(per)),
                     "drive_s_max": float(np.max(per))}
        print(f"  study {name}: {wall:.1f} s {out[name]}", flush=True)
    a, b = _rows(tmp / "study_0"), _rows(tmp / "study_2")
    out["2 workers"]["max_relative_difference"] = _worst(
        [{k: v for k, v in r.items() if k != "commit"} for r in a],
        [{k: v for k, v in r.items() if k != "commit"} for r in b])
    drive = out["2 workers"]["drive_s_mean"]  # one core per worker, as on a cluster
    out["estimate"] = {"drive_s": drive, "drives": STUDY_DRIVES,
                       **{f"{w}_workers_s": math.ceil(STUDY_DRIVES / w) * drive
                          for w in (1, 8, 64)}}
    return out


def markdown(result: dict, command: str) -> str:
    lines = ["## K2 Identification's jobs on a local cluster", "",
             f"Command: `{command}`.", machine_line(result["machine"]), "",
             "Each job plain and with `--workers 2` (a local Dask cluster of two worker "
             "processes of one thread) in a fresh process, after a warm-up run of the same "
             "configuration. A chunk: 32 refits (`identify --refits 200` on the bundled worn "
             "drive), a batch of the 200 draws (`predict --force 100` on that "
             f"identification), one drive (the robustness study, {DRIVES} drives of the "
             "`preload` set). Outputs compared with the plain run's: refits.npz, "
             "prediction.json's numbers, the study's rows.", "",
             "| job | run | wall | speed-up | chunks | chunk mean / max | as plain (largest "
             "relative difference) |", "|---|---|---|---|---|---|---|"]
    jobs = {"identify --refits 200": result["identify"], "predict": result["predict"],
            f"robustness study, {DRIVES} drives": {k: v for k, v in result["study"].items()
                                                   if k != "estimate"}}
    for job, runs in jobs.items():
        plain = runs["plain"]["wall_s"]
        for name, r in runs.items():
            if "chunk_s_mean" in r:
                chunk = f"{r['chunk_s_mean']:.2f} / {r['chunk_s_max']:.2f} s"
            elif "drive_s_mean" in r and name != "plain":
                chunk = f"{r['drive_s_mean']:.1f} / {r['drive_s_max']:.1f} s"
            else:
                chunk = "–"
            same = r.get("max_relative_difference")
            lines.append(f"| {job} | {name} | {_fmt(r['wall_s'])} | "
                         f"{plain / r['wall_s']:.2f}x | "
                         f"{r.get('chunks', r.get('drives', '–') if name != 'plain' else '–')}"
                         f" | {chunk} | "
                         + ("–" if same is None else f"{'yes' if same <= 1e-12 else '**no**'}"
                            f" ({same:.1g})") + " |")
    e = result["study"]["estimate"]
    lines += ["", f"Estimate of a {e['drives']}-drive robustness study of the same set (the "
              f"size of the study in docs/ROBUSTNESS.md): one drive {e['drive_s']:.1f} s on a "
              f"worker of one core (the mean above, its synthesis and fit), the cache warm: **{_fmt(e['1_workers_s'])} on one worker, "
              f"{_fmt(e['8_workers_s'])} on 8, {_fmt(e['64_workers_s'])} on 64** (drives per "
              "worker x the mean drive; the start-up and a batch system's queue left out). "
              "On this 2-core machine the plain run already uses both cores for a job of "
              "one program, so two workers gain only where the plain run leaves a core "
              "idle.", ""]
    return "\n".join(lines) + "\n"


def main() -> None:
    if "--render" in sys.argv:  # the markdown again from the kept json
        result = json.loads((HERE / "results" / "cluster_jobs.json").read_text())
        write_result("cluster_jobs", result, markdown(result, COMMAND))
        return
    result = {"machine": machine_info()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "cache"
        result.update(identify_and_predict(tmp, cache))
        result["study"] = study(tmp, cache)
    write_result("cluster_jobs", result, markdown(result, COMMAND))


if __name__ == "__main__":
    main()
