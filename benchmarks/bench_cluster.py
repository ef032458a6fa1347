"""Atlases on a local Dask cluster: `bsfs map` plain, with `--workers 1` and `--workers 2`.

The README's 16 x 8 atlas and a 64 x 64 atlas over the same ranges, each configuration in a
fresh process with a compilation cache warmed beforehand (the same command on two rows of
the same width, once per configuration: the plain run's cache and the workers' CPU folder
of it are both filled), so the times are those of a repeated study, not of compiling.
Per configuration: wall seconds, speed-up and overhead against the plain run; from the
cluster runs' summary.json the seconds of each chunk (one row of the atlas), the rows per
worker and the programs the workers compiled. Separately, the scheduler's overhead per
task (`Cluster.run` of tasks that do nothing, on the two workers) and the time to start a
local cluster. From these, the wall time of a 256 x 256 atlas on 8 and 64 workers.

    python benchmarks/bench_cluster.py [--grids 16x8,64x64] [--quick]

writes benchmarks/results/cluster.json and .md (a section of BENCHMARKS.md); `--quick`
(the 16 x 8 atlas only) writes cluster_quick.*, which are not results.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from _cli import run_cli, write_result  # noqa: E402
from _machine import machine_info, machine_line  # noqa: E402

RANGES = ["--x", "frequency_hz", "--x-start", "400", "--x-stop", "1600",
          "--y", "force_n", "--y-start", "1000", "--y-stop", "8000"]
CONFIGS = [("plain", []), ("1 worker", ["--workers", "1"]), ("2 workers", ["--workers", "2"])]
TASKS = 200  # empty tasks timed for the scheduler's overhead


def map_args(nx: int, ny: int) -> list[str]:
    return ["map", *RANGES, "--x-num", str(nx), "--y-num", str(ny), "--no-progress"]


def _noop(item):
    return item


def scheduler_overhead(workers: int = 2) -> dict:
    """Seconds to start a local cluster of `workers`, and the wall seconds per task of
    `Cluster.run` over `TASKS` tasks that do nothing (submit, schedule, run on a worker
    with its record, result back), after a first round that starts the workers' side."""
    from bsfs_jax.cluster import Cluster

    t0 = time.perf_counter()
    with Cluster(workers=workers) as cluster:
        start = time.perf_counter() - t0
        list(cluster.run(_noop, range(workers)))  # the workers' first task (imports)
        t0 = time.perf_counter()
        got = list(cluster.run(_noop, range(TASKS)))
        per_task = (time.perf_counter() - t0) / TASKS
    assert len(got) == TASKS
    return {"start_s": start, "per_task_s": per_task, "tasks": TASKS, "workers": workers}


def _points(atlas) -> list:
    """The atlas's bifurcation points (row, kind, x to 12 digits), in order."""
    return sorted((float(b["y"]), b["kind"], f"{float(b['x']):.12g}")
                  for b in atlas.bifurcations)


def run_grid(nx: int, ny: int, tmp: Path, cache: Path) -> dict:
    out = {}
    for name, extra in CONFIGS:  # warm the cache for this row width, per configuration
        _, wall, _ = run_cli([*map_args(nx, 2), *extra, "--out", str(tmp / f"warm{nx}{name}")],
                             cache)
        print(f"  warm-up {nx} x 2 {name}: {wall:.1f} s", flush=True)
    for name, extra in CONFIGS:
        folder = tmp / f"{nx}x{ny}_{name.replace(' ', '_')}"
        _, wall, stats = run_cli([*map_args(nx, ny), *extra, "--out", str(folder)], cache)
        summary = json.loads((folder / "summary.json").read_text())
        row = {"wall_s": wall, "client_compiles": stats.get("compiles"),
               "motion_counts": summary.get("motion_counts")}
        if "cluster" in summary:
            c = summary["cluster"]
            row.update(chunks=c["chunks_done"], chunk_s_mean=c["chunk_seconds"]["mean"],
                       chunk_s_max=c["chunk_seconds"]["max"],
                       chunk_s_total=c["chunk_seconds"]["total"],
                       worker_compiles=c["programs_compiled"],
                       rows_per_worker=sorted(w["chunks"] for w in c["workers"].values()),
                       failed=len(c["failed_chunks"]))
        out[name] = row
        print(f"  {nx} x {ny} {name}: {wall:.1f} s {row}", flush=True)
    plain = out["plain"]
    from bsfs_jax.analysis import load_atlas

    ref = load_atlas(tmp / f"{nx}x{ny}_plain" / "atlas.nc")
    for name, row in out.items():
        row["speed_up"] = plain["wall_s"] / row["wall_s"]
        row["overhead_vs_plain"] = row["wall_s"] / plain["wall_s"] - 1.0
        got = load_atlas(tmp / f"{nx}x{ny}_{name.replace(' ', '_')}" / "atlas.nc")
        a, b = np.asarray(got.amplitude, float), np.asarray(ref.amplitude, float)
        row["same_labels_as_plain"] = bool((got.motion == ref.motion).all()
                                           and (np.isnan(a) == np.isnan(b)).all())
        row["max_amplitude_difference"] = float(np.nanmax(np.abs(a - b), initial=0.0))
        row["same_bifurcations_as_plain"] = _points(got) == _points(ref)
    return out


