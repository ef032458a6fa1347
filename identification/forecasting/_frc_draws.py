"""The FRC's peak and folds by the model itself at each of the identification's draws.

Where the identification saved draws (bootstrap refits or posterior draws), each located
point of the estimate's branch (the peak, each fold) is followed to every draw by Newton
on its extended system (`bsfs_jax.design.follow_point`), in one program: the draws
vmapped, the points one after another. The values decide the interval
(`_forecast_frc_checks.from_draws`: the linear model's error measured over the draws;
where it is large, their 2.5-97.5 % range, method "model at each draw"). A draw at which
a point cannot be followed (a fold gone, a Newton failure) is given NaN, not a value:
the quantity then falls back to the probes' quadratic model and says at how many draws
the model failed.

The same program gives each point's gradient at the estimate, from the extended system
it follows the point with (`bsfs_jax.design.follow_start_and_gradient`: implicit
differentiation with E's Jacobian, the chord Newton's, from the same forward pass).
Where the joints lose contact at the peak (the curve continued by shooting) the force is
only C^1, and the second derivatives of the shooting residual that the peak frequency's
implicit gradient needs are approximate: on the bundled worn drive at 100 N it was
1.6-2.8 % off central differences of the located peak on the three dampers (the
augmented system used before: 0.1-1.6 %).
There the peak frequency's gradient is taken by central differences of the followed peak
instead (`central=True`): 2p more lanes, at the estimate +-0.5 standard deviations of
each coordinate (the peak followed to within about 5e-5 Hz), in the same program. The
amplitude's and the folds' gradients are the implicit ones, equal to the hyperplane
system's (`bsfs_jax.design.frc_point_values`) to 1e-6 relative.
"""

from __future__ import annotations

import functools

import numpy as np

import bsfs_jax

from ._batches import draw_batches, lane_parts, run_batches
from ._intervals import Identified

BATCH_ROUND = 8  # the last batch of draws padded to a multiple of this (`draw_batches`)
#: The peak frequency's central differences step +-CENTRAL_SD standard deviations of each
#: fitted coordinate (`central_steps`).
CENTRAL_SD = 0.5


@bsfs_jax.cached_jit
def _points_at_draws(coords, theta, thetas, force, hints, weights):
    """((k, n, 3), (k, 2, p)): (nut amplitude [m], frequency [Hz], converged) of each of
    the k stacked located points `hints` (`weights`: 1 the peak, 0 a fold) at each row of
    `thetas`, followed from the estimate `theta`; and each point's gradient
    d(amplitude, frequency)/dtheta at the estimate (`follow_start_and_gradient`, from the same
    extended system and its factored Jacobian)."""
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design.building import follow_point, follow_start_and_gradient

    def one(hint, weight):
        start, gradient = follow_start_and_gradient(coords.at, theta, force, hint, weight)

        def lane(th):
            amp, freq, ok = follow_point(coords.at(th), force, hint, weight, start)
            return jnp.stack([amp, freq, ok.astype(float)])

        return jax.vmap(lane)(thetas), gradient

    # The points one after another (a scan), each its draws vmapped: vmapped over the
    # points too, every lane of the three waited for the slowest of all (the chord steps
    # differ by point), and the nested batching traced and compiled more. On the bundled
    # worn drive at 100 N (3 points x 112 lanes): 3.6 s a call against 7.1 s, compiled in
    # 11.3 s against 12.8 s; the values the same to the followed peak's own noise (its
    # frequency within 3e-4 Hz, median 1.3e-5 Hz, of an interval 0.45 Hz wide; the folds'
    # within 6e-9 Hz).
    return jax.lax.map(lambda point: one(*point), (hints, weights))


def central_steps(ident: Identified) -> np.ndarray:
    """(2p, p): the estimate moved by +-CENTRAL_SD standard deviations along each fitted
    coordinate, the lanes whose followed peak gives the peak frequency's central
    differences (`frc_points`)."""
    moves = np.diag(_central_step(ident))
    return ident.theta + np.concatenate([moves, -moves])


def _central_step(ident: Identified) -> np.ndarray:
    return CENTRAL_SD * np.sqrt(np.diag(ident.covariance))


