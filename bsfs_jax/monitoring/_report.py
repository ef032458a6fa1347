"""monitor.json, monitor.png and monitor.html from a `MonitorResult`."""

import base64
import html
import io
import json
import math
from pathlib import Path

import numpy as np

from .._files import save_figure, write_bytes_atomic, write_text_atomic


def plain(obj):
    """`obj` as JSON-ready Python: numpy to lists and numbers, NaN to None; +-inf kept
    (written as JSON's `Infinity`, which Python's and JavaScript's readers accept)."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, np.generic):
        return plain(obj.item())
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return obj


def monitor_figure(result):
    """One panel per quantity against operating hours: tests with 95 % error bars, the
    trend and its 95 % prediction band, the limit and warning levels, change points."""
    import matplotlib.pyplot as plt

    qs = list(result.quantities.values())
    fig, axes = plt.subplots(len(qs), 1, figsize=(7.5, 2.6 * len(qs)), squeeze=False,
                             sharex=True)
    for ax, q in zip(axes[:, 0], qs):
        err = None if q.std is None else [1.96 * s for s in q.std]
        ax.errorbar(q.hours, q.values, yerr=err, fmt="o", ms=4, color="k", capsize=2,
                    label="tests (95 %)")
        if q.trend is not None:
            tr = q.trend
            ax.plot(tr["hours"], tr["mean"], color="C0", label=f"{tr['kind']} trend")
            ax.fill_between(tr["hours"], *tr["band95"], color="C0", alpha=0.2,
                            label="95 % prediction band")
        for c in q.change_points_h:
            ax.axvline(c, color="C3", ls=":", lw=1.2)
        if q.limit is not None:
            ax.axhline(q.limit, color="C3", lw=1.2, label="limit")
        if q.warn is not None:
            ax.axhline(q.warn, color="C1", lw=1.0, ls="--", label="warning")
        ttl = q.time_to_limit_h
        if ttl is not None and math.isfinite(ttl.lower):
            hi = ttl.upper if math.isfinite(ttl.upper) else ax.get_xlim()[1]
            ax.axvspan(ttl.lower, hi, color="C3", alpha=0.08, label="time to limit (95 %)")
        ax.set_ylabel(f"{q.name} [{q.unit}]" if q.unit else q.name)
        ax.set_title(f"{q.name}: {q.status}", fontsize=9, loc="left")
        ax.legend(fontsize=6, loc="best")
    axes[-1, 0].set_xlabel("operating hours [h]")
    fig.tight_layout()
    return fig


def _fmt(x, digits=4):
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "open (&infin;)"
    return f"{x:.{digits}g}"


def monitor_html(result, png: bytes) -> str:
    """A self-contained report (the figure embedded as base64 PNG, tables)."""
    e = html.escape
    rows = []
    for q in result.quantities.values():
        ttl = q.time_to_limit_h
        span = "-" if ttl is None else (f"{_fmt(ttl.estimate, 5)} h "
                                        f"[{_fmt(ttl.lower, 5)}, {_fmt(ttl.upper, 5)}]")
        p = "-" if ttl is None else f"{100 * ttl.p_before_next:.1f} %"
        rows.append(
            f"<tr><td>{e(q.name)}</td><td>{e(q.unit)}</td>"
            f"<td>{_fmt(q.baseline['value'])} @ {_fmt(q.baseline['hours'])} h</td>"
            f"<td>{_fmt(q.values[-1])}</td><td>{e(q.model or '-')}</td>"
            f"<td>{e(', '.join(f'{c:g}' for c in q.change_points_h) or 'none')}</td>"
            f"<td>{_fmt(q.limit)}</td><td>{span}</td><td>{p}</td>"
            f"<td class='{q.status}'>{q.status}</td></tr>")
    changes = []
    for q in result.quantities.values():
        for c in q.changes:
            changes.append(f"<tr><td>{e(q.name)}</td><td>{c['hours']:g}</td>"
                           f"<td>{_fmt(c['change'])}</td><td>[{_fmt(c['ci95'][0])}, "
                           f"{_fmt(c['ci95'][1])}]</td></tr>")
    actions = "".join(f"<li>{e(a)}</li>" for a in result.actions.values()) or \
        "<li>no limits set</li>"
    img = base64.b64encode(png).decode()
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>bsfs monitor: {e(result.source)}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}
table{{border-collapse:collapse;font-size:0.85em}}td,th{{border:1px solid #bbb;padding:2px 6px}}
.ok{{background:#d8f0d8}}.warning{{background:#fbe8b0}}.alarm{{background:#f6c0c0}}</style>
</head><body>
<h1>Condition monitoring</h1>
<p>History: {e(result.source)}; {len(result.hours)} tests from {result.hours[0]:g} to
{result.hours[-1]:g} h; next test at {result.next_test_h:g} h.</p>
<h2>Actions</h2><ul>{actions}</ul>
<h2>Quantities</h2>
<table><tr><th>quantity</th><th>unit</th><th>baseline</th><th>last</th><th>trend</th>
<th>change points [h]</th><th>limit</th><th>time to limit (95 %)</th>
<th>P(by next test)</th><th>status</th></tr>{''.join(rows)}</table>
<h2>Trends</h2><img alt="monitor figure" style="max-width:100%"
src="data:image/png;base64,{img}">
<h2>Change from baseline, per test</h2>
<table><tr><th>quantity</th><th>hours</th><th>change</th><th>95 % interval</th></tr>
{''.join(changes)}</table>
<p style="font-size:0.8em">Baseline: the first test after the last change point.
Trend: linear, exponential or Wiener with drift, chosen by AICc, each test weighted by its
own variance plus the between-test scatter. Time to limit: 95 % interval from draws of the
trend's parameters (open where the upper bound is infinite).</p>
</body></html>
"""


def write_monitor(result, out) -> list[Path]:
    """Write monitor.json, monitor.png and monitor.html into folder `out`."""
    import matplotlib.pyplot as plt

    out = Path(out)
    data = plain(result.to_dict())
    write_bytes_atomic(out / "monitor.json",
                       (json.dumps(data, indent=2, allow_nan=True) + "\n").encode())
    fig = monitor_figure(result)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    save_figure(fig, out / "monitor.png", tight=False, dpi=110)
    plt.close(fig)
    write_text_atomic(out / "monitor.html", monitor_html(result, buf.getvalue()))
    return [out / "monitor.json", out / "monitor.png", out / "monitor.html"]
