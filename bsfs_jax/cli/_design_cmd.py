"""`bsfs sensitivity` and `bsfs optimize`: design gradients and optimisation."""

import importlib
import math
import sys
import time

from . import _common as ui


def register(sub) -> None:
    from ..design import DEFAULT_FORCE_N, DEFAULT_FREQUENCY_HZ, DESIGN_PARAMETERS, METRIC_INFO

    metric_help = "; ".join(f"{m.name} [{m.unit}, {m.direction}imise]" for m in
                            METRIC_INFO.values())
    p = sub.add_parser(
        "sensitivity", help="exact sensitivities of a response metric to design parameters",
        description="Gradient of a metric with respect to design parameters by implicit "
        "differentiation (periodic orbit / static equilibrium), normalised as "
        "d ln m / d ln p. The two largest entries are checked by central differences "
        "(gradient_check; exit status 3 where they disagree). Writes sensitivity.json, "
        "sensitivity.png (tornado plot) and sensitivity.md (table + comparison with the "
        f"paper's trends). Metrics: {metric_help}.")
    p.add_argument("--metric", required=True, choices=list(METRIC_INFO), metavar="NAME",
                   help=f"one of: {', '.join(METRIC_INFO)}")
    _operating_args(p, DEFAULT_FREQUENCY_HZ, DEFAULT_FORCE_N)
    p.add_argument("--vary", metavar="NAME,...",
                   help="design parameters (vocabulary names, comma-separated); default: "
                   + ",".join(DESIGN_PARAMETERS))
    p.add_argument("--check-fd", action="store_true",
                   help="compute central finite differences for every parameter and report "
                   "the agreement (by default only the two largest entries are probed)")
    p.add_argument("--no-fd-probe", action="store_true",
                   help="skip the default central-difference probe of the two largest "
                   "entries (the gradients are then reported as unchecked)")
    ui.add_params_args(p)
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bars (they show only on a terminal anyway)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_sensitivity)

    q = sub.add_parser(
        "optimize", help="optimise a metric over design parameters within bounds",
        description="Minimise (or maximise, for natural_frequency and static_stiffness) a "
        "metric over --vary within --bounds with optimistix BFGS on a sigmoid transform; an "
        "optional minimum static stiffness is enforced by an exterior quadratic penalty. The "
        "exact gradient is checked by central differences on its two largest entries at the "
        "start (a disagreement refuses the run) and at the optimum (flagged, exit status 3); "
        "the start and the optimum are verified by time simulation. Writes optimize.json, "
        "optimize.md, optimize.png and optimum.toml.")
    q.add_argument("--metric", required=True, choices=list(METRIC_INFO), metavar="NAME",
                   help=f"one of: {', '.join(METRIC_INFO)}")
    q.add_argument("--vary", required=True, metavar="NAME,...",
                   help="design parameters to vary (vocabulary names, comma-separated)")
    q.add_argument("--bounds", metavar="NAME=LO:HI,...",
                   help="bounds in file units, e.g. nut.balls=40:60,nut.preload_n=1000:2000 "
                   "(default +-30 %% of the start value)")
    q.add_argument("--min-stiffness", type=ui.finite_float, metavar="N_PER_UM",
                   help="require a static axial stiffness of at least this [N/um]")
    q.add_argument("--max-steps", type=ui.count(1, 10**5), default=60,
                   help="BFGS steps per penalty round (60)")
    q.add_argument("--no-verify", action="store_true", help="skip the simulation check")
    q.add_argument("--no-fd-probe", action="store_true",
                   help="skip the central-difference probe of the exact gradient's largest "
                   "entries at the start and at the optimum (reported as unchecked then)")
    _operating_args(q, DEFAULT_FREQUENCY_HZ, DEFAULT_FORCE_N)
    ui.add_params_args(q)
    q.add_argument("--no-progress", action="store_true",
                   help="no progress bars (they show only on a terminal anyway)")
    q.add_argument("--out", required=True, metavar="DIR", help="output folder")
    q.set_defaults(func=run_optimize)


