"""Design figures: tornado plot of normalised sensitivities, optimisation summary.

Drawing only: the numbers come from `bsfs_jax.design` results.
"""


import matplotlib.pyplot as plt
import numpy as np

from ._layout import legend_below, place_legend


def tornado(result, *, ax=None, max_rows: int | None = None, compare=None, title=None):
    """Horizontal bars of d ln m / d ln p, largest magnitude on top.

    `result` is a `SensitivityResult`; `compare` (optional, e.g. finite differences) is
    drawn as black ticks on the same rows. Blue: increasing the parameter increases the
    metric; red: it decreases it.
    """
    order = result.ranked()
    if max_rows:
        order = order[:max_rows]
    names = [result.names[i] for i in order]
    values = np.array([result.normalised[i] for i in order])
    if ax is None:
        fig, ax = plt.subplots(figsize=(8.0, 0.38 * len(names) + 1.6))
    else:
        fig = ax.figure
    y = np.arange(len(names))[::-1]
    colours = np.where(values >= 0, "#2a6fb0", "#c23b22")
    ax.barh(y, values, color=colours, height=0.7)
    if compare is not None:
        cmp_vals = np.array([compare.normalised[compare.names.index(n)] for n in names])
        ax.scatter(cmp_vals, y, marker="|", s=220, color="black", zorder=3,
                   label=compare.method)
    ax.axvline(0.0, color="0.3", lw=0.8)
    ax.set_yticks(y)
    ax.set_yticklabels(names, fontsize=8)
    ax.set_xlabel("normalised sensitivity d ln(metric) / d ln(parameter) [-]")
    span = max(float(np.nanmax(np.abs(values))) if len(values) else 1.0, 1e-12)
    ax.set_xlim(-1.25 * span, 1.25 * span)
    for yi, v in zip(y, values, strict=True):
        ax.text(v + (0.02 if v >= 0 else -0.02) * span, yi, f"{v:+.3f}", va="center",
                ha="left" if v >= 0 else "right", fontsize=7)
    where = ""
    if result.frequency_hz is not None:
        where += f" at {result.frequency_hz:g} Hz"
    if result.force_n is not None:
        where += f", {result.force_n:g} N" if where else f" at {result.force_n:g} N"
    ax.set_title(title or f"Sensitivity of {result.metric} = {result.value:.4g} "
                 f"{result.unit}{where}", fontsize=10)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    if compare is not None:
        place_legend(ax, fontsize=8)
    return fig


def optimization_summary(result, *, checks=None):
    """Two panels: start vs optimum of each variable (relative to its bounds), and the
    metric at start and optimum (with simulated values from `checks` when given)."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10.0, 0.4 * len(result.names) + 2.4),
                                   gridspec_kw={"width_ratios": [1.6, 1.0]})
    y = np.arange(len(result.names))[::-1]
    lo = np.array([result.bounds[n][0] for n in result.names])
    hi = np.array([result.bounds[n][1] for n in result.names])
    frac0 = (result.start - lo) / (hi - lo)
    frac1 = (result.optimum - lo) / (hi - lo)
    ax1.hlines(y, 0, 1, color="0.8", lw=6)
    ax1.scatter(frac0, y, color="0.4", label="start", zorder=3)
    ax1.scatter(frac1, y, color="#2a6fb0", marker="D", label="optimum", zorder=3)
    for yi, n, a, b in zip(y, result.names, result.start, result.optimum, strict=True):
        ax1.text(1.02, yi, f"{a:.4g} -> {b:.4g}", va="center", fontsize=7)
    ax1.set_yticks(y)
    ax1.set_yticklabels(result.names, fontsize=8)
    ax1.set_xlim(-0.05, 1.45)
    ax1.set_ylim(y.min() - 0.6, y.max() + 0.6)
    ax1.set_xlabel("position within bounds (0 = lower, 1 = upper) [-]")
    ax1.set_title("Design variables (file units)", fontsize=10)
    labels = ["start", "optimum"]
    vals = [result.start_value, result.optimum_value]
    ax2.bar(labels, vals, color=["0.6", "#2a6fb0"], width=0.5, label="model")
    sims = [c.get("simulated") for c in checks or []]
    if sims and all(s is not None for s in sims):
        ax2.scatter(labels, sims, color="black", marker="x", s=60, zorder=3,
                    label="simulation")
        vals = vals + sims
    top = max(vals)
    if top > 0:  # headroom above the bars for the legend
        ax2.set_ylim(min(0.0, min(vals)), 1.3 * top)
    ax2.set_ylabel(f"{result.metric.replace('_', ' ')} [{result.unit}]")
    ax2.set_title(f"{result.direction}imise {result.metric}: "
                  f"{result.improvement_percent:+.1f} % better", fontsize=10)
    fig.tight_layout()
    legend_below(ax1, fontsize=8, ncol=2)
    place_legend(ax2, fontsize=8, ncol=2)
    fig.tight_layout()
    return fig
