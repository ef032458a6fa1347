"""Run each test file in its own pytest process (`make test`), two files at a time.

One process accumulating every compiled XLA program of the suite grew past 7 GB and once
crashed (a segmentation fault inside a compiled solve) on the 2-core CI machine; diffrax
runs its tests file by file for the same reason. Files run `BSFS_TEST_JOBS` at a time
(default: 2, or 1 on a one-core machine), the longest first, so that the 2-core CI machine
is kept busy (most of the suite's time is single-threaded XLA compilation). Each file's
output is printed whole when it ends. Arguments are passed on to pytest.

The run is recorded in `tests/last_run.json` (per file: the counts of pytest's summary line,
the seconds, and jax's own seconds of tracing, lowering and XLA compilation with the
executables obtained and those read from the persistent cache, and its 12 costliest
programs by name (conftest.py); the 20 costliest programs over the files; totals, date,
machine, pytest arguments); `scripts/status.py` fills the README's status table from it.
`BSFS_TEST_RECORD` names another file for the record, or turns it off when empty.
Exit status: 0 when every file passed, else 1 (the failing files are listed).
"""

import datetime
import importlib.util
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
RECORD = HERE / "last_run.json"

# Seconds per file on the 2-core machine (two at a time, 2026-11-28), to start the longest
# first.
_EXPECTED_S = {"test_notebooks.py": 294, "test_forecast.py": 178, "test_periodic.py": 172,
               "test_design.py": 153, "test_identification.py": 132, "test_verify.py": 78,
               "test_lanes.py": 70, "test_branch_points.py": 65, "test_posterior.py": 64,
               "test_sweep.py": 60, "test_branches.py": 59, "test_first_estimate.py": 57,
               "test_continuation.py": 49, "test_reproduce.py": 47, "test_simulate.py": 44,
               "test_atlas.py": 43, "test_offsets.py": 40, "test_fit_solve.py": 40,
               "test_fused.py": 30, "test_cli.py": 15, "test_physics.py": 13,
               "test_weak_nonlinearity.py": 11, "test_analysis.py": 10, "test_fuzz.py": 9,
               "test_frf.py": 8, "test_model.py": 7, "test_figures.py": 4,
               "test_programs.py": 2, "test_params.py": 2, "test_status.py": 2,
               "test_records.py": 2, "test_tdms.py": 2, "test_layers.py": 1}

_COUNT = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected)\b")
_SUMMARY = re.compile(r"^=*\s*(\d+ \w+|no tests ran)\b.* in [\d.]+s")


def parse_summary(output: str) -> dict | None:
    """Counts of pytest's last summary line ("3 passed, 1 skipped in 2.1s"), or None."""
    for line in reversed(output.splitlines()):
        if _SUMMARY.match(line.strip()):
            counts = {"passed": 0, "failed": 0, "errors": 0, "skipped": 0}
            for n, word in _COUNT.findall(line):
                counts["errors" if word.startswith("error") else word] = int(n)
            return counts
    return None


def _deselects_slow(args) -> bool:
    """Whether the pytest arguments leave out the tests marked `slow` (`-m "not slow"`)."""
    marks = [b for a, b in zip(args, args[1:], strict=False) if a == "-m"]
    marks += [a[2:] for a in args if a.startswith("-m") and len(a) > 2]
    return any("not slow" in m for m in marks)


def _run(path, extra, env):
    """(path, exit code, output, seconds, compile stats or {}): one file's pytest process;
    the stats are conftest.py's (BSFS_TEST_COMPILE_STATS): seconds of jax's tracing,
    lowering and XLA compilation (or persistent-cache reads), executables obtained, of
    them read from the persistent cache."""
    fd, stats_path = tempfile.mkstemp(prefix="bsfs-compile-", suffix=".json")
    os.close(fd)
    env = dict(env, BSFS_TEST_COMPILE_STATS=stats_path)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", str(path), *extra], env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seconds = time.perf_counter() - t0
    try:
        stats = json.loads(Path(stats_path).read_text() or "{}")
    except (OSError, ValueError):
        stats = {}
    finally:
        Path(stats_path).unlink(missing_ok=True)
    return path, proc.returncode, proc.stdout, seconds, stats


