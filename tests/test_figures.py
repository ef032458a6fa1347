"""Every figure of `bsfs_jax.plotting`, built from small synthetic results: axis labels in
words with units, limits that cover the data and not much more, no legend over data.

Set BSFS_FIGURE_DIR to a folder to also save each figure there as PNG (to look at them).
"""

import os
import re
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pytest

from bsfs_jax import plotting

UNIT = re.compile(r"\[[^\]]+\]")


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _save(fig, name):
    folder = os.environ.get("BSFS_FIGURE_DIR")
    if folder:
        os.makedirs(folder, exist_ok=True)
        fig.savefig(os.path.join(folder, f"{name}.png"), dpi=110, bbox_inches="tight")


# -- checks -------------------------------------------------------------------------------
def _labelled(ax, *, x=True, y=True):
    """Axis labels in words (at least one word of 3+ letters) with a [unit]."""
    for on, label in ((x, ax.get_xlabel()), (y, ax.get_ylabel())):
        if on:
            assert UNIT.search(label) and re.search(r"[A-Za-z]{3}", label), repr(label)


def _renderer(fig):
    if not hasattr(fig.canvas, "get_renderer"):  # a bare Figure: give it an Agg canvas
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _line_points(ax, *, dense: int = 20) -> np.ndarray:
    """Display coordinates of every drawn line (each segment sampled `dense` times, so a
    line crossing a box is seen even between its vertices), markers and scatter points."""
    pts = []
    for line in ax.get_lines():
        xy = np.asarray(line.get_xydata(), float)
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if not len(xy):
            continue
        disp = ax.transData.transform(xy)
        if line.get_linestyle() not in ("None", "", " ") and len(disp) > 1:
            s = np.linspace(0, 1, dense, endpoint=False)[:, None, None]
            disp = np.concatenate([(disp[:-1] + s * (disp[1:] - disp[:-1])).reshape(-1, 2),
                                   disp[-1:]])
        pts.append(disp)
    for coll in ax.collections:
        off = np.asarray(coll.get_offsets(), float)
        if off.ndim == 2 and len(off) and off.shape[1] == 2:
            pts.append(coll.get_offset_transform().transform(off))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def _data_limits(ax):
    """(x range, y range) of the lines and scatter points in data coordinates."""
    pts = ax.transData.inverted().transform(_line_points(ax, dense=1))
    return (pts[:, 0].min(), pts[:, 0].max()), (pts[:, 1].min(), pts[:, 1].max())


def _tight(ax, *, x=True, y=True, slack=0.15, log_y=False):
    """The limits hold all data and add at most `slack` of the data span on each side."""
    _renderer(ax.figure)
    (x0, x1), (y0, y1) = _data_limits(ax)
    for on, (lo, hi), (a, b), log in ((x, (x0, x1), ax.get_xlim(), False),
                                      (y, (y0, y1), ax.get_ylim(), log_y)):
        if not on:
            continue
        if log:
            lo, hi, a, b = np.log10([lo, hi, a, b])
        span = max(hi - lo, 1e-12 * max(abs(hi), 1.0))
        assert min(a, b) <= lo + 1e-9 * span and max(a, b) >= hi - 1e-9 * span, \
            ((a, b), (lo, hi))
        assert (lo - min(a, b)) <= slack * span and (max(a, b) - hi) <= slack * span, \
            ((a, b), (lo, hi))


def _legend_clear(ax, legend=None, *, allowed: float = 0.01):
    """At most `allowed` of the drawn data (densely sampled) lies under the legend box."""
    renderer = _renderer(ax.figure)
    legend = legend or ax.get_legend()
    assert legend is not None
    box = legend.get_window_extent(renderer)
    pts = _line_points(ax)
    inside = (pts[:, 0] > box.x0) & (pts[:, 0] < box.x1) & (pts[:, 1] > box.y0) & \
        (pts[:, 1] < box.y1)
    assert inside.sum() <= max(3, allowed * len(pts)), (inside.sum(), len(pts))


