"""`bsfs sweep`: batched, resumable sweeps with bifurcation diagram, FRC and waterfall."""

import argparse

import numpy as np

from . import _cluster_opts
from . import _common as ui

#: Most points of one sweep, and most samples (points x periods x samples per period).
MAX_POINTS = 10**5
MAX_SAMPLES = 10**9


def register(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="sweep frequency, force or any parameter; bifurcation diagram, FRC, waterfall",
        description="Steady response at each of N parameter values (vectorised, chunked, "
        "checkpointed under OUT/checkpoint so that a rerun with the same --out resumes). "
        "Writes sweep.nc (labelled NetCDF4: every array with its dimensions and units; "
        "open with xarray.open_dataset or bsfs_jax.analysis.load_sweep), summary.json "
        "(per point: value, amplitude, motion label, whether it is verified, its evidence "
        "- orbit residual and Floquet multipliers, or the largest Lyapunov exponent with "
        "its 95 %% interval - and the reason), bifurcation.png, frc.png and waterfall.png. "
        "Every label is verified by default: an orbit found from the sampled state, or an "
        "exponent with its confidence interval; anything else is 'unresolved'.")
    p.add_argument("--param", default="frequency_hz",
                   help="'frequency_hz', 'force_n' or a parameter key such as nut.balls, "
                   "bearing.contact_angle_deg, nut.preload_n (file units)")
    p.add_argument("--start", type=ui.finite_float, required=True, help="first value")
    p.add_argument("--stop", type=ui.finite_float, required=True, help="last value")
    p.add_argument("--num", type=ui.count(1, MAX_POINTS), required=True,
                   help="number of values (evenly spaced)")
    p.add_argument("--frequency", type=ui.finite_float, help="excitation frequency [Hz] (fixed)")
    p.add_argument("--force", type=ui.finite_float, default=5000.0,
                   help="excitation amplitude [N] on the nut (default 5000)")
    p.add_argument("--mode", choices=("cold", "continued"), default="cold")
    p.add_argument("--direction", choices=("up", "down", "both"), default="up",
                   help="continued mode: sweep up, down or both (hysteresis)")
    ui.add_params_args(p)
    p.add_argument("--transient", default="auto",
                   help="transient periods discarded at cold starts: 'auto' (default: three "
                   "time constants of the slowest linear mode per point when verifying, "
                   "else 200) or a number")
    p.add_argument("--continued-transient", type=ui.count(1, 10**7), default=20,
                   help="transient periods of continued points (default 20)")
    p.add_argument("--periods", type=ui.count(1, 10**5), default=32,
                   help="recorded periods = stroboscopic samples - 1 (default 32; points "
                   "without a periodic orbit are continued in blocks by the verifier)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip the verification of the motion labels (they are then reported "
                   "as unverified candidates read from the samples)")
    p.add_argument("--log-waterfall", action="store_true",
                   help="draw the waterfall's amplitudes on a log scale (weak harmonics and "
                   "subharmonics beside the forced line)")
    p.add_argument("--no-folds", action="store_true",
                   help="continued mode: do not locate the folds behind the jumps")
    p.add_argument("--samples-per-period", type=ui.count(8, 10**4), default=32,
                   help="samples per recorded period (32)")
    p.add_argument("--lyapunov", action="store_true",
                   help="also integrate the tangent dynamics over every recorded record "
                   "(the verifier computes exponents with confidence intervals where it "
                   "needs them anyway)")
    p.add_argument("--rtol", type=ui.tolerance, default=1e-8)
    p.add_argument("--atol", type=ui.positive_float, default=1e-12)
    p.add_argument("--max-steps", type=ui.count(1, 10**10), default=4_000_000)
    p.add_argument("--solver", default="dopri5-fused",
                   choices=("dopri5-fused", "tsit5", "dopri5", "dopri8", "kvaerno5"),
                   help="integrator: dopri5-fused (default, fast forward-only loop) or a "
                   "diffrax solver: tsit5, dopri5, dopri8, kvaerno5")
    p.add_argument("--batch", type=ui.count(0, 10**4), default=8,
                   help="points integrated in lockstep (vmap; 0: the whole chunk)")
    ui.add_engine_args(p)
    p.add_argument("--shard", action="store_true",
                   help="shard cold-mode chunks over all JAX devices")
    _cluster_opts.add_args(p)
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..analysis import SweepConfig, VerifySettings, bsfs_problem, locate_jump_folds, sweep
    from ..plotting import plot_bifurcation, plot_frc, plot_waterfall
    from ..solvers import SolverSettings

    if args.param == "frequency_hz" and min(args.start, args.stop) <= 0:
        raise ui.CLIError(f"frequencies must be positive, got --start {args.start} "
                       f"--stop {args.stop}")
    if args.param == "force_n" and min(args.start, args.stop) < 0:
        raise ui.CLIError(f"force amplitudes must be >= 0, got --start {args.start} "
                       f"--stop {args.stop}")
    if args.param != "frequency_hz" and args.frequency is None:
        raise ui.CLIError(f"sweeping {args.param} needs a fixed --frequency HZ")
    if args.frequency is not None and not args.frequency > 0:
        raise ui.CLIError(f"--frequency must be positive, got {args.frequency}")
    if not args.force >= 0:
        raise ui.CLIError(f"--force must be >= 0, got {args.force}")
    if args.transient != "auto":
        try:
            transient = ui.count(1, 10**7)(args.transient)
        except argparse.ArgumentTypeError as exc:
            raise ui.CLIError(f"--transient must be 'auto' or a number of periods: {exc}"
                           ) from None
    if args.num * args.periods * args.samples_per_period > MAX_SAMPLES:
        raise ui.CLIError(f"--num {args.num} x --periods {args.periods} x --samples-per-period "
                       f"{args.samples_per_period} samples exceed {MAX_SAMPLES:.0e}: the "
                       "spectra alone would not fit in memory; lower one of them")
    params = ui.load_params_from_args(args)
    if args.no_verify and args.kernel_checks:
        raise ui.CLIError("--kernel-checks runs the verification's orbit checks: drop "
                          "--no-verify")
    verify = None if args.no_verify else VerifySettings(kernel_checks=args.kernel_checks)
    try:
        problem = bsfs_problem(params, args.param, frequency_hz=args.frequency,
                               force_n=args.force)
        config = SweepConfig(
            transient_periods=200 if args.transient == "auto" else transient,
            continued_transient_periods=args.continued_transient, periods=args.periods,
            samples_per_period=args.samples_per_period, lyapunov=args.lyapunov,
            batch_size=args.batch, **ui.engine_settings(args),
            settings=SolverSettings(args.rtol, args.atol, args.max_steps, args.solver))
    except ValueError as exc:
        raise ui.CLIError(str(exc)) from None
    values = np.linspace(args.start, args.stop, args.num)
    if args.param not in ("frequency_hz", "force_n"):
        ui.validate_sweep_values(params, args.param, values, "--param")
    ui.warn_implausible_excitation(
        forces=values if args.param == "force_n" else [args.force],
        frequencies=values if args.param == "frequency_hz" else [args.frequency])
    source = args.params or f"preset:{args.preset or 'default'}"
    fixed = None if args.transient == "auto" or args.mode != "cold" else \
        np.full(values.size, transient)
    here = args.mode != "cold" or args.shard  # (not independent chunks: BSFS_SCHEDULER idle)
    if here and _cluster_opts.explicit(args):
        raise ui.CLIError("--scheduler/--workers run the independent chunks of a cold sweep: "
                          "drop them for --mode continued (each point starts from the last) "
                          "or drop --shard (the devices of this one process)")
    with _cluster_opts.cluster_from_args(args, "sweep", enabled=not here) as cluster:
        # only now: a refused command line (or an unreachable scheduler) leaves no folder
        folder = ui.out_dir(args.out)
        try:
            result = sweep(problem, values, mode=args.mode, direction=args.direction,
                           config=config, transient=fixed if verify is not None else None,
                           checkpoint_dir=folder / "checkpoint",
                           progress=ui.progress_enabled(args), shard=args.shard,
                           verify=verify, runner=None if cluster is None else cluster.run,
                           metadata={"parameters": source, "overrides": list(args.set),
                                     "frequency_hz": args.frequency, "force_n": args.force})
        except ValueError as exc:  # e.g. the --out folder holds a different sweep
            raise ui.CLIError(str(exc)) from None
        except RuntimeError as exc:  # every chunk failed on the cluster
            if cluster is None:
                raise
            raise ui.CLIError(str(exc).splitlines()[0]) from None
        on_cluster = _cluster_opts.report(cluster, "sweep",
                                          result.metadata.get("failed_chunks", []))
    jumps = result.jumps()
    if args.mode == "continued" and not args.no_folds:
        real = [j for j in jumps if j.hysteresis is not False]
        locate_jump_folds(problem, result, real)
    result.save(folder / "sweep.nc")
    summary = result.summary(jumps=jumps)
    if on_cluster is not None:
        summary["cluster"] = on_cluster
    ui.write_json(folder / "summary.json", summary)
    force = f"{args.force:g} N" if args.param != "force_n" else "swept force"
    where = f", {args.frequency:g} Hz" if args.param != "frequency_hz" else ""
    tag = f"({force}{where}, {source})"
    swept = {"frequency_hz": "excitation frequency", "force_n": "force amplitude"}.get(
        args.param, args.param)
    ui.save_figure(plot_bifurcation(result, title=f"Bifurcation diagram of the nut displacement "
                                 f"vs {swept} {tag}"), folder / "bifurcation.png")
    ui.save_figure(plot_frc(result, jumps=jumps), folder / "frc.png")
    ui.save_figure(plot_waterfall(result, log_amplitude=args.log_waterfall),
                folder / "waterfall.png")
    failed = summary["failed_points"]
    counts = ", ".join(f"{k} {v}" for k, v in summary["motion_counts"].items())
    state = "verified" if verify is not None else "NOT verified (--no-verify)"
    print(f"bsfs sweep: {len(summary['points'])} points, {failed} failed, "
          f"{len(summary['jumps'])} jumps -> {folder}")
    print(f"  motion ({state}): {counts}")
    for j in summary["jumps"]:
        if j.get("hysteresis") is False:
            continue  # a steep single-valued flank, not a jump between branches
        fold = (f"; fold at {j['fold_value']:.6g} {result.unit}" if j.get("fold_value")
                is not None else "")
        print(f"  {j['direction']} {j['kind']} between {j['value_before']:.6g} and "
              f"{j['value_after']:.6g} {result.unit}: amplitude of x_n "
              f"{j['amplitude_before'] * 1e6:.4g} -> {j['amplitude_after'] * 1e6:.4g} um{fold}")
    return 0
