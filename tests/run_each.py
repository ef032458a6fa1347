"""Run each test file in its own pytest process (`make test`), two at a time.

One process accumulating every compiled XLA program of the suite grew past 7 GB and once
crashed (a segmentation fault inside a compiled solve) on the 2-core CI machine; diffrax
runs its tests file by file for the same reason. Files run `BSFS_TEST_JOBS` at a time
(default: 2, or 1 on a one-core machine), so that the 2-core CI machine is kept busy (most
of the suite's time is single-threaded XLA compilation). Each file's output is printed
whole when it ends. Arguments are passed on to pytest.

The order: the processes share one compilation cache (conftest.py), so a unit that uses
many of another's programs waits until that one has finished (`_AFTER`) and loads them
instead of compiling them beside it; among the units that may start, the one heading the
longest chain of expected seconds starts first. The notebooks run one process each
(`_SPLIT`): each waits for the test file that compiles its programs.

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
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from pathlib import Path

HERE = Path(__file__).resolve().parent
RECORD = HERE / "last_run.json"

# Seconds per unit on the 2-core machine (two at a time, Intel Xeon, 2026-11-30), to start
# the longest chains first.
_EXPECTED_S = {"test_identification.py": 462, "test_forecast.py": 397, "test_periodic.py": 294,
               "test_design.py": 237, "test_verify.py": 196, "test_lanes.py": 149,
               "test_posterior.py": 142, "test_branches.py": 134, "test_first_estimate.py": 117,
               "test_sweep.py": 115, "test_continuation.py": 108, "test_offsets.py": 106,
               "test_fit_solve.py": 105, "test_atlas.py": 97, "test_simulate.py": 93,
               "test_reproduce.py": 85, "test_fused.py": 71, "test_branch_points.py": 67,
               "test_cli.py": 36, "test_physics.py": 33, "test_fuzz.py": 28,
               "test_weak_nonlinearity.py": 28, "test_analysis.py": 28, "test_frf.py": 19,
               "test_model.py": 18, "test_figures.py": 9, "test_records.py": 7,
               "test_status.py": 6, "test_programs.py": 5, "test_params.py": 4,
               "test_tdms.py": 4, "test_layers.py": 3, "test_monitoring.py": 125,
               "test_line_correlation.py": 200, "test_long_records.py": 100, "test_host.py": 25,
               "test_notebooks.py::test_notebook_runs[design_study]": 110,
               "test_notebooks.py::test_notebook_runs[preload_loss]": 100,
               "test_notebooks.py::test_notebook_runs[identification]": 30,
               "test_notebooks.py::test_notebook_runs[reproduction]": 12}

# Files run as one process per test (node ids under the file): each notebook runs in a
# kernel of its own, and each can then wait for the file whose programs it uses.
_SPLIT = {"test_notebooks.py": lambda: [
    f"test_notebook_runs[{nb.stem}]"
    for nb in sorted((HERE.parent / "notebooks").glob("*.ipynb"))]}

# unit -> the unit it starts after (it loads that one's programs from the shared cache):
# the notebooks repeat the jobs of the files they follow (the worn drive's identification
# and forecast; the design metrics and their gradients; the paper test's fit and plan).
_AFTER = {"test_notebooks.py::test_notebook_runs[preload_loss]": "test_forecast.py",
          "test_notebooks.py::test_notebook_runs[design_study]": "test_design.py",
          "test_notebooks.py::test_notebook_runs[identification]": "test_identification.py",
          "test_notebooks.py::test_notebook_runs[reproduction]": "test_reproduce.py"}


def units_of(files) -> list[str]:
    """The units (a file's path, or `path::node id` for the files of `_SPLIT`) to run."""
    out = []
    for f in files:
        split = _SPLIT.get(Path(f).name)
        nodes = split() if split else []
        out += [f"{f}::{n}" for n in nodes] if nodes else [str(f)]
    return out


def _name(unit: str) -> str:
    """The unit's key in `_EXPECTED_S` and `_AFTER`: the file's name, and its node id."""
    path, _, node = unit.partition("::")
    return Path(path).name + (f"::{node}" if node else "")


def order(units) -> list[str]:
    """The units by the expected seconds of the longest chain they head (a unit and what
    waits for it, `_AFTER`), longest first; ties by name."""
    names = {_name(u) for u in units}
    waiting = {}
    for u, before in _AFTER.items():
        if u in names and before in names:
            waiting.setdefault(before, []).append(u)

    def chain(name):
        return _EXPECTED_S.get(name, 30) + max((chain(w) for w in waiting.get(name, [])),
                                               default=0)

    return sorted(units, key=lambda u: (-chain(_name(u)), _name(u)))


def run_ordered(units, jobs: int, run):
    """Yield `run(unit)` for every unit as each ends, `jobs` at a time: a unit starts once
    the unit it follows (`_AFTER`, where that one is run too) has ended, in `order`."""
    pending = order(units)
    names = {_name(u) for u in pending}
    done: set[str] = set()
    running = {}
    jobs = max(1, jobs)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        while pending or running:
            for u in list(pending):
                if len(running) >= jobs:
                    break
                before = _AFTER.get(_name(u))
                if before is None or before not in names or before in done:
                    pending.remove(u)
                    running[pool.submit(run, u)] = u
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in finished:
                done.add(_name(running.pop(fut)))
                yield fut.result()


def merge_rows(rows) -> list[dict]:
    """One row per file: a split file's units summed (counts, seconds, jax's seconds and
    executables), its units' own names and seconds under "units"."""
    merged: dict[str, dict] = {}
    for r in rows:
        file, _, node = r["file"].partition("::")
        if not node:
            merged[file] = r
            continue
        m = merged.setdefault(file, {"file": file, "status": "ok", "exit_code": 0,
                                     "seconds": 0.0, "units": []})
        m["units"].append({"node": node, "seconds": r["seconds"], "status": r["status"]})
        m["seconds"] = round(m["seconds"] + r["seconds"], 1)
        if r["status"] != "ok":
            m["status"], m["exit_code"] = r["status"], r["exit_code"]
        for k in _COUNTS:
            if k in r:
                m[k] = m.get(k, 0) + r[k]
        if r.get("summary_line_found") is False:
            m["summary_line_found"] = False
        if r.get("jax"):
            jm = m.setdefault("jax", {})
            for k, v in r["jax"].items():
                if isinstance(v, int | float):
                    jm[k] = round(jm.get(k, 0) + v, 2)
    return sorted(merged.values(), key=lambda r: r["file"])


# The counts of pytest's summary line that the record keeps.
_COUNTS = ("passed", "failed", "errors", "skipped", "xfailed", "xpassed", "deselected")
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
    files = sorted(HERE.glob("test_*.py") if files is None else map(Path, files))
    env = dict(os.environ)
    env.setdefault("BSFS_TEST_FAST_EXIT", "1")  # conftest.py: no interpreter teardown
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    jobs = int(os.environ.get("BSFS_TEST_JOBS", min(2, os.cpu_count() or 1)))
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    load_start = _load()
    failed, rows = [], []
    start = time.perf_counter()
    units = units_of(files)
    for unit, code, output, seconds, stats in run_ordered(units, jobs,
                                                          lambda u: _run(u, extra, env)):
        print(output, end="", flush=True)
        ok = code in (0, 5)  # 5: no tests collected (e.g. all deselected)
        print(f"== {_name(unit)}: {'ok' if ok else 'FAILED'} ({seconds:.0f} s)", flush=True)
        if not ok:
            failed.append(_name(unit))
        counts = parse_summary(output)
        rows.append({"file": _name(unit), "status": "ok" if ok else "FAILED",
                     "exit_code": code, "seconds": round(seconds, 1),
                     **(counts or {"summary_line_found": False}),
                     **({"jax": stats} if stats else {})})
    total = time.perf_counter() - start
    record_path = os.environ.get("BSFS_TEST_RECORD", str(RECORD))
    if record_path:
        totals = {k: sum(r.get(k, 0) for r in rows) for k in _COUNTS}
        write_record(Path(record_path), {
            "date_utc": date, "seconds": round(total, 1), "jobs": jobs,
            "pytest_args": extra, "slow_tests": not _deselects_slow(extra),
            "load_average_at_start": load_start, "machine": _machine(),
            "files": len(files), "processes": len(units), "failed_files": failed,
            "totals": {k: v for k, v in totals.items() if v or k in _COUNTS[:4]},
            # summed over the files' processes (two at a time): CPU seconds, not wall
            **_jax_summary(rows),
            "per_file": merge_rows(rows)})
        print(f"recorded in {record_path} (`make status` puts it in README's status table)")
    if failed:
        print(f"FAILED files ({len(failed)}): {', '.join(failed)}; total {total:.0f} s")
        return 1
    print(f"all {len(files)} test files passed ({len(units)} processes); total {total:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
