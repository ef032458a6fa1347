"""Stroboscopic Poincare sections of forced systems (samples at t = t0 + kT)."""

import numpy as np


def stroboscopic(samples, samples_per_period: int, *, offset: int = 0):
    """Every `samples_per_period`-th sample (time along axis -2 or -1 for 1-D signals).

    For a record sampled `samples_per_period` times per forcing period starting at phase
    zero, these are the states at t = kT (+ `offset` samples): the stroboscopic section.
    """
    a = np.asarray(samples)
    if samples_per_period < 1:
        raise ValueError(f"samples_per_period must be >= 1, got {samples_per_period}")
    axis = -2 if a.ndim >= 2 else -1
    index = np.arange(offset, a.shape[axis], samples_per_period)
    return np.take(a, index, axis=axis)


def poincare_points(strobe, i: int = 0, j: int = 1):
    """(x_i, x_j) pairs of a stroboscopic section (k, n): the points to scatter-plot."""
    s = np.asarray(strobe)
    if s.ndim != 2:
        raise ValueError(f"expected a (samples, states) array, got shape {s.shape}")
    return s[:, i], s[:, j]
