"""Search for the paper's route to chaos with verified labels (docs/ROUTE_TO_CHAOS.md).

Runs three two-parameter atlases with `bsfs map` (default preset, thermal deformation as
in the preset, excitation on the nut), each row a verified cold frequency sweep of
100-4000 Hz, and beside every row the same grid analysed the way the paper did: a fixed
transient of 200 forcing periods, labels read from the samples (`SweepResult.motions`).

1. frequency x force, 1-20 kN (the joints unload at 2^1.5 x 1500 N = 4.2 kN), with the
   branch of each row continued over 700-1700 Hz (the resonance) for the bifurcation
   curves;
2. frequency x damping scale 0.2-1.0 (all three dampers; physics.md's defaults = 1);
3. frequency x nut preload 500-3000 N (paper: 1000/1500/2000 N), 5000 N.

Writes out/route/<name>/ (atlas.nc, summary.json, motion.png, amplitude.png,
fixed_transient.json), copies the figures to docs/img/route_<name>_*.png and writes
docs/ROUTE_TO_CHAOS.md. Resumable: a rerun loads finished rows.

Usage: python scripts/route_to_chaos.py [--num 60] [--no-bifurcations]
"""

import argparse
import json
import shutil
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# the three dampers `bsfs map --y damping_scale` scales
DAMPERS = ("damping.bearing_n_s_per_m", "damping.screw_n_s_per_m", "damping.nut_n_s_per_m")
MAPS = {
    "force": (["--y", "force_n", "--y-start", "1000", "--y-stop", "20000", "--y-num", "6",
               "--band", "700", "1700", "--max-points", "400", "--ds", "0.1"],
              "force amplitude [N]"),
    "damping": (["--y", "damping_scale", "--y-start", "0.2", "--y-stop", "1.0", "--y-num", "5",
                 "--force", "5000", "--no-bifurcations"], "damping scale (x physics.md defaults)"),
    "preload": (["--y", "nut.preload_n", "--y-start", "500", "--y-stop", "3000", "--y-num", "4",
                 "--force", "5000", "--no-bifurcations"], "nut preload [N]"),
}


def fixed_transient_labels(name, summary, num):
    """The paper's kind of analysis on the same grid: 200 periods, labels from samples."""
    from bsfs_jax.analysis import SweepConfig, bsfs_problem, sweep
    from bsfs_jax.params import preset

    base = preset("default")
    x = np.linspace(100.0, 4000.0, num)
    cfg = SweepConfig(transient_periods=200, periods=64, samples_per_period=16, lyapunov=True,
                      batch_size=8, chunk_size=num)
    yname = summary["y_name"]
    rows = {}
    for y in sorted({p[yname] for p in summary["points"]}):
        params, force = base, 5000.0
        if name == "force":
            force = y
        elif name == "damping":
            for k in DAMPERS:
                params = params.replace(k, float(base.get(k)) * y)
        else:
            params = base.replace(yname, y)
        res = sweep(bsfs_problem(params, "frequency_hz", force_n=force), x, config=cfg,
                    progress=False)
        rows[y] = [m.label for m in res.motions()[0]]
    return x, rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num", type=int, default=60, help="frequencies per row")
    ap.add_argument("--no-bifurcations", action="store_true")
    ap.add_argument("--only", choices=sorted(MAPS), action="append")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "route",
                    help="the atlases' folder (default out/route)")
    ap.add_argument("--docs", type=Path, default=ROOT / "docs",
                    help="where the report and its figures go (default docs/)")
    args = ap.parse_args()
    from bsfs_jax.cli import main as bsfs

    out, docs = args.out, args.docs
    (docs / "img").mkdir(parents=True, exist_ok=True)
    for name, (extra, _) in MAPS.items():
        if args.only and name not in args.only:
            continue
        t0 = time.time()
        argv = ["map", "--x", "frequency_hz", "--x-start", "100", "--x-stop", "4000",
                "--x-num", str(args.num), "--periods", "16", *extra, "--no-progress",
                "--out", str(out / name)]
        if args.no_bifurcations:
            argv.append("--no-bifurcations")
        print(f"route: {name}: bsfs {' '.join(argv)}", flush=True)
        bsfs(argv)
        summary = json.loads((out / name / "summary.json").read_text())
        ft = out / name / "fixed_transient.json"
        if not ft.exists():
            x, rows = fixed_transient_labels(name, summary, args.num)
            ft.write_text(json.dumps({"x": x.tolist(),
                                      "rows": {str(k): v for k, v in rows.items()}}))
        for kind in ("motion", "amplitude"):
            shutil.copy(out / name / f"{kind}.png",
                        docs / "img" / f"route_{name}_{kind}.png")
        print(f"route: {name} done in {time.time() - t0:.0f} s", flush=True)
    write_report(out, docs)


