"""Analogues of the paper's Figs. 10-27, from the numbers `_run.py` computed.

Figures are built without pyplot's global state (`matplotlib.figure.Figure`), so they can
be made in any process and saved atomically. Displacements are drawn in um, velocities
in mm/s, accelerations in m/s^2. Figs. 18-21 reuse `bsfs_jax.plotting`'s response panel;
the multi-variant figures (Figs. 13-17, 22-27) compare several parameter sets on shared
axes, as the paper does.
"""

import numpy as np
from matplotlib.figure import Figure

from .._numerics import half_range
from ..plotting import response_figure
from ._judge import hysteretic_jumps


def _x_um(traj):
    t = np.asarray(traj.t)
    return (t - t[0]) * 1e3, np.asarray(traj.displacement)[:, 2] * 1e6, \
        np.asarray(traj.velocity)[:, 2] * 1e3


def _last_periods(traj, k: int = 6):
    n = k * traj.samples_per_period + 1
    t, x, v = _x_um(traj)
    return t[-n:] - t[-n], x[-n:], v[-n:]


def compare_figure(trajs: dict, *, title: str, kind: str = "both"):
    """Time histories (last 6 periods) and/or phase portraits of the nut, one line per case.

    `trajs` maps a legend label to a `Trajectory`; `kind` is "time", "phase" or "both".
    """
    panels = {"time": 1, "phase": 1, "both": 2}[kind]
    fig = Figure(figsize=(6 * panels + 1, 4.6))
    axs = fig.subplots(1, panels, squeeze=False)[0]
    styles = ["-", "--", ":", "-."]
    for i, (label, traj) in enumerate(trajs.items()):
        t, x, v = _last_periods(traj)
        amp = half_range(np.asarray(traj.displacement)[:, 2]) * 1e6
        lab = f"{label} (amplitude {amp:.2f} um)"
        if kind in ("time", "both"):
            axs[0].plot(t, x, styles[i % 4], lw=1.1, label=lab)
        if kind in ("phase", "both"):
            axs[-1].plot(x, v, styles[i % 4], lw=1.1, label=lab)
    if kind in ("time", "both"):
        axs[0].set_xlabel("time (last 6 forcing periods) [ms]")
        axs[0].set_ylabel("nut + worktable displacement x_n [um]")
        axs[0].set_title("time history")
    if kind in ("phase", "both"):
        axs[-1].set_xlabel("x_n [um]")
        axs[-1].set_ylabel("velocity dx_n/dt [mm/s]")
        axs[-1].set_title("phase portrait")
    for ax in axs:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def motion_figure(traj, *, title: str):
    """Figs. 18-21: the four-panel response of `bsfs simulate` (plotting/_response.py)."""
    return response_figure(traj, title=title)


def waterfall_figure(data: dict, *, param_label: str, title: str, max_harmonic: float = 6.0):
    """Figs. 22-23: amplitude spectra of x_n (log scale) against ball diameter, in 3-D."""
    fig = Figure(figsize=(9, 6.2))
    ax = fig.add_subplot(projection="3d")
    freqs = np.asarray(data["freqs_hz"])
    keep = (freqs > 0) & (freqs <= max_harmonic * data["frequency_hz"])
    for d, spec, st in zip(data["values_mm"], data["spectra_m"], data["status"]):
        if st != 0:
            continue
        amp = np.log10(np.maximum(spec[keep] * 1e6, 1e-6))
        ax.plot(freqs[keep], np.full(keep.sum(), d), amp, lw=0.8, color="C0")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(param_label)
    ax.set_zlabel("log10(amplitude of x_n [um])")
    ax.set_title(title, fontsize=10)
    return fig


