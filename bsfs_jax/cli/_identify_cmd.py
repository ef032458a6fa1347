"""`bsfs identify` and `bsfs plan-test`: parameter identification from exciter records."""

import importlib
import sys
import time

from . import _cluster_opts
from . import _common as ui


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
    p.add_argument("--data", choices=["paper-test", "stepped-sine", "preload-loss", "resonance"],
                   default="paper-test",
                   help="bundled data set used when no RECORD is given (paper-test)")
    ui.add_params_args(p)
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
    p.add_argument("--profile", choices=["auto", "on", "off"], default="auto",
                   help="profile-likelihood intervals where the linearised ones are doubtful "
                   "(auto: when every record uses a linear model; with periodic-orbit "
                   "records each profile point re-fits the orbits)")
    p.add_argument("--compare", metavar="DIR",
                   help="an earlier `bsfs identify --out DIR`: draw compare.png, the two "
                   "identifications side by side")
    p.add_argument("--model", choices=["auto", "linear", "first-order", "nonlinear"],
                   default="auto",
                   help="steady-state model per sine record (auto: the linear FRF where its "
                   "predicted error is below 0.1 standard errors, else the first-order "
                   "harmonic-balance correction where that is, else the periodic orbit)")
    p.add_argument("--max-lines", type=ui.count(0, 10_000_000), default=None, metavar="N",
                   help="fit an FRF of more lines on runs of adjacent lines merged to at "
                   "most N (inverse-variance means; default 32768; 0: every line)")
    p.add_argument("--starts", type=ui.count(1, 100), default=3, help="multi-start count (3)")
    p.add_argument("--max-steps", type=ui.count(1, 100_000), default=100,
                   help="LM iterations per start (100)")
    p.add_argument("--seed", type=ui.count(0, 2**32 - 1), default=0)
    p.add_argument("--posterior", type=ui.count(0, 100_000), default=0, metavar="DRAWS",
                   help="also sample the posterior by NUTS (blackjax), DRAWS per chain "
                   "after as many warm-up steps, 4 chains; report.json's 'posterior' with "
                   "R-hat and effective sample sizes (needs priors and no periodic-orbit records; "
                   "0: off)")
    p.add_argument("--refits", type=_refits_count, default="auto", metavar="N|auto",
                   help="randomised-maximum-likelihood refits saved for `bsfs predict` "
                   "(refits.npz: data and prior perturbed at their stated errors, refitted "
                   "from the estimate; the forecast's draws where its delta method is "
                   "doubtful). auto: 200 where at most 5 parameters are fitted and no record "
                   "needs the periodic-orbit model (about 2 s), else none; 0: none")
    _cluster_opts.add_args(p, "the refits, in batches of 32")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bars (they show only on a terminal anyway)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_identify)

    t = sub.add_parser("plan-test", help="compare exciter test plans by Fisher information",
                       description="Predict the standard errors of the chosen parameters "
                       "for candidate test plans and recommend one.")
    ui.add_params_args(t)
    t.add_argument("--fit", metavar="NAME,...", default=None)
    t.add_argument("--noise-db", type=ui.snr_db, default=35.0, metavar="DB",
                   help="accelerometer SNR (35 dB); force sensor +5 dB")
    t.add_argument("--all-plans", action="store_true",
                   help="also a plan with 3000 N records (its Fisher information needs the "
                   "periodic-orbit model: about a minute more)")
    t.add_argument("--no-resonance", action="store_true",
                   help="leave out the through-resonance plan (100 N sines within +-10 %% of "
                   "the prior's first resonance; its Fisher information needs the "
                   "periodic-orbit model)")
    t.add_argument("--out", required=True, metavar="DIR")
    t.set_defaults(func=run_plan)


def _refits_count(text: str):
    if text.strip().lower() == "auto":
        return "auto"
    return ui.count(0, 100_000)(text)


def _fit_names(text):
    import identification as idn

    try:
        return idn.parse_fit(text)
    except ValueError as exc:
        raise ui.CLIError(str(exc)) from None