# -- synthetic results ----------------------------------------------------------------------
def _sweep_result(directions=("up", "down")):
    """A Duffing-like frequency sweep of 41 points: a hardening resonance near 120 Hz with
    a jump between the directions, period 2 between 150 and 160 Hz."""
    from bsfs_jax.analysis import SweepResult
    from bsfs_jax.solvers import result_from_codes

    values = np.linspace(60.0, 180.0, 41)
    n_dir, n, periods = len(directions), values.size, 16
    base = 1e-6 / np.sqrt((1 - (values / 120.0) ** 2) ** 2 + (0.05 * values / 120.0) ** 2)
    amp = np.stack([np.where(values < 135, base, base * 0.3) if d == "up" else base
                    for d in directions])
    k = np.arange(periods + 1)
    strobe = np.zeros((n_dir, n, periods + 1, 6))
    p2 = (values > 150) & (values < 160)
    phase = np.where(p2[None, :, None], (-1.0) ** k, 1.0)
    strobe[..., 2] = amp[..., None] * 0.6 * phase
    strobe[..., 5] = amp[..., None] * 2 * np.pi * values[None, :, None] * 0.8
    order = np.arange(0, 8.01, 0.5)
    spectrum = np.zeros((n_dir, n, order.size))
    spectrum[..., order == 1] = amp[..., None]
    spectrum[..., order == 3] = 0.05 * amp[..., None]
    spectrum[..., order == 0.5] = np.where(p2, 0.3 * amp, 0.0)[..., None]
    ampl = np.zeros((n_dir, n, 6))
    ampl[..., 2] = amp
    codes = np.zeros((n_dir, n), int)
    return SweepResult(
        param="frequency_hz", unit="Hz", values=values, directions=tuple(directions),
        mode="continued", period=1.0 / values, spectrum_order=order, strobe=strobe,
        amplitude=ampl, mean=np.zeros((n_dir, n, 6)), peak=ampl, spectrum=spectrum,
        lyapunov=np.full((n_dir, n), np.nan), log_growth=np.zeros((n_dir, n, periods)),
        result=result_from_codes(codes), num_steps=np.full((n_dir, n), 100),
        end_state=np.zeros((n_dir, n, 6)),
        state_names=("x_b", "x_s", "x_n", "v_b", "v_s", "v_n"),
        state_units=("m",) * 3 + ("m/s",) * 3, observe=2, time_unit="s", config={},
        metadata={})


def _trajectory(f=500.0, spp=64, periods=20):
    t = np.arange(periods * spp + 1) / (spp * f)
    w = 2 * np.pi * f
    x = 1e-6 * np.sin(w * t) + 0.1e-6 * np.sin(3 * w * t)
    v = 1e-6 * w * np.cos(w * t) + 0.3e-6 * w * np.cos(3 * w * t)
    state = np.zeros((t.size, 6))
    state[:, 2], state[:, 5] = x, v
    return SimpleNamespace(t=t, state=state, displacement=state[:, :3], velocity=state[:, 3:],
                           samples_per_period=spp, period=1.0 / f)


def _branch():
    """A folded frequency-response branch (p in Hz, amplitude in m) with two folds."""
    s = np.linspace(0.0, 1.0, 60)
    p = 1000 + 300 * s - 250 * np.exp(-((s - 0.6) / 0.12) ** 2)
    amp = 20e-6 * np.exp(-((s - 0.6) / 0.25) ** 2) + 2e-6
    stable = ~((s > 0.5) & (s < 0.68))
    fold = lambda i: SimpleNamespace(p=float(p[i]), amplitude=float(amp[i]), kind="fold",  # noqa: E731
                                     index=i, multipliers=np.array([1.0]))
    i1, i2 = int(np.argmax(s > 0.5)) - 1, int(np.argmax(s > 0.68)) - 1
    top = int(np.argmax(amp))
    return SimpleNamespace(p=p, amplitude=amp, stable=stable, bifurcations=[fold(i1), fold(i2)],
                           peak=SimpleNamespace(p=float(p[top]), amplitude=float(amp[top])))


