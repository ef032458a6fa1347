"""`bsfs simulate`, `bsfs params` and `bsfs modes`."""

import functools
import time

import numpy as np

from .._numerics import half_range
from . import _common as ui

#: Most rows `simulate` writes to timeseries.csv (about 1.7 GB of text).
MAX_ROWS = 10**7


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate the response to a harmonic force on the nut",
                       description="Simulate Eq. 31 under P sin(2 pi f t) on the nut; write "
                       "summary.json, timeseries.csv and response.png.")
    p.add_argument("--frequency", type=ui.finite_float, required=True, metavar="HZ",
                   help="excitation frequency [Hz]")
    p.add_argument("--force", type=ui.finite_float, required=True, metavar="N",
                   help="force amplitude [N]")
    p.add_argument("--speed", type=ui.finite_float, metavar="RPM",
                   help="screw speed [r/min] (thermal chain)")
    p.add_argument("--no-thermal", action="store_true", help="switch thermal deformation off")
    ui.add_params_args(p)
    p.add_argument("--periods", type=ui.count(2, 10**6), default=50,
                   help="saved steady-state periods (50)")
    p.add_argument("--verify", action="store_true",
                   help="verify the steady state: Newton (shooting) from the final state finds "
                   "the periodic orbit and its Floquet multipliers, else the run is continued "
                   "until a verified label or 'unresolved' (adds a compile of ~30 s)")
    p.add_argument("--transient", type=ui.count(0, 10**7), default=200,
                   help="discarded periods (200)")
    p.add_argument("--samples-per-period", type=ui.count(8, 10**4), default=64,
                   help="output points per period (64)")
    p.add_argument("--rtol", type=ui.tolerance, default=1e-8, help="relative tolerance (1e-8)")
    p.add_argument("--atol", type=ui.positive_float, default=1e-12,
                   help="absolute tolerance [SI] (1e-12)")
    p.add_argument("--max-steps", type=ui.count(1, 10**10), default=4_000_000)
    p.add_argument("--solver", default="dopri5-fused",
                   choices=("dopri5-fused", "tsit5", "dopri5", "dopri8", "kvaerno5"),
                   help="dopri5-fused (default: fast forward-only loop) or a diffrax solver: "
                   "tsit5, dopri5, dopri8, kvaerno5")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bars (they show only on a terminal anyway)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_simulate)

    q = sub.add_parser("params", help="print a complete TOML parameter file")
    ui.add_params_args(q)
    q.add_argument("--list", action="store_true", help="list the bundled presets")
    q.set_defaults(func=run_params)

    m = sub.add_parser("modes", help="natural frequencies and mode shapes about equilibrium")
    ui.add_params_args(m)
    m.add_argument("--speed", type=ui.finite_float, metavar="RPM")
    m.add_argument("--no-thermal", action="store_true")
    m.add_argument("--static-force", type=ui.finite_float, default=0.0, metavar="N",
                   help="constant axial force on the nut for the equilibrium [N]")
    m.add_argument("--json", action="store_true", help="print JSON instead of a table")
    m.set_defaults(func=run_modes)


def _apply_common(params, args):
    if getattr(args, "speed", None) is not None:
        params = params.replace("thermal.speed_rpm", args.speed)
    if getattr(args, "no_thermal", False):
        params = params.replace("thermal.enabled", False)
    from ..params import validate

    return validate(params, source="command line")


@functools.cache
def _report_fn():
    """One jitted function for everything reported besides the trajectory (built once)."""
    import equinox as eqx

    from ..machine import modes
    from ..model import build_system

    @eqx.filter_jit
    def report(params, static_force):
        system = build_system(params)
        md = modes(system, static_force)
        return system, md, md.static_stiffness

    return report


def _thermal_dict(system):
    th = system.thermal
    temps = np.asarray(th.temperatures_c)
    return {
        "temperatures_c": {"bearing": temps[0], "screw": temps[1], "nut": temps[2]},
        "temperature_rise_k": dict(zip(("bearing", "screw", "nut"),
                                       np.asarray(th.temperature_rise_k).tolist())),
        "heat_w": {"bearing": np.asarray(th.heat_w)[0], "nut": np.asarray(th.heat_w)[1]},
        "nut_offset_um": float(th.nut_offset) * 1e6,
        "bearing_offset_um": float(th.bearing_offset) * 1e6,
        "screw_elongation_um": float(th.elongation) * 1e6,
    }


