"""`bsfs map`: a two-parameter atlas of the verified motion, with bifurcation curves."""

import numpy as np

from . import _cluster_opts
from . import _common as ui

FREQUENCY, FORCE, DAMPING_SCALE = "frequency_hz", "force_n", "damping_scale"
DAMPERS = ("damping.bearing_n_s_per_m", "damping.screw_n_s_per_m", "damping.nut_n_s_per_m")
_WORDS = {FREQUENCY: "Excitation frequency", FORCE: "Force amplitude",
          DAMPING_SCALE: "Damping scale (factor on the three dampers)"}
_SUFFIXES = ("_n_s_per_m", "_m_per_n23", "_n_per_um", "_w_per_m2k", "_w_per_k", "_mm2_s",
             "_per_k", "_gpa", "_rpm", "_deg", "_mm", "_um", "_kg", "_hz", "_n", "_c", "_w")


#: Most values per axis, points of one atlas, and samples (points x periods x samples
#: per period).
MAX_NUM = 10**4
#: The row continuations' largest step, in units of --ds, and the tangent's turn per step
#: that their step lengths aim at (`continue_orbits(angle_target=...)`) and may not
#: exceed. The state scale comes from the first orbit, far below the resonance, so near
#: the peak a branch is hundreds of scaled units long: with 10 x ds and steps grown by the
#: Newton steps alone the README's 16 x 8 map ran out of its 200 points before the end of
#: the band in every row; with 100 x ds they reached it in 190-224 corrector calls. With
#: steps that follow the turn (0.25 rad aimed at, 0.4 at most) and up to 1000 x ds, in
#: 70-144 (8 rows 22.1 -> 15.9 s warm, the same 16 folds to 1e-6 Hz, 2026-12-02), and in
#: 57-130 with the folds located to their test function's noise floor (13.9 s).
DS_MAX_FACTOR = 1000
ANGLE_TARGET, MAX_ANGLE = 0.25, 0.4
#: Regula falsi iterations per event of a row continuation: with the longer steps a fold's
#: bracket is wider, and 14 left 4 of the example's 16 folds bracketed, not located.
LOCATE_ITERS = 40
MAX_POINTS = 10**6
MAX_SAMPLES = 10**9


