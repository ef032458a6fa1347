"""The FRC's peak and folds by the model itself at each of the identification's draws.

Where the identification saved draws (bootstrap refits or posterior draws), each located
point of the estimate's branch (the peak, each fold) is followed to every draw by Newton
on its extended system (`bsfs_jax.design.follow_point`), all draws and points in one
vmapped program. The values decide the interval (`_forecast_frc_checks.from_draws`: the
linear model's error measured over the draws; where it is large, their 2.5-97.5 % range,
method "model at each draw"). A draw at which a point cannot be followed (a fold gone, a
Newton failure) is given NaN, not a value: the quantity then falls back to the probes'
quadratic model and says at how many draws the model failed.
"""

from __future__ import annotations

import functools

import numpy as np

import bsfs_jax

from ._forecast import Identified, draw_batches

BATCH_ROUND = 8  # the last batch of draws padded to a multiple of this (`draw_batches`)


@bsfs_jax.cached_jit
def _points_at_draws(coords, theta, thetas, force, hints, weights):
    """(k, n, 3): (nut amplitude [m], frequency [Hz], converged) of each of the k stacked
    located points `hints` (`weights`: 1 the peak, 0 a fold) at each row of `thetas`,
    followed from the estimate `theta`."""
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design import follow_point, follow_start

    params = coords.at(theta)

    def one(hint, weight):
        start = follow_start(params, force, hint, weight)

        def lane(th):
            amp, freq, ok = follow_point(coords.at(th), force, hint, weight, start)
            return jnp.stack([amp, freq, ok.astype(float)])

        return jax.vmap(lane)(thetas)

    return jax.vmap(one)(hints, weights)


def _calls(ident: Identified, force: float, hints, peak) -> list:
    """The arguments of `_points_at_draws` for each batch of the draws (`draw_batches`,
    padded to a multiple of BATCH_ROUND: each lane costs its integrations)."""
    import jax
    import jax.numpy as jnp

    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *hints)
    weights = jnp.asarray([1.0 if p else 0.0 for p in peak])
    theta, force = jnp.asarray(ident.theta, float), jnp.asarray(force, float)
    return [(ident.coordinates, theta, jnp.asarray(thetas, float), force, stacked, weights)
            for thetas in draw_batches(ident, BATCH_ROUND)]


def points_at_draws(ident: Identified, force: float, hints, peak, calls=None) -> np.ndarray:
    """(k, n, 2): (nut amplitude [m], frequency [Hz]) of each located point `hints[i]`
    (`peak[i]`: the FRC peak, else a fold) followed to each of the n draws; NaN where it
    could not be followed. `calls`: `_calls`'s arguments, where already laid out."""
    calls = _calls(ident, force, hints, peak) if calls is None else calls
    out = np.concatenate([np.asarray(_points_at_draws(*args)) for args in calls],
                         axis=1)[:, :len(ident.draws)]
    return np.where(out[:, :, 2:] > 0.5, out[:, :, :2], np.nan)


def frc_exact(ident: Identified, force: float, specs) -> dict:
    """{name: callable returning the quantity at each draw (m, Hz: before the quantity's
    `scale`)} for the FRC quantities `specs` ((name, unit, scale, hint) each; the peak's
    two share its hint), for `_checked`'s `exact`; every point is followed in one batch,
    on the first call, whose program starts compiling now on the background thread (the
    probes' continuations run meanwhile). {} where the identification has no draws."""
    if ident.draws is None:
        return {}
    hints, peak, where = [], [], {}
    for name, _, _, hint in specs:
        is_peak = name in ("peak_frequency_hz", "peak_amplitude_um")
        column = 0 if name == "peak_amplitude_um" else 1
        if is_peak and True in peak:
            where[name] = (peak.index(True), column)
            continue
        where[name] = (len(hints), column)
        hints.append(hint)
        peak.append(is_peak)
    calls = _calls(ident, force, hints, peak)
    _points_at_draws.prefetch_now(*calls[0])
    batch = functools.cache(lambda: points_at_draws(ident, force, hints, peak, calls))
    return {name: (lambda k=k, c=c: batch()[k, :, c]) for name, (k, c) in where.items()}