def estimate(grids: dict, sched: dict, n: int = 256) -> dict:
    """Wall seconds of an n x n atlas on W workers, each a core like this machine's:
    start-up + ceil(n / W) rows per worker x (the seconds of one n-point row + the
    overhead per task); one n-point row taken as n / nx times a row of the widest grid
    measured, from its 2-worker run (each worker then has one core): the cost per point
    constant (the rows' continuation, whose cost does not grow with the points, makes
    this an over-estimate)."""
    key = max(grids, key=lambda k: int(k.split("x")[0]))
    nx = int(key.split("x")[0])
    row_s = grids[key]["2 workers"]["chunk_s_mean"] * n / nx
    return {"from_grid": key, "row_s": row_s,
            **{f"{w}_workers_s": sched["start_s"] + math.ceil(n / w)
               * (row_s + sched["per_task_s"]) for w in (8, 64)}}


def _fmt(s: float) -> str:
    """Seconds as s, min (from 2 min) or h (from 1.5 h)."""
    if s >= 5400:
        return f"{s / 3600:.1f} h"
    return f"{s / 60:.1f} min" if s >= 120 else f"{s:.1f} s"


def markdown(result: dict, command: str) -> str:
    lines = ["## K1 Atlases on a local cluster", "",
             f"Command: `{command}`.", machine_line(result["machine"]), "",
             "`bsfs map` over 400-1600 Hz x 1000-8000 N (the README's example ranges) in a "
             "fresh process, the compilation cache warmed beforehand for each configuration "
             "(plain, `--workers 1`, `--workers 2`: a local Dask cluster of worker processes "
             "of one thread, one row per chunk). Speed-up and overhead against the plain "
             "run; a chunk is one row (its verified sweep, and beside it on a thread its "
             "continuation, as in the plain run). The labels and amplitudes are compared "
             "with the plain run's atlas.nc.", "",
             "| atlas | run | wall | speed-up | overhead | rows per worker | chunk (row) "
             "mean / max | compiled on workers | as plain: labels, max amplitude difference [m], "
             "bifurcation points |",
             "|---|---|---|---|---|---|---|---|---|"]
    for grid, runs in result["grids"].items():
        for name, r in runs.items():
            chunk = (f"{r['chunk_s_mean']:.2f} / {r['chunk_s_max']:.2f} s"
                     if "chunk_s_mean" in r else "–")
            lines.append(
                f"| {grid.replace('x', ' x ')} | {name} | {_fmt(r['wall_s'])} | "
                f"{r['speed_up']:.2f}x | {100 * r['overhead_vs_plain']:+.0f} % | "
                f"{r.get('rows_per_worker', '–')} | {chunk} | "
                f"{r.get('worker_compiles', '–')} | "
                f"{'yes' if r['same_labels_as_plain'] else '**no**'}, "
                f"{r['max_amplitude_difference']:.1g}, "
                f"{'yes' if r['same_bifurcations_as_plain'] else '**no**'} |")
    s = result["scheduler"]
    lines += ["", f"Scheduler: a local cluster of {s['workers']} workers starts in "
              f"{s['start_s']:.1f} s; a task that does nothing costs {1e3 * s['per_task_s']:.1f}"
              f" ms of wall time per task (`Cluster.run`, {s['tasks']} tasks)."]
    e = result.get("estimate")
    if e:
        lines += ["", f"Estimate of a 256 x 256 atlas (256 rows of 256 points): one row "
                  f"{e['row_s']:.1f} s (the {e['from_grid'].replace('x', ' x ')} atlas's mean "
                  "row on 2 workers, times 256 / its row's points: the cost per point taken "
                  "as constant), each worker a core like these, the cache warm: "
                  f"**{_fmt(e['8_workers_s'])} on 8 workers, {_fmt(e['64_workers_s'])} on "
                  "64** (start-up + rows per worker x (row + task overhead); the local "
                  "cluster's start-up, not a batch system's queue; each worker's first row "
                  "also loads its programs from the shared cache, a few seconds, which the "
                  "mean row holds only as 1 in 32).", ""]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", default="16x8,64x64")
    ap.add_argument("--quick", action="store_true", help="the 16 x 8 atlas only; not kept")
    a = ap.parse_args()
    grids = ["16x8"] if a.quick else a.grids.split(",")
    result = {"machine": machine_info(), "grids": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for g in grids:
            nx, ny = (int(v) for v in g.split("x"))
            result["grids"][g] = run_grid(nx, ny, tmp, tmp / "cache")
    result["scheduler"] = scheduler_overhead()
    result["estimate"] = estimate(result["grids"], result["scheduler"])
    command = "python benchmarks/bench_cluster.py" + (" --quick" if a.quick else
                                                       f" --grids {a.grids}")
    write_result("cluster_quick" if a.quick else "cluster", result,
                 markdown(result, command))


if __name__ == "__main__":
    main()
