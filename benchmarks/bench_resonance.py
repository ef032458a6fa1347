"""Through-resonance identification: time to answer, cold and warm.

`bsfs identify --data resonance` (the bundled through-resonance test: 100 N stepped sines
150-2000 Hz with two within 8 % of the first resonance, two 3000 N sines, a 5 N chirp; 11
records) with each of the two fit sets:

- `preload`: both preloads and the three dampers (`--fit PRELOAD_FIT`);
- `default`: the CLI's default set (Hertz coefficients, screw stiffness, dampers, thermal
  expansion: `identification.DEFAULT_FIT`).

Each repeat runs the command in a fresh process with an empty compilation cache (cold: what a
first run on a machine sees), then again with the cache that run filled (warm: every later
run). Wall seconds, XLA compile seconds and the number of compiled programs (jax's compile
events), peak memory; convergence and the records' branches from report.json. The targets:
at most 30 s cold and 8 s warm on the 2-core machine.

    python benchmarks/bench_resonance.py [--repeats 2]

writes benchmarks/results/resonance.json and .md (a section of BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

from _cli import RESULTS, cold_warm_runs, write_result  # noqa: E402
from bench_identify import PRELOAD_FIT  # noqa: E402

TARGET_COLD_S, TARGET_WARM_S = 30.0, 8.0


def fit_sets():
    import identification as idn

    return {"preload": PRELOAD_FIT, "default": ",".join(idn.DEFAULT_FIT)}


def run_set(name, fit, repeats, tmp):
    args = ["identify", "--data", "resonance", "--fit", fit]
    med, out = cold_warm_runs(args, repeats, tmp, name)
    report = json.loads((out / "report.json").read_text())
    fit_info = report["fit"]
    branches = {r["name"]: r["branch"] for r in report["records"] if "branch" in r}
    return dict(command="bsfs " + " ".join(args), fit_set=name, cold=med["cold"],
                warm=med["warm"], converged=bool(fit_info["converged"]),
                exit_code=med["cold"]["exit_code"], branches=branches,
                targets=dict(cold_s=TARGET_COLD_S, warm_s=TARGET_WARM_S,
                             cold_met=bool(med["cold"]["wall_s"] <= TARGET_COLD_S),
                             warm_met=bool(med["warm"]["wall_s"] <= TARGET_WARM_S)))


def markdown(r) -> str:
    m = r["machine"]
    lines = ["## I2 Identification through the resonance", "",
             f"Command: `python benchmarks/bench_resonance.py --repeats {r['repeats']}` "
             f"(medians of {r['repeats']} fresh processes).",
             f"Machine: {m.get('cpu', 'CPU')}, {m.get('cores', '?')} cores; jax "
             f"{m.get('jax', '?')}. Date: {r['date']} UTC.", "",
             "`bsfs identify --data resonance` (11 records through the first resonance, four "
             "of them on the periodic-orbit model) with the preload fit set (`--fit "
             "nut_preload,bearing_preload,c_b,c_s,c_n`) and with the default fit set. Cold: "
             "empty compilation cache; warm: the cache the cold run filled (compiled "
             "programs and the traced programs `cached_jit` keeps). Compile adds the seconds "
             "of both threads (the check at the estimate is compiled in the background "
             "during the fit), so it can exceed the critical path. Targets: at most "
             f"{TARGET_COLD_S:.0f} s cold and {TARGET_WARM_S:.0f} s warm.", "",
             "| fit set | cold wall | compile | programs | warm wall | compile | programs | "
             "peak memory | converged | targets (cold / warm) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in r["sets"]:
        c, w, t = s["cold"], s["warm"], s["targets"]
        lines.append(
            f"| {s['fit_set']} | {c['wall_s']:.1f} s | {c['compile_s']:.1f} s | "
            f"{c['compiles']:.0f} | {w['wall_s']:.1f} s | {w['compile_s']:.2f} s | "
            f"{w['compiles']:.0f} | {c['peak_rss_mb']:.0f} MB | {s['converged']} | "
            f"{'met' if t['cold_met'] else '**not met**'} / "
            f"{'met' if t['warm_met'] else '**not met**'} |")
    return "\n".join(lines) + "\n"

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--set", action="append", choices=["preload", "default"])
    args = ap.parse_args(argv)
    from _machine import machine_info

    info = machine_info()
    info["load_average_at_start"] = list(os.getloadavg())
    t0 = time.perf_counter()
    sets = fit_sets()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_resonance_") as tmp:
        for name in args.set or list(sets):
            print(f"fit set {name}", flush=True)
            rows.append(run_set(name, sets[name], args.repeats, Path(tmp)))
    result = dict(date=info["date_utc"][:16].replace("T", " "), machine=info,
                  repeats=args.repeats, sets=rows)
    write_result("resonance", result, markdown(result))
    print(f"wrote {RESULTS / 'resonance'}.json and .md ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