def _jax_summary(rows) -> dict:
    """The files' jax seconds summed (`jax_totals`: over processes that ran two at a time,
    so CPU seconds, not wall) and the 20 programs costliest to trace and compile over the
    files' 12 costliest each (`jax_costliest_programs`, with the files they appear in)."""
    keys = ("programs", "compile_s", "trace_s", "lower_s", "cache_hits")
    totals = {k: round(sum(r.get("jax", {}).get(k, 0) for r in rows), 1) for k in keys}
    programs = {}
    for r in rows:
        for name, p in r.get("jax", {}).get("top_programs", {}).items():
            acc = programs.setdefault(name, {"compile_s": 0.0, "trace_s": 0.0,
                                             "executables": 0, "files": 0})
            for k in ("compile_s", "trace_s", "executables"):
                acc[k] += p.get(k, 0)
            acc["files"] += 1
    costliest = sorted(programs.items(), key=lambda kv: -(kv[1]["compile_s"] + kv[1]["trace_s"]))
    return {"jax_totals": totals,
            "jax_costliest_programs": {name: {k: round(v, 1) for k, v in acc.items()}
                                       for name, acc in costliest[:20]}}


def _machine() -> dict:
    """benchmarks/_machine.py's stamp (CPU model, cores, Python, jax), less its date."""
    try:
        sys.path.insert(0, str(HERE.parent / "benchmarks"))
        from _machine import machine_info

        info = dict(machine_info())
    except Exception:  # the record must not fail the run
        info = {"cpu": platform.processor() or "unknown", "cores": os.cpu_count(),
                "python": platform.python_version()}
    finally:
        if sys.path and sys.path[0] == str(HERE.parent / "benchmarks"):
            sys.path.pop(0)
    info.pop("date_utc", None)
    return info


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def write_record(path: Path, data: dict) -> None:
    """Write the record atomically, by the project's one atomic writer
    (`bsfs_jax/_files.py`, loaded by its path: this runner does not import jax)."""
    spec = importlib.util.spec_from_file_location("_bsfs_files",
                                                  HERE.parent / "bsfs_jax/_files.py")
    files = sys.modules.setdefault(spec.name, importlib.util.module_from_spec(spec))
    spec.loader.exec_module(files)
    files.write_text_atomic(path, json.dumps(data, indent=1) + "\n")


def main(argv=None, files=None) -> int:
    """Run `files` (default: every tests/test_*.py), record the run, return the status."""
    extra = list(sys.argv[1:] if argv is None else argv)
    files = sorted(HERE.glob("test_*.py") if files is None else map(Path, files),
                   key=lambda p: (-_EXPECTED_S.get(p.name, 30), p.name))
    env = dict(os.environ)
    env.setdefault("BSFS_TEST_FAST_EXIT", "1")  # conftest.py: no interpreter teardown
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    jobs = int(os.environ.get("BSFS_TEST_JOBS", min(2, os.cpu_count() or 1)))
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    load_start = _load()
    failed, rows = [], []
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        for path, code, output, seconds, stats in pool.map(lambda p: _run(p, extra, env),
                                                           files):
            print(output, end="", flush=True)
            ok = code in (0, 5)  # 5: no tests collected (e.g. all deselected)
            print(f"== {path.name}: {'ok' if ok else 'FAILED'} ({seconds:.0f} s)", flush=True)
            if not ok:
                failed.append(path.name)
            counts = parse_summary(output)
            rows.append({"file": path.name, "status": "ok" if ok else "FAILED",
                         "exit_code": code, "seconds": round(seconds, 1),
                         **(counts or {"summary_line_found": False}),
                         **({"jax": stats} if stats else {})})
    total = time.perf_counter() - start
    record_path = os.environ.get("BSFS_TEST_RECORD", str(RECORD))
    if record_path:
        keys = ("passed", "failed", "errors", "skipped", "xfailed", "xpassed", "deselected")
        totals = {k: sum(r.get(k, 0) for r in rows) for k in keys}
        write_record(Path(record_path), {
            "date_utc": date, "seconds": round(total, 1), "jobs": jobs,
            "pytest_args": extra, "slow_tests": not _deselects_slow(extra),
            "load_average_at_start": load_start, "machine": _machine(),
            "files": len(rows), "failed_files": failed,
            "totals": {k: v for k, v in totals.items() if v or k in keys[:4]},
            # summed over the files' processes (two at a time): CPU seconds, not wall
            **_jax_summary(rows),
            "per_file": sorted(rows, key=lambda r: r["file"])})
        print(f"recorded in {record_path} (`make status` puts it in README's status table)")
    if failed:
        print(f"FAILED files ({len(failed)}): {', '.join(failed)}; total {total:.0f} s")
        return 1
    print(f"all {len(files)} test files passed; total {total:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
