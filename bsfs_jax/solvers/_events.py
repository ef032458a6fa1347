"""Locating continuation events (bifurcations, amplitude peaks) and assembling a Branch."""

import numpy as np

from ._branch import Bifurcation, Branch, Peak, test_values
from ._orbit import BRANCH_POINT, FOLD, NEIMARK_SACKER, PERIOD_DOUBLING

EVENT_KINDS = (FOLD, BRANCH_POINT, PERIOD_DOUBLING, NEIMARK_SACKER, "peak")
_PEAK = EVENT_KINDS.index("peak")


#: `_illinois` stops at the test function's noise floor: once the best |g| is at most
#: this fraction of its larger value at the bracket's ends and `STALLED` iterations in a
#: row have not halved it, the best point counts as located (a converged orbit's tangent,
#: and so a fold's test function, carries the corrector tolerance's noise: on `bsfs map`'s
#: 8000 N row |g| fell from 6e-6 to 1e-11 in 6 iterations and then wandered between
#: 1e-11 and 1e-9 for 12 more before one landed below 1e-6 relative by chance).
NOISE_FLOOR, STALLED = 1e-4, 2


def _illinois(kernel, before, after, k, iters):
    """Regula falsi (Illinois) on the step length h in (0, ds) for test function k.

    Returns (best point, located): the point of smallest |g| met, located where |g| is
    below 1e-6 of its larger value at the ends, the bracket has shrunk to 1e-10 of the
    step, or |g| has reached the noise floor (`NOISE_FLOOR`, `STALLED`)."""
    g_lo = test_values(before)[k]
    g_hi = test_values(after)[k]
    h_lo, h_hi = 0.0, after.ds_used
    g_ends = max(abs(g_lo), abs(g_hi))
    g_tol = 1e-6 * g_ends
    best, located = (after if abs(g_hi) < abs(g_lo) else before), False
    g_best = min(abs(g_lo), abs(g_hi))
    side = stalled = 0
    for _ in range(iters):
        h = (h_lo * g_hi - h_hi * g_lo) / (g_hi - g_lo)
        if not h_lo < h < h_hi:
            h = 0.5 * (h_lo + h_hi)
        pt = kernel.correct(before.u + h * before.tangent, before.tangent, ds_used=h,
                            chord=before)
        if not pt.converged:
            break
        g = test_values(pt)[k]
        stalled = stalled + 1 if abs(g) > 0.5 * g_best else 0
        if abs(g) < g_best:
            best, g_best = pt, abs(g)
        if abs(g) <= g_tol:
            located = True
            break
        if stalled >= STALLED and g_best <= NOISE_FLOOR * g_ends:
            located = True
            break
        if np.sign(g) == np.sign(g_lo):
            h_lo, g_lo = h, g
            if side == -1:
                g_hi *= 0.5
            side = -1
        else:
            h_hi, g_hi = h, g
            if side == 1:
                g_lo *= 0.5
            side = 1
        if abs(h_hi - h_lo) < 1e-10 * max(after.ds_used, 1e-300):
            located = True
            break
    return best, located


def locate_event(kernel, before, after, index, k, kind, iters):
    """A `Bifurcation` between two branch points (None for a neutral saddle)."""
    best, located = _illinois(kernel, before, after, k, iters)
    mu = best.mu
    if kind == NEIMARK_SACKER:
        # A genuine NS point has a complex pair on the unit circle; otherwise the test
        # function vanished at a real pair mu_i mu_j = 1 (a neutral saddle): skip it.
        near = np.abs(np.abs(mu) - 1.0) < 1e-2
        if not np.any(near & (np.abs(mu.imag) > 1e-6)):
            return None
    return Bifurcation(kind=kind, p=best.p(kernel.p_scale), state=best.state,
                       amplitude=float(best.amplitudes[kernel.amplitude_index]),
                       amplitudes=best.amplitudes, multipliers=mu, index=int(index),
                       located=located, point=best)


def locate_peak(kernel, before, after, index, iters):
    """The amplitude maximum (dA/ds = 0) between two branch points."""
    best, located = _illinois(kernel, before, after, _PEAK, iters)
    return Peak(p=best.p(kernel.p_scale),
                amplitude=float(best.amplitudes[kernel.amplitude_index]),
                amplitudes=best.amplitudes, state=best.state, point=best, index=int(index),
                located=located, slope=float(best.slope))


def points_to_branch(points, arclength, bifurcations, peaks, kernel, n_periods, info):
    mus = np.stack([pt.mu for pt in points])
    return Branch(
        p=np.array([pt.p(kernel.p_scale) for pt in points]),
        states=np.stack([pt.state for pt in points]),
        amplitudes=np.stack([pt.amplitudes for pt in points]),
        amplitude_index=int(kernel.amplitude_index),
        multipliers=mus,
        stable=np.max(np.abs(mus), axis=1) < 1.0,
        arclength=np.array(arclength),
        residuals=np.array([pt.residual for pt in points]),
        error_estimates=np.array([pt.error for pt in points]),
        newton_steps=np.array([pt.steps for pt in points]),
        bifurcations=tuple(bifurcations),
        peaks=tuple(sorted(peaks, key=lambda pk: pk.index)),
        n_periods=int(n_periods),
        info=info,
        method=kernel.method,
        scale=np.asarray(kernel.scale),
    )