def run_simulate(args) -> int:
    import bsfs_jax

    from ..machine import simulate
    from ..params import params_summary

    if not args.frequency > 0:
        raise ui.CLIError(f"--frequency must be positive, got {args.frequency}")
    if not args.force >= 0:
        raise ui.CLIError(f"--force must be >= 0, got {args.force}")
    rows = (args.periods + 1) * args.samples_per_period
    if rows > MAX_ROWS:
        raise ui.CLIError(f"--periods {args.periods} x --samples-per-period "
                       f"{args.samples_per_period} would write {rows:,} rows to timeseries.csv "
                       f"(more than {MAX_ROWS:,}); lower one of them")
    params = _apply_common(ui.load_params_from_args(args), args)
    ui.warn_implausible_excitation(forces=[args.force], frequencies=[args.frequency])
    folder = ui.out_dir(args.out)
    started = time.perf_counter()
    system, md, k_static = _report_fn()(params, 0.0)
    print(f"natural frequencies: {', '.join(f'{f:.1f}' for f in np.asarray(md.frequencies_hz))} Hz")
    print(f"simulating {args.transient} + {args.periods} periods at {args.frequency:g} Hz, "
          f"{args.force:g} N ...", flush=True)
    traj = simulate(system, frequency_hz=args.frequency, force_n=args.force,
                    periods=args.periods, transient_periods=args.transient,
                    samples_per_period=args.samples_per_period, rtol=args.rtol, atol=args.atol,
                    max_steps=args.max_steps, solver=args.solver,
                    progress=ui.progress_enabled(args) and args.solver != "dopri5-fused")
    from ..plotting import response_figure, trajectory_spectrum

    t = np.asarray(traj.t)
    x = np.asarray(traj.displacement)
    v = np.asarray(traj.velocity)
    a = np.asarray(traj.acceleration)
    jf = np.asarray(traj.joint_force)
    amp = half_range(x, axis=0)
    strobe = x[:: traj.samples_per_period, 2]
    spread = np.ptp(strobe) / max(amp[2], 1e-30)
    freq, spec = trajectory_spectrum(traj)
    top = np.argsort(spec)[::-1][:5]
    summary = {
        "bsfs_version": bsfs_jax.__version__,
        "frequency_hz": args.frequency,
        "force_n": args.force,
        "speed_rpm": float(params.thermal.speed_rpm),
        "thermal_enabled": bool(params.thermal.enabled),
        "amplitude_um": amp[2] * 1e6,
        "amplitudes_um": {"bearing": amp[0] * 1e6, "screw": amp[1] * 1e6, "nut": amp[2] * 1e6},
        "peak_acceleration_m_s2": {"nut": float(np.abs(a[:, 2]).max())},
        "peak_joint_force_n": dict(zip(("bearing", "screw", "nut"),
                                       np.abs(jf).max(axis=0).tolist())),
        "natural_frequencies_hz": np.asarray(md.frequencies_hz),
        "modal_damping_ratios": np.asarray(md.damping_ratios),
        "static_stiffness_n_per_um": float(k_static) * 1e-6,
        **_thermal_dict(system),
        "poincare_spread": float(spread),
        "dominant_spectral_lines_hz": [{"frequency_hz": float(freq[i]),
                                        "amplitude_um": float(spec[i]) * 1e6} for i in top],
        "settings": {"periods": args.periods, "transient_periods": args.transient,
                     "samples_per_period": args.samples_per_period, "rtol": args.rtol,
                     "atol": args.atol, "solver": args.solver, "num_steps": int(traj.num_steps)},
        "parameters": params_summary(params),
        "units": {"amplitude": "um (half peak-to-peak of x_n in steady state)",
                  "poincare_spread": "1 (peak-to-peak of x_n at t = kT over its amplitude; "
                                     "0 for period-1 motion)",
                  "offsets": "um (positive reduces contact deformation)"},
        "runtime_s": time.perf_counter() - started,
    }
    header = [
        "# bsfs simulate: steady-state response (transient discarded)",
        f"# frequency_hz = {args.frequency}", f"# force_n = {args.force}",
        f"# speed_rpm = {float(params.thermal.speed_rpm)}",
        f"# thermal_enabled = {bool(params.thermal.enabled)}",
        f"# transient_periods = {args.transient}", f"# periods = {args.periods}",
        "# columns: time [s]; displacements [m]; velocities [m/s]; accelerations [m/s^2]; "
        "joint forces [N]; external force on the nut [N]",
    ]
    cols = ["time_s", "x_b_m", "x_s_m", "x_n_m", "v_b_m_s", "v_s_m_s", "v_n_m_s", "a_b_m_s2",
            "a_s_m_s2", "a_n_m_s2", "f_bearing_n", "f_screw_n", "f_nut_n", "force_n"]
    table = np.column_stack([t, x, v, a, jf, np.asarray(traj.force)])
    import io

    from ._common import write_bytes_atomic

    buf = io.StringIO()
    buf.write("\n".join(header) + "\n" + ",".join(cols) + "\n")
    np.savetxt(buf, table, delimiter=",", fmt="%.10e")
    write_bytes_atomic(folder / "timeseries.csv", buf.getvalue().encode())
    fig = response_figure(traj, title=f"BSFS response: {args.frequency:g} Hz, {args.force:g} N, "
                          f"{float(params.thermal.speed_rpm):g} r/min, thermal "
                          f"{'on' if params.thermal.enabled else 'off'}")
    ui.save_figure(fig, folder / "response.png", tight=False)  # margins set by the figure
    summary["steady_state"] = _steady_state(args, params, traj, amp, x, v)
    summary["runtime_s"] = time.perf_counter() - started
    ui.write_json(folder / "summary.json", summary)
    print(f"amplitude of x_n: {amp[2] * 1e6:.3f} um (half peak-to-peak); "
          f"nut offset {summary['nut_offset_um']:.3f} um, bearing offset "
          f"{summary['bearing_offset_um']:.3f} um; {traj.num_steps} steps")
    st = summary["steady_state"]
    print(f"steady state: {'verified ' + st['motion'] if st['verified'] else 'NOT verified'}"
          f" ({st['reason']})")
    if st["verified"] and st.get("amplitude_um") is not None:
        print(f"amplitude of x_n on the verified orbit: {st['amplitude_um']:.3f} um (the "
              f"recorded samples give {amp[2] * 1e6:.3f} um)")
    print(f"wrote {folder}/summary.json, timeseries.csv, response.png")
    return 0