def _calls(ident: Identified, force: float, hints, peak, central: bool = False) -> list:
    """The arguments of `_points_at_draws` for each batch of its lanes: the
    `central_steps` first where `central`, then the draws (`draw_batches`, padded to a
    multiple of BATCH_ROUND: each lane costs its integrations); without either, one lane,
    the estimate (for the gradients)."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *hints)
    weights = jnp.asarray([1.0 if p else 0.0 for p in peak])
    theta, force = jnp.asarray(ident.theta, float), jnp.asarray(force, float)
    rows = [central_steps(ident)] if central else []
    rows += [] if ident.draws is None else [ident.draws]
    batches = [np.asarray(ident.theta)[None]] if not rows else draw_batches(
        dataclasses.replace(ident, draws=np.concatenate(rows)), BATCH_ROUND,
        lane_parts(ident))
    return [(ident.coordinates, theta, jnp.asarray(thetas, float), force, stacked, weights)
            for thetas in batches]


def points_at_draws(ident: Identified, force: float, hints, peak, calls=None,
                    first=None, skip: int = 0) -> np.ndarray:
    """(k, n, 2): (nut amplitude [m], frequency [Hz]) of each located point `hints[i]`
    (`peak[i]`: the FRC peak, else a fold) followed to each of the n draws; NaN where it
    could not be followed. `calls`: `_calls`'s arguments, where already laid out, with
    `skip` lanes before the draws; `first`: the first call's result, where computed."""
    calls = _calls(ident, force, hints, peak) if calls is None else calls
    done = [] if first is None else [first]
    return _followed(done + run_batches(_points_at_draws, calls[len(done):],
                                    ident.cluster), skip,
                     len(ident.draws))


def _followed(results: list, skip: int, n: int) -> np.ndarray:
    """`points_at_draws`' array from `_points_at_draws`' results for every batch."""
    out = np.concatenate([np.asarray(r[0]) for r in results], axis=1)[:, skip:skip + n]
    return np.where(out[:, :, 2:] > 0.5, out[:, :, :2], np.nan)


def frc_points(ident: Identified, force: float, specs, central: bool = False
               ) -> tuple[dict, object]:
    """(exact, gradients) for the FRC quantities `specs` ((name, unit, scale, hint) each;
    the peak's two share its hint), from one program (`_points_at_draws`), which starts
    compiling now on the background thread (the probes' continuations run meanwhile):

    - exact: {name: callable returning the quantity at each draw (m, Hz: before the
      quantity's `scale`)} for `_checked`'s `exact`, every point followed in one batch on
      the first call; {} where the identification has no draws;
    - gradients(): ({name: d(quantity)/dtheta at the estimate (m, Hz per fitted unit)},
      whether the peak frequency's is by central differences): by the implicit function
      theorem (`follow_start_and_gradient`); with `central`, the peak frequency's by central
      differences of the followed peak instead (module docstring), where the peak was
      followed to every step (else the implicit one, and False)."""
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
    central = central and True in peak
    calls = _calls(ident, force, hints, peak, central)
    if ident.cluster is None or ident.draws is None:  # (else the workers compile it)
        _points_at_draws.prefetch_now(*calls[0])
    # every batch at once, on `run_batches`' threads (the gradients are the first's)
    results = functools.cache(lambda: run_batches(_points_at_draws, calls, ident.cluster))
    p = len(ident.theta)
    skip = 2 * p if central else 0

    def gradients():
        lanes = np.concatenate([r[0] for r in results()], axis=1)
        grads = results()[0][1]
        out = {name: grads[k, c] for name, (k, c) in where.items()}
        if central:
            k = peak.index(True)
            f, ok = lanes[k, :2 * p, 1], lanes[k, :2 * p, 2] > 0.5
            if np.all(ok):
                out["peak_frequency_hz"] = (f[:p] - f[p:]) / (2.0 * _central_step(ident))
                return out, True
        return out, False

    if ident.draws is None:
        return {}, gradients
    batch = functools.cache(lambda: _followed(results(), skip, len(ident.draws)))
    exact = {name: (lambda k=k, c=c: batch()[k, :, c]) for name, (k, c) in where.items()}
    return exact, gradients
