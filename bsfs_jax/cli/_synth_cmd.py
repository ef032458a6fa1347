"""`bsfs synth`: write a synthetic exciter record (sine, chirp or random) from a parameter set."""

from pathlib import Path

from . import _common as ui


def register(sub) -> None:
    s = sub.add_parser("synth", help="write a synthetic exciter record from a parameter file",
                       description="Simulate the nonlinear model under a realistic shaker "
                       "force (distortion, drift, anti-alias filter, offsets, noise) and write "
                       "a record (CSV, or UFF58 for FILE.uff) that `bsfs identify` reads: a "
                       "sine at --frequency, a linear burst chirp --start..--stop over the "
                       "record, or band-limited random force in --start..--stop.")
    ui.add_params_args(s)
    s.add_argument("--excitation", choices=("sine", "chirp", "random"), default="sine",
                   help="sine (default), chirp (linear sweep) or random (band-limited)")
    s.add_argument("--frequency", type=ui.finite_float, metavar="HZ",
                   help="sine frequency (required for sine)")
    s.add_argument("--start", type=ui.finite_float, metavar="HZ",
                   help="lower band edge of a chirp or random record")
    s.add_argument("--stop", type=ui.finite_float, metavar="HZ",
                   help="upper band edge of a chirp or random record")
    s.add_argument("--force", type=ui.finite_float, required=True, metavar="N",
                   help="force amplitude (sine, chirp) or RMS (random)")
    s.add_argument("--speed", type=ui.finite_float, metavar="RPM",
                   help="spindle speed (thermal chain)")
    s.add_argument("--noise-db", type=ui.snr_db, default=35.0, metavar="DB",
                   help="accelerometer SNR in dB (35); the force sensor gets +5 dB")
    s.add_argument("--duration", type=ui.finite_float, default=2.0, metavar="S",
                   help="record length (2); a chirp sweeps over all of it")
    s.add_argument("--sample-rate", type=ui.finite_float, default=10240.0, metavar="HZ")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--frf", action="store_true",
                   help="chirp/random: also write the estimated FRF as FILE_frf.csv/.uff")
    s.add_argument("--out", required=True, metavar="FILE.csv")
    s.add_argument("--overwrite", action="store_true",
                   help="replace FILE.csv if it exists (refused otherwise)")
    s.set_defaults(func=run_synth)


def _check_args(args) -> None:
    sine = args.excitation == "sine"
    if sine and args.frequency is None:
        raise ui.CLIError("--frequency is required for --excitation sine")
    if not sine and args.frequency is not None:
        raise ui.CLIError(f"--frequency is for sines; a {args.excitation} record takes "
                       "--start and --stop")
    if sine and (args.start is not None or args.stop is not None):
        raise ui.CLIError("--start/--stop are for chirp and random records; a sine takes "
                       "--frequency")
    if not sine and (args.start is None or args.stop is None):
        raise ui.CLIError(f"--excitation {args.excitation} needs --start HZ and --stop HZ")
    if sine and args.frf:
        raise ui.CLIError("--frf is for chirp and random records (a sine has no broadband FRF)")
    names = ("frequency",) if sine else ("start", "stop")
    for name in (*names, "force", "duration", "sample_rate"):
        if not getattr(args, name) > 0:
            raise ui.CLIError(f"--{name.replace('_', '-')} must be positive, got "
                           f"{getattr(args, name)}")
    top = args.frequency if sine else args.stop
    if top >= 0.4 * args.sample_rate:
        raise ui.CLIError(f"--{names[-1]} {top:g} Hz is above the anti-alias band "
                       f"(0.4 x sample rate = {0.4 * args.sample_rate:g} Hz)")
    if not sine and not args.start < args.stop:
        raise ui.CLIError(f"--start {args.start:g} Hz must be below --stop {args.stop:g} Hz")


def run_synth(args) -> int:
    import identification as idn

    _check_args(args)
    params = ui.load_params_from_args(args)
    if args.speed is not None:
        params = params.replace("thermal.speed_rpm", args.speed)
    out = Path(args.out)
    if out.is_dir():
        raise ui.CLIError(f"--out '{out}' is a folder; synth writes one record file: give a "
                       "file name such as record_100hz.csv")
    uff = out.suffix.lower() in (".uff", ".unv")
    frf_out = out.with_name(f"{out.stem}_frf{'.uff' if uff else '.csv'}")
    for path in (out, frf_out) if args.frf else (out,):
        if path.exists() and not args.overwrite:
            raise ui.CLIError(f"--out '{path}' exists; choose another name or add --overwrite")
    if not out.parent.is_dir():
        raise ui.CLIError(f"--out '{out}': the folder '{out.parent}' does not exist")
    effects = idn.TestEffects(accel_snr_db=args.noise_db, force_snr_db=args.noise_db + 5.0)
    n = int(round(args.duration * args.sample_rate))
    ui.say(f"synth: simulating a {args.duration:g} s {args.excitation} record, {n} samples at "
           f"{args.sample_rate:g} Hz ({effects.oversample}x oversampled for the anti-alias "
           "filter)")
    try:
        rec = idn.synthesize(params, args.frequency, args.force, duration_s=args.duration,
                             sample_rate_hz=args.sample_rate, effects=effects, seed=args.seed,
                             excitation=args.excitation, start_hz=args.start,
                             stop_hz=args.stop,
                             progress=ui.Progress("synth: simulated", ui.progress_wanted(args)))
    except ValueError as exc:
        raise ui.CLIError(str(exc)) from None
    rec.meta["source"] = "synthetic: bsfs synth"
    rec.meta["parameters"] = args.params or f"preset:{args.preset or 'default'}"
    if args.set:
        rec.meta["overrides"] = "; ".join(args.set)
    frf = None
    if args.frf:
        try:
            frf = idn.estimate_frf(rec)
        except idn.RecordError as exc:
            raise ui.CLIError(str(exc)) from None
    path = (idn.write_record_uff if uff else idn.write_record_csv)(out, rec)
    print(f"wrote {path}: {rec.summary()}")
    if frf is not None:
        path = (idn.write_frf_uff if uff else idn.write_frf_csv)(frf_out, frf)
        print(f"wrote {path}: {frf.summary()}")
    return 0
