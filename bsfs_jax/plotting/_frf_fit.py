"""Measured FRF lines (with their 95 % bands) against the fitted model's accelerance."""

from __future__ import annotations

import numpy as np


def frf_fit_figure(frequencies_hz, measured, model, variances, names):
    """Magnitude and phase of accelerance per FRF record, measured vs fitted model.

    Each argument is a list with one entry per record: line frequencies [Hz], measured and
    model accelerance [m/s^2 per N] (complex), (L, 2) variances of (Re, Im) and a name.
    """
    import matplotlib.pyplot as plt

    n = len(names)
    fig, axes = plt.subplots(2, n, figsize=(5.2 * n + 0.8, 6.0), squeeze=False,
                             sharex="col", gridspec_kw=dict(height_ratios=(2, 1)))
    for j in range(n):
        f = np.asarray(frequencies_hz[j], float)
        h = np.asarray(measured[j], complex)
        m = np.asarray(model[j], complex)
        sd = np.sqrt(np.sum(np.asarray(variances[j], float), axis=1) / 2.0)
        ax = axes[0, j]
        ax.fill_between(f, np.maximum(np.abs(h) - 1.96 * sd, np.abs(h) * 1e-3),
                        np.abs(h) + 1.96 * sd, color="0.8", lw=0, label="measured, 95 % band")
        ax.semilogy(f, np.abs(h), ".", ms=2.5, color="0.35", label="measured lines")
        ax.semilogy(f, np.abs(m), "-", color="C3", lw=1.3, label="fitted model")
        ax.set_ylabel("accelerance |A/F| [m/s² per N]")
        ax.set_title(str(names[j]), fontsize=9)
        ax.set_xlim(f.min(), f.max())
        ax = axes[1, j]
        ax.plot(f, np.degrees(np.angle(h)), ".", ms=2.5, color="0.35")
        ax.plot(f, np.degrees(np.angle(m)), "-", color="C3", lw=1.3)
        ax.set_ylabel("phase [degrees]")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylim(-185, 185)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=3, fontsize=8,
               bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig
