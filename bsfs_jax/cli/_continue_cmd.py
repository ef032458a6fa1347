"""`bsfs continue`: the frequency-response curve by continuation of periodic orbits."""

import io
import time

import numpy as np

from . import _common as ui

_DOFS = {"bearing": 0, "screw": 1, "nut": 2}


def register(sub) -> None:
    p = sub.add_parser(
        "continue", help="continue periodic orbits in frequency: FRC with unstable branches",
        description="Follow the T-periodic response to P sin(2 pi f t) on the nut from --start "
        "to --stop Hz by pseudo-arclength continuation of periodic orbits (through folds), "
        "with harmonic balance or shooting. Folds are cross-checked with the other method. "
        "Writes frc.png (stable solid, unstable dashed, bifurcations marked), branch.csv, "
        "bifurcations.json and summary.json.")
    p.add_argument("--start", type=ui.finite_float, required=True, metavar="HZ",
                   help="start frequency [Hz] (a transient simulation there gives the guess)")
    p.add_argument("--stop", type=ui.finite_float, required=True, metavar="HZ",
                   help="stop frequency [Hz]")
    p.add_argument("--force", type=ui.finite_float, default=5000.0, metavar="N",
                   help="force amplitude on the nut [N] (5000, as sweep and map)")
    ui.add_params_args(p)
    p.add_argument("--method", choices=("auto", "hb", "shooting"), default="auto",
                   help="orbit method: harmonic balance (hb), shooting, or auto (default: "
                   "hb where its error estimate passes along the whole branch, else shooting)")
    p.add_argument("--harmonics", type=ui.count(1, 1024), default=None,
                   help="starting harmonic count for hb; doubled where the error estimate "
                   f"exceeds --hb-tol (default {HARMONICS}, or {CONTACT_HARMONICS} where the "
                   "force opens a joint in the interval)")
    p.add_argument("--hb-tol", type=ui.finite_float, default=1e-5,
                   help="hb error tolerance: estimated state error relative to the orbit "
                   "size (1e-5)")
    p.add_argument("--no-cross-check", action="store_true",
                   help="skip the cross-check of the folds with the other method")
    p.add_argument("--ds", type=ui.finite_float, default=0.1,
                   help="initial arclength step in scaled units (0.1; adapted)")
    p.add_argument("--ds-max", type=ui.positive_float, default=None,
                   help="largest step (10 ds)")
    p.add_argument("--max-points", type=ui.count(2, 10**6), default=400,
                   help="most branch points (400)")
    p.add_argument("--dof", choices=sorted(_DOFS), default="nut",
                   help="mass whose amplitude is plotted and tabulated (nut)")
    p.add_argument("--transient-periods", type=ui.count(0, 10**7), default=150,
                   help="periods simulated from rest at --start for the first guess (150)")
    p.add_argument("--rtol", type=ui.tolerance, default=1e-11, help="ODE rtol (1e-11)")
    p.add_argument("--atol", type=ui.positive_float, default=1e-13,
                   help="ODE atol, on states scaled to order one (1e-13)")
    p.add_argument("--solver", default="dopri8",
                   choices=("dopri8", "dopri8-fused", "dopri5", "tsit5", "kvaerno5"),
                   help="shooting's ODE solver (dopri8); dopri8-fused takes the same steps "
                   "3-4x faster but compiles about 8 s longer: for long shooting branches")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_continue)


#: hb's starting harmonics, and where the force opens a joint inside the interval (there the
#: contact force is only C^1, the series converges algebraically, and near the peak the
#: error estimate asks for about CONTACT_HARMONICS at the default --hb-tol, half as many at
#: 1e-4: on the default drive at 100 N, 1000-1250 Hz, starting at 8 compiled and rejected
#: 8, 16 and 32 harmonics in turn, 26 s cold against 19-20 s starting at 64, the same
#: orbits to 1e-13).
HARMONICS, CONTACT_HARMONICS = 8, 64


