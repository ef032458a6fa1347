"""`bsfs continue`: the frequency-response curve by continuation of periodic orbits."""

import io
import time

import numpy as np

from ._common import (
    CLIError,
    add_params_args,
    load_params_from_args,
    out_dir,
    save_figure,
    write_bytes_atomic,
    write_json,
)

_DOFS = {"bearing": 0, "screw": 1, "nut": 2}


def register(sub) -> None:
    p = sub.add_parser(
        "continue", help="continue periodic orbits in frequency: FRC with unstable branches",
        description="Follow the T-periodic response to P sin(2 pi f t) on the nut from --start "
        "to --stop Hz by shooting and pseudo-arclength continuation (through folds). Writes "
        "frc.png (stable solid, unstable dashed, bifurcations marked), branch.csv, "
        "bifurcations.json and summary.json.")
    p.add_argument("--start", type=float, required=True, metavar="HZ",
                   help="start frequency [Hz] (a transient simulation there gives the guess)")
    p.add_argument("--stop", type=float, required=True, metavar="HZ", help="stop frequency [Hz]")
    p.add_argument("--force", type=float, default=3000.0, metavar="N",
                   help="force amplitude on the nut [N] (3000)")
    add_params_args(p)
    p.add_argument("--ds", type=float, default=0.1,
                   help="initial arclength step in scaled units (0.1; adapted)")
    p.add_argument("--ds-max", type=float, default=None, help="largest step (10 ds)")
    p.add_argument("--max-points", type=int, default=400, help="most branch points (400)")
    p.add_argument("--dof", choices=sorted(_DOFS), default="nut",
                   help="mass whose amplitude is plotted and tabulated (nut)")
    p.add_argument("--transient-periods", type=int, default=150,
                   help="periods simulated from rest at --start for the first guess (150)")
    p.add_argument("--rtol", type=float, default=1e-11, help="ODE rtol (1e-11)")
    p.add_argument("--atol", type=float, default=1e-13,
                   help="ODE atol, on states scaled to order one (1e-13)")
    p.add_argument("--solver", default="dopri8", help="ODE solver (dopri8)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_continue)


def run_continue(args) -> int:
    import bsfs_jax

    from ..params import params_summary
    from ..plotting import plot_continuation
    from ..solvers import SolverSettings, bsfs_family, continue_orbits, simulate

    if not (args.start > 0 and args.stop > 0) or args.start == args.stop:
        raise CLIError(f"--start and --stop must be positive and differ, got {args.start} "
                       f"and {args.stop}")
    if not args.force > 0:
        raise CLIError(f"--force must be positive, got {args.force}")
    if not args.ds > 0 or args.max_points < 2 or args.transient_periods < 0:
        raise CLIError("need --ds > 0, --max-points >= 2 and --transient-periods >= 0")
    params = load_params_from_args(args)
    folder = out_dir(args.out)
    settings = SolverSettings(rtol=args.rtol, atol=args.atol, solver=args.solver)
    dof = _DOFS[args.dof]
    started = time.perf_counter()
    family = bsfs_family(params, args.force)
    print(f"transient of {args.transient_periods} periods at {args.start:g} Hz, "
          f"{args.force:g} N ...", flush=True)
    guess = simulate(params, frequency_hz=args.start, force_n=args.force,
                     transient_periods=args.transient_periods, periods=1,
                     samples_per_period=64).final_state
    print(f"continuing from {args.start:g} to {args.stop:g} Hz ...", flush=True)
    t_cont = time.perf_counter()
    branch = continue_orbits(family, guess, args.start, args.stop, ds=args.ds,
                             ds_max=args.ds_max, max_points=args.max_points,
                             settings=settings, amplitude_index=dof,
                             progress=not args.no_progress)
    t_cont = time.perf_counter() - t_cont

    # branch.csv: one row per orbit.
    mu_mod = np.abs(branch.multipliers)
    amps_um = branch.amplitudes[:, :3] * 1e6
    header = [
        "# bsfs continue: periodic orbits (period 1/f) continued in the excitation frequency",
        f"# force_n = {args.force}", f"# dof = {args.dof}",
        "# amplitude = half peak-to-peak displacement over one period [um]",
        "# state at t = 0 (phase of P sin(2 pi f t)): displacements [m], velocities [m/s]",
        "# stable = 1 when every Floquet multiplier has modulus < 1",
    ]
    cols = ["frequency_hz", "amplitude_um", "amp_bearing_um", "amp_screw_um", "amp_nut_um",
            "stable", "max_multiplier_modulus", "x_b_m", "x_s_m", "x_n_m", "v_b_m_s",
            "v_s_m_s", "v_n_m_s"]
    table = np.column_stack([branch.p, branch.amplitude * 1e6, amps_um,
                             branch.stable.astype(float), mu_mod.max(axis=1), branch.states])
    buf = io.StringIO()
    buf.write("\n".join(header) + "\n" + ",".join(cols) + "\n")
    np.savetxt(buf, table, delimiter=",", fmt="%.10e")
    write_bytes_atomic(folder / "branch.csv", buf.getvalue().encode())

    bifs = [{
        "type": b.kind,
        "frequency_hz": b.p,
        "amplitude_um": b.amplitude * 1e6,
        "multipliers": [[float(m.real), float(m.imag)] for m in b.multipliers],
        "multiplier_moduli": np.abs(b.multipliers).tolist(),
        "located": b.located,
        "branch_index": b.index,
    } for b in branch.bifurcations]
    write_json(folder / "bifurcations.json", bifs)

    fig = plot_continuation(
        branch, y_label=f"{args.dof.capitalize()} amplitude (half peak-to-peak) [µm]",
        title=f"BSFS frequency response by continuation: {args.force:g} N, "
              f"{float(params.thermal.speed_rpm):g} r/min, thermal "
              f"{'on' if params.thermal.enabled else 'off'}")
    save_figure(fig, folder / "frc.png")
    import matplotlib.pyplot as plt

    plt.close(fig)

    peak = int(np.argmax(branch.amplitude))
    summary = {
        "bsfs_version": bsfs_jax.__version__,
        "start_hz": args.start, "stop_hz": args.stop, "force_n": args.force,
        "dof": args.dof, "points": len(branch),
        "stable_points": int(branch.stable.sum()),
        "unstable_points": int((~branch.stable).sum()),
        "peak_amplitude_um": float(branch.amplitude[peak] * 1e6),
        "peak_frequency_hz": float(branch.p[peak]),
        "bifurcations": [{"type": b["type"], "frequency_hz": b["frequency_hz"]} for b in bifs],
        "stop_reason": branch.info["stop_reason"],
        "steps": branch.info["steps"], "rejected_steps": branch.info["rejected"],
        "settings": {"ds": args.ds, "ds_max": args.ds_max, "max_points": args.max_points,
                     "rtol": args.rtol, "atol": args.atol, "solver": args.solver,
                     "transient_periods": args.transient_periods,
                     "state_scale": branch.info["scale"]},
        "parameters": params_summary(params),
        "units": {"frequency": "Hz", "amplitude": "um (half peak-to-peak over one period)"},
        "continuation_s": t_cont,
        "runtime_s": time.perf_counter() - started,
    }
    write_json(folder / "summary.json", summary)
    print(f"{len(branch)} orbits ({summary['stable_points']} stable), peak "
          f"{summary['peak_amplitude_um']:.3f} um at {summary['peak_frequency_hz']:.2f} Hz; "
          + (", ".join(f"{b['type']} at {b['frequency_hz']:.2f} Hz" for b in bifs)
             or "no bifurcations"))
    if branch.info["stop_reason"] != "left the parameter interval":
        print(f"warning: the branch stopped before {args.stop:g} Hz: "
              f"{branch.info['stop_reason']}. Try a smaller --ds or a larger --max-points.")
    print(f"wrote {folder}/frc.png, branch.csv, bifurcations.json, summary.json")
    return 0