def _motion_colours(result, d):
    """Colour per point: from the verified labels where the sweep has them (grey:
    unresolved or failed), else from the fixed-transient classifier labels."""
    if result.verdicts is not None:
        colours = []
        for label in result.verdicts["motion"][d]:
            label = str(label)
            colours.append("C3" if label == "chaotic" else "C2" if label == "quasi-periodic"
                           else "C0" if label == "period-1" else "C1"
                           if label.startswith("period-") else "0.6")
        return colours
    ms = result.motions()[d]
    colours = []
    for m in ms:
        if m.kind == "chaotic":
            colours.append("C3")
        elif m.kind == "quasi-periodic":
            colours.append("C2")
        elif m.kind == "periodic" and m.period > 1:
            colours.append("C1")
        else:
            colours.append("C0")
    return colours


def bifurcation_figure(results: dict, *, label: str, title: str, unit: str = ""):
    """Figs. 24-25: Poincare samples of x_n against frequency, one panel per variant.

    Both sweep directions are drawn; colours give the motion class per point
    (blue period-1, orange period-n > 1, green quasi-periodic, red chaotic, grey
    unresolved), verified where the sweep has verdicts.
    """
    n = len(results)
    fig = Figure(figsize=(6.2 * n, 4.8))
    axs = fig.subplots(1, n, squeeze=False)[0]
    for ax, (value, res) in zip(axs, results.items()):
        for d, name in enumerate(res.directions):
            cols = _motion_colours(res, d)
            for i, f in enumerate(res.values):
                s = res.strobe[d, i, :, 2] * 1e6
                ax.plot(np.full(s.shape, f), s, ".", ms=1.6, color=cols[i],
                        alpha=0.7 if name == "up" else 0.45)
        for c, lab in (("C0", "period-1"), ("C1", "period-n > 1"), ("C2", "quasi-periodic"),
                       ("C3", "chaotic"), ("0.6", "unresolved")):
            ax.plot([], [], "o", color=c, ms=4, label=lab)
        ax.set_xlabel("excitation frequency [Hz]")
        ax.set_ylabel("x_n at t = kT [um]")
        ax.set_title(f"{label} = {value:g}{unit}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def frc_figure(results: dict, *, label: str, title: str, unit: str = ""):
    """Figs. 26-27: amplitude of x_n vs frequency, up (solid) and down (dashed) sweeps per
    variant, with the jumps between coexisting branches marked by arrows."""
    fig = Figure(figsize=(9, 5.6))
    ax = fig.add_subplot()
    for k, (value, res) in enumerate(results.items()):
        c = f"C{k}"
        for d, name in enumerate(res.directions):
            ax.plot(res.values, res.amplitude[d, :, 2] * 1e6, "-" if name == "up" else "--",
                    color=c, lw=1.2, marker="^" if name == "up" else "v", ms=3,
                    label=f"{label} = {value:g}{unit}, {name} sweep")
        for j in hysteretic_jumps(res):
            x = 0.5 * (j.value_before + j.value_after)
            ax.annotate("", xy=(x, j.amplitude_after * 1e6),
                        xytext=(x, j.amplitude_before * 1e6),
                        arrowprops=dict(arrowstyle="->", color=c, lw=1.3))
    ax.set_yscale("log")
    ax.set_xlabel("excitation frequency [Hz]")
    ax.set_ylabel("amplitude of x_n (half peak-to-peak) [um]")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="best", ncol=2)
    fig.tight_layout()
    return fig


def exciter_figure(trajs: dict, *, title: str):
    """Figs. 10-12 (model side): worktable acceleration under 100 N at 100/120/150 Hz."""
    fig = Figure(figsize=(12, 3.8))
    axs = fig.subplots(1, len(trajs), squeeze=False)[0]
    for ax, (f, traj) in zip(axs, trajs.items()):
        t = np.asarray(traj.t)
        a = np.asarray(traj.acceleration)[:, 2]
        ax.plot((t - t[0]) * 1e3, a, lw=0.9)
        ax.set_xlabel("time [ms]")
        ax.set_ylabel("worktable acceleration [m/s^2]")
        ax.set_title(f"{f:g} Hz, 100 N: amplitude {half_range(a):.3f} m/s^2", fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