def starting_harmonics(params, force_n, start, stop, method: str, given,
                       hb_tol: float = 1e-5) -> tuple:
    """(hb's starting harmonic count, a note or None): `given` (--harmonics) where set,
    else, where the force opens a joint inside the interval (`design.opens_joint`, the
    linearised lift-off force's test that the design metrics use), `CONTACT_HARMONICS`
    (half as many for an `hb_tol` of 1e-4 or looser), else `HARMONICS`. The count is still
    doubled wherever the error estimate asks for more."""
    if given is not None:
        return int(given), None
    if method == "shooting":
        return HARMONICS, None
    from ..design import opens_joint

    if opens_joint(params, force_n, min(start, stop), max(start, stop)):
        h = CONTACT_HARMONICS // 2 if hb_tol >= 1e-4 else CONTACT_HARMONICS
        return h, (f"at {force_n:g} N a joint loses contact in the interval (linearised "
                   f"lift-off force): harmonic balance started at {h} harmonics "
                   "(--harmonics sets it)")
    return HARMONICS, None


def continue_by_method(run, method: str, hb, shooting, hb_tol: float):
    """(branch, notes) of `run(method)` for --method shooting, hb or auto (harmonic
    balance where it reaches the end of the interval with its error estimate within
    `hb_tol` at every orbit, else shooting, with a note saying why)."""
    from ..solvers import SolverError

    notes = []
    if method == "shooting":
        return run(shooting), notes
    try:
        branch = run(hb)
        bad = branch.info["stop_reason"] != "left the parameter interval" or not bool(
            np.all(branch.error_estimates <= hb_tol))
    except SolverError as exc:
        if method == "hb":
            raise
        branch, bad = None, True
        notes.append(f"harmonic balance failed ({exc})")
    if bad and method == "auto":
        notes.append("harmonic balance did not pass its error estimate along the whole "
                      "branch: used shooting")
        branch = run(shooting)
    return branch, notes


def _cross_check_folds(family, branch, method, settings, args):
    """Locate each fold again with `method`, by a short continuation across it."""
    from ..solvers import continue_orbits

    checks = []
    for b in branch.bifurcations:
        if b.kind != "fold":
            continue
        i = b.index
        p0 = float(branch.p[i])
        p_far = b.p + 2.0 * (b.p - p0) if b.p != p0 else b.p * 1.001
        try:
            local = continue_orbits(family, branch.states[i], p0, p_far, method=method,
                                    ds=0.02, max_points=60, amplitudes=False,
                                    find_peaks=False, p_scale=abs(p_far - p0) * 10,
                                    brief=True)
            folds = [f for f in local.bifurcations if f.kind == "fold"]
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            checks.append({"frequency_hz": b.p, "other_method": method.name,
                           "other_frequency_hz": None, "relative_difference": None,
                           "note": f"cross-check failed: {exc}"})
            continue
        if not folds:
            checks.append({"frequency_hz": b.p, "other_method": method.name,
                           "other_frequency_hz": None, "relative_difference": None,
                           "note": "the other method found no fold near this one"})
            continue
        f = min(folds, key=lambda f: abs(f.p - b.p))
        checks.append({"frequency_hz": b.p, "other_method": method.name,
                       "other_frequency_hz": f.p,
                       "relative_difference": abs(f.p - b.p) / abs(b.p),
                       "note": "agree" if abs(f.p - b.p) <= 1e-4 * abs(b.p) else
                       "DISAGREE by more than 1e-4 (relative)"})
    return checks


