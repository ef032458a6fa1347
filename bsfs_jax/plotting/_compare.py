"""Two identifications side by side: what each test determines, parameter by parameter."""

from __future__ import annotations

import numpy as np


def identification_comparison_figure(panels):
    """One panel per identification: each fitted parameter's relative 95 % interval width
    (log-values; offsets in um), the prior's width beside it, and whether the data
    determine it.

    `panels`: list of (title, parameters) with `parameters` as in report.json:
    {name: {"value", "ci95", "prior_sigma", "identified", "unit", ...}}.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    n = len(panels)
    height = max(len(p) for _, p in panels)
    fig, axes = plt.subplots(1, n, figsize=(6.0 * n, 1.0 + 0.45 * height + 1.2),
                             squeeze=False)
    for ax, (title, params) in zip(axes[0], panels):
        names = list(params)
        y = np.arange(len(names))[::-1]
        widths, priors, colours = [], [], []
        for name in names:
            row = params[name]
            lo, hi = row["ci95"] if row.get("ci95") else (np.nan, np.nan)
            log = row.get("unit") != "um"
            widths.append(100 * (hi / lo - 1.0) if log and lo and lo > 0 else np.nan)
            sig = row.get("prior_sigma")
            priors.append(100 * (np.exp(2 * 1.96 * sig) - 1.0) if sig and log else np.nan)
            colours.append("C2" if row.get("identified") else "0.6")
        widths = np.asarray(widths, float)
        ax.barh(y, np.where(np.isfinite(widths), widths, 0.0), color=colours, height=0.6)
        ax.plot(priors, y, "k|", ms=14, mew=2)
        for yi, w in zip(y, widths):
            if not np.isfinite(w):
                ax.text(1.2e-3, yi, "not determined", va="center", fontsize=8)
        ax.set_xscale("log")
        ax.set_yticks(y, names)
        finite = [v for v in (*widths, *priors) if np.isfinite(v) and v > 0]
        lo = min(finite + [1e-2]) / 3
        hi = max(finite + [100.0]) * 3
        ax.set_xlim(lo, hi)
        ax.set_ylim(-0.7, len(names) - 0.3)
        ax.set_xlabel("width of the 95 % interval [% of the value]")
        ax.set_title(title, fontsize=10)
        ax.grid(axis="x", which="major", alpha=0.3)
    handles = [Patch(color="C2", label="determined by the data"),
               Patch(color="0.6", label="prior-dominated"),
               plt.Line2D([], [], color="k", marker="|", ls="", ms=12, mew=2,
                          label="the prior's 95 % width")]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return fig
