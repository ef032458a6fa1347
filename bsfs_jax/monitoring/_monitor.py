"""Monitoring one history: baseline, change, trend, change points, time to a limit,
status and an action per joint."""

import dataclasses
import math

import numpy as np

from ._history import History, HistoryError
from ._passage import DRAWS, crossing_draws
from ._steps import change_points
from ._trends import Fit, fit_models

_Z = 1.959964


@dataclasses.dataclass(frozen=True)
class Level:
    """A limit or warning level: `value` in the quantity's unit, or `percent` of the
    baseline (then `value` is filled in once the baseline is known)."""

    value: float | None = None
    percent: float | None = None

    def resolve(self, baseline: float) -> float:
        return self.value if self.percent is None else baseline * self.percent / 100.0

    def to_dict(self) -> dict:
        return dict(value=self.value, percent=self.percent)


def parse_level(text: str) -> tuple[str, Level]:
    """'NAME=VALUE' or 'NAME=P%' -> (NAME, Level); HistoryError (one line) otherwise."""
    if "=" not in text:
        raise HistoryError(f"expected NAME=VALUE or NAME=P%, got '{text[:60]}'")
    name, val = (s.strip() for s in text.split("=", 1))
    pct = val.endswith("%")
    try:
        x = float(val[:-1] if pct else val)
    except ValueError:
        raise HistoryError(f"'{name}': '{val[:40]}' is not a number or a percentage") from None
    if not math.isfinite(x) or not name:
        raise HistoryError(f"expected NAME=VALUE or NAME=P% with a finite number, got "
                           f"'{text[:60]}'")
    if pct and not x > 0:
        raise HistoryError(f"'{name}': a percentage of the baseline must be positive, "
                           f"got {val}")
    return name, (Level(percent=x) if pct else Level(value=x))


@dataclasses.dataclass(frozen=True)
class TimeToLimit:
    """Operating hours [h] at which the trend reaches the limit: the estimate and its 95 %
    interval (upper may be inf: the interval is open), and P(reaching it by the next
    test)."""

    estimate: float
    lower: float
    upper: float
    p_before_next: float
    next_test_h: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class QuantityResult:
    """Everything monitored of one quantity (hours in h, values in `unit`)."""

    name: str
    unit: str
    hours: list
    values: list
    std: list | None
    baseline: dict
    changes: list
    change_points_h: list
    model: str | None
    models: dict
    trend: dict | None
    limit: float | None
    warn: float | None
    falling: bool | None
    time_to_limit_h: TimeToLimit | None
    status: str
    action: str

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["time_to_limit_h"] = None if self.time_to_limit_h is None else \
            self.time_to_limit_h.to_dict()
        return d


@dataclasses.dataclass(frozen=True)
class MonitorResult:
    """`quantities` by name; `actions`: one line per joint (nut, bearing) or quantity."""

    source: str
    hours: list
    next_test_h: float
    quantities: dict
    actions: dict

    def to_dict(self) -> dict:
        return dict(source=self.source, hours=self.hours, next_test_h=self.next_test_h,
                    quantities={k: q.to_dict() for k, q in self.quantities.items()},
                    actions=self.actions,
                    method="baseline = first test after the last change point; change with "
                           "a 95 % interval from both tests' standard errors (and the "
                           "between-test scatter); trends (linear, exponential, Wiener with "
                           "drift) weighted by each test's variance plus the scatter "
                           "(Paule-Mandel), compared by AICc on the increments; steps by "
                           "a likelihood-ratio (F) scan calibrated by simulation; time to "
                           "limit from 4000 draws of the trends' parameters (multivariate "
                           "t; the models mixed by Akaike weight) and, for a Wiener trend, "
                           "of its diffusion, scatter and drift (restricted-likelihood "
                           "posterior, flat priors) and of the first passage")


def _select(fits: dict) -> Fit | None:
    return min(fits.values(), key=lambda f: f.aicc) if fits else None


def _joint(name: str) -> str | None:
    low = name.lower()
    for j in ("nut", "bearing"):
        if low.startswith(j) or f"{j}." in low or f"{j}_" in low:
            return j
    return None


