"""`bsfs reproduce`: analogues of the paper's Figs. 10-27 and REPRODUCTION.md."""

import time

from . import _common as ui


def register(sub) -> None:
    p = sub.add_parser(
        "reproduce", help="reproduce the paper's Section 3 (Figs. 13-27) and write "
        "REPRODUCTION.md",
        description="Compute analogues of Yang et al. (2022) Figs. 10-27 (thermal deformation, "
        "speed, preload, motion types at 5000 N, ball diameters, ball counts, contact angles) "
        "and write the PNG figures, REPRODUCTION.md (the claims table of physics.md section 6 "
        "with this model's numbers and a verdict per claim) and reproduction.json.")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--quick", action="store_true",
                   help="coarse grids and short horizons (about a minute): a smoke run whose "
                   "numbers are indicative only")
    p.add_argument("--preset", default="paper-tuned", metavar="NAME",
                   help="parameter preset (default: paper-tuned; 'default' for physics.md's "
                   "values)")
    p.add_argument("--thermal-frequency", type=ui.finite_float, metavar="HZ",
                   help="excitation frequency of Figs. 13-17 [Hz] (default 500)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run_reproduce)


def run_reproduce(args) -> int:
    from ..params import list_presets
    from ..reproduce import ReproduceSettings, reproduce

    if args.preset not in list_presets():
        raise ui.CLIError(f"--preset '{args.preset}' is not a bundled preset; choose one of "
                       f"{', '.join(list_presets())}")
    kw = {"preset": args.preset}
    if args.thermal_frequency is not None:
        if not args.thermal_frequency > 0:
            raise ui.CLIError(f"--thermal-frequency must be positive, got {args.thermal_frequency}")
        kw["thermal_frequency_hz"] = args.thermal_frequency
    settings = ReproduceSettings.quick_settings(**kw) if args.quick else ReproduceSettings(**kw)
    folder = ui.out_dir(args.out)
    t0 = time.perf_counter()
    rep = reproduce(folder, settings, progress=ui.progress_enabled(args),
                    log=lambda msg: print(f"[{time.perf_counter() - t0:6.1f} s] {msg}",
                                          flush=True))
    counts = {}
    for r in rep.rows:
        counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
    print(f"wrote {len(rep.figures)} figures and {rep.report_path} in "
          f"{time.perf_counter() - t0:.0f} s; verdicts: "
          + ", ".join(f"{v} {k}" for k, v in counts.items()))
    return 0
