"""Legends that never cover data: inside the axes where a corner is free, else below them.

matplotlib's loc="best" weighs only the vertices of lines, so a legend can sit on a line
drawn between two distant vertices (a resonance peak sampled coarsely) or on a colour
map. `place_legend` samples every drawn segment densely and moves the legend outside
when more than a trace of the data would lie under it.
"""

import numpy as np


def renderer(fig):
    """The renderer of `fig`, attaching an Agg canvas to a bare `Figure` first."""
    if not hasattr(fig.canvas, "get_renderer"):
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    return fig.canvas.get_renderer()


def drawn_points(ax, dense: int = 20) -> np.ndarray:
    """Display coordinates of the data of `ax`: each line segment sampled `dense` times,
    markers, scatter offsets and the corners of bars."""
    pts = []
    for line in ax.get_lines():
        xy = np.asarray(line.get_xydata(), float)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if not len(xy):
            continue
        disp = ax.transData.transform(xy)
        if line.get_linestyle() not in ("None", "", " ") and len(disp) > 1:
            s = np.linspace(0.0, 1.0, dense, endpoint=False)[:, None, None]
            disp = np.concatenate([(disp[:-1] + s * (disp[1:] - disp[:-1])).reshape(-1, 2),
                                   disp[-1:]])
        pts.append(disp)
    for coll in ax.collections:
        off = np.asarray(coll.get_offsets(), float)
        if off.ndim == 2 and len(off) and off.shape[1] == 2 and np.all(np.isfinite(off)):
            pts.append(coll.get_offset_transform().transform(off))
    for patch in ax.patches:
        box = patch.get_window_extent()
        if np.all(np.isfinite(box.get_points())):
            xs, ys = np.linspace(box.x0, box.x1, 5), np.linspace(box.y0, box.y1, 5)
            pts.append(np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def covered_fraction(ax, legend) -> float:
    """Fraction of the drawn data of `ax` that lies under `legend` (the figure is laid
    out first: a legend at loc="best" finds its place only when drawn)."""
    r = renderer(ax.figure)
    ax.figure.draw_without_rendering()
    box = legend.get_window_extent(r)
    pts = drawn_points(ax)
    if not len(pts):
        return 0.0
    inside = ((pts[:, 0] > box.x0) & (pts[:, 0] < box.x1) & (pts[:, 1] > box.y0)
              & (pts[:, 1] < box.y1))
    return float(inside.mean())


def legend_below(ax, handles=None, **kwargs):
    """A legend (of `handles`, default the labelled artists of `ax`) centred under the
    axes, below its tick labels and x label."""
    old = ax.get_legend()
    if old is not None:
        old.remove()
    fig = ax.figure
    below = ax.get_tightbbox(renderer(fig)).y0
    y = ax.transAxes.inverted().transform((0.0, below))[1]
    if handles is None:
        handles, _ = ax.get_legend_handles_labels()
    kwargs.setdefault("ncol", min(3, max(1, len(handles))))
    return ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, y - 0.02),
                     **kwargs)


def place_legend(ax, *, limit: float = 0.005, **kwargs):
    """`ax.legend(loc="best", **kwargs)`, moved below the axes (`legend_below`) when more
    than `limit` of the drawn data would lie under it."""
    legend = ax.legend(loc="best", **kwargs)
    if covered_fraction(ax, legend) > limit:
        legend = legend_below(ax, **kwargs)
    return legend