def _atlas():
    from bsfs_jax.analysis import Atlas

    x = np.linspace(800.0, 1600.0, 17)
    y = np.linspace(1000.0, 5000.0, 9)
    gx, gy = np.meshgrid(x, y)
    motion = np.where(gx < 1200, "period-1", np.where(gy > 3500, "chaotic", "period-2"))
    motion[0, -1] = "failed"
    verified = np.ones(gx.shape, bool)
    verified[2, 3] = False
    amplitude = 1e-6 * (1 + gy / 1000) * np.exp(-((gx - 1200) / 300) ** 2)
    bifs = [{"x": 1200.0 + 10 * j, "y": float(yy), "kind": "period-doubling",
             "amplitude": 1e-6} for j, yy in enumerate(y)]
    return Atlas("frequency_hz", "Hz", "force_n", "N", x, y,
                 {"motion": motion, "verified": verified, "amplitude": amplitude},
                 bifurcations=bifs, x_label="Excitation frequency", y_label="Force amplitude")


def _records(n=2, fs=20000.0, f=800.0):
    recs, coeffs, freqs = [], [], []
    for i in range(n):
        t = np.arange(int(0.05 * fs)) / fs
        c = np.array([2.0 + i, 0.3j, 0.05])
        a = np.real(np.exp(2j * np.pi * f * np.outer(t, np.arange(1, 4))) @ c)
        a += 0.05 * np.random.default_rng(i).standard_normal(t.size) + 0.3
        recs.append(SimpleNamespace(time=t, acceleration=a, sample_rate_hz=fs,
                                    name=f"record {i + 1}"))
        coeffs.append(c)
        freqs.append(f * (1 + 0.1 * i))
    return recs, coeffs, freqs


# -- sweeps -------------------------------------------------------------------------------
def test_bifurcation_diagram():
    fig = plotting.plot_bifurcation(_sweep_result())
    _save(fig, "bifurcation")
    ax = fig.axes[0]
    _labelled(ax)
    assert ax.get_xlabel() == "Excitation frequency [Hz]"
    assert ax.get_ylabel() == "Nut displacement x_n at t = kT [µm]"
    _tight(ax, slack=0.1)
    _legend_clear(ax)


def test_frequency_response_curve():
    res = _sweep_result()
    fig = plotting.plot_frc(res)
    _save(fig, "frc")
    ax = fig.axes[0]
    _labelled(ax)
    _tight(ax, slack=0.1)
    _legend_clear(ax)


@pytest.mark.parametrize("log", [False, True])
def test_waterfall_ends_at_its_content(log):
    fig = plotting.plot_waterfall(_sweep_result(("cold",)), log_amplitude=log)
    _save(fig, f"waterfall{'_log' if log else ''}")
    ax = fig.axes[0]
    _labelled(ax)
    assert UNIT.search(ax.get_zlabel())
    # The last significant line is the 3rd harmonic of 180 Hz: 540 Hz, plus 10 %.
    assert ax.get_xlim() == pytest.approx((0.0, 3 * 180.0 * 1.1))
    assert ax.get_ylim()[0] <= 60.0 and ax.get_ylim()[1] >= 180.0


def test_response_panels():
    traj = _trajectory()
    fig = plotting.response_figure(traj, title="test")
    _save(fig, "response")
    time_ax, phase_ax, poincare_ax, spec_ax = fig.axes
    for ax in fig.axes:
        _labelled(ax)
    _tight(time_ax, y=False, slack=1e-9)
    _tight(phase_ax, slack=0.1)
    # The spectrum ends at its last line (3 f) plus 10 %, from 0 Hz.
    assert spec_ax.get_xlim() == pytest.approx((0.0, 1.1 * 1500.0))
    lines = spec_ax.get_lines()[0]
    f, a = lines.get_xdata(), lines.get_ydata()
    assert spec_ax.get_ylim()[1] >= a.max() and spec_ax.get_ylim()[1] <= 10 * a.max()
    assert a[np.argmin(np.abs(f - 1500.0))] > 0.05 * a.max()  # 3rd harmonic shown
    # Sampled densely enough to look smooth: >= 32 points per period in the time history.
    t = time_ax.get_lines()[0].get_xdata()
    assert np.median(np.diff(t)) <= 1e3 / 500.0 / 32


