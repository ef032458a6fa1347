"""`bsfs predict`: what an identified drive will do, with 95 % intervals."""

from . import _cluster_opts
from . import _common as ui


def register(sub) -> None:
    p = sub.add_parser(
        "predict", help="forecast an identified drive: resonance, FRC peak and folds, "
        "lift-off force, preload health, with 95 %% intervals",
        description="Read a `bsfs identify --out` folder and carry the fit's covariance "
        "through the model: first natural frequency, damping ratio and static stiffness; "
        "the FRC's peak and folds at --force (continued branch, exact implicit gradients, "
        "delta method checked at second order; where it is doubtful, the quadratic model over "
        "the posterior draws of `bsfs identify --posterior` or the bootstrap refits of "
        "`bsfs identify --refits` when the folder has them); the lift-off force "
        "(on the nonlinear orbit at the FRC peak); "
        "preloads retained against the nominal drive; a health verdict per joint. Writes "
        "prediction.json and prediction.png.")
    p.add_argument("--from", dest="source", required=True, metavar="DIR",
                   help="an identification's output folder (identified.toml, report.json)")
    p.add_argument("--force", type=ui.finite_float, default=100.0, metavar="N",
                   help="working force amplitude [N] (default 100)")
    p.add_argument("--start", type=ui.finite_float, metavar="HZ",
                   help="band start [Hz] (default 0.8 x the identified f1)")
    p.add_argument("--stop", type=ui.finite_float, metavar="HZ",
                   help="band stop [Hz] (default 1.2 x f1)")
    p.add_argument("--speed", type=ui.finite_float, metavar="RPM",
                   help="screw speed [r/min] (default: the identification's)")
    p.add_argument("--nominal", metavar="TOML",
                   help="the nominal drive (default: the default preset)")
    _cluster_opts.add_args(p, "the model at the identification's draws (its refits or "
                           "posterior draws), in batches")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run_predict)


def run_predict(args) -> int:
    import bsfs_jax
    from identification import ForecastError, forecast, load_identified

    from ..plotting import forecast_figure

    ui.out_dir(args.out, create=False)
    try:
        ident = load_identified(args.source, args.speed)
        nominal = bsfs_jax.load_params(args.nominal) if args.nominal else None
    except ForecastError as exc:
        raise ui.CLIError(str(exc)) from None
    if ident.draws is None and _cluster_opts.explicit(args):
        raise ui.CLIError(f"--scheduler/--workers run the model at the identification's "
                          f"draws, and {args.source} has none ({ident.draws_note}); run "
                          "`bsfs identify --refits N` first, or drop the option")
    with _cluster_opts.cluster_from_args(args, "predict",
                                         enabled=ident.draws is not None) as cluster:
        try:
            fc = forecast(ident, args.force, start_hz=args.start, stop_hz=args.stop,
                          nominal=nominal, cluster=cluster)
        except ForecastError as exc:
            raise ui.CLIError(str(exc)) from None
        on_cluster = _cluster_report(cluster)
    result = fc.to_dict()
    quantities = result["quantities"]
    by_name = {q["name"]: q for q in quantities}
    data = dict(
        source=str(args.source), force_n=result["force_n"], band_hz=result["band_hz"],
        speed_rpm=float(ident.params.get("thermal.speed_rpm")),
        fitted=list(ident.names), quantities=quantities,
        per_joint_liftoff=result["per_joint_liftoff"], health=result["health"],
        draws=ident.draws_note,
        note="95 % intervals from the identification's covariance: delta method through "
             "exact implicit gradients, checked at second order (exact Hessian; for the FRC "
             "quantities, the linear model's error over the saved draws, else probes along "
             "the covariance's least determined directions). Where the second-order std "
             "exceeds 10 % of the linear one, the 2.5-97.5 % range over draws: of the "
             "model itself at each saved draw (the modal quantities, the FRC's peak and "
             "folds, the first joint's lift-off force), else of the quadratic model (the "
             "posterior draws, else the bootstrap refits, else Gaussian draws from the "
             "covariance; 'draws' says which were saved, each quantity's method which was "
             "used). dominated_by names the fitted parameter whose own variance "
             "contributes most")
    if on_cluster is not None:
        data["cluster"] = on_cluster
    out = ui.out_dir(args.out)
    ui.write_json(out / "prediction.json", data)
    fig = forecast_figure(fc.curves, fc.nominal_branch, by_name, fc.force_n)
    ui.save_figure(fig, out / "prediction.png")
    print(_table(quantities))
    for h in fc["health"].values():
        print(h["line"])
    print(f"wrote {out / 'prediction.json'}, {out / 'prediction.png'}")
    return 0


def _cluster_report(cluster) -> dict | None:
    """prediction.json's "cluster" (None without one): `_cluster_opts.report`'s account;
    a batch that failed on every attempt there was computed in this process instead."""
    if cluster is None:
        return None
    out = _cluster_opts.account(cluster)
    for f in out["failed_chunks"]:
        f["note"] = "computed in this process instead"
        print(f"bsfs predict: warning: a batch of draws failed {f['attempts']} times on the "
              f"cluster ({f['cause']}); computed here instead", flush=True)
    return out


def _fmt(x):
    return "-" if x is None else f"{x:.5g}"


def _table(quantities) -> str:
    rows = [f"{'quantity':28s} {'value':>10s}  {'95 % interval':>23s}  method / dominated by"]
    for q in quantities:
        ci = q["ci95"]
        ci_text = "-" if ci is None else f"{_fmt(ci[0])} - {_fmt(ci[1])}"
        tail = q.get("reason") or f"{q['method']}; {q['dominated_by'] or '-'}"
        rows.append(f"{q['name'] + ' [' + q['unit'] + ']':28s} {_fmt(q['value']):>10s}  "
                    f"{ci_text:>23s}  {tail}")
    return "\n".join(rows)
