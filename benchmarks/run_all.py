"""Run every benchmark script and assemble BENCHMARKS.md from benchmarks/results/*.md.

Usage: python benchmarks/run_all.py [--quick] [--only NAME ...] [--assemble-only | --check]

BENCHMARKS.md is only ever written by `assemble()` (the header below, then each result's
Markdown in RESULT_ORDER); `--check` exits 1 with a one-line summary when the committed
BENCHMARKS.md differs from that assembly (tests/test_status.py checks the same). After a
run, `python scripts/status.py` (`make status`) puts the new numbers in README's status table.
"""

import argparse
import importlib.util
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
FILES_MODULE = Path(__file__).resolve().parent.parent / "bsfs_jax" / "_files.py"
ORDER = ["bench_cold.py", "bench_simulate.py", "bench_sweep.py", "bench_orbits.py",
         "bench_identify.py", "bench_resonance.py", "bench_fit_solver.py", "bench_design.py"]
RESULT_ORDER = ["cold.md", "ab.md", "ab_host.md", "ab_forecast.md", "ab_prefetch.md", "xla_level.md", "simulate.md", "b1_sweep.md", "gpu_b1.md", "orbits.md", "identify.md",
                "resonance.md", "fit_solver.md", "design.md"]


def assemble() -> str:
    parts = [
        "# Benchmarks",
        "",
        "Produced by `python benchmarks/run_all.py` (each script also runs alone; `--quick` for a",
        "short check). Times are medians over repeats after compilation unless stated; ratios are",
        "the peer's time over ours. Shared 2-core machines drift, so compare ratios, not seconds.",
        "",
    ]
    # `--quick` results (b1_sweep_quick.md) and `--only` runs of bench_cold.py (cold_partial.md) are checks, not results.
    found = sorted((p for p in (HERE / "results").glob("*.md")
                    if not p.stem.endswith(("_quick", "_partial"))),
                   key=lambda p: (RESULT_ORDER.index(p.name) if p.name in RESULT_ORDER else 99,
                                  p.name))
    for path in found:
        text = path.read_text().strip()
        # Each result file is one section of BENCHMARKS.md.
        lines = [("#" + ln if ln.startswith("# ") else ln) for ln in text.splitlines()]
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
