"""`bsfs synth`: write a synthetic exciter record from a parameter set."""

from pathlib import Path

from ._common import CLIError, add_params_args, finite_float, load_params_from_args


def register(sub) -> None:
    s = sub.add_parser("synth", help="write a synthetic exciter record from a parameter file",
                       description="Simulate the nonlinear model under a realistic shaker "
                       "force (distortion, drift, anti-alias filter, offsets, noise) and write "
                       "a record CSV that `bsfs identify` reads.")
    add_params_args(s)
    s.add_argument("--frequency", type=finite_float, required=True, metavar="HZ")
    s.add_argument("--force", type=finite_float, required=True, metavar="N")
    s.add_argument("--speed", type=finite_float, metavar="RPM",
                   help="spindle speed (thermal chain)")
    s.add_argument("--noise-db", type=finite_float, default=35.0, metavar="DB",
                   help="accelerometer SNR in dB (35); the force sensor gets +5 dB")
    s.add_argument("--duration", type=finite_float, default=2.0, metavar="S",
                   help="record length (2)")
    s.add_argument("--sample-rate", type=finite_float, default=10240.0, metavar="HZ")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, metavar="FILE.csv")
    s.add_argument("--overwrite", action="store_true",
                   help="replace FILE.csv if it exists (refused otherwise)")
    s.set_defaults(func=run_synth)


def run_synth(args) -> int:
    import identification as idn

    params = load_params_from_args(args)
    if args.speed is not None:
        params = params.replace("thermal.speed_rpm", args.speed)
    for name in ("frequency", "force", "duration", "sample_rate"):
        if not getattr(args, name) > 0:
            raise CLIError(f"--{name.replace('_', '-')} must be positive, got "
                           f"{getattr(args, name)}")
    if args.frequency >= 0.4 * args.sample_rate:
        raise CLIError(f"--frequency {args.frequency:g} Hz is above the anti-alias band "
                       f"(0.4 x sample rate = {0.4 * args.sample_rate:g} Hz)")
    out = Path(args.out)
    if out.is_dir():
        raise CLIError(f"--out '{out}' is a folder; synth writes one record file: give a "
                       "file name such as record_100hz.csv")
    if out.exists() and not args.overwrite:
        raise CLIError(f"--out '{out}' exists; choose another name or add --overwrite")
    if not out.parent.is_dir():
        raise CLIError(f"--out '{out}': the folder '{out.parent}' does not exist")
    effects = idn.TestEffects(accel_snr_db=args.noise_db, force_snr_db=args.noise_db + 5.0)
    rec = idn.synthesize(params, args.frequency, args.force, duration_s=args.duration,
                         sample_rate_hz=args.sample_rate, effects=effects, seed=args.seed)
    rec.meta["source"] = "synthetic: bsfs synth"
    rec.meta["parameters"] = args.params or f"preset:{args.preset or 'default'}"
    if args.set:
        rec.meta["overrides"] = "; ".join(args.set)
    path = idn.write_record_csv(out, rec)
    print(f"wrote {path}: {rec.summary()}")
    return 0