def write_report(out, docs=ROOT / "docs"):
    lines = ["# The paper's route to chaos, searched with verified labels", "",
             "Generated by `python scripts/route_to_chaos.py` from three `bsfs map` atlases "
             "(default preset; each row a verified cold frequency sweep of 100-4000 Hz). A "
             "label counts only with its evidence (`bsfs_jax/analysis/_verify.py`): a stable "
             "orbit found by Newton from the sampled state whose samples follow its "
             "linearisation (period-n), or a Lyapunov exponent with a 95 % interval from "
             "independent segments plus the torus or broadband tests; everything else is "
             "*unresolved*. Beside each atlas: what a fixed transient of 200 forcing periods "
             "with labels read from the samples (the paper's kind of analysis) says on the "
             "same grid.", ""]
    for name, (_, ylabel) in MAPS.items():
        folder = out / name
        if not (folder / "summary.json").exists():
            continue
        s = json.loads((folder / "summary.json").read_text())
        pts = s["points"]
        yname = s["y_name"]
        for p in pts:
            p["y"] = p[yname]
        counts = Counter(p["motion"] if p["verified"] else "unresolved" for p in pts)
        lines += [f"## Frequency x {ylabel}", "",
                  f"![motion](img/route_{name}_motion.png)", "",
                  f"Verified labels over {len(pts)} points: " +
                  ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + ".", ""]
        unres = [p for p in pts if not p["verified"]]
        if unres:
            lines.append("Unresolved points (reason):")
            lines.append("")
            for p in unres[:12]:
                lines.append(f"- {p['frequency_hz']:.0f} Hz, y = {p['y']:g}: {p['reason']}")
            lines.append("")
        non1 = [p for p in pts if p["verified"] and p["motion"] != "period-1"]
        if non1:
            lines.append("Verified motions other than period-1:")
            lines.append("")
            for p in non1:
                ev = p["evidence"]
                lines.append(f"- {p['frequency_hz']:.0f} Hz, y = {p['y']:g}: {p['motion']} "
                             f"({p['reason']}; lambda T {ev.get('lyapunov_per_period')})")
            lines.append("")
        ft = folder / "fixed_transient.json"
        if ft.exists():
            f = json.loads(ft.read_text())
            lookup = {(round(p["y"], 9), round(p["frequency_hz"], 6)): p for p in pts}
            fake, total = Counter(), 0
            for y, labels in f["rows"].items():
                for xv, lab in zip(f["x"], labels, strict=True):
                    p = lookup.get((round(float(y), 9), round(xv, 6)))
                    if p is None or lab == "period-1":
                        continue
                    total += 1
                    if p["verified"] and p["motion"] == "period-1":
                        fake[lab] += 1
            lines += [f"Fixed 200-period transient on the same grid: {total} points labelled "
                      "other than a converged period-1 (the classifier's unconverged "
                      "'settling' labels included); of those, the verifier shows period-1 at "
                      f"{sum(fake.values())} ({', '.join(f'{k} {v}' for k, v in fake.items())})."
                      " The first mode decays at about 81 1/s (less with less damping), so "
                      "200 periods at 2-4 kHz last 50-100 ms and leave its free vibration in "
                      "the samples, seen stroboscopically as a torus or period-n.", ""]
        curves = s.get("bifurcation_curves", [])
        if curves:
            lines += ["Bifurcation curves from the orbit engine's shooting continuation of "
                      "each row's branch (700-1700 Hz): no period doubling or Neimark-Sacker "
                      "point on any row; " if not any(c["kind"] != "fold" for c in curves)
                      else "Bifurcation curves: "]
            for c in curves:
                pts = ", ".join(f"{x:.0f} Hz at {y:g}" for x, y in zip(c["x"], c["y"],
                                                                      strict=True))
                lines[-1] += f"{c['kind']} curve through {pts}; "
            lines[-1] = lines[-1].rstrip("; ") + ". The two folds bound the hysteresis band "
            lines[-1] += "of the hardening resonance, which widens and rises with the force."
            lines.append("")
        for note in s.get("notes", []):
            lines += [f"Note: {note}", ""]
    lines += _conclusion(out)
    (docs / "ROUTE_TO_CHAOS.md").write_text("\n".join(lines) + "\n")


def _conclusion(out):
    """The answer, computed from the atlases (not typed by hand)."""
    total, other, unresolved = 0, [], 0
    fake = 0
    for name in MAPS:
        f = out / name / "summary.json"
        if not f.exists():
            continue
        pts = json.loads(f.read_text())["points"]
        total += len(pts)
        other += [p for p in pts if p["verified"] and p["motion"] != "period-1"]
        unresolved += sum(not p["verified"] for p in pts)
        ft = out / name / "fixed_transient.json"
        if ft.exists():
            rows = json.loads(ft.read_text())["rows"]
            fake += sum(lab != "period-1" for labels in rows.values() for lab in labels)
    lines = ["## Answer", ""]
    if not other:
        lines.append(
            f"Over {total} verified points ({unresolved} unresolved) no period-n (n > 1), "
            "quasi-periodic or chaotic motion exists in these ranges with this model: every "
            "verified point is a stable period-1 orbit. The same grids read the paper's way "
            f"(200 forcing periods, labels from the samples) give {fake} labels other than "
            "period-1. The paper's period-7, quasi-periodic and chaotic motions (Figs. 19-21, "
            "24-25) are therefore what a fixed-length run reads from the first mode's slowly "
            "decaying free vibration, or they need parameters that the paper does not give "
            "(no preset is added: there is no verified region to document). With the "
            "`paper-tuned` preset the reproduction's verified sweeps (docs/REPRODUCTION.md, "
            "Figs. 24-25) find the same: every point period-1.")
    else:
        lines.append(f"Verified motions other than period-1 at {len(other)} of {total} points "
                     f"({unresolved} unresolved); see the lists above.")
    return lines + [""]


if __name__ == "__main__":
    main()
