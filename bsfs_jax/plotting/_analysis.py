"""Figures of sweeps and responses: bifurcation diagram, FRC with jumps, waterfall, panels.

Every function takes results (a `SweepResult` or arrays) and returns a matplotlib
`Figure` built without pyplot's global state, so the CLI can save it atomically.
Displacements in metres are drawn in micrometres for legibility.
"""

import numpy as np
from matplotlib.figure import Figure

from ._layout import place_legend

_DIR_STYLE = {
    "cold": dict(color="C0", marker="o", ls="-"),
    "up": dict(color="C3", marker="^", ls="-"),
    "down": dict(color="C0", marker="v", ls="--"),
}


def _display(unit: str):
    """(factor, label unit) to draw a quantity in `unit` legibly."""
    return {"m": (1e6, "µm"), "m/s": (1.0, "m/s")}.get(unit, (1.0, unit))


_PARAM_WORDS = {"frequency_hz": "Excitation frequency", "force_n": "Force amplitude"}
# The ball screw's state symbols in words (other problems keep their own names).
_STATE_WORDS = {"x_b": "bearing-joint displacement", "x_s": "screw displacement",
                "x_n": "nut displacement", "v_b": "bearing-joint velocity",
                "v_s": "screw velocity", "v_n": "nut velocity"}


def _param_label(result) -> str:
    name = _PARAM_WORDS.get(result.param, result.param)
    return f"{name} [{result.unit}]" if result.unit else name


def _state_label(result, c: int, *, what: str = "", suffix: str = ""):
    """(factor, label): '{what} {words} {symbol}{suffix} [unit]', e.g. 'amplitude of nut
    displacement x_n [µm]'."""
    names, units = result.state_names, result.state_units
    name = names[c] if names else f"y{c}"
    words = f"{_STATE_WORDS[name]} {name}" if name in _STATE_WORDS else name
    unit = units[c] if units else ""
    factor, shown = _display(unit)
    text = f"{what}{words}{suffix}"
    text = text[0].upper() + text[1:]
    return factor, (f"{text} [{shown}]" if shown else text)


def _short_name(result, c: int) -> str:
    names = result.state_names
    return names[c] if names else f"y{c}"


def plot_bifurcation(result, *, coordinate: int | None = None, title: str | None = None):
    """Stroboscopic samples of one state against the swept parameter, per direction.

    Verified periodic points show their orbit's n stroboscopic points; other verified
    points their recorded samples; unresolved points are grey; failed points are marked
    with a red x on the axis.
    """
    c = result.observe if coordinate is None else coordinate
    factor, ylabel = _state_label(result, c, suffix=" at t = kT")
    fig = Figure(figsize=(8, 5))
    ax = fig.add_subplot()
    verdicts = getattr(result, "verdicts", None)
    orbit = None if verdicts is None or c != result.observe else verdicts.get("orbit_strobe")
    for d, name in enumerate(result.directions):
        s = result.strobe[d, :, :, c] * factor
        x = np.broadcast_to(result.values[:, None], s.shape)
        style = _DIR_STYLE.get(name, {})
        color = style.get("color", "k")
        ok = np.ones(result.values.size, bool) if verdicts is None else \
            np.asarray(verdicts["verified"][d], bool)
        on_orbit = np.zeros_like(ok) if orbit is None else \
            ok & np.any(np.isfinite(orbit[d]), axis=-1)
        if on_orbit.any():
            # Verified periodic points: the orbit's own stroboscopic points (n of them),
            # not the record, which may still hold a decaying transient.
            o = orbit[d][on_orbit] * factor
            ox = np.broadcast_to(result.values[on_orbit][:, None], o.shape)
            ax.plot(ox.ravel(), o.ravel(), "o", ms=3.5, color=color, alpha=0.8)
        rest = ok & ~on_orbit
        ax.plot(x[rest].ravel(), s[rest].ravel(), ".", ms=2.5, color=color, alpha=0.6)
        what = "verified labels" if verdicts is not None else "labels not verified"
        ax.plot([], [], "o", ms=3, color=color, label=f"{name} sweep ({what})")
        if verdicts is not None and (~ok).any():
            ax.plot(x[~ok].ravel(), s[~ok].ravel(), ".", ms=2.5, color="0.6", alpha=0.6)
            ax.plot([], [], "o", ms=3, color="0.6",
                    label=f"{name}: unresolved or failed ({int((~ok).sum())} points)")
        bad = result.failed[d]
        if bad.any():
            ax.plot(result.values[bad], np.zeros(bad.sum()), "x", color="red",
                    label="failed point")
    ax.set_xlabel(_param_label(result))
    ax.set_ylabel(ylabel)
    ax.set_title(title or f"Bifurcation diagram: Poincare samples of {_short_name(result, c)} "
                 f"vs {_param_label(result).split(' [')[0].lower()}")
    ax.grid(alpha=0.3)
    place_legend(ax, fontsize=8, markerscale=2)
    return fig


