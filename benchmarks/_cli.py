"""Timing `bsfs` commands as a user meets them: fresh processes, cold and warm caches.

Shared by bench_identify.py, bench_resonance.py and bench_cold.py.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
CLI = "from bsfs_jax.cli import run; run()"  # what the `bsfs` command runs
STAT_KEYS = ("wall_s", "compile_s", "run_s", "compiles", "peak_rss_mb")


def env(cache=None, root: Path = ROOT) -> dict:
    """The environment of a child process: one BLAS thread (as the CLI sets), the source
    tree `root` (default this one) on the path, and the compilation cache `cache` (None:
    the parent's)."""
    out = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        out.setdefault(var, "1")  # as the CLI does (bsfs_jax/cli/_common.py)
    out["PYTHONPATH"] = os.pathsep.join([str(root), out.get("PYTHONPATH", "")]).rstrip(
        os.pathsep)
    if cache is not None:
        out["BSFS_CACHE_DIR"] = str(cache)
    return out


def run_cli(args, cache, *, check: bool = True, root: Path = ROOT):
    """`bsfs ARGS` in a fresh process with the compilation cache `cache`: (exit, seconds,
    compile stats: compiles, compile_s, peak_rss_mb from jax's compile events; None where
    the process wrote none). `check`: stop the benchmark unless the exit is 0 or 4 (4:
    identify ran but did not converge); otherwise print the failure and go on. `root`: the
    source tree that runs (default this one; `bench_ab.py` runs another commit's)."""
    cmd = [sys.executable, "-c", CLI, *args]
    if args[0] == "identify":
        cmd.append("--no-progress")
    child = env(cache, root)
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as fh:
        child["BSFS_COMPILE_STATS"] = fh.name
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=child, cwd=root)
    wall = time.perf_counter() - t0
    stats_file = Path(child["BSFS_COMPILE_STATS"])
    try:
        stats = json.loads(stats_file.read_text())
    except (OSError, ValueError):
        stats = {"compiles": None, "compile_s": None, "peak_rss_mb": None}
    finally:
        stats_file.unlink(missing_ok=True)
    if proc.returncode not in (0, 4):
        message = (f"bsfs {' '.join(args)} failed (exit {proc.returncode}):\n"
                   f"{(proc.stderr or proc.stdout)[-3000:]}")
        if check:
            raise SystemExit(message)
        print("  " + message, flush=True)
    return proc.returncode, wall, stats


def _median(xs):
    xs = [x for x in xs if x is not None]
    return float(statistics.median(xs)) if xs else None


def cold_warm_runs(args, repeats, tmp, tag, *, out: str | None = "dir",
                   check: bool = True, root: Path = ROOT):
    """Each repeat: `bsfs ARGS` with an empty compilation cache (cold), then again with the
    cache that run filled (warm). `out`: what `--out` names ("dir": a folder, ".csv" or
    another suffix: a file, None: no --out). Medians of wall, compile and run (= wall -
    compile) seconds, the compilations and peak memory, each kind's wall times and last
    exit code; and the last cold run's output path. `root`: the source tree that runs."""
    rows = []
    for k in range(repeats):
        cache = tmp / f"cache_{tag}{k}"
        row = {}
        for kind in ("cold", "warm"):
            path = None if out is None else tmp / (f"{tag}{k}_{kind}"
                                                   + ("" if out == "dir" else out))
            code, wall, st = run_cli([*args] + ([] if path is None else ["--out", str(path)]),
                                     cache, check=check, root=root)
            comp = st["compile_s"]
            row[kind] = dict(wall_s=wall, compile_s=comp,
                             run_s=None if comp is None else wall - comp,
                             compiles=st["compiles"], peak_rss_mb=st["peak_rss_mb"],
                             exit_code=code)
            shown = "?" if comp is None else f"{comp:.1f}"
            print(f"  bsfs {' '.join(args)} ({kind}): {wall:.1f} s, compile {shown} s in "
                  f"{st['compiles']} programs (exit {code})", flush=True)
        rows.append(row)
    med = {kind: {key: _median([r[kind][key] for r in rows]) for key in STAT_KEYS}
           for kind in ("cold", "warm")}
    for kind in ("cold", "warm"):
        med[kind]["wall_s_runs"] = [r[kind]["wall_s"] for r in rows]
        med[kind]["exit_code"] = rows[-1][kind]["exit_code"]
    last = None if out is None else tmp / (f"{tag}{repeats - 1}_cold"
                                           + ("" if out == "dir" else out))
    return med, last


def write_result(stem: str, result: dict, md: str) -> None:
    """benchmarks/results/<stem>.json and .md (a section of BENCHMARKS.md)."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{stem}.json").write_text(json.dumps(result, indent=2) + "\n")
    (RESULTS / f"{stem}.md").write_text(md)
    print(md)