def _operating_args(p, f0, p0):
    p.add_argument("--frequency", type=ui.finite_float, metavar="HZ",
                   help=f"operating frequency of the point orbit metrics (amplitude, floquet) "
                   f"[Hz] (default {f0:g}, the paper's exciter tests); frc_peak locates its "
                   "own peak frequency and the static metrics use none, so it is refused "
                   "for them")
    p.add_argument("--force", type=ui.finite_float, metavar="N",
                   help=f"force amplitude on the nut for orbit metrics [N] (default {p0:g})")


def _names(text):
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise ui.CLIError("--vary is empty; give vocabulary names such as nut.balls,nut.preload_n")
    return names


def _parse_bounds(text) -> dict:
    out = {}
    if not text:
        return out
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item or ":" not in item.split("=", 1)[1]:
            raise ui.CLIError(f"--bounds expects NAME=LO:HI, got '{item}'")
        name, rng = item.split("=", 1)
        lo, hi = rng.split(":", 1)
        try:
            lo, hi = float(lo), float(hi)
        except ValueError:
            raise ui.CLIError(f"--bounds {name}: '{rng}' is not LO:HI numbers") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ui.CLIError(f"--bounds {name}: '{rng}' must be finite numbers")
        out[name.strip()] = (lo, hi)
    return out


def _check_operating_point(args, metric) -> None:
    """--frequency only where the metric has an operating frequency; positive values."""
    if args.frequency is not None and args.metric not in ("amplitude", "floquet"):
        raise ui.CLIError(f"--frequency means nothing for --metric {args.metric} (frc_peak finds "
                       "its own peak; the other metrics are static): leave it out")
    for flag, value in (("--frequency", args.frequency), ("--force", args.force)):
        if value is not None and not value > 0:
            raise ui.CLIError(f"{flag} must be positive, got {value:g}")


def _design_error(exc):
    return ui.CLIError(str(exc))


def _check_line(check: dict) -> str:
    return f"gradient check: {check['summary']}"


def run_sensitivity(args) -> int:
    from .._programs import in_background
    from ..design import (
        DESIGN_PARAMETERS,
        compare_gradients,
        crosscheck_markdown,
        finite_difference_sensitivities,
        get_metric,
        paper_crosscheck,
        probe_gradient,
        sensitivities,
    )
    from ..design.building import check_design_inputs, gradient_not_checked, prefetch_programs

    params = ui.load_params_from_args(args)
    names = _names(args.vary) if args.vary else DESIGN_PARAMETERS
    metric = get_metric(args.metric)
    _check_operating_point(args, metric)
    try:  # every input checked before anything is computed
        check_design_inputs(metric.name, params, names, frequency_hz=args.frequency,
                            force_n=args.force)
    except ValueError as exc:
        raise _design_error(exc) from None
    out = ui.out_dir(args.out)
    t0 = time.perf_counter()
    try:
        # The gradient's program compiles beside the search; the probes take their values
        # from it, a full check (--check-fd) from the value program.
        prefetch_programs(metric.name, params, names, frequency_hz=args.frequency,
                          force_n=args.force, value=args.check_fd)
        # The figure's modules (matplotlib, 0.5 s) load there after them, not here first.
        in_background(lambda: importlib.import_module("bsfs_jax.plotting"))
        res = sensitivities(metric.name, params, names, frequency_hz=args.frequency,
                            force_n=args.force)
        t_ad = time.perf_counter() - t0
        fd = None
        if args.check_fd:
            fd = finite_difference_sensitivities(metric.name, params, names,
                                                 frequency_hz=args.frequency,
                                                 force_n=args.force)
            check = compare_gradients(res, fd)
        elif args.no_fd_probe:
            check = gradient_not_checked()
        else:
            check = probe_gradient(metric.name, params, res, frequency_hz=args.frequency,
                                   force_n=args.force)
    except (ValueError, FloatingPointError) as exc:
        raise _design_error(exc) from None
    data = res.to_dict()
    data["gradient_check"] = check
    data["description"] = metric.description
    data["direction"] = metric.direction
    data["wall_time_s"] = t_ad
    if fd is not None:
        import numpy as np

        denom = np.maximum(np.abs(fd.gradient), 1e-300)
        rel = np.abs(res.gradient - fd.gradient) / denom
        data["finite_difference"] = fd.to_dict()
        data["max_relative_difference_vs_fd"] = float(np.max(
            np.where(np.abs(fd.normalised) > 1e-6, rel, 0.0)))
    rows = paper_crosscheck({metric.name: res})
    data["paper_crosscheck"] = [{k: r[k] for k in ("parameter", "figure", "claim", "metric",
                                                   "expected", "normalised", "agrees")}
                                for r in rows]
    ui.write_json(out / "sensitivity.json", data)
    from ..plotting import tornado

    fig = tornado(res, compare=fd)
    ui.save_figure(fig, out / "sensitivity.png")
    md = [f"# Sensitivity of {metric.label}", "",
          f"{metric.description}.", "",
          f"Value: **{res.value:.6g} {res.unit}**"
          + (f" at {res.frequency_hz:g} Hz" if res.frequency_hz is not None else "")
          + (f", {res.force_n:g} N" if res.force_n is not None else "")
          + f". Gradients by {res.method} in {t_ad:.2f} s (including compilation).", "",
          res.table_markdown(), ""]
    if fd is not None:
        md += [f"Largest relative difference to {fd.method}: "
               f"{data['max_relative_difference_vs_fd']:.2e}.", ""]
    md += [f"Gradient check: {data['gradient_check']['summary']}", ""]
    md += ["## Comparison with the paper's trends", ""]
    if rows:
        md += [crosscheck_markdown(rows), "",
               "The paper's trends are one-at-a-time comparisons at a few levels and mostly "
               "at 5000 N in the strongly nonlinear regime; ours are local derivatives at "
               "this design and operating point. See notebooks/design_study.ipynb for the "
               "discussion of each difference."]
    else:
        md += [f"The paper states no trend for the metric '{metric.name}' and these "
               "parameters; run with --metric floquet, amplitude, frc_peak or "
               "natural_frequency for the comparison."]
    from ..files import write_text_atomic

    write_text_atomic(out / "sensitivity.md", "\n".join(md) + "\n")
    print(f"{metric.label}: {res.value:.6g} {res.unit}")
    print(res.table_markdown())
    print(_check_line(check))
    print(f"wrote {out / 'sensitivity.json'}, sensitivity.png, sensitivity.md")
    if check["passed"] is False:
        print("bsfs sensitivity: warning: the exact gradients failed their check (see "
              "gradient_check in sensitivity.json)", file=sys.stderr)
        return 3
    return 0