def run_identify(args) -> int:
    import identification as idn

    prior = ui.load_params_from_args(args)
    names = _fit_names(args.fit)
    if args.no_priors and args.prior:
        raise ui.CLIError("--prior and --no-priors contradict each other; give one")
    if 0 < args.posterior < idn.MIN_DRAWS:
        raise ui.CLIError(f"--posterior: give at least {idn.MIN_DRAWS} draws per chain (or 0 "
                       "for none)")
    if args.posterior and args.no_priors:
        raise ui.CLIError("--posterior needs priors (without them an undetermined parameter "
                       "has an improper posterior); drop --no-priors")
    try:
        priors = None if args.no_priors else idn.parse_priors(args.prior, names)
    except ValueError as exc:
        raise ui.CLIError(str(exc)) from None
    if args.refits == 0 and _cluster_opts.explicit(args):
        raise ui.CLIError("--scheduler/--workers run identify's bootstrap refits, and "
                          "--refits 0 asks for none; drop one of them")
    earlier = _read_report(args.compare) if args.compare else None
    # a cluster is opened before the output folder is made: an unreachable one leaves none
    with _cluster_opts.cluster_from_args(args, "identify", enabled=args.refits != 0) as cl:
        return _identify(args, prior, names, priors, earlier, cl)


def _identify(args, prior, names, priors, earlier, cluster) -> int:
    import identification as idn

    records = args.records or [str(p) for p in idn.bundled_records(args.data)]
    if not args.records:
        print(f"bsfs identify: no records named; using the bundled SYNTHETIC data set "
              f"'{args.data}' ({len(records)} records)", file=sys.stderr)
    out = ui.out_dir(args.out)
    t0 = time.perf_counter()
    # The figures' modules (matplotlib) load on the background thread while the fit's
    # programs run, after the compilations the identification queues there: about 0.4 s
    # of a warm run otherwise spent on the main thread before the fit.
    from .._programs import in_background

    def load_figure_modules(_problem):
        in_background(lambda: importlib.import_module("bsfs_jax.plotting"))

    try:
        res = idn.identify(records, prior, names, model=args.model, starts=args.starts,
                           seed=args.seed, max_steps=args.max_steps, priors=priors,
                           profile={"auto": "auto", "on": True, "off": False}[args.profile],
                           on_models=load_figure_modules,
                           max_lines=idn.MAX_LINES if args.max_lines is None else args.max_lines,
                           say=(lambda text: ui.say(f"identify: {text}"))
                           if ui.progress_wanted(args) else None)
    except (idn.RecordError, ValueError) as exc:
        raise ui.CLIError(str(exc)) from None
    report = idn.report_dict(res)
    post = _posterior(res, args) if args.posterior else None
    if post is not None:
        report["posterior"] = post.as_dict()
        report["summary"] += "\n" + idn.posterior_text(report["posterior"], report)
    refits = _refits(res, args, cluster)
    if refits is not None:
        report["refits"] = refits.as_dict()
        if cluster is not None:
            report["refits"]["cluster"] = _cluster_opts.account(cluster)
            for f in refits.failed:
                print(f"bsfs identify: warning: a batch of {f['refits']} refits failed on "
                      f"the cluster ({f['cause']}); counted as not converged", flush=True)
        report["summary"] += "\n" + _refits_line(refits)
    paths = idn.write_identified(res, out)
    ui.write_json(out / "report.json", report)
    written = [*paths, out / "report.json"]
    import numpy as np

    from ..files import save_npz_atomic

    # The draws themselves, for `bsfs predict`, each with the estimate they belong to.
    estimate = np.asarray(res.fit.values, float)
    if post is not None:
        written.append(save_npz_atomic(out / "posterior.npz", names=np.asarray(post.names),
                                       samples=post.samples, estimate=estimate))
    if refits is not None:
        written.append(idn.save_refits(refits, out, estimate))
    from ..plotting import correlation_figure, fit_figure

    sines = [(d, m, c) for d, m, c in zip(res.data, res.model_labels(), res.model_harmonics())
             if m != "frf"]
    if sines:
        fig = fit_figure([d.record for d, _, _ in sines], [c for _, _, c in sines],
                         [d.frequency_hz for d, _, _ in sines], [m for _, m, _ in sines])
        ui.save_figure(fig, out / "fit.png", tight=False)
        written.append(out / "fit.png")
    frfs = [(d, c) for d, m, c in zip(res.data, res.problem.models, res.model_harmonics())
            if m == "frf"]
    if frfs:
        from ..plotting import frf_fit_figure

        fig = frf_fit_figure([d.frequency_hz for d, _ in frfs], [d.accelerance for d, _ in frfs],
                             [c for _, c in frfs], [d.variance for d, _ in frfs],
                             [d.name for d, _ in frfs])
        ui.save_figure(fig, out / "frf_fit.png", tight=False)
        written.append(out / "frf_fit.png")
    if earlier is not None:
        written.append(_compare(earlier, report, out))
    u = res.uncertainty
    fig2 = correlation_figure(res.problem.names, u.correlation, u.singular_values,
                              u.direction_std, 0.1)
    ui.save_figure(fig2, out / "correlation.png", tight=False)
    written.append(out / "correlation.png")
    import matplotlib.pyplot as plt

    plt.close("all")
    print(report["summary"])
    print(f"\nwrote {', '.join(str(p) for p in written)} ({time.perf_counter() - t0:.1f} s)")
    return 0 if res.fit.converged else 4


