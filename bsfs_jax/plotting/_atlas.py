"""Figures of two-parameter atlases: verified motion classes and amplitude, with the
bifurcation curves on top. Each function takes an `analysis.Atlas` and returns a Figure."""

import numpy as np
from matplotlib import patheffects
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from ._layout import legend_below

# Words for the usual parameter names (anything else: the name, "_" as spaces).
_WORDS = {"frequency_hz": "Excitation frequency", "force_n": "Force amplitude",
          "damping_scale": "Damping scale (factor on all dampers)"}
_PERIOD_COLORS = ("#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf",
                  "#bcbd22", "#393b79", "#637939", "#8c6d31")
_CLASS_COLORS = {"quasi-periodic": "#ff7f0e", "chaotic": "#d62728", "unresolved": "#cfcfcf",
                 "failed": "#000000"}
CURVE_STYLES = {"fold": ("-", "fold"), "period-doubling": ("--", "period doubling"),
                "neimark-sacker": (":", "Neimark-Sacker"),
                "branch-point": ("-.", "branch point")}


def axis_label(name: str, unit: str, words: str = "") -> str:
    """'Excitation frequency [Hz]': the words for `name` (or `words`) and the unit."""
    words = words or _WORDS.get(name) or name.replace("_", " ").capitalize()
    return f"{words} [{unit}]" if unit else words


def _edges(v):
    v = np.asarray(v, dtype=float)
    if v.size == 1:
        h = 0.5 * (abs(v[0]) * 0.05 or 1.0)
        return np.array([v[0] - h, v[0] + h])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])


def motion_classes(atlas):
    """(labels (Ny, Nx) of str, ordered class names): a verified label, else "unresolved"
    (and "failed"); classes period-1, period-2, ..., quasi-periodic, chaotic, unresolved,
    failed, those present only."""
    motion = np.asarray(atlas.motion).astype(str)
    verified = np.asarray(atlas.verified, dtype=bool)
    shown = np.where(verified | (motion == "failed"), motion, "unresolved")
    present = set(shown.ravel().tolist())
    periodic = sorted((c for c in present if c.startswith("period-")),
                      key=lambda c: int(c.split("-")[1]) if c.split("-")[1].isdigit() else 99)
    rest = [c for c in ("quasi-periodic", "chaotic", "unresolved", "failed") if c in present]
    others = sorted(present - set(periodic) - set(rest))
    return shown, periodic + others + rest


def _color(name: str, k_periodic: int) -> str:
    if name in _CLASS_COLORS:
        return _CLASS_COLORS[name]
    return _PERIOD_COLORS[k_periodic % len(_PERIOD_COLORS)]


def _overlay(ax, atlas):
    """Draw the bifurcation curves (black with a white halo, a dot at each located point);
    returns legend handles, one per kind present."""
    handles, seen = [], set()
    halo = [patheffects.withStroke(linewidth=4, foreground="w")]
    for c in atlas.curves():
        ls, words = CURVE_STYLES.get(c["kind"], ("-", c["kind"]))
        style = dict(ls=ls, color="k", lw=2.0, marker="o", ms=3.5, path_effects=halo)
        ax.plot(c["x"], c["y"], **style)
        if c["kind"] not in seen:
            seen.add(c["kind"])
            handles.append(Line2D([], [], label=words, **{**style, "marker": None}))
    return handles


def _axes(fig, atlas, title):
    ax = fig.add_subplot()
    ax.set_xlabel(axis_label(atlas.x_name, atlas.x_unit, atlas.x_label))
    ax.set_ylabel(axis_label(atlas.y_name, atlas.y_unit, atlas.y_label))
    ax.set_title(title)
    ax.set_xlim(_edges(atlas.x)[[0, -1]])
    ax.set_ylim(_edges(atlas.y)[[0, -1]])
    return ax


def plot_atlas_motion(atlas, *, title: str | None = None):
    """Categorical map of the verified motion: each period-n, quasi-periodic and chaotic
    its own colour, unverified points grey and hatched ("unresolved"), failed black, with
    the bifurcation curves (fold solid, period doubling dashed, Neimark-Sacker dotted)."""
    shown, classes = motion_classes(atlas)
    code = np.zeros(shown.shape, dtype=int)
    colors, k_per = [], 0
    for k, name in enumerate(classes):
        code[shown == name] = k
        colors.append(_color(name, k_per))
        k_per += name not in _CLASS_COLORS
    fig = Figure(figsize=(9, 5.5))
    ax = _axes(fig, atlas, title or "Verified motion")
    xe, ye = _edges(atlas.x), _edges(atlas.y)
    ax.pcolormesh(xe, ye, code, cmap=ListedColormap(colors), vmin=-0.5,
                  vmax=len(classes) - 0.5, shading="flat")
    for j, i in zip(*np.nonzero(shown == "unresolved"), strict=True):
        ax.add_patch(Rectangle((xe[i], ye[j]), xe[i + 1] - xe[i], ye[j + 1] - ye[j],
                               fill=False, hatch="//", edgecolor="#8a8a8a", lw=0))
    handles = [Patch(facecolor=c, edgecolor="#8a8a8a" if n == "unresolved" else c,
                     hatch="//" if n == "unresolved" else None,
                     label="unresolved (not verified)" if n == "unresolved" else n)
               for n, c in zip(classes, colors, strict=True)]
    handles += _overlay(ax, atlas)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8,
              handlelength=3.5,
              title="motion / bifurcation", title_fontsize=8)
    fig.tight_layout()
    return fig


def plot_atlas_amplitude(atlas, unit_scale: float = 1e6, unit: str = "µm", *,
                         title: str | None = None):
    """Colour map of the amplitude (half peak-to-peak, times `unit_scale`, in `unit`) with
    a labelled colour bar and the bifurcation curves; failed points are blank."""
    amp = np.asarray(atlas.amplitude, dtype=float) * unit_scale
    amp = np.where(np.asarray(atlas.motion).astype(str) == "failed", np.nan, amp)
    fig = Figure(figsize=(9, 5.5))
    ax = _axes(fig, atlas, title or "Response amplitude")
    mesh = ax.pcolormesh(_edges(atlas.x), _edges(atlas.y), np.ma.masked_invalid(amp),
                         cmap="viridis", shading="flat")
    bar = fig.colorbar(mesh, ax=ax)
    bar.set_label(f"Amplitude (half peak-to-peak) [{unit}]" if unit else
                  "Amplitude (half peak-to-peak)")
    handles = _overlay(ax, atlas)
    fig.tight_layout()
    if handles:  # a colour map is data everywhere: the legend goes below it
        legend_below(ax, handles=handles, fontsize=8, handlelength=3.5,
                     ncol=len(handles))
    return fig