def plot_frc(result, *, coordinate: int | None = None, jumps=None, title: str | None = None):
    """Amplitude (half peak-to-peak; of the verified orbit where known) against the
    parameter for each sweep direction, with the detected jumps drawn as arrows at their
    located folds and listed in the legend."""
    c = result.observe if coordinate is None else coordinate
    factor, ylabel = _state_label(result, c, what="amplitude of ")
    fig = Figure(figsize=(8, 5))
    ax = fig.add_subplot()
    for d, name in enumerate(result.directions):
        style = _DIR_STYLE.get(name, {})
        ax.plot(result.values, result.steady_amplitude(c)[d] * factor, ms=3, lw=1.2,
                label=f"{name} sweep", **style)
    jumps = result.jumps(coordinate=c) if jumps is None else jumps
    # With both directions, draw only the jumps that leave a coexisting branch.
    jumps = [j for j in jumps if j.hysteresis is not False]
    for j in jumps:
        # At the located fold; a jump without one is drawn between its two grid points and
        # says so.
        located = j.fold_value is not None
        x = j.fold_value if located else 0.5 * (j.value_before + j.value_after)
        ax.annotate("", xy=(x, j.amplitude_after * factor), xytext=(x, j.amplitude_before * factor),
                    arrowprops=dict(arrowstyle="->", color="k", lw=1.5))
        where = (f"fold at {x:.6g} {result.unit}" if located else
                 f"between {j.value_before:.5g} and {j.value_after:.5g} {result.unit} "
                 "(fold not located)")
        ax.plot([], [], ls="none", marker=r"$\updownarrow$", color="k",
                label=f"{j.direction} {j.kind}: {where}".rstrip())
    ax.set_xlabel(_param_label(result))
    ax.set_ylabel(ylabel)
    ax.set_title(title or f"Frequency-response curve ({result.mode} sweep)"
                 if result.param == "frequency_hz" else
                 title or f"Response amplitude vs {result.param} ({result.mode} sweep)")
    ax.grid(alpha=0.3)
    place_legend(ax, fontsize=8)
    return fig


def plot_waterfall(result, *, direction: str | None = None, max_harmonic: float = 8.0,
                   log_amplitude: bool = False, significant: float = 1e-3,
                   title: str | None = None):
    """3-D waterfall: amplitude spectrum of the observed state (frequency in Hz when the
    time unit is s) against the swept parameter.

    The frequency axis ends at the last significant line (amplitude above `significant`
    times the largest, within `max_harmonic` harmonics of the forcing), not at the
    Nyquist frequency; `log_amplitude` draws log10 of the amplitude, so that weak
    harmonics and subharmonics show beside the forced line.
    """
    d = 0 if direction is None else result.direction_index(direction)
    c = result.observe
    factor, zlabel = _state_label(result, c, what="amplitude of ")
    fig = Figure(figsize=(9, 6))
    ax = fig.add_subplot(projection="3d")
    keep = (result.spectrum_order > 0) & (result.spectrum_order <= max_harmonic)
    freq = result.spectrum_hz()[:, keep]
    spec = result.spectrum[d][:, keep] * factor
    finite = np.all(np.isfinite(spec), axis=1)
    top = np.max(spec[finite]) if finite.any() else 1.0
    strong = finite[:, None] & (spec > significant * top)
    f_max = float(np.max(freq[strong])) * 1.1 if strong.any() else float(np.max(freq))
    floor = significant * top * 1e-3
    for i, v in enumerate(result.values):
        if not finite[i]:
            continue
        a = np.log10(np.maximum(spec[i], floor)) if log_amplitude else spec[i]
        inside = freq[i] <= f_max
        ax.plot(freq[i][inside], np.full(int(inside.sum()), v), a[inside], lw=0.7, color="C0")
    funit = "Hz" if result.time_unit == "s" else f"1/{result.time_unit}"
    ax.set_xlim(0.0, f_max)
    ax.set_xlabel(f"Response frequency [{funit}]")
    ax.set_ylabel(_param_label(result))
    zlabel = zlabel[0].lower() + zlabel[1:]
    ax.set_zlabel(f"log10 {zlabel}" if log_amplitude else zlabel)
    ax.set_title(title or f"Waterfall: spectrum of {_short_name(result, c)} vs "
                 f"{_param_label(result).split(' [')[0].lower()}")
    return fig


