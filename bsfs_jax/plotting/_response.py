"""The four-panel response figure of `bsfs simulate` (like the paper's Figs. 18-21)."""

import numpy as np


def amplitude_spectrum(t, x):
    """One-sided amplitude spectrum of a uniformly sampled signal: (freq [Hz], amplitude).

    The window is rectangular: `bsfs simulate` saves a whole number of forcing periods, so
    the forcing harmonics fall exactly on FFT bins (no leakage for periodic responses).
    The last sample (t = end, a duplicate of the first period's phase) is dropped.
    """
    t = np.asarray(t)[:-1]
    x = np.asarray(x)[:-1]
    n = x.size
    dt = (t[-1] - t[0]) / (n - 1)
    spec = np.fft.rfft(x - x.mean()) / n
    amp = np.abs(spec) * 2.0
    amp[0] /= 2.0
    return np.fft.rfftfreq(n, dt), amp


def response_figure(traj, *, title: str = "", dof: int = 2, max_harmonic: float = 8.0):
    """Time history, phase portrait, stroboscopic Poincare points and spectrum of one mass.

    `traj` is a `Trajectory` (numpy-convertible). Displacements in um, velocities in mm/s.
    """
    import matplotlib.pyplot as plt

    names = ("bearing joint x_b", "screw x_s", "nut + worktable x_n")
    t = np.asarray(traj.t)
    x = np.asarray(traj.displacement)[:, dof] * 1e6
    v = np.asarray(traj.velocity)[:, dof] * 1e3
    spp = traj.samples_per_period
    period = float(traj.period)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    ax = axes[0, 0]
    ax.plot((t - t[0]) * 1e3, x, lw=0.8, color="C0")
    ax.set_xlabel("time after transient [ms]")
    ax.set_ylabel(f"{names[dof]} [um]")
    ax.set_title("(a) time history")
    ax.grid(alpha=0.3)
    ax = axes[0, 1]
    ax.plot(x, v, lw=0.6, color="C1")
    ax.set_xlabel(f"{names[dof].split()[-1]} [um]")
    ax.set_ylabel("velocity [mm/s]")
    ax.set_title("(b) phase portrait")
    ax.grid(alpha=0.3)
    xlim, ylim = ax.get_xlim(), ax.get_ylim()
    ax = axes[1, 0]
    # Same limits as the phase portrait: a period-1 orbit shows as one isolated point
    # instead of an autoscaled cloud of integration round-off.
    ax.plot(x, v, lw=0.4, color="0.85", zorder=0)
    ax.plot(x[::spp], v[::spp], "o", ms=3.5, color="C3")
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    ax.set_xlabel(f"{names[dof].split()[-1]} at t = kT [um]")
    ax.set_ylabel("velocity at t = kT [mm/s]")
    ax.set_title(f"(c) Poincare section ({x[::spp].size} stroboscopic points)")
    ax.grid(alpha=0.3)
    ax = axes[1, 1]
    freq, amp = amplitude_spectrum(t, x)
    keep = freq <= max_harmonic / period
    ax.semilogy(freq[keep], amp[keep], lw=0.9, color="C2")
    ax.set_ylim(max(amp[keep].max(), 1e-12) * 1e-6, max(amp[keep].max(), 1e-12) * 3)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("amplitude [um] (log scale)")
    ax.set_title("(d) amplitude spectrum")
    ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
