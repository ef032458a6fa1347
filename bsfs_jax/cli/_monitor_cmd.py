"""`bsfs monitor`: a drive's test history to trends, change points and time to a limit."""

from . import _common as ui


def register(sub) -> None:
    m = sub.add_parser(
        "monitor", help="trend a drive's test history: change points, time to a limit "
        "with a 95 %% interval, status and action per joint",
        description="Read a history (a CSV with a first column 'hours', one column per "
        "quantity and optional NAME_std columns; or a manifest CSV 'folder,hours' of "
        "`bsfs identify --out` folders, each identified parameter and `bsfs predict` "
        "quantity a series with its standard error) and report per quantity: the baseline "
        "(first test after the last change point), the change from it with 95 %% "
        "intervals, a linear, exponential or Wiener trend chosen by AICc with its 95 %% "
        "prediction band, change points, the hours to each --limit as a 95 %% interval, "
        "the probability of reaching it by --next-test, a status and an action per joint. "
        "Writes monitor.json, monitor.png and monitor.html.")
    m.add_argument("file", nargs="?", metavar="CSV",
                   help="a history CSV or a manifest CSV, told apart by the header's first "
                   "column ('hours' or 'folder')")
    src = m.add_mutually_exclusive_group()
    src.add_argument("--history", metavar="CSV", help="a history CSV (hours, NAME, NAME_std)")
    src.add_argument("--manifest", metavar="CSV",
                     help="a manifest CSV 'folder,hours' of `bsfs identify` output folders")
    m.add_argument("--limit", action="append", default=[], metavar="NAME=VALUE|NAME=P%",
                   help="alarm limit, in the quantity's unit or as P %% of the baseline "
                   "(repeatable)")
    m.add_argument("--warn", action="append", default=[], metavar="NAME=VALUE|NAME=P%",
                   help="warning level, as --limit (repeatable)")
    m.add_argument("--next-test", type=ui.finite_float, metavar="HOURS",
                   help="operating hours of the next planned test (default: one median "
                   "interval after the last)")
    m.add_argument("--out", required=True, metavar="DIR", help="output folder")
    m.set_defaults(func=run_monitor)


def _source(args) -> tuple[str, str]:
    """(kind, path) of the history: --history, --manifest, or the positional file by its
    header's first column."""
    given = [x for x in (args.file, args.history, args.manifest) if x]
    if len(given) != 1:
        raise ui.CLIError("give one history: a CSV file (history or manifest), "
                          "or --history CSV, or --manifest CSV")
    if args.history or args.manifest:
        return ("history", args.history) if args.history else ("manifest", args.manifest)
    try:
        with open(args.file, encoding="utf-8-sig") as fh:
            first = fh.readline()
    except OSError as exc:
        raise ui.CLIError(f"'{args.file}': cannot read ({exc.strerror}); check the path") from None
    head = first.replace(";", ",").split(",")[0].strip().strip('"').lower()
    return ("manifest", args.file) if head == "folder" else ("history", args.file)


def run_monitor(args) -> int:
    from .. import monitoring as mon

    kind, path = _source(args)
    ui.out_dir(args.out, create=False)
    try:
        history = (mon.read_history_csv(path) if kind == "history"
                   else mon.read_manifest(path))
        limits = dict(mon.parse_level(x) for x in args.limit)
        warns = dict(mon.parse_level(x) for x in args.warn)
        ui.say(f"monitor: {len(history.hours)} tests, {len(history.series)} quantities "
               f"({', '.join(history.series)})")
        result = mon.monitor(history, limits, warns, args.next_test)
    except mon.HistoryError as exc:
        raise ui.CLIError(str(exc)) from None
    out = ui.out_dir(args.out)
    paths = mon.write_monitor(result, out)
    for q in result.quantities.values():
        ttl = q.time_to_limit_h
        span = "" if ttl is None else (f"; limit {q.limit:.4g} at {ttl.estimate:.5g} h "
                                       f"[{ttl.lower:.5g}, {ttl.upper:.5g}], "
                                       f"P(by {ttl.next_test_h:g} h) = "
                                       f"{100 * ttl.p_before_next:.1f} %")
        cps = (f"change points at {', '.join(f'{c:g}' for c in q.change_points_h)} h"
               if q.change_points_h else "no change point")
        print(f"{q.name} [{q.unit or '-'}]: {q.status}; {q.model or 'no'} trend; {cps}{span}")
    for a in result.actions.values():
        print(a)
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0
