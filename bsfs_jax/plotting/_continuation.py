"""Frequency-response curves from a continued branch: stable solid, unstable dashed."""

import re

import numpy as np

from ._layout import place_legend

_MARKERS = {
    "fold": ("o", "tab:red", "fold (mu = +1)"),
    "branch-point": ("s", "tab:purple", "branch point (mu = +1)"),
    "period-doubling": ("D", "tab:green", "period doubling (mu = -1)"),
    "neimark-sacker": ("^", "tab:orange", "Neimark-Sacker (|mu| = 1)"),
}


def stability_segments(p, amp, stable, bifurcations=()):
    """Polylines [(p, amp, is_stable), ...] of constant stability along the branch.

    Located bifurcation points are inserted after their branch index, so a change of
    stability is drawn exactly at the fold / period doubling, not halfway to the next point.
    """
    p, amp = np.asarray(p, dtype=float), np.asarray(amp, dtype=float)
    stable = np.asarray(stable, dtype=bool)
    xs, ys, flags = [], [], []  # flags: True/False for branch points, None for inserted
    extra = {}
    for b in bifurcations:
        extra.setdefault(int(b.index), []).append(b)
    for i in range(p.size):
        xs.append(p[i])
        ys.append(amp[i])
        flags.append(bool(stable[i]))
        for b in sorted(extra.get(i, []), key=lambda b: abs(b.p - p[i])):
            xs.append(b.p)
            ys.append(b.amplitude)
            flags.append(None)
    lines = []
    for k in range(len(xs) - 1):
        left, right = flags[k], flags[k + 1]
        style = left if left is not None else (right if right is not None else True)
        if lines and lines[-1][2] == style and lines[-1][3] == k:
            lines[-1][0].append(xs[k + 1])
            lines[-1][1].append(ys[k + 1])
            lines[-1][3] = k + 1
        else:
            lines.append([[xs[k], xs[k + 1]], [ys[k], ys[k + 1]], style, k + 1])
    if not lines and xs:
        lines.append([xs, ys, flags[0], 0])
    return [(np.asarray(a), np.asarray(b), bool(c)) for a, b, c, _ in lines]


def plot_continuation(branch, *, ax=None, x_scale: float = 1.0, y_scale: float = 1e6,
             x_label: str = "Excitation frequency [Hz]",
             y_label: str = "Nut amplitude (half peak-to-peak) [µm]",
             title: str | None = None, label: str | None = None, color: str = "tab:blue"):
    """Draw `branch.amplitude` against `branch.p`: stable solid, unstable dashed.

    Bifurcations are marked by type, the located amplitude peak (if any) by a triangle
    with its value in the legend. `x_scale`, `y_scale` convert the branch's units
    (default: Hz and m -> µm). Draws into `ax` if given; returns the Figure.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(7.5, 4.5))
    drawn = set()
    bifs = [b for b in branch.bifurcations if np.isfinite(b.p)]
    for xs, ys, is_stable in stability_segments(branch.p, branch.amplitude, branch.stable,
                                                bifs):
        key = "stable" if is_stable else "unstable"
        name = f"{label + ', ' if label else ''}{key}"
        ax.plot(xs * x_scale, ys * y_scale, "-" if is_stable else "--", color=color,
                lw=1.8 if is_stable else 1.4, label=None if key in drawn else name)
        drawn.add(key)
    for bif in branch.bifurcations:
        marker, mcolor, text = _MARKERS.get(bif.kind, ("x", "k", bif.kind))
        ax.plot(bif.p * x_scale, bif.amplitude * y_scale, marker, color=mcolor, ms=7,
                mfc="none", mew=1.8, label=None if bif.kind in drawn else text)
        drawn.add(bif.kind)
    peak = getattr(branch, "peak", None)
    if peak is not None:
        ax.plot(peak.p * x_scale, peak.amplitude * y_scale, "v", color="k", ms=6,
                label=f"peak {peak.amplitude * y_scale:.4g}{_unit(y_label)} at "
                      f"{peak.p * x_scale:.5g}{_unit(x_label)}")
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    if title:
        ax.set_title(title)
    ax.grid(True, alpha=0.3)
    place_legend(ax, fontsize=8)
    return ax.figure


def _unit(label: str) -> str:
    """' unit' from an axis label 'words [unit]' ('' without one)."""
    found = re.search(r"\[([^\]]+)\]\s*$", label)
    return f" {found.group(1)}" if found else ""