def plot_response(t, displacement, velocity, strobe, freqs_hz, amplitude, *,
                  title: str = "Response", displacement_unit: str = "m",
                  velocity_unit: str = "m/s", name: str = "displacement",
                  max_frequency_hz: float | None = None, window: str = "hann",
                  min_frequency_hz: float | None = None):
    """Four panels as in the paper's Figs. 18-21: time history, phase portrait,
    stroboscopic Poincare section and amplitude spectrum (log scale).

    `strobe` is (k, 2): (displacement, velocity) at t = kT. The spectrum's axis ends at
    `max_frequency_hz`, by default at the last line above its plotted floor (1e-6 of the
    largest) plus 10 %, but not before `min_frequency_hz`. The Poincare panel shares the
    phase portrait's limits, so a period-1 orbit shows as one isolated point rather than an
    autoscaled cloud of integration round-off; the orbit is drawn faintly behind it.
    """
    fx, ux = _display(displacement_unit)
    fv, uv = _display(velocity_unit)
    if velocity_unit == "m/s":
        fv, uv = 1e3, "mm/s"
    t = np.asarray(t)
    x = np.asarray(displacement) * fx
    v = np.asarray(velocity) * fv
    fig = Figure(figsize=(11, 7.5))
    axs = fig.subplots(2, 2)
    ax = axs[0, 0]
    ax.plot((t - t[0]) * 1e3, x, lw=0.8, color="C0")
    ax.set_xlim(0.0, (t[-1] - t[0]) * 1e3)
    ax.set_xlabel("time after transient [ms]")
    ax.set_ylabel(f"{name} [{ux}]")
    ax.set_title("(a) time history")
    ax = axs[0, 1]
    ax.plot(x, v, lw=0.6, color="C1")
    ax.set_xlabel(f"{name} [{ux}]")
    ax.set_ylabel(f"velocity [{uv}]")
    ax.set_title("(b) phase portrait")
    xlim, ylim = ax.get_xlim(), ax.get_ylim()
    ax = axs[1, 0]
    s = np.asarray(strobe)
    ax.plot(x, v, lw=0.4, color="0.85", zorder=0)
    ax.plot(s[:, 0] * fx, s[:, 1] * fv, "o", ms=3.5, color="C3")
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    ax.set_xlabel(f"{name} at t = kT [{ux}]")
    ax.set_ylabel(f"velocity at t = kT [{uv}]")
    ax.set_title(f"(c) Poincare section ({len(s)} stroboscopic points)")
    ax = axs[1, 1]
    f = np.asarray(freqs_hz)
    a = np.asarray(amplitude) * fx
    top = max(float(np.nanmax(a)), 1e-300)
    if max_frequency_hz is None:  # the last line above the plotted floor, plus 10 %
        shown = np.flatnonzero(a > top * 1e-6)
        max_frequency_hz = 1.1 * float(f[shown[-1]]) if shown.size else float(f.max())
        max_frequency_hz = min(max(max_frequency_hz, min_frequency_hz or 0.0), f.max())
    keep = f <= max_frequency_hz
    ax.semilogy(f[keep], np.maximum(a[keep], top * 1e-7), lw=0.9, color="C2")
    ax.set_xlim(0.0, max_frequency_hz)
    ax.set_ylim(top * 1e-6, top * 3)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"amplitude (log scale) [{ux}]")
    ax.set_title(f"(d) amplitude spectrum ({window} window)")
    for a_ in axs.ravel():
        a_.grid(alpha=0.3)
    fig.suptitle(title)
    # Fixed margins for this fixed 2 x 2 layout: `tight_layout` measured every artist in an
    # extra drawing pass (0.4 s of a 4 s `bsfs simulate`).
    fig.subplots_adjust(left=0.08, right=0.985, bottom=0.075, top=0.91, wspace=0.22,
                        hspace=0.33)
    return fig