# -- continuation and atlas ----------------------------------------------------------------
def test_forecast_figure():
    br = _branch()
    folds = br.bifurcations
    q = {"peak_frequency_hz": dict(value=br.peak.p, ci95=[br.peak.p - 5, br.peak.p + 6]),
         "peak_amplitude_um": dict(value=br.peak.amplitude * 1e6,
                                   ci95=[br.peak.amplitude * 1e6 - 1, None]),
         "fold_up_hz": dict(value=folds[0].p, ci95=[folds[0].p - 3, folds[0].p + 3]),
         "fold_down_hz": dict(value=None, ci95=None)}
    shifted = SimpleNamespace(p=br.p + 10, amplitude=br.amplitude * 1.05, stable=br.stable)
    fig = plotting.forecast_figure({"estimate": br, "probe0+": shifted}, br, q, 100.0)
    _save(fig, "forecast")
    ax = fig.axes[0]
    _labelled(ax)
    _legend_clear(ax)
    assert "[um]" in ax.get_ylabel() and "[Hz]" in ax.get_xlabel()


def test_continuation_frc():
    fig = plotting.plot_continuation(_branch(), title="test")
    _save(fig, "continuation")
    ax = fig.axes[0]
    _labelled(ax)
    _tight(ax, slack=0.1)
    _legend_clear(ax)


def test_atlas_motion_and_amplitude():
    atlas = _atlas()
    fig = plotting.plot_atlas_motion(atlas)
    _save(fig, "atlas_motion")
    ax = fig.axes[0]
    _labelled(ax)
    assert ax.get_xlim() == pytest.approx((775.0, 1625.0))  # the cells' edges
    assert ax.get_ylim() == pytest.approx((750.0, 5250.0))
    box = ax.get_legend().get_window_extent(_renderer(fig))
    assert box.x0 >= ax.get_window_extent().x1  # outside, right of the map
    fig = plotting.plot_atlas_amplitude(atlas)
    _save(fig, "atlas_amplitude")
    ax = fig.axes[0]
    _labelled(ax)
    assert UNIT.search(fig.axes[1].get_ylabel())  # the colour bar
    assert ax.get_xlim() == pytest.approx((775.0, 1625.0))
    renderer = _renderer(fig)
    box = ax.get_legend().get_window_extent(renderer)
    assert box.y1 <= ax.xaxis.label.get_window_extent(renderer).y0  # below the x label


# -- design -------------------------------------------------------------------------------
def _sensitivity():
    from bsfs_jax.design import SensitivityResult

    names = ("nut.balls", "bearing.balls", "nut.preload_n", "masses.nut_kg")
    norm = np.array([0.31, -0.05, 0.12, -0.48])
    theta = np.array([50.0, 16.0, 1500.0, 1.5])
    return SensitivityResult("natural_frequency", "Hz", 1141.2, None, None, names, theta,
                             norm * 1141.2 / theta, norm, "implicit AD")


def test_tornado():
    res = _sensitivity()
    fig = plotting.tornado(res, compare=res)
    _save(fig, "tornado")
    ax = fig.axes[0]
    _labelled(ax, y=False)
    assert ax.get_xlim() == pytest.approx((-0.6, 0.6))  # 1.25 x the largest bar
    _legend_clear(ax)


def test_optimization_summary():
    from bsfs_jax.design import OptimizationResult

    names = ("nut.balls", "masses.nut_kg")
    res = OptimizationResult(
        "natural_frequency", "Hz", "max", names, {"nut.balls": (35.0, 65.0),
                                                  "masses.nut_kg": (1.05, 1.95)},
        np.array([50.0, 1.5]), np.array([65.0, 1.05]), 1141.2, 1332.7, 16.8, None, 132.2,
        149.9, True, names, 60, False, None)
    checks = [{"simulated": 1140.0}, {"simulated": 1330.0}]
    fig = plotting.optimization_summary(res, checks=checks)
    _save(fig, "optimize")
    ax1, ax2 = fig.axes
    _labelled(ax1, y=False)
    _labelled(ax2, x=False)
    _legend_clear(ax1)
    _legend_clear(ax2)
    assert ax2.get_ylim()[1] >= 1332.7