def _steady_state(args, params, traj, amp, x, v) -> dict:
    """Whether the recorded response is a verified steady state (`--verify`), with the
    verifier's evidence; without `--verify` it says that it was not checked."""
    if not args.verify:
        return {"verified": False, "motion": "not checked",
                "reason": f"a fixed transient of {args.transient} periods; the samples may "
                          "still hold decaying free vibration (rerun with --verify)"}
    from ..analysis import VerifySettings, bsfs_problem, verify_points

    spp = traj.samples_per_period
    states = np.concatenate([x, v], axis=1)[::spp]
    period = 1.0 / args.frequency
    problem = bsfs_problem(params, "frequency_hz", force_n=args.force)
    got = verify_points(problem, np.array([args.frequency]), states[None],
                        np.concatenate([amp, half_range(v, axis=0)])[None],
                        np.array([period]),
                        np.array([(args.transient + args.periods) * period]),
                        settings=VerifySettings())
    one = {k: a[0] for k, a in got.items()}
    return {"verified": bool(one["verified"]), "motion": str(one["motion"]),
            "reason": str(one["reason"]),
            "amplitude_um": float(one["amplitude"] * 1e6),
            "evidence": {"orbit_residual": float(one["orbit_residual"]),
                         "max_multiplier": float(one["max_multiplier"]),
                         "lyapunov_per_period": float(one["lyapunov_per_period"]),
                         "lyapunov_per_period_95": [float(one["lyapunov_low"]),
                                                    float(one["lyapunov_high"])]}}


def run_params(args) -> int:
    from ..params import list_presets, params_to_toml, preset_description

    if args.list:
        for name in list_presets():
            print(f"{name:18s} {preset_description(name)}")
        return 0
    params = ui.load_params_from_args(args)
    source = args.params or f"preset '{args.preset or 'default'}'"
    print(params_to_toml(params, header=f"bsfs parameter file (from {source}).\n"
                         "Units are in the key names; see physics.md section 2."), end="")
    return 0


def run_modes(args) -> int:
    params = _apply_common(ui.load_params_from_args(args), args)
    system, md, k_static = _report_fn()(params, args.static_force)
    f = np.asarray(md.frequencies_hz)
    z = np.asarray(md.damping_ratios)
    shapes = np.asarray(md.shapes)
    shapes = shapes / np.abs(shapes).max(axis=0, keepdims=True)
    if args.json:
        import json

        from ._common import jsonable

        print(json.dumps(jsonable({"natural_frequencies_hz": f, "damping_ratios": z,
                                   "mode_shapes_bsn": shapes.T,
                                   "static_stiffness_n_per_um": float(k_static) / 1e6,
                                   **_thermal_dict(system)}), indent=2))
        return 0
    print("mode  frequency [Hz]  damping ratio   shape (bearing, screw, nut; max = 1)")
    for i in range(3):
        print(f"{i + 1:4d}  {f[i]:14.1f}  {z[i]:13.4f}   "
              + "  ".join(f"{s:+.3f}" for s in shapes[:, i]))
    th = _thermal_dict(system)
    print(f"static axial stiffness at the nut: {float(k_static) / 1e6:.1f} N/um")
    print(f"thermal: {'on' if params.thermal.enabled else 'off'} at "
          f"{float(params.thermal.speed_rpm):g} r/min; T_bearing/screw/nut = "
          + "/".join(f"{v:.1f}" for v in th["temperatures_c"].values())
          + f" C; offsets D_n = {th['nut_offset_um']:.3f} um, "
            f"D_b = {th['bearing_offset_um']:.3f} um")
    return 0
