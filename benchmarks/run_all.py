"""Run every benchmark script and assemble BENCHMARKS.md from benchmarks/results/*.md.

Usage: python benchmarks/run_all.py [--quick] [--only NAME ...] [--assemble-only | --check]

Each benchmark script writes its current measurement to benchmarks/results/<name>.json
(the data) and <name>.md (one section: its command, machine, date and table); a new run
replaces both. BENCHMARKS.md is only ever written by `assemble()`: a header, a contents
list, then each result's section in RESULT_ORDER. `--check` exits 1 with a one-line
summary when the committed BENCHMARKS.md differs from that assembly (tests/test_status.py
checks the same). After a run, `python scripts/status.py` (`make status`) puts the new
figures in README's status table.
"""

import argparse
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
FILES_MODULE = Path(__file__).resolve().parent.parent / "bsfs_jax" / "_files.py"
ORDER = ["bench_cold.py", "bench_simulate.py", "bench_sweep.py", "bench_orbits.py",
         "bench_identify.py", "bench_resonance.py", "bench_fit_solver.py", "bench_design.py",
         "bench_long.py", "bench_cluster.py", "bench_cluster_jobs.py"]
RESULT_ORDER = ["cold.md", "xla_level.md", "simulate.md", "b1_sweep.md", "gpu_b1.md",
                "orbits.md", "identify.md", "resonance.md", "fit_solver.md", "design.md",
                "long_records.md", "cluster.md", "cluster_jobs.md"]


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation other than
    hyphens dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _results() -> list[Path]:
    """The result files that make up BENCHMARKS.md: `--quick` checks (`*_quick.md`) and
    partial runs (`*_partial.md`) are not results."""
    return sorted((p for p in (HERE / "results").glob("*.md")
                   if not p.stem.endswith(("_quick", "_partial"))),
                  key=lambda p: (RESULT_ORDER.index(p.name) if p.name in RESULT_ORDER else 99,
                                 p.name))


def assemble() -> str:
    sections = []
    for path in _results():
        text = path.read_text().strip()
        # Each result file is one section of BENCHMARKS.md, its title a level-2 heading.
        lines = [("#" + ln if ln.startswith("# ") else ln) for ln in text.splitlines()]
        sections.append(lines)
    titles = [next((ln[3:] for ln in lines if ln.startswith("## ")), None)
              for lines in sections]
    parts = [
        "# Benchmarks",
        "",
        "The current measurement of each benchmark: its command, machine and date, then its",
        "table. A new run replaces its section (`python benchmarks/run_all.py`, or one script",
        "alone; `--quick` for a short check that is not kept). Times are medians after",
        "compilation unless a table says otherwise; ratios are the peer's time over ours.",
        "Two-core machines of different makes, and one machine from hour to hour, differ by",
        "tens of per cent: compare within a table. To compare a change with the code before",
        "it, run both in alternation: `python benchmarks/bench_ab.py --base COMMIT`.",
        "",
    ]
    parts += [f"- [{t}](#{slug(t)})" for t in titles if t] + [""]
    for lines in sections:
        parts += ["\n".join(lines), ""]
    return "\n".join(parts)


def diff_summary(old: str, new: str) -> str:
    """One line: how many lines differ and where the first difference is."""
    a, b = old.splitlines(), new.splitlines()
    n = sum(1 for x, y in zip(a, b, strict=False) if x != y) + abs(len(a) - len(b))
    first = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y),
                 min(len(a), len(b)))
    return f"{n} line(s) differ, the first at line {first + 1}"


def write_atomic(path: Path, text: str) -> None:
    """The project's one atomic writer (`bsfs_jax/_files.py`), loaded by its path: this
    script runs without jax, which `import bsfs_jax` would import."""
    spec = importlib.util.spec_from_file_location("_bsfs_files", FILES_MODULE)
    files = sys.modules.setdefault(spec.name, importlib.util.module_from_spec(spec))
    spec.loader.exec_module(files)
    files.write_text_atomic(path, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--assemble-only", action="store_true",
                    help="run nothing; write BENCHMARKS.md from benchmarks/results/*.md")
    ap.add_argument("--check", action="store_true",
                    help="run nothing; exit 1 if BENCHMARKS.md differs from the assembly")
    args = ap.parse_args(argv)
    target = HERE.parent / "BENCHMARKS.md"
    if args.check:
        text = assemble() + "\n"
        old = target.read_text() if target.exists() else ""
        if old == text:
            print("BENCHMARKS.md is up to date with benchmarks/results/*.md")
            return 0
        print(f"BENCHMARKS.md differs from the assembly of benchmarks/results/*.md: "
              f"{diff_summary(old, text)}; run `python benchmarks/run_all.py --assemble-only`")
        return 1
    if not args.assemble_only:
        for name in ORDER:
            script = HERE / name
            if not script.exists() or (args.only and script.stem not in args.only
                                       and name not in args.only):
                continue
            print(f"== {name}", flush=True)
            cmd = [sys.executable, str(script)] + (["--quick"] if args.quick else [])
            subprocess.run(cmd, check=True)
    write_atomic(target, assemble() + "\n")
    print(f"wrote {target}")
    if not args.assemble_only:
        print("README's status table: run `python scripts/status.py` (make status)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