# -- identification -----------------------------------------------------------------------
def test_fit_figure_legend_is_off_the_data():
    recs, coeffs, freqs = _records()
    fig = plotting.fit_figure(recs, coeffs, freqs, models=["model A", "model B"])
    _save(fig, "fit")
    axes = fig.axes
    renderer = _renderer(fig)
    for ax in axes:
        _labelled(ax, x=False)
        assert ax.get_legend() is None
    assert len(fig.legends) == 1  # one legend for all panels, outside every axes
    box = fig.legends[0].get_window_extent(renderer)
    for ax in axes:
        assert not box.overlaps(ax.get_window_extent(renderer))
    _labelled(axes[-2])
    _labelled(axes[-1])
    # Time panels: a few periods of the record, the model drawn smoothly (>= 32 points
    # per period even at a few samples per period).
    time_ax = axes[0]
    _tight(time_ax, y=False, slack=0.02)
    model = [ln for ln in time_ax.get_lines() if ln.get_linestyle() == "-"][0]
    assert np.median(np.diff(model.get_xdata())) <= 1e3 / freqs[0] / 32
    spec_ax = axes[1]
    assert spec_ax.get_xlim()[1] <= 4.5 * freqs[0] * 1.001


def test_fit_figure_sparse_record_draws_a_smooth_model():
    recs, coeffs, freqs = _records(n=1, fs=4000.0, f=900.0)  # 4.4 samples per period
    fig = plotting.fit_figure(recs, coeffs, freqs)
    _save(fig, "fit_sparse")
    model = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "-"][0]
    assert np.median(np.diff(model.get_xdata())) <= 1e3 / freqs[0] / 32


def test_correlation_figure():
    names = ["nut.preload_n", "bearing.preload_n", "damping.nut_n_s_per_m"]
    corr = np.array([[1.0, 0.9, -0.2], [0.9, 1.0, 0.1], [-0.2, 0.1, 1.0]])
    fig = plotting.correlation_figure(names, corr, [10.0, 1.0, 0.01], [0.01, 0.1, 5.0],
                                      threshold=0.1)
    _save(fig, "correlation")
    ax2 = fig.axes[1]
    _labelled(ax2, x=False)  # the x axis counts directions: whole numbers, no unit
    assert list(ax2.get_xticks()) == [1, 2, 3]
    _legend_clear(ax2)
    assert fig.axes[-1].get_ylabel() == "correlation [-]"


def test_plan_figure():
    plans = ["sine dwell", "stepped sine", "random"]
    params = ["nut.preload_n", "bearing.preload_n", "thermal.nut_offset_um"]
    rel = np.array([[0.01, 0.5, 2.0], [0.02, 0.05, np.inf], [0.2, 0.3, 0.4]])
    fig = plotting.plan_figure(plans, params, rel, recommended="stepped sine")
    _save(fig, "plan")
    ax = fig.axes[0]
    _labelled(ax, x=False)
    box = ax.get_legend().get_window_extent(_renderer(fig))
    tops = [ax.transData.transform((p.get_x() + p.get_width() / 2, p.get_height()))
            for p in ax.patches]
    assert sum(box.contains(*xy) for xy in tops) == 0  # no bar top under the legend


def test_frf_fit_figure():
    if not hasattr(plotting, "frf_fit_figure"):
        pytest.skip("no FRF fit figure in this version")
    f = np.linspace(600.0, 1800.0, 121)
    model = [-(f ** 2) / (1200.0 ** 2 - f ** 2 + 1j * 0.04 * 1200.0 * f) / 1.5]
    rng = np.random.default_rng(0)
    measured = [model[0] * (1 + 0.02 * rng.standard_normal(f.size))]
    variances = [np.full((f.size, 2), (0.02 * np.abs(model[0])[:, None]) ** 2 / 2)]
    fig = plotting.frf_fit_figure([f], measured, model, variances, ["stepped sine"])
    _save(fig, "frf_fit")
    mag, phase = fig.axes
    _labelled(mag, x=False)
    _labelled(phase)
    assert mag.get_xlim() == pytest.approx((600.0, 1800.0))
    box = fig.legends[0].get_window_extent(_renderer(fig))
    assert not box.overlaps(mag.get_window_extent(_renderer(fig)))