def run_continue(args) -> int:
    import bsfs_jax

    from .._programs import settle
    from ..machine import bsfs_family, simulate
    from ..params import params_summary
    from ..plotting import plot_continuation
    from ..solvers import (
        HarmonicBalance,
        Shooting,
        SolverSettings,
        continue_orbits,
        prefetch_corrector,
    )

    if not (args.start > 0 and args.stop > 0) or args.start == args.stop:
        raise ui.CLIError(f"--start and --stop must be positive and differ, got {args.start} "
                       f"and {args.stop}")
    if not args.force > 0:
        raise ui.CLIError(f"--force must be positive, got {args.force}")
    if not args.ds > 0 or args.max_points < 2 or args.transient_periods < 0:
        raise ui.CLIError("need --ds > 0, --max-points >= 2 and --transient-periods >= 0")
    if args.ds_max is not None and not args.ds_max >= args.ds:
        raise ui.CLIError(f"--ds-max {args.ds_max:g} must be at least --ds {args.ds:g}")
    if not args.hb_tol > 0:
        raise ui.CLIError("need --hb-tol > 0")
    params = ui.load_params_from_args(args)
    folder = ui.out_dir(args.out)
    settings = SolverSettings(rtol=args.rtol, atol=args.atol, solver=args.solver)
    shooting = Shooting(settings=settings)
    harmonics, harmonics_note = starting_harmonics(params, args.force, args.start, args.stop,
                                                   args.method, args.harmonics, args.hb_tol)
    # The BSFS state is (positions, velocities): harmonic balance in the positions alone.
    hb = HarmonicBalance(harmonics=harmonics, error_tol=args.hb_tol, second_order=True)
    dof = _DOFS[args.dof]
    started = time.perf_counter()
    family = bsfs_family(params, args.force)
    # Shooting's corrector for the folds' cross-check (amplitudes left out, `brief`: a few
    # dozen calls, so XLA's quicker compilation) is traced and compiled on the second core
    # meanwhile: from here (its layout needs only the state's size, six), beside the
    # transient's and harmonic balance's own compilations.
    pending = None if args.method == "shooting" or (
        args.method == "hb" and args.no_cross_check) else prefetch_corrector(
            family, family.vector_field, shooting, np.zeros(6), args.start,
            amplitudes=False, brief=True)
    print(f"transient of {args.transient_periods} periods at {args.start:g} Hz, "
          f"{args.force:g} N ...", flush=True)
    # Only a start for the corrector: the forward-only fused loop compiles in about half
    # the time of diffrax's general loop (the orbit is then corrected by the chosen method).
    # The transient's last period (4 H samples): harmonic balance starts from its Fourier
    # coefficients, with no program of its own to integrate one (`init_from_samples`).
    spp = max(64, 4 * harmonics)
    traj = simulate(params, frequency_hz=args.start, force_n=args.force,
                    transient_periods=args.transient_periods, periods=1,
                    samples_per_period=spp, solver="dopri5-fused")
    guess = traj.host_state()[:spp]

    def run(method):
        if method is shooting:
            settle(pending)
        print(f"continuing from {args.start:g} to {args.stop:g} Hz ({method.name}) ...",
              flush=True)
        return continue_orbits(family, guess, args.start, args.stop, method=method,
                               ds=args.ds, ds_max=args.ds_max, max_points=args.max_points,
                               amplitude_index=dof, progress=ui.progress_enabled(args))

    t_cont = time.perf_counter()
    branch, notes = continue_by_method(run, args.method, hb, shooting, args.hb_tol)
    notes = ([harmonics_note] if harmonics_note else []) + notes
    t_cont = time.perf_counter() - t_cont
    primary = branch.method
    other = shooting if isinstance(primary, HarmonicBalance) else HarmonicBalance(
        harmonics=max(harmonics, 16), error_tol=args.hb_tol, second_order=True)
    settle(pending)
    checks = [] if args.no_cross_check else _cross_check_folds(family, branch, other,
                                                               settings, args)

    # branch.csv: one row per orbit.
    mu_mod = np.abs(branch.multipliers)
    amps_um = branch.amplitudes[:, :3] * 1e6
    header = [
        "# bsfs continue: periodic orbits (period 1/f) continued in the excitation frequency",
        f"# force_n = {args.force}", f"# dof = {args.dof}", f"# method = {primary.name}"
        + (f" ({primary.harmonics} harmonics)" if isinstance(primary, HarmonicBalance)
           else ""),
        "# amplitude = half peak-to-peak displacement over one period [um]",
        "# state at t = 0 (phase of P sin(2 pi f t)): displacements [m], velocities [m/s]",
        "# stable = 1 when every Floquet multiplier has modulus < 1",
        "# residual = Newton residual (scaled); error_estimate = harmonic balance: estimated "
        "state error relative to the orbit size, shooting: the residual",
    ]
    cols = ["frequency_hz", "amplitude_um", "amp_bearing_um", "amp_screw_um", "amp_nut_um",
            "stable", "max_multiplier_modulus", "x_b_m", "x_s_m", "x_n_m", "v_b_m_s",
            "v_s_m_s", "v_n_m_s", "residual", "error_estimate"]
    table = np.column_stack([branch.p, branch.amplitude * 1e6, amps_um,
                             branch.stable.astype(float), mu_mod.max(axis=1), branch.states,
                             branch.residuals, branch.error_estimates])
    buf = io.StringIO()
    buf.write("\n".join(header) + "\n" + ",".join(cols) + "\n")
    np.savetxt(buf, table, delimiter=",", fmt="%.10e")
    ui.write_bytes_atomic(folder / "branch.csv", buf.getvalue().encode())

    check_by_f = {c["frequency_hz"]: c for c in checks}
    bifs = [{
        "type": b.kind,
        "frequency_hz": b.p,
        "amplitude_um": b.amplitude * 1e6,
        "multipliers": [[float(m.real), float(m.imag)] for m in b.multipliers],
        "multiplier_moduli": np.abs(b.multipliers).tolist(),
        "located": b.located,
        "branch_index": b.index,
        "method": primary.name,
        **({"cross_check": check_by_f[b.p]} if b.p in check_by_f else {}),
    } for b in branch.bifurcations]
    ui.write_json(folder / "bifurcations.json", bifs)

    fig = plot_continuation(
        branch, y_label=f"{args.dof.capitalize()} amplitude (half peak-to-peak) [µm]",
        title=f"BSFS frequency response by continuation ({primary.name}): {args.force:g} N, "
              f"{float(params.thermal.speed_rpm):g} r/min, thermal "
              f"{'on' if params.thermal.enabled else 'off'}")
    ui.save_figure(fig, folder / "frc.png")
    import matplotlib.pyplot as plt

    plt.close(fig)

    pk = branch.peak
    if pk is not None:
        peak_amp, peak_f, peak_how = pk.amplitude, pk.p, (
            "located maximum along the branch (dA/ds = 0)" if pk.located else
            "bracketed maximum along the branch (dA/ds not driven to zero)")
    else:
        i = int(np.argmax(branch.amplitude))
        peak_amp, peak_f = float(branch.amplitude[i]), float(branch.p[i])
        peak_how = "no interior maximum: the largest amplitude is at an end of the interval"
    summary = {
        "bsfs_version": bsfs_jax.__version__,
        "start_hz": args.start, "stop_hz": args.stop, "force_n": args.force,
        "dof": args.dof, "points": len(branch),
        "method": primary.name,
        "harmonics": getattr(primary, "harmonics", None),
        "stable_points": int(branch.stable.sum()),
        "unstable_points": int((~branch.stable).sum()),
        "peak_amplitude_um": float(peak_amp * 1e6),
        "peak_frequency_hz": float(peak_f),
        "peak": peak_how,
        "bifurcations": [{"type": b["type"], "frequency_hz": b["frequency_hz"]} for b in bifs],
        "fold_cross_checks": checks,
        "max_residual": float(np.max(branch.residuals)),
        "max_error_estimate": float(np.max(branch.error_estimates)),
        "stop_reason": branch.info["stop_reason"],
        "steps": branch.info["steps"], "rejected_steps": branch.info["rejected"],
        "notes": notes,
        "settings": {"ds": args.ds, "ds_max": args.ds_max, "max_points": args.max_points,
                     "method": args.method, "hb_tol": args.hb_tol,
                     "rtol": args.rtol, "atol": args.atol, "solver": args.solver,
                     "transient_periods": args.transient_periods,
                     "state_scale": branch.info["scale"]},
        "parameters": params_summary(params),
        "units": {"frequency": "Hz", "amplitude": "um (half peak-to-peak over one period)"},
        "continuation_s": t_cont,
        "runtime_s": time.perf_counter() - started,
    }
    ui.write_json(folder / "summary.json", summary)
    for note in notes:
        print(f"note: {note}")
    print(f"{len(branch)} orbits by {primary.name} ({summary['stable_points']} stable), peak "
          f"{summary['peak_amplitude_um']:.4f} um at {summary['peak_frequency_hz']:.3f} Hz; "
          + (", ".join(f"{b['type']} at {b['frequency_hz']:.3f} Hz" for b in bifs)
             or "no bifurcations"))
    for c in checks:
        other_f = c["other_frequency_hz"]
        print(f"fold at {c['frequency_hz']:.4f} Hz cross-checked by {c['other_method']}: "
              + (f"{other_f:.4f} Hz (relative difference {c['relative_difference']:.1e}, "
                 f"{c['note']})" if other_f is not None else c["note"]))
    if branch.info["stop_reason"] != "left the parameter interval":
        print(f"warning: the branch stopped before {args.stop:g} Hz: "
              f"{branch.info['stop_reason']}. Try a smaller --ds or a larger --max-points.")
    print(f"wrote {folder}/frc.png, branch.csv, bifurcations.json, summary.json")
    return 0