def run_optimize(args) -> int:
    from ..design import get_metric, optimize, verify_by_simulation
    from ..design.building import optimization_start
    from ..files import write_text_atomic
    from ..params import params_to_toml
    from ..plotting import optimization_summary

    params = ui.load_params_from_args(args)
    metric = get_metric(args.metric)
    _check_operating_point(args, metric)
    names = _names(args.vary)
    bounds = _parse_bounds(args.bounds)
    if args.min_stiffness is not None and not args.min_stiffness > 0:
        raise ui.CLIError(f"--min-stiffness must be positive, got {args.min_stiffness}")
    try:  # every input checked before anything is computed
        start = optimization_start(metric.name, params, names, bounds,
                                   frequency_hz=args.frequency, force_n=args.force)
    except ValueError as exc:
        raise _design_error(exc) from None
    ui.out_dir(args.out, create=False)
    t0 = time.perf_counter()
    try:
        from ..design import with_values

        start_params = with_values(params, start.names, start.theta)
        grad_start = _probe_point(args, metric, start_params, start.names, "start")
        res = optimize(metric.name, params, names, bounds,
                       min_stiffness_n_per_um=args.min_stiffness, frequency_hz=args.frequency,
                       force_n=args.force, max_steps=args.max_steps)
        grad_opt = _probe_point(args, metric, res.params, res.names, "optimum")
    except (ValueError, FloatingPointError) as exc:
        raise _design_error(exc) from None
    wall = time.perf_counter() - t0
    checks = None
    if not args.no_verify:
        checks = [verify_by_simulation(metric.name, p, frequency_hz=args.frequency,
                                       force_n=args.force)
                  for p in (start_params, res.params)]
    grad = _gradient_record(grad_start, grad_opt)
    out = ui.out_dir(args.out)
    data = res.to_dict()
    data["wall_time_s"] = wall
    data["gradient_check"] = grad
    data["simulation_check"] = checks
    ui.write_json(out / "optimize.json", data)
    write_text_atomic(out / "optimum.toml", params_to_toml(
        res.params, header=f"bsfs optimize --metric {metric.name}: optimum"))
    ui.save_figure(optimization_summary(res, checks=checks), out / "optimize.png")
    md = _optimize_markdown(res, metric, checks, grad)
    write_text_atomic(out / "optimize.md", "\n".join(md) + "\n")
    print("\n".join(md))
    print(f"wrote {out / 'optimize.json'}, optimize.md, optimize.png, optimum.toml")
    status = 0
    if res.min_stiffness_n_per_um and not res.constraint_satisfied:
        print("warning: the stiffness constraint is not satisfied at the returned point")
        status = 3
    if grad["passed"] is False:
        print("bsfs optimize: warning: the exact gradient DISAGREES with central differences "
              "at the optimum (see gradient_check in optimize.json)", file=sys.stderr)
        status = 3
    return status


