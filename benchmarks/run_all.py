"""Run every benchmark script and assemble BENCHMARKS.md from benchmarks/results/*.md.

Usage: python benchmarks/run_all.py [--quick] [--only NAME ...] [--assemble-only]
"""

import argparse
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
ORDER = ["bench_simulate.py", "bench_sweep.py", "bench_orbits.py", "bench_identify.py",
         "bench_design.py"]
RESULT_ORDER = ["simulate.md", "b1_sweep.md", "orbits.md", "identify.md", "design.md"]


def assemble() -> str:
    parts = [
        "# Benchmarks",
        "",
        "Produced by `python benchmarks/run_all.py` (each script also runs alone; `--quick` for a",
        "short check). Times are medians over repeats after compilation unless stated; ratios are",
        "the peer's time over ours. Shared 2-core machines drift, so compare ratios, not seconds.",
        "",
    ]
    found = sorted((HERE / "results").glob("*.md"),
                   key=lambda p: (RESULT_ORDER.index(p.name) if p.name in RESULT_ORDER else 99,
                                  p.name))
    for path in found:
        text = path.read_text().strip()
        # Each result file is one section of BENCHMARKS.md.
        lines = [("#" + ln if ln.startswith("# ") else ln) for ln in text.splitlines()]
        parts += ["\n".join(lines), ""]
    return "\n".join(parts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--assemble-only", action="store_true")
    args = ap.parse_args()
    if not args.assemble_only:
        for name in ORDER:
            script = HERE / name
            if not script.exists() or (args.only and script.stem not in args.only
                                       and name not in args.only):
                continue
            print(f"== {name}", flush=True)
            cmd = [sys.executable, str(script)] + (["--quick"] if args.quick else [])
            subprocess.run(cmd, check=True)
    text = assemble()
    (HERE.parent / "BENCHMARKS.md").write_text(text + "\n")
    print(f"wrote {HERE.parent / 'BENCHMARKS.md'}")


if __name__ == "__main__":
    main()