def monitor_quantity(hours, series, limit: Level | None = None, warn: Level | None = None,
                     next_test_h: float | None = None, rng=None) -> QuantityResult:
    """Monitor one `Series` over `hours` (n,). `next_test_h`: hours of the next test
    (default: one median interval after the last)."""
    t = np.asarray(hours, float)
    y = np.asarray(series.values, float)
    base = np.zeros_like(y) if series.std is None else np.asarray(series.std, float) ** 2
    nxt = float(next_test_h) if next_test_h is not None else float(t[-1] + np.median(
        np.diff(t)))
    cps = change_points(t, y, base)
    start = cps[-1] if cps else 0
    ts, ys, bs = t[start:], y[start:], base[start:]
    fits = fit_models(ts, ys, bs) if len(ts) >= 3 else {}
    fit = _select(fits)
    scatter = fit.scatter if fit is not None and fit.kind != "wiener" else 0.0
    y0, v0 = float(ys[0]), float(bs[0])
    changes = []
    for i in range(len(t)):
        ref = max((c for c in cps if c <= i), default=0)
        d = float(y[i] - y[ref])
        sd = 0.0 if i == ref else math.sqrt(base[i] + base[ref] + 2 * scatter)
        changes.append(dict(hours=float(t[i]), change=d,
                            relative=d / y[ref] if y[ref] != 0 else None,
                            ci95=[d - _Z * sd, d + _Z * sd]))
    lim = None if limit is None else limit.resolve(y0)
    wrn = None if warn is None else warn.resolve(y0)
    falling = None if lim is None else bool(lim < y0)
    ttl = None
    trend = None
    if fit is not None:
        grid = np.linspace(ts[0], max(nxt, t[-1]) + 0.5 * (t[-1] - ts[0]), 80)
        m, lo, hi = fit.band(grid)
        aic = np.array([f.aicc for f in fits.values()])
        w = np.exp(-0.5 * (aic - aic.min()))
        w = w / w.sum()
        trend = dict(kind=fit.kind, params=fit.params.tolist(), cov=fit.cov.tolist(),
                     scatter=fit.scatter, dof=fit.dof, t0_h=fit.t0,
                     hours=grid.tolist(), mean=m.tolist(), band95=[lo.tolist(), hi.tolist()],
                     aicc={k: f.aicc for k, f in fits.items()},
                     weights=dict(zip(fits, w.tolist())),
                     rate_per_h=float(fit.params[1]) if fit.kind != "exponential" else None,
                     rate_relative_per_h=float(fit.params[1]) if fit.kind == "exponential"
                     else None)
    if fit is not None and lim is not None:
        # Model uncertainty too: each model's draws in proportion to its Akaike weight.
        gen = np.random.default_rng(1) if rng is None else rng
        weights = trend["weights"]
        dr = np.concatenate([crossing_draws(f, lim, falling, gen,
                                            int(round(weights[k] * DRAWS)))
                             for k, f in fits.items() if round(weights[k] * DRAWS) > 0])
        lo_t, mid, hi_t = np.quantile(dr, [0.025, 0.5, 0.975], method="inverted_cdf")
        ttl = TimeToLimit(float(mid), float(lo_t), float(hi_t), float(np.mean(dr <= nxt)),
                          nxt)
    status = "ok"
    last = float(y[-1])
    beyond = (lambda level: level is not None and (last <= level if falling else last >= level)
              if falling is not None else False)
    if lim is not None and (beyond(lim) or (ttl is not None and ttl.p_before_next >= 0.5)):
        status = "alarm"
    elif (wrn is not None and beyond(wrn)) or (ttl is not None and ttl.p_before_next >= 0.05):
        status = "warning"
    action = _action(series.name, status, ttl, lim, series.unit)
    return QuantityResult(
        name=series.name, unit=series.unit, hours=t.tolist(), values=y.tolist(),
        std=None if series.std is None else np.asarray(series.std).tolist(),
        baseline=dict(hours=float(ts[0]), value=y0, std=math.sqrt(v0) if v0 > 0 else None),
        changes=changes, change_points_h=[float(t[c]) for c in cps],
        model=None if fit is None else fit.kind, models={k: f.aicc for k, f in fits.items()},
        trend=trend, limit=lim, warn=wrn, falling=falling, time_to_limit_h=ttl,
        status=status, action=action)


def _action(name: str, status: str, ttl: TimeToLimit | None, lim, unit: str) -> str:
    joint = _joint(name)
    fix = {"nut": "re-preload the nut", "bearing": "re-preload (or replace) the support "
           "bearings"}.get(joint, f"service what '{name}' measures")
    if lim is None:
        return f"{name}: no limit set; trend only"
    if status == "alarm":
        return f"{name}: at or near its limit {lim:.4g} {unit}: {fix} now"
    if ttl is None or not math.isfinite(ttl.lower):
        return f"{name}: no crossing of {lim:.4g} {unit} foreseen; keep testing"
    when = f"~{ttl.lower:.0f} h (95 % lower bound; expected {ttl.estimate:.0f} h)"
    head = "warning: " if status == "warning" else ""
    return f"{name}: {head}{fix} before {when}"


def monitor(history: History, limits: dict | None = None, warns: dict | None = None,
            next_test_h: float | None = None) -> MonitorResult:
    """Monitor every quantity of `history`. `limits`, `warns`: {name: Level}; a name not in
    the history is a HistoryError. `next_test_h`: hours of the next test (> the last)."""
    limits, warns = dict(limits or {}), dict(warns or {})
    for what, levels in (("--limit", limits), ("--warn", warns)):
        for n in levels:
            if n not in history.series:
                raise HistoryError(f"{what} {n}: no such quantity (the history has "
                                   f"{', '.join(history.series)})")
    t = np.asarray(history.hours, float)
    if next_test_h is not None and not next_test_h > t[-1]:
        raise HistoryError(f"--next-test {next_test_h:g} h must be after the last test "
                           f"({t[-1]:g} h)")
    nxt = float(next_test_h) if next_test_h is not None else float(t[-1] + np.median(
        np.diff(t)))
    out = {n: monitor_quantity(t, s, limits.get(n), warns.get(n), nxt)
           for n, s in history.series.items()}
    actions = {}
    rank = {"alarm": 2, "warning": 1, "ok": 0}
    for q in out.values():
        key = _joint(q.name) or q.name
        if q.limit is None:
            continue
        if key not in actions or rank[q.status] > actions[key][0]:
            actions[key] = (rank[q.status], q.action)
    return MonitorResult(history.source, t.tolist(), nxt, out,
                         {k: v[1] for k, v in actions.items()})