def _probe_point(args, metric, params, names, where: str) -> dict:
    """The exact gradient of the metric at one design, probed by central differences on
    its largest entries (or the record that it was not checked). At the start point a
    disagreement refuses the optimisation: BFGS would follow a wrong gradient."""
    from ..design import check_gradient
    from ..design.building import gradient_not_checked

    if args.no_fd_probe:
        return gradient_not_checked()
    try:
        check = check_gradient(metric.name, params, names, frequency_hz=args.frequency,
                               force_n=args.force)
    except FloatingPointError as exc:  # e.g. a difference step beyond the allowed range
        return gradient_not_checked(f"at the {where}: {exc}")
    if where == "start" and not check["passed"]:
        raise ui.CLIError(f"the exact gradient of {metric.name} at the start point "
                       f"{check['summary'].split(';')[0]}: the optimiser would follow a wrong "
                       "gradient, so nothing was optimised (--no-fd-probe skips this check)")
    return check


def _gradient_record(start: dict, optimum: dict) -> dict:
    """optimize.json's gradient_check: both probes and one verdict (None: not checked)."""
    verdicts = (start["passed"], optimum["passed"])
    passed = False if False in verdicts else None if None in verdicts else True
    if start is optimum or start["summary"] == optimum["summary"]:
        summary = start["summary"]
    else:
        summary = f"start: {start['summary']}; optimum: {optimum['summary']}"
    return {"passed": passed, "summary": summary, "start": start, "optimum": optimum}


def _optimize_markdown(res, metric, checks, grad) -> list:
    md = [f"# Optimisation of {metric.label} ({metric.direction}imise)", "",
          f"Start {res.start_value:.6g} {res.unit} -> optimum {res.optimum_value:.6g} "
          f"{res.unit}: **{res.improvement_percent:+.2f} %** in the {metric.direction}imising "
          f"direction; {res.steps} BFGS steps, converged: {res.converged}.", "",
          "| variable | lower | start | optimum | upper | at bound |", "|---|---|---|---|---|---|"]
    for n, s, o in zip(res.names, res.start, res.optimum, strict=True):
        lo, hi = res.bounds[n]
        md.append(f"| `{n}` | {lo:.6g} | {s:.6g} | {o:.6g} | {hi:.6g} | "
                  f"{'yes' if n in res.at_bound else ''} |")
    md += ["", f"Static axial stiffness: {res.start_stiffness_n_per_um:.4g} -> "
           f"{res.optimum_stiffness_n_per_um:.4g} N/um"
           + (f" (required >= {res.min_stiffness_n_per_um:g}; satisfied: "
              f"{res.constraint_satisfied}; exterior quadratic penalty)"
              if res.min_stiffness_n_per_um else " (no constraint)") + "."]
    md += ["", f"Gradient check (exact gradient of {metric.name} vs central differences on its "
           f"largest entries): {grad['summary']}."]
    if checks:
        md += ["", "## Verification by time simulation", "",
               "| design | quantity | model | simulated | relative difference |",
               "|---|---|---|---|---|"]
        for label, c in zip(("start", "optimum"), checks, strict=True):
            if c["checked"]:
                md.append(f"| {label} | {c['quantity']} | {c['model']:.6g} | "
                          f"{c['simulated']:.6g} | {c['relative_difference']:.2e} |")
            else:
                md.append(f"| {label} | {c['quantity']} | - | - | - |")
    return md