def _refits(res, args, cluster=None):
    """The refits `--refits` asks for (`identification.refits_for`), with a progress bar;
    on `cluster`'s workers where one is open."""
    from tqdm.auto import tqdm

    import identification as idn

    bar_on = ui.progress_enabled(args)
    lines = ui.Progress("identify: bootstrap refits", ui.progress_wanted(args) and not bar_on)
    with tqdm(desc="refits", unit="fit", disable=not bar_on) as bar:
        def on_batch(done, n):
            bar.total = n
            bar.update(done - bar.n)
            lines(done, n)

        return idn.refits_for(res, args.refits, seed=args.seed, on_batch=on_batch,
                              runner=None if cluster is None else cluster.run)


def _refits_line(refits) -> str:
    use = ("saved for `bsfs predict` (refits.npz)" if refits.usable else
           f"fewer than {refits.as_dict()['min_converged']:.0%} converged: not used by "
           "`bsfs predict`")
    return (f"Bootstrap refits: {refits.converged} of {refits.requested} converged "
            f"({refits.seconds:.1f} s), {use}.")


def _posterior(res, args):
    import identification as idn

    try:
        return idn.posterior(res.fit, res.uncertainty, samples=args.posterior,
                             warmup=args.posterior, chains=4, seed=args.seed)
    except ValueError as exc:
        raise ui.CLIError(f"--posterior: {exc}") from None


def _read_report(other_dir):
    import json
    from pathlib import Path

    path = Path(other_dir) / "report.json"
    try:
        other = json.loads(path.read_text())
        _title(other)
        return other
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ui.CLIError(f"--compare: cannot read '{path}' as a `bsfs identify` report "
                       f"({exc.__class__.__name__}); give the --out folder of an earlier "
                       "identify run") from None


def _compare(other, report, out):
    from ..plotting import identification_comparison_figure

    panels = [(_title(other), other["parameters"]), (_title(report), report["parameters"])]
    ui.save_figure(identification_comparison_figure(panels), out / "compare.png")
    return out / "compare.png"


def _title(report) -> str:
    recs = report.get("records", [])
    kinds = sorted({r.get("excitation", "sine") for r in recs})
    n_det = sum(bool(p["identified"]) for p in report["parameters"].values())
    return (f"{len(recs)} record(s) ({', '.join(kinds)}): {n_det} of "
            f"{len(report['parameters'])} parameters determined")


def run_plan(args) -> int:
    import identification as idn

    from ..plotting import plan_figure

    prior = ui.load_params_from_args(args)
    names = _fit_names(args.fit)
    out = ui.out_dir(args.out)
    try:
        f1 = None
        if not args.no_resonance:
            import equinox as eqx

            from .. import build_system, modes

            # One compiled program (eagerly the equilibrium's Newton and the eigenproblem
            # were about 40 small ones).
            first = eqx.filter_jit(lambda p: modes(build_system(p), throw=False))
            f1 = float(first(prior.replace("thermal.speed_rpm", 2000.0)).frequencies_hz[0])
            if not f1 > 0:
                raise ValueError("the prior's first natural frequency could not be computed "
                                 "(its static equilibrium failed); use --no-resonance")
        result = idn.plan_test(prior, names, idn.candidate_plans(args.all_plans, f1),
                               accel_snr_db=args.noise_db, force_snr_db=args.noise_db + 5.0)
    except ValueError as exc:
        raise ui.CLIError(str(exc)) from None
    ui.write_json(out / "plan.json", result)
    params = result["parameters"]
    fig = plan_figure([r["name"] for r in result["plans"]], params,
                      [[r["expected_std"][p] for p in params] for r in result["plans"]],
                      threshold=result["threshold"], recommended=result["recommended"])
    ui.save_figure(fig, out / "plan.png")
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
