"""The four-panel response figure of a simulated `Trajectory` (like the paper's Figs. 18-21)."""

import numpy as np

from ..analysis import amplitude_spectrum
from ._analysis import plot_response

_NAMES = ("bearing joint x_b", "screw x_s", "nut + worktable x_n")


def trajectory_spectrum(traj, dof: int = 2):
    """(freqs [Hz], amplitude [m]) of one mass over the saved steady state.

    Rectangular window: `simulate` saves a whole number of forcing periods, so the forcing
    harmonics fall on FFT bins (no leakage for periodic responses). The last saved sample
    (the end time, the same phase as the first) is dropped.
    """
    t = np.asarray(traj.t)
    x = np.asarray(traj.displacement)[:-1, dof]
    return amplitude_spectrum(x, float(t[1] - t[0]), window="rect")


def response_figure(traj, *, title: str = "", dof: int = 2,
                    max_harmonic: float | None = None):
    """Time history, phase portrait, Poincare points and spectrum of one mass of `traj`.

    The spectrum's axis ends at its last line above the plotted floor (every line that
    `simulate`'s summary lists as dominant is on it), at least at the 2nd harmonic of the
    forcing; `max_harmonic` caps it at that many harmonics instead.
    """
    # On the host: `traj.state` would compile a concatenation program for one figure.
    state = np.concatenate([np.asarray(traj.displacement), np.asarray(traj.velocity)], axis=-1)
    strobe = state[:: traj.samples_per_period][:, [dof, dof + 3]]
    freqs, amp = trajectory_spectrum(traj, dof)
    f0 = 1.0 / float(traj.period)
    return plot_response(np.asarray(traj.t), state[:, dof], state[:, dof + 3], strobe, freqs,
                         amp, title=title or "Response", name=_NAMES[dof],
                         max_frequency_hz=None if max_harmonic is None else max_harmonic * f0,
                         min_frequency_hz=2.0 * f0, window="rect")
