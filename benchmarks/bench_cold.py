"""Time to first answer: every command of the README's table, cold and warm.

Each command runs on its documented example as a fresh process (`python -c` running the
`bsfs` entry point), first with an empty compilation cache (cold: a user's first run on a
machine), then again with the cache that run filled (warm: every later run; the cache holds
XLA's executables and, where a program uses `bsfs_jax.cached_jit`, the traced program).

Per run: wall seconds, XLA compile seconds and the number of compiled programs (jax's
`/jax/core/compile/backend_compile_duration` events, recorded by the CLI when
`BSFS_COMPILE_STATS` names a file), run seconds (wall - compile: tracing, execution, Python,
files) and peak memory. The targets on the 2-core CPU are checked per command:
cold wall time, compilation at most 40 % of the cold wall time, the warm run at most 40 %
of the cold one.

    python benchmarks/bench_cold.py [--only simulate,modes] [--repeats 1]

writes benchmarks/results/cold.json and .md (a section of BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _cli import RESULTS, cold_warm_runs, write_result  # noqa: E402
from bench_identify import PRELOAD_FIT  # noqa: E402

# (name, arguments without --out, cold target [s] or None, writes an --out folder)
COMMANDS = [
    ("simulate", ["simulate", "--frequency", "500", "--force", "5000"], 4.0, True),
    ("modes", ["modes"], 2.0, False),
    ("params", ["params"], None, False),
    ("continue", ["continue", "--start", "1000", "--stop", "1250", "--force", "100"], 12.0,
     True),
    ("sweep", ["sweep", "--param", "frequency_hz", "--start", "100", "--stop", "4000",
               "--num", "240", "--force", "5000"], 15.0, True),
    ("map", ["map", "--x", "frequency_hz", "--x-start", "400", "--x-stop", "1600",
             "--x-num", "16", "--y", "force_n", "--y-start", "1000", "--y-stop", "8000",
             "--y-num", "8"], 25.0, True),
    ("sensitivity", ["sensitivity", "--metric", "frc_peak", "--force", "100"], 15.0, True),
    ("identify", ["identify"], None, True),
    ("identify resonance", ["identify", "--data", "resonance", "--fit", PRELOAD_FIT], 30.0,
     True),
    ("predict", ["predict", "--from", "{identified}", "--force", "100"], None, True),
    ("plan-test", ["plan-test", "--fit", PRELOAD_FIT], None, True),
    ("synth", ["synth", "--preset", "default", "--frequency", "120", "--force", "100"], None,
     "file"),
    ("optimize", ["optimize", "--metric", "natural_frequency", "--vary",
                  "nut.balls,nut.contact_angle_deg"], None, True),
    ("reproduce --quick", ["reproduce", "--quick"], 60.0, True),
]
COMPILE_SHARE, WARM_SHARE = 0.40, 0.40


def _identified(tmp: Path) -> str:
    """An identification folder for `bsfs predict` (the README's example: the bundled
    preload-loss records), made once, untimed, with its own compilation cache (the
    predict runs still start from an empty one)."""
    from _cli import run_cli

    folder = tmp / "identified_preload_loss"
    if not folder.is_dir():
        run_cli(["identify", "--data", "preload-loss", "--fit", PRELOAD_FIT, "--out",
                 str(folder)], tmp / "cache_identified")
    return str(folder)


def measure(name, args, target, writes, repeats, tmp):
    shown = ["out/preload-loss" if a == "{identified}" else a for a in args]
    if "{identified}" in args:
        args = [_identified(tmp) if a == "{identified}" else a for a in args]
    out = {True: "dir", False: None, "file": ".csv"}[writes]
    res, _ = cold_warm_runs(args, repeats, tmp, name.replace(" ", "_").replace("-", ""),
                            out=out, check=False)
    cold, warm = res["cold"], res["warm"]
    share = None if cold["compile_s"] is None else cold["compile_s"] / cold["wall_s"]
    res.update(name=name, command="bsfs " + " ".join(shown), target_cold_s=target,
               compile_share=share, warm_over_cold=warm["wall_s"] / cold["wall_s"],
               met=dict(cold=None if target is None else bool(cold["wall_s"] <= target),
                        compile_share=None if share is None else bool(share <= COMPILE_SHARE),
                        warm=bool(warm["wall_s"] <= WARM_SHARE * cold["wall_s"])))
    return res


def _yes(v):
    return "–" if v is None else ("met" if v else "**not met**")


def markdown(r) -> str:
    m = r["machine"]
    lines = ["## C1 Time to first answer", "",
             f"Command: `python benchmarks/bench_cold.py` (medians of {r['repeats']} "
             "fresh process(es) per command and state).",
             f"Machine: {m.get('cpu', 'CPU')}, {m.get('cores', '?')} cores; jax "
             f"{m.get('jax', '?')}. Date: {r['date']} UTC.", "",
             "Cold: empty compilation cache; warm: the cache the cold run filled. Compile: "
             "XLA's compile seconds (jax's compile events); run = wall - compile (tracing, "
             "execution, Python, files). Targets (2-core CPU): the cold wall time where "
             f"one is set, compilation <= {COMPILE_SHARE:.0%} of the cold wall, "
             f"warm <= {WARM_SHARE:.0%} of cold.", "",
             "| command | cold wall | compile | programs | run | warm wall | warm compile | "
             "peak memory | cold target | compile share | warm / cold |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(x, nd=1):
        return "–" if x is None else f"{x:.{nd}f}"
    for c in r["commands"]:
        cold, warm, met = c["cold"], c["warm"], c["met"]
        tgt = "–" if c["target_cold_s"] is None else \
            f"<= {c['target_cold_s']:.0f} s: {_yes(met['cold'])}"
        lines.append(
            f"| `{c['command']}` | {f(cold['wall_s'])} s | {f(cold['compile_s'])} s | "
            f"{f(cold['compiles'], 0)} | {f(cold['run_s'])} s | {f(warm['wall_s'])} s | "
            f"{f(warm['compile_s'], 2)} s | {f(cold['peak_rss_mb'], 0)} MB | {tgt} | "
            f"{f(100 * c['compile_share'] if c['compile_share'] is not None else None, 0)} %"
            f": {_yes(met['compile_share'])} | {c['warm_over_cold']:.2f}: "
            f"{_yes(met['warm'])} |")
    for c in r["commands"]:
        if c.get("date") and c["date"] != r["date"]:  # measured again after the run
            reps = c.get("repeats")
            lines += ["", f"`{c['command']}` was measured on {c['date']} UTC"
                      + (f" (medians of {reps} fresh processes)" if reps else "") + "."]
    lines += ["", "Exit codes other than 0 (4: identify did not converge) are listed in "
              "`benchmarks/results/cold.json`."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="comma-separated command names (default: all)")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args(argv)
    from _machine import machine_info

    info = machine_info()
    info["load_average_at_start"] = list(os.getloadavg())
    only = None if not args.only else set(args.only.split(","))
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_cold_") as tmp:
        for name, cmd, target, writes in COMMANDS:
            if only and name not in only:
                continue
            print(name, flush=True)
            rows.append(measure(name, cmd, target, writes, args.repeats, Path(tmp)))
    result = dict(date=info["date_utc"][:16], machine=info, repeats=args.repeats,
                  commands=rows)
    name = "cold" if only is None else "cold_partial"
    write_result(name, result, markdown(result))
    print(f"wrote {RESULTS / name}.json and .md ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
