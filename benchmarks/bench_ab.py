"""A change against the code before it: commands of `bench_cold.py`, cold and warm, each
tree in turn.

A shared 2-core machine's speed drifts by 10-20 % within hours, so a C1 run (bench_cold.py)
cannot tell a change's few seconds from the hour it ran in. This script runs the same
commands from two source trees, alternating them round by round (base first in odd rounds,
head first in even ones), each run a fresh process with a fresh compilation cache (cold)
and then with the cache that run filled (warm), and reports both trees' times side by
side with their medians and the ratio head / base.

    python benchmarks/bench_ab.py --base COMMIT [--only map,continue] [--rounds 2]

The base tree is checked out into a temporary git worktree (removed afterwards). Prints the
table and writes out/bench_ab/ab.json and ab.md: a comparison describes a change, so it is
not kept among the benchmarks' current results (BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _cli import ROOT, cold_warm_runs  # noqa: E402
from bench_cold import COMMANDS, _identified  # noqa: E402


def _git(*args) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout.strip()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="commit to compare against")
    ap.add_argument("--only", default="map", help="comma-separated bench_cold.py names "
                    "(commands with an --out folder; predict reads an identification made "
                    "once, untimed, by the head tree; default map)")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    table = {name: cmd for name, cmd, _, out in COMMANDS if out is True}
    names = [n.strip() for n in args.only.split(",")]
    unknown = [n for n in names if n not in table]
    if unknown:
        raise SystemExit(f"bench_ab.py: unknown or unsupported command(s) {unknown}; "
                         f"choose from {sorted(table)}")
    base, head = _git("rev-parse", "--short", args.base), _git("rev-parse", "--short",
                                                                  "HEAD")
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no"))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bsfs-ab-") as td:
        tmp = Path(td)
        tree = tmp / "base"
        shown = {n: list(table[n]) for n in names}
        for n in names:  # the prepared input (`bench_cold._identified`), made once
            if "{identified}" in table[n]:
                table[n] = [_identified(tmp) if a == "{identified}" else a
                            for a in table[n]]
                shown[n] = ["out/preload-loss" if a == "{identified}" else a
                            for a in shown[n]]
        _git("worktree", "add", "--detach", str(tree), base)
        try:
            for name in names:
                times = {"base": [], "head": []}
                for k in range(args.rounds):
                    order = ("base", "head") if k % 2 == 0 else ("head", "base")
                    for which in order:
                        root = tree if which == "base" else ROOT
                        print(f"{name} round {k + 1} {which}", flush=True)
                        med, _ = cold_warm_runs(table[name], 1, tmp, f"{name}_{which}{k}",
                                                root=root)
                        times[which].append([med[kind][key] for kind in ("cold", "warm")
                                             for key in ("wall_s", "compiles")])
                med = {w: [statistics.median(t[i] for t in times[w]) for i in (0, 2)]
                       for w in times}
                rows.append(dict(name=name, command="bsfs " + " ".join(shown[name]),
                                 base=times["base"], head=times["head"], median=med))
        finally:
            _git("worktree", "remove", "--force", str(tree))
    date = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    result = dict(date=date, base=base, head=head + ("+" if dirty else ""),
                  rounds=args.rounds, commands=rows)
    md = ["## A change against the code before it, run alternately", "",
          f"Machine: 2-core CPU; {date} UTC. `python benchmarks/bench_ab.py --base {base} "
          f"--only {args.only} --rounds {args.rounds}`: base {base}, head {result['head']}; "
          "each run a fresh process, cold (empty cache) then warm (the cache it filled); "
          "the trees alternate round by round. Seconds of every run, medians, head / base, "
          "and each run's compiled programs (jax's compile events).", "",
          "| command | base cold [s] | head cold [s] | head / base | base warm [s] | "
          "head warm [s] | head / base | programs cold / warm, base | head |",
          "|---|---|---|---|---|---|---|---|---|"]

    def runs(ts, i):
        return ", ".join(f"{t[i]:.1f}" for t in ts)

    def programs(ts):
        return "; ".join(f"{t[1]:.0f} / {t[3]:.0f}" for t in ts)

    for r in rows:
        b, h = r["median"]["base"], r["median"]["head"]
        md.append(
            f"| `{r['command']}` | {runs(r['base'], 0)} (median {b[0]:.1f}) | "
            f"{runs(r['head'], 0)} (median {h[0]:.1f}) | {h[0] / b[0]:.2f} | "
            f"{runs(r['base'], 2)} (median {b[1]:.1f}) | {runs(r['head'], 2)} "
            f"(median {h[1]:.1f}) | {h[1] / b[1]:.2f} | {programs(r['base'])} | "
            f"{programs(r['head'])} |")
    out = ROOT / "out" / "bench_ab"
    out.mkdir(parents=True, exist_ok=True)
    (out / "ab.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "ab.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    print(f"wrote {out}/ab.json and ab.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
