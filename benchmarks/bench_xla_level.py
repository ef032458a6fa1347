"""XLA's backend optimisation level for every program, cold and warm.

A measured question: would compiling every program at a lower LLVM optimisation level
(`XLA_FLAGS=--xla_backend_optimization_level=1` or `0`; the default is 2) shorten a cold
command enough to set it for every run? `cached_jit(fast_compile=True)` already compiles
the fit's solve and the branch kernel at level 1. Each command of `bench_cold.py` named
runs cold (empty cache) then warm, once per level, the levels one after another per
command; warm runs show what the level costs in execution.

    python benchmarks/bench_xla_level.py [--only continue,sweep,map,sensitivity]

writes benchmarks/results/xla_level.json and .md (a section of BENCHMARKS.md). Not part
of `run_all.py`: it answers one question and is run again only when that is asked anew.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_cold  # noqa: E402
from _cli import write_result  # noqa: E402

LEVELS = {"2 (default)": "", "1": "--xla_backend_optimization_level=1",
          "0": "--xla_backend_optimization_level=0"}
DEFAULT_ONLY = "continue,sweep,map,sensitivity"


def markdown(r) -> str:
    m = r["machine"]
    lines = ["## C2 XLA optimisation level", "",
             "Command: `python benchmarks/bench_xla_level.py` (one fresh process per run; "
             "per command the levels one after another, each cold then warm).",
             f"Machine: {m.get('cpu', 'CPU')}, {m.get('cores', '?')} cores; jax "
             f"{m.get('jax', '?')}. Date: {r['date']} UTC; commit {r.get('commit', '?')}.",
             "",
             "| command | level | cold wall | compile | programs | warm wall | warm run |",
             "|---|---|---|---|---|---|---|"]
    for row in r["rows"]:
        c, w = row["cold"], row["warm"]
        lines.append(f"| `{row['command']}` | {row['level']} | {c['wall_s']:.1f} s | "
                     f"{c['compile_s']:.1f} s | {c['compiles']:.0f} | {w['wall_s']:.1f} s | "
                     f"{w['run_s']:.1f} s |")
    lines += ["", "Against level 2, per command (compile seconds, warm run seconds): "
              + "; ".join(_ratios(r["rows"])) + "."]
    if r.get("verdict"):  # the conclusion, written by whoever ran it
        lines += ["", r["verdict"]]
    return "\n".join(lines) + "\n"


def _ratios(rows) -> list[str]:
    """Each command's compile and warm-run seconds at levels 1 and 0 over level 2's."""
    base = {row["command"]: row for row in rows if row["level"] == "2 (default)"}
    out = []
    for row in rows:
        b = base.get(row["command"])
        if b is None or row is b:
            continue
        name = row["command"].split()[1]
        out.append(f"`{name}` level {row['level']}: "
                   f"{row['cold']['compile_s'] / b['cold']['compile_s']:.2f}x, "
                   f"{row['warm']['run_s'] / b['warm']['run_s']:.2f}x")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=DEFAULT_ONLY, help="comma-separated bench_cold names")
    args = ap.parse_args(argv)
    from _machine import machine_info

    info = machine_info()
    names = set(args.only.split(","))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_xla_level_") as tmp:
        for name, cmd, target, writes in bench_cold.COMMANDS:
            if name not in names:
                continue
            for level, flags in LEVELS.items():
                os.environ["XLA_FLAGS"] = flags  # the child processes' environment
                folder = Path(tmp) / f"level{level.split()[0]}"
                folder.mkdir(exist_ok=True)
                print(f"{name}, level {level}", flush=True)
                res = bench_cold.measure(name, cmd, target, writes, 1, folder)
                rows.append(dict(command=res["command"], level=level, cold=res["cold"],
                                 warm=res["warm"]))
    result = dict(date=info["date_utc"][:16], machine=info, rows=rows)
    write_result("xla_level", result, markdown(result))
    print(f"wrote {bench_cold.RESULTS / 'xla_level'}.json and .md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
