"""Figures of the identification: measured vs model acceleration, correlations, test plans.

Plotting only: every number comes from the identification results passed in.
"""

import numpy as np

from ._layout import place_legend


def fit_figure(records, model_coeffs, frequencies_hz, models=None, *, periods: float = 3.0,
               max_records: int = 18):
    """Per record: time (a few periods, DC removed) and amplitude spectrum, measured vs model.

    `records`: objects with `time`, `acceleration`, `sample_rate_hz`, `name`;
    `model_coeffs`: complex acceleration harmonics per record; `frequencies_hz`: refined
    excitation frequency per record; `models`: optional label per record.
    """
    import matplotlib.pyplot as plt

    n = min(len(records), max_records)
    height = 2.0 * n + 1.0
    fig, axes = plt.subplots(n, 2, figsize=(11, height), squeeze=False)
    for i in range(n):
        rec, c, f = records[i], np.asarray(model_coeffs[i]), float(frequencies_hz[i])
        t, a = rec.time, rec.acceleration - np.mean(rec.acceleration)
        m = t < t[0] + periods / f
        k = np.arange(1, c.size + 1)
        # The model on its own dense grid (64 points per period): smooth even where the
        # record has only a few samples per period.
        tm = t[0] + np.arange(int(np.ceil(64 * periods)) + 1) / (64 * f)
        model = np.real(np.exp(2j * np.pi * f * np.outer(tm, k)) @ c)
        ax = axes[i, 0]
        ax.plot(1e3 * (t[m] - t[0]), a[m], ".", ms=2, color="0.45", label="measured")
        ax.plot(1e3 * (tm - t[0]), model, "-", color="C3", lw=1.2,
                label="model (steady state)")
        ax.set_xlim(0.0, 1e3 * periods / f)
        ax.set_ylabel("acceleration [m/s²]")
        label = f" ({models[i]})" if models is not None else ""
        ax.set_title(f"{rec.name}{label}", fontsize=9)
        if i == n - 1:
            ax.set_xlabel("time from the record's start [ms]")
        ax = axes[i, 1]
        win = np.hanning(a.size)
        spec = 2 * np.abs(np.fft.rfft(a * win)) / np.sum(win)
        fr = np.fft.rfftfreq(a.size, 1 / rec.sample_rate_hz)
        ax.semilogy(fr, spec, color="0.45", lw=0.7, label="measured (Hann)")
        ax.semilogy(f * k, np.abs(c), "o", mfc="none", color="C3", label="model harmonics")
        ax.set_xlim(0, min(rec.sample_rate_hz / 2, 4.5 * f))
        ax.set_ylabel("amplitude [m/s²]")
        if i == n - 1:
            ax.set_xlabel("frequency [Hz]")
    # One legend for all panels, between the title and the first row: never over data.
    handles = [h for ax in axes[0] for h in ax.get_legend_handles_labels()[0]]
    # Heights in inches from the top: title 0.08-0.33, legend 0.36-0.6, panels below.
    fig.suptitle("Worktable acceleration: measured vs identified model", fontsize=11,
                 y=1.0 - 0.08 / height, va="top")
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 1.0 - 0.36 / height))
    # A fixed layout in inches (tight_layout measured every tick label of the 2n panels:
    # about 0.7 s of a warm `bsfs identify`): 0.85 in for the y labels of each column,
    # 0.6 in between rows for the tick labels and the next title, 0.55 in for the x label,
    # 0.95 in above the first row for the suptitle, the legend and the first title.
    left, right, gap_x, top, bottom, gap_y = 0.85, 0.2, 1.0, 0.95, 0.55, 0.6
    width = fig.get_figwidth()
    ax_w = (width - left - right - gap_x) / 2
    ax_h = (height - top - bottom - (n - 1) * gap_y) / n
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height,
                        top=1 - top / height, wspace=gap_x / ax_w, hspace=gap_y / ax_h)
    return fig


def correlation_figure(names, correlation, singular_values, direction_std=None,
                       threshold=None):
    """Correlation matrix of the estimates and the scaled singular values."""
    import matplotlib.pyplot as plt

    corr = np.asarray(correlation, float)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.8),
                                   gridspec_kw=dict(width_ratios=[1.2, 1]))
    im = ax1.imshow(np.nan_to_num(corr), vmin=-1, vmax=1, cmap="RdBu_r")
    ax1.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=8)
    ax1.set_yticks(range(len(names)), names, fontsize=8)
    for i in range(len(names)):
        for j in range(len(names)):
            if np.isfinite(corr[i, j]):
                ax1.text(j, i, f"{corr[i, j]:.2f}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax1, label="correlation [-]")
    ax1.set_title("Correlation of the estimates (Gauss-Newton)")
    sv = np.asarray(singular_values, float)
    sv = sv / sv[0]
    ax2.semilogy(np.arange(1, sv.size + 1), sv, "o-", label="scaled singular value")
    if direction_std is not None:
        ax2.semilogy(np.arange(1, sv.size + 1), direction_std, "s--",
                     label="std of the combination")
    if threshold is not None:
        ax2.axhline(threshold, color="C3", lw=0.8, ls=":", label=f"identified below {threshold}")
    ax2.set_xticks(np.arange(1, sv.size + 1))
    ax2.set_xlabel("direction: right singular vector number (largest first)")
    ax2.set_ylabel("scaled value [-]")
    ax2.set_title("Identifiability: scaled Jacobian spectrum")
    fig.tight_layout()
    place_legend(ax2, fontsize=8)
    fig.tight_layout()
    return fig


def plan_figure(plan_names, param_names, rel_std, *, threshold=0.1, recommended=None):
    """Expected standard errors (relative, or um for offsets) of each parameter per plan."""
    import matplotlib.pyplot as plt

    rel = np.asarray(rel_std, float)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    width = 0.8 / len(plan_names)
    x = np.arange(len(param_names))
    for j, name in enumerate(plan_names):
        lbl = name + ("  (recommended)" if name == recommended else "")
        ax.bar(x + (j - (len(plan_names) - 1) / 2) * width, np.minimum(rel[j], 1e6), width,
               label=lbl)
    ax.axhline(threshold, color="k", ls=":", lw=0.8, label=f"identifiable below {threshold}")
    ax.set_yscale("log")
    ax.set_xticks(x, param_names, rotation=30, ha="right")
    ax.set_ylabel("expected standard error [relative; µm for offsets]")
    ax.set_title("Test plans: expected standard errors from the Fisher information\n"
                 "(bars at 1e6: not identifiable, infinite variance)", fontsize=10)
    fig.tight_layout()
    place_legend(ax, fontsize=8)
    fig.tight_layout()
    return fig