def register(sub) -> None:
    p = sub.add_parser(
        "map", help="two-parameter atlas: verified motion classes, amplitude, bifurcation "
        "curves",
        description="One verified cold sweep of --x per value of --y (vectorised, chunked, "
        "checkpointed under OUT/checkpoint: a rerun with the same --out loads finished rows). "
        "Every point is labelled period-n, quasi-periodic or chaotic only with its evidence "
        "(orbit residual and Floquet multipliers, Lyapunov exponent with its confidence "
        "interval), else 'unresolved' with the reason. With --x frequency_hz, each row's "
        "periodic branch is continued by shooting and its folds, period doublings and "
        "Neimark-Sacker points are joined across rows into curves. Writes atlas.nc "
        "(NetCDF4, open with xarray or bsfs_jax.analysis.load_atlas), summary.json, "
        "motion.png and amplitude.png.")
    p.add_argument("--x", default=FREQUENCY,
                   help="parameter swept along each row: frequency_hz (default), force_n or "
                   "a parameter key such as nut.preload_n (file units)")
    p.add_argument("--x-start", type=ui.finite_float, required=True)
    p.add_argument("--x-stop", type=ui.finite_float, required=True)
    p.add_argument("--x-num", type=int, required=True)
    p.add_argument("--y", default=FORCE,
                   help="parameter fixed per row: force_n (default), frequency_hz, a "
                   "parameter key, or damping_scale (multiplies the bearing, screw and nut "
                   "dampers of the parameter file)")
    p.add_argument("--y-start", type=ui.finite_float, required=True)
    p.add_argument("--y-stop", type=ui.finite_float, required=True)
    p.add_argument("--y-num", type=int, required=True)
    p.add_argument("--frequency", type=ui.finite_float,
                   help="excitation frequency [Hz] when neither axis is frequency_hz")
    p.add_argument("--force", type=ui.finite_float, default=5000.0,
                   help="excitation amplitude [N] when neither axis is force_n (5000)")
    ui.add_params_args(p)
    p.add_argument("--transient", type=ui.count(1, 10**7), default=200,
                   help="transient periods where no linear decay rate is known (default "
                   "200; otherwise each point runs three time constants of the slowest "
                   "linear mode)")
    p.add_argument("--periods", type=ui.count(1, 10**5), default=32,
                   help="recorded periods (default 32)")
    p.add_argument("--samples-per-period", type=ui.count(8, 10**4), default=32)
    p.add_argument("--lyapunov", action="store_true",
                   help="also integrate the tangent dynamics over every record (the "
                   "verification computes its own exponent where it needs one)")
    p.add_argument("--rtol", type=ui.tolerance, default=1e-8)
    p.add_argument("--atol", type=ui.positive_float, default=1e-12)
    p.add_argument("--max-steps", type=ui.count(1, 10**10), default=4_000_000)
    p.add_argument("--solver", default="dopri5-fused",
                   choices=("dopri5-fused", "tsit5", "dopri5", "dopri8", "kvaerno5"))
    p.add_argument("--batch", type=ui.count(0, 10**4), default=8,
                   help="points integrated in lockstep (0: the whole chunk)")
    ui.add_engine_args(p)
    p.add_argument("--shard", action="store_true", help="shard rows over all JAX devices")
    _cluster_opts.add_args(p)
    p.add_argument("--batch-atlas", choices=("auto", "rows", "grid"), default="auto",
                   help="'grid': every point of the atlas in one sweep (one batch, sharded "
                   "with --shard); 'rows': one sweep per row; 'auto' (default): grid with "
                   "the kernel engine (on a GPU), else rows")
    p.add_argument("--max-period", type=ui.count(1, 1000), default=16,
                   help="largest n of period-n orbits looked for (16)")
    p.add_argument("--max-blocks", type=ui.count(1, 1000), default=8,
                   help="continuation blocks an unresolved point may get (8)")
    # A block is cut into 8 spectral segments of at least 4 periods (`VerifySettings`).
    p.add_argument("--block-periods", type=ui.count(32, 10**6), default=256,
                   help="forcing periods per continuation block (256; at least 32)")
    p.add_argument("--no-bifurcations", action="store_true",
                   help="skip the continuation of each row's periodic branch")
    p.add_argument("--ds", type=ui.positive_float, default=0.05,
                   help="initial arclength step of the row continuations (0.05)")
    p.add_argument("--max-points", type=ui.count(2, 10**6), default=200,
                   help="most orbits per row continuation (200); a row whose continuation "
                   "stops early is named in summary.json's notes")
    p.add_argument("--method", choices=("auto", "hb", "shooting"), default="shooting",
                   help="orbit method of the row continuations: shooting (default), "
                   "harmonic balance (hb), or auto (hb where its error estimate passes "
                   "along the whole row, else shooting), as `bsfs continue`; on the "
                   "README's 16 x 8 example hb's rows at 6000-8000 N stop where 128 "
                   "harmonics miss the 1e-5 estimate (the joints lose contact) and the "
                   "5000 N row at --max-points")
    p.add_argument("--harmonics", type=ui.count(1, 1024), default=8,
                   help="starting harmonic count for hb (8; doubled where needed)")
    p.add_argument("--hb-tol", type=ui.positive_float, default=1e-5,
                   help="hb error tolerance relative to the orbit size (1e-5)")
    p.add_argument("--band", type=ui.finite_float, nargs=2, metavar=("LO", "HI"),
                   help="continue each row's branch over this frequency band only (default: "
                   "the whole x range)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run)


def _words(name: str) -> str:
    if name in _WORDS:
        return _WORDS[name]
    section, _, field = name.partition(".")
    for s in _SUFFIXES:
        if field.endswith(s):
            field = field[: -len(s)]
            break
    return f"{section.capitalize()} {field.replace('_', ' ')}".strip()


def _check(args) -> None:
    from ..params import lookup_key

    for axis in ("x", "y"):
        name, start, stop, num = (getattr(args, f"{axis}{s}") for s in
                                  ("", "_start", "_stop", "_num"))
        if not 1 <= num <= MAX_NUM:
            raise ui.CLIError(f"--{axis}-num must be a whole number from 1 to {MAX_NUM:,}, "
                           f"got {num}")
        if not start < stop:
            raise ui.CLIError(f"--{axis}-start must be smaller than --{axis}-stop, got {start:g} "
                           f"and {stop:g}")
        if name == FREQUENCY and not start > 0:
            raise ui.CLIError(f"frequencies must be positive, got --{axis}-start {start:g}")
        if name == DAMPING_SCALE and (axis == "x" or not start > 0):
            raise ui.CLIError("damping_scale is a --y parameter only, with positive values")
        if name not in (FREQUENCY, FORCE, DAMPING_SCALE):
            if lookup_key(name).kind != "float":  # unknown: ParameterError, one line
                raise ui.CLIError(f"'{name}' is a switch, not a scalar parameter")
    if args.x == args.y:
        raise ui.CLIError(f"--x and --y are the same parameter '{args.x}'")
    if FREQUENCY not in (args.x, args.y) and not (args.frequency or 0) > 0:
        raise ui.CLIError("neither axis is frequency_hz: give a positive --frequency HZ")
    if args.frequency is not None and not args.frequency > 0:
        raise ui.CLIError(f"--frequency must be positive, got {args.frequency}")
    if not args.force > 0:
        raise ui.CLIError(f"--force must be positive, got {args.force}")
    if FORCE in (args.x, args.y):
        start = args.x_start if args.x == FORCE else args.y_start
        if not start >= 0:
            raise ui.CLIError(f"force amplitudes must be >= 0, got {start:g}")
    if args.band is not None and not 0 < args.band[0] < args.band[1]:
        raise ui.CLIError(f"--band needs 0 < LO < HI, got {args.band[0]:g} {args.band[1]:g}")
    if args.x_num * args.y_num > MAX_POINTS:
        raise ui.CLIError(f"--x-num x --y-num = {args.x_num * args.y_num:,} points exceed "
                       f"{MAX_POINTS:,}; lower one of them")
    if args.x_num * args.y_num * args.periods * args.samples_per_period > MAX_SAMPLES:
        raise ui.CLIError(f"points x --periods x --samples-per-period exceed {MAX_SAMPLES:.0e} "
                       "samples: the spectra would not fit in memory; lower one of them")


def _check_grid(params, args, x, ys) -> None:
    """Validate every (x, y) parameter combination in one vectorised pass, before anything
    is computed (a range that crosses an invalid value is refused up front)."""
    from ..params import validate

    grid_x, grid_y = np.meshgrid(x, ys)
    p = params
    if args.y == DAMPING_SCALE:
        for k in DAMPERS:
            p = p.replace(k, float(params.get(k)) * grid_y)
    elif args.y not in (FREQUENCY, FORCE):
        p = p.replace(args.y, grid_y)
    if args.x not in (FREQUENCY, FORCE):
        p = p.replace(args.x, grid_x)
    validate(p, source=f"--x {args.x} / --y {args.y} range")


def run(args) -> int:
    from ..analysis import SweepConfig, VerifySettings, atlas, bsfs_problem
    from ..params import validate
    from ..plotting import plot_atlas_amplitude, plot_atlas_motion
    from ..solvers import FUSED_SHOOTING_SETTINGS, Shooting, SolverSettings

    _check(args)
    params = ui.load_params_from_args(args)
    base = {k: float(params.get(k)) for k in DAMPERS}

    def row(y):
        """(params, frequency, force) of the row at y."""
        p, f, force = params, args.frequency, args.force
        if args.y == FREQUENCY:
            f = y
        elif args.y == FORCE:
            force = y
        elif args.y == DAMPING_SCALE:
            for k in DAMPERS:
                p = p.replace(k, base[k] * y)
        else:
            p = p.replace(args.y, y)
        return validate(p, source=f"--y {args.y}={y:g}"), f, force

    def row_problem(y):
        p, f, force = row(y)
        return bsfs_problem(p, args.x, frequency_hz=f, force_n=force)

    x = np.linspace(args.x_start, args.x_stop, args.x_num)
    ys = np.linspace(args.y_start, args.y_stop, args.y_num)
    # Refuse up front a range that crosses an invalid value (not after some rows ran).
    _check_grid(params, args, x, ys)
    ui.warn_implausible_excitation(
        forces=[*(x if args.x == FORCE else []), *(ys if args.y == FORCE else []), args.force],
        frequencies=[*(x if args.x == FREQUENCY else []), *(ys if args.y == FREQUENCY else []),
                     args.frequency])
    pending = None
    # The rows' shooting by the fused 8(7) loop: its program compiles ~7 s longer than
    # diffrax's, but each of a row's ~200 corrector calls takes half the time. Only the
    # folds' amplitudes are drawn: the corrector leaves the orbits' amplitudes out and
    # a small program computes them at the located points (amplitudes="events": on the
    # README's 16 x 8 map each row's continuation 3.8 -> 2.4 s, the corrector's
    # compilation about 5 s shorter).
    shooting = Shooting(settings=FUSED_SHOOTING_SETTINGS)

    def row_bifurcations(y):
        from .._programs import settle
        from ..machine import bsfs_family, simulate
        from ..solvers import HarmonicBalance, SolverError, continue_orbits
        from ._continue_cmd import continue_by_method

        p, _, force = row(y)
        mine = []  # notes on this row (returned: the row may run on a cluster worker)
        try:
            lo, hi = (x[0], x[-1]) if args.band is None else args.band
            family = bsfs_family(p, force)

            def transient():
                # The transient's last period: harmonic balance starts from its Fourier
                # coefficients (`init_from_samples`), shooting from its first state.
                spp = max(64, 4 * args.harmonics)
                traj = simulate(p, frequency_hz=lo, force_n=force,
                                transient_periods=args.transient, periods=1,
                                samples_per_period=spp)
                return traj.host_state()[:spp]

            def from_guess(guess):
                settle(pending)
                return continue_by_method(
                    lambda method: continue_orbits(
                        family, guess, lo, hi, method=method, ds=args.ds,
                        ds_max=DS_MAX_FACTOR * args.ds, max_points=args.max_points,
                        amplitude_index=2, locate_iters=LOCATE_ITERS, find_peaks=False,
                        amplitudes="events", angle_target=ANGLE_TARGET,
                        max_angle=MAX_ANGLE),
                    args.method, HarmonicBalance(harmonics=args.harmonics,
                                                 error_tol=args.hb_tol, second_order=True),
                    shooting, args.hb_tol)

            branch = None
            if args.method == "shooting":
                # Shooting's first orbit by Newton from rest, kept where it is stable
                # (an attracting orbit at the band's start): no transient, and no program
                # to integrate one (on the README's example about 2.5 s of the two cores'
                # time at the start, all 8 rows starting so); else from a transient.
                try:
                    branch, why = from_guess(np.zeros(6))
                except SolverError:
                    branch = None
                if branch is not None and not bool(branch.stable[0]):
                    branch = None
            if branch is None:
                branch, why = from_guess(transient())
            for w in why:
                mine.append(f"{args.y} = {y:g}: {w}")
        except Exception as exc:  # noqa: BLE001 - a row without curves is reported
            mine.append(f"{args.y} = {y:g}: continuation failed ({exc})")
            print(f"bsfs map: warning: {mine[-1]}", flush=True)
            return [], mine
        reached = float(np.max(branch.p)) if hi > lo else float(np.min(branch.p))
        if abs(reached - hi) > 1e-6 * abs(hi - lo):
            mine.append(f"{args.y} = {y:g}: continuation stopped at {reached:.6g} Hz "
                        f"({branch.info.get('stop_reason')}); bifurcations beyond it are "
                        "not shown (raise --max-points or --ds, or narrow --band)")
            print(f"bsfs map: warning: {mine[-1]}", flush=True)
        return [{"x": b.p, "kind": b.kind, "amplitude": b.amplitude, "located": b.located,
                 "multiplier_moduli": np.abs(b.multipliers).tolist()}
                for b in branch.bifurcations], mine

    bifs = None if args.no_bifurcations or args.x != FREQUENCY or args.x_num < 2 else \
        row_bifurcations
    source = args.params or f"preset:{args.preset or 'default'}"
    unit = {FREQUENCY: "Hz", FORCE: "N", DAMPING_SCALE: "1"}
    from ..machine import parameter_unit

    try:
        config = SweepConfig(
            transient_periods=args.transient, periods=args.periods,
            samples_per_period=args.samples_per_period, lyapunov=args.lyapunov,
            lyapunov_align_periods=min(16, args.transient - 1), batch_size=args.batch,
            **ui.engine_settings(args),
            settings=SolverSettings(args.rtol, args.atol, args.max_steps, args.solver))
        y_unit = unit.get(args.y) or parameter_unit(args.y)
    except ValueError as exc:
        raise ui.CLIError(str(exc).splitlines()[0]) from None
    verify = VerifySettings(max_period=args.max_period, max_blocks=args.max_blocks,
                            min_blocks=min(3, args.max_blocks),
                            block_periods=args.block_periods,
                            align_periods=min(16, args.block_periods // 4),
                            kernel_checks=args.kernel_checks)
    here = args.shard or args.batch_atlas == "grid"  # (one process: BSFS_SCHEDULER idle)
    if here and _cluster_opts.explicit(args):
        raise ui.CLIError("--scheduler/--workers run one row per chunk: drop --shard (the "
                          "devices of this one process) or --batch-atlas grid")
    remote = _cluster_opts.wanted(args) and not here
    # only now: a refused command line (or an unreachable scheduler) leaves no folder behind
    folder = None if remote else ui.out_dir(args.out)
    if bifs is not None and args.method == "shooting" and not remote:
        # The rows' corrector is the longest compilation of a cold map (traced ~4 s,
        # compiled 7-14 s): start it first, on the background thread, from the first
        # row's family (its layout needs only the state's size, six).
        from ..machine import bsfs_family
        from ..solvers import prefetch_corrector

        p0, _, force0 = row(ys[0])
        family0 = bsfs_family(p0, force0)
        pending = prefetch_corrector(
            family0, family0.vector_field, shooting, np.zeros(6),
            x[0] if args.band is None else args.band[0], amplitude_index=2,
            amplitudes="events")
    with _cluster_opts.cluster_from_args(args, "map", enabled=remote) as cluster:
        folder = folder or ui.out_dir(args.out)
        try:
            result = atlas(
                row_problem, x, ys, y_name=args.y, y_unit=y_unit, config=config,
                verify=verify, checkpoint_dir=folder / "checkpoint",
                progress=ui.progress_enabled(args), shard=args.shard, row_bifurcations=bifs,
                batch=args.batch_atlas, runner=None if cluster is None else cluster.run,
                x_label=_words(args.x), y_label=_words(args.y),
                metadata={"parameters": source, "overrides": list(args.set), **{
                    k: v for k, v in ((FREQUENCY, args.frequency), (FORCE, args.force))
                    if k not in (args.x, args.y)}})
        except ValueError as exc:
            raise ui.CLIError(str(exc).splitlines()[0]) from None
        except RuntimeError as exc:  # every row's chunk failed on the cluster
            if cluster is None:
                raise
            raise ui.CLIError(str(exc).splitlines()[0]) from None
        on_cluster = _cluster_opts.report(cluster, "map", result.metadata.get("failed_rows", []))
    notes = result.metadata.pop("row_notes", [])
    for note in notes if cluster is not None else []:  # (printed on the workers)
        print(f"bsfs map: warning: {note}", flush=True)
    result.save(folder / "atlas.nc")
    summary = result.summary()
    summary["notes"] = notes
    if on_cluster is not None:
        summary["cluster"] = on_cluster
    ui.write_json(folder / "summary.json", summary)
    fixed = ", ".join(s for s in (
        f"{args.frequency:g} Hz" if FREQUENCY not in (args.x, args.y) else "",
        f"{args.force:g} N" if FORCE not in (args.x, args.y) else "", source) if s)
    ui.save_figure(plot_atlas_motion(result, title=f"Verified motion of the nut ({fixed})"),
                folder / "motion.png")
    ui.save_figure(plot_atlas_amplitude(result, title=f"Nut amplitude ({fixed})"),
                folder / "amplitude.png")
    counts = ", ".join(f"{n} {k}" for k, n in summary["motion_counts"].items())
    print(f"bsfs map: {args.y_num} x {args.x_num} points ({counts}); "
          f"{len(summary['bifurcation_curves'])} bifurcation curves -> {folder}")
    return 0
