"""`bsfs identify` and `bsfs plan-test` (parameter identification, issue 4)."""

import sys
import time

from ._common import (
    CLIError,
    add_params_args,
    finite_float,
    load_params_from_args,
    out_dir,
    save_figure,
    write_json,
)


def register(sub) -> None:
    p = sub.add_parser(
        "identify", help="fit preloads, stiffness, damping and thermal offsets to exciter "
        "records",
        description="Fit model parameters to exciter records (stepped sines: force + "
        "worktable acceleration; chirp/random records; FRFs from UFF58 files) with "
        "Levenberg-Marquardt through JAX gradients, maximum a posteriori with stated priors "
        "by default. Says for each parameter whether the data determine it. Writes "
        "identified.toml, report.json, fit.png and correlation.png. With no records it runs "
        "on a bundled synthetic data set.")
    p.add_argument("records", nargs="*", metavar="RECORD",
                   help="record files (.csv with '# key = value' header, UFF58 .uff: time "
                   "records or FRFs)")
    p.add_argument("--data", choices=["paper-test", "stepped-sine", "preload-loss"],
                   default="paper-test",
                   help="bundled data set used when no RECORD is given (paper-test)")
    add_params_args(p)
    p.add_argument("--fit", metavar="NAME,...", default=None,
                   help="parameters to fit (default nut_k,bearing_k,screw_k,c_b,c_s,c_n,"
                   "expansion; also nut_preload,bearing_preload and d_n,d_b per speed)")
    p.add_argument("--prior", metavar="NAME=SIGMA,...", default=None,
                   help="prior standard deviations of the scaled parameters (log-value, or "
                   "um for offsets), replacing the defaults (0.5 stiffness/preload, 1.0 "
                   "damping, 0.3 expansion, 1 um offsets)")
    p.add_argument("--no-priors", action="store_true",
                   help="maximum likelihood: no priors (undetermined parameters are then "
                   "reported without an interval)")
    p.add_argument("--no-profile", action="store_true",
                   help="skip profile-likelihood intervals where the linearised ones are "
                   "doubtful")
    p.add_argument("--model", choices=["auto", "linear", "nonlinear"], default="auto",
                   help="steady-state model per sine record (auto: linear FRF at small "
                   "amplitude, shooting otherwise)")
    p.add_argument("--starts", type=int, default=3, help="multi-start count (3)")
    p.add_argument("--max-steps", type=int, default=100, help="LM iterations per start (100)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bars (they show only on a terminal anyway)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_identify)

    t = sub.add_parser("plan-test", help="compare exciter test plans by Fisher information",
                       description="Predict the standard errors of the chosen parameters "
                       "for candidate test plans and recommend one.")
    add_params_args(t)
    t.add_argument("--fit", metavar="NAME,...", default=None)
    t.add_argument("--noise-db", type=finite_float, default=35.0, metavar="DB",
                   help="accelerometer SNR (35 dB); force sensor +5 dB")
    t.add_argument("--out", required=True, metavar="DIR")
    t.set_defaults(func=run_plan)


def _fit_names(text):
    import identification as idn

    try:
        return idn.parse_fit(text)
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def run_identify(args) -> int:
    import identification as idn

    from ..plotting import correlation_figure, fit_figure

    prior = load_params_from_args(args)
    names = _fit_names(args.fit)
    for flag in ("starts", "max_steps"):
        if getattr(args, flag) < 1:
            raise CLIError(f"--{flag.replace('_', '-')} must be at least 1, got "
                           f"{getattr(args, flag)}")
    if args.no_priors and args.prior:
        raise CLIError("--prior and --no-priors contradict each other; give one")
    try:
        priors = None if args.no_priors else idn.parse_priors(args.prior, names)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    records = args.records or [str(p) for p in idn.bundled_records(args.data)]
    if not args.records:
        print(f"bsfs identify: no records named; using the bundled SYNTHETIC data set "
              f"'{args.data}' ({len(records)} records)", file=sys.stderr)
    out = out_dir(args.out)
    t0 = time.perf_counter()
    try:
        res = idn.identify(records, prior, names, model=args.model, starts=args.starts,
                           seed=args.seed, max_steps=args.max_steps, priors=priors,
                           profile=not args.no_profile)
    except (idn.RecordError, ValueError) as exc:
        raise CLIError(str(exc)) from None
    report = idn.report_dict(res)
    paths = idn.write_identified(res, out)
    write_json(out / "report.json", report)
    written = [*paths, out / "report.json"]
    sines = [(d, m, c) for d, m, c in zip(res.data, res.problem.models, res.model_harmonics())
             if m != "frf"]
    if sines:
        fig = fit_figure([d.record for d, _, _ in sines], [c for _, _, c in sines],
                         [d.frequency_hz for d, _, _ in sines], [m for _, m, _ in sines])
        save_figure(fig, out / "fit.png")
        written.append(out / "fit.png")
    frfs = [(d, c) for d, m, c in zip(res.data, res.problem.models, res.model_harmonics())
            if m == "frf"]
    if frfs:
        from ..plotting import frf_fit_figure

        fig = frf_fit_figure([d.frequency_hz for d, _ in frfs], [d.accelerance for d, _ in frfs],
                             [c for _, c in frfs], [d.variance for d, _ in frfs],
                             [d.name for d, _ in frfs])
        save_figure(fig, out / "frf_fit.png")
        written.append(out / "frf_fit.png")
    u = res.uncertainty
    fig2 = correlation_figure(res.problem.names, u.correlation, u.singular_values,
                              u.direction_std, 0.1)
    save_figure(fig2, out / "correlation.png")
    written.append(out / "correlation.png")
    import matplotlib.pyplot as plt

    plt.close("all")
    print(report["summary"])
    print(f"\nwrote {', '.join(str(p) for p in written)} ({time.perf_counter() - t0:.1f} s)")
    return 0 if res.fit.converged else 4


def run_plan(args) -> int:
    import identification as idn

    from ..plotting import plan_figure

    prior = load_params_from_args(args)
    names = _fit_names(args.fit)
    out = out_dir(args.out)
    try:
        result = idn.plan_test(prior, names, accel_snr_db=args.noise_db,
                               force_snr_db=args.noise_db + 5.0)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    write_json(out / "plan.json", result)
    params = result["parameters"]
    fig = plan_figure([r["name"] for r in result["plans"]], params,
                      [[r["expected_std"][p] for p in params] for r in result["plans"]],
                      threshold=result["threshold"], recommended=result["recommended"])
    save_figure(fig, out / "plan.png")
    print(f"Expected standard errors (relative; um for offsets) at {args.noise_db:g} dB:")
    print(f"{'plan':<40}{'records':>8}{'time s':>8}  " + " ".join(f"{p:>10}" for p in params))
    for r in result["plans"]:
        print(f"{r['name']:<40}{r['records']:>8}{r['test_time_s']:>8.1f}  "
              + " ".join(f"{r['expected_std'][p]:>10.2g}" for p in params))
    verdict = ("identifies every chosen parameter" if result["all_identified"]
               else "is the best available but leaves some parameters undetermined")
    print(f"\nRecommended: {result['recommended']} ({verdict}).")
    print(f"wrote {out / 'plan.json'}, {out / 'plan.png'}")
    return 0
