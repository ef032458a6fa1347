"""Largest Lyapunov exponent from the tangent dynamics (jax.jvp + Benettin renormalisation).

The variational equation v' = J(t, y) v is integrated alongside y' = f(t, y, args), with
J v computed by `jax.jvp` of the vector field (no Jacobian is formed). Every `interval`
the tangent vector is renormalised to unit length and log|v| is accumulated (Benettin et
al. 1980); the exponent is the mean growth rate after the tangent has aligned with the
most unstable direction.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..solvers import RESULTS, SolverSettings, integrate


class TangentField(eqx.Module):
    """The augmented field z = (y, v) -> (f(t, y), J(t, y) v) of a vector field f(t, y, args)."""

    vector_field: object

    def __call__(self, t, z, args):
        n = z.shape[0] // 2
        y, v = z[:n], z[n:]
        fy, jv = jax.jvp(lambda yy: self.vector_field(t, yy, args), (y,), (v,))
        return jnp.concatenate([fy, jv])


class LyapunovResult(eqx.Module):
    """`exponent` [1/time unit], per-interval `log_growth`, final `state`, the solver
    `result` (a `RESULTS` item; the exponent is NaN unless it is successful) and the
    renormalisation `interval`."""

    exponent: jax.Array
    log_growth: jax.Array
    state: jax.Array
    result: RESULTS
    interval: jax.Array = None

    def confidence_interval(self, segments: int = 8):
        """(low, high): the 95 % confidence interval of `exponent` [1/time unit] from
        `segments` independent consecutive segments of the counted intervals
        (Student t on the segment means; NaN if the run failed)."""
        from ._evidence import exponent_interval

        _, lo, hi = exponent_interval(np.asarray(self.log_growth), segments)
        dt = float(self.interval)
        return lo / dt, hi / dt

    @property
    def ok(self) -> jax.Array:
        """Bool array: `result == RESULTS.successful`."""
        return self.result == RESULTS.successful


def first_failure(a, b):
    """The first unsuccessful of two `RESULTS` items (`a` if it failed, else `b`)."""
    return RESULTS.where(a == RESULTS.successful, b, a)


def initial_tangent(n: int):
    """A fixed generic unit tangent vector (not aligned with any coordinate axis)."""
    v = 1.0 + 0.1 * jnp.arange(n, dtype=float)
    return v / jnp.linalg.norm(v)


def benettin_steps(vector_field, y, args, t0, interval, n_intervals: int,
                   settings: SolverSettings, *, tangent=None, ts_per_interval=None):
    """Integrate state + tangent over `n_intervals` intervals, renormalising after each.

    Traceable core used by `largest_lyapunov` and by the sweeps.

    **Returns:** `(y_end, v_end, log_growth (n_intervals,), samples, result, num_steps)`,
    with `v_end` the unit tangent vector at the end, and `samples`
    (n_intervals, k, n) states at `t_i + interval * (1..k)/k` when `ts_per_interval=k`
    is given (else (n_intervals, 1, n): the state at the end of each interval); `result`
    is the first unsuccessful `RESULTS` item of the intervals (or `successful`).
    """
    n = y.shape[0]
    k = 1 if ts_per_interval is None else int(ts_per_interval)
    v = initial_tangent(n) if tangent is None else tangent
    field = TangentField(vector_field)
    frac = jnp.arange(1, k + 1, dtype=float) / k

    def step(carry, i):
        z, result, steps = carry
        t_a = t0 + i * interval
        t_b = t0 + (i + 1) * interval
        ts = t_a + interval * frac
        ts = ts.at[-1].set(t_b)
        res = integrate(field, z, args, t_a, t_b, ts, settings, throw=False)
        z_end = res.ys[-1]
        g = jnp.linalg.norm(z_end[n:])
        ok = jnp.isfinite(g) & (g > 0)
        g_safe = jnp.where(ok, g, 1.0)
        z_new = jnp.concatenate([z_end[:n], z_end[n:] / g_safe])
        result = first_failure(result, res.result)
        log_g = jnp.where(ok, jnp.log(g_safe), jnp.nan)
        return (z_new, result, steps + res.num_steps), (log_g, res.ys[:, :n])

    z0 = jnp.concatenate([y, v])
    init = (z0, RESULTS.successful, jnp.asarray(0))
    (z, result, steps), (logs, samples) = jax.lax.scan(step, init, jnp.arange(n_intervals))
    return z[:n], z[n:], logs, samples, result, steps


def exponent_from_growth(log_growth, interval, discard: float = 0.25):
    """Mean growth rate of `log_growth` per unit time, dropping the first `discard` fraction
    (tangent alignment)."""
    m = log_growth.shape[-1]
    start = int(discard * m)
    return jnp.mean(log_growth[..., start:], axis=-1) / interval


@eqx.filter_jit
def _lyapunov_core(vector_field, y0, args, t0, interval, transient_intervals: int,
                   align_intervals: int, n_intervals: int, settings: SolverSettings):
    y = jnp.asarray(y0, dtype=float)
    result = RESULTS.successful
    if transient_intervals > 0:
        t1 = t0 + transient_intervals * interval
        res = integrate(vector_field, y, args, t0, t1, jnp.stack([t1]), settings, throw=False)
        y, result = res.ys[-1], res.result
        t0 = t1
    tangent = None
    if align_intervals > 0:
        # The tangent vector turns towards the most unstable direction; its growth over
        # these intervals is not counted.
        y, tangent, _, _, st, _ = benettin_steps(vector_field, y, args, t0, interval,
                                                 align_intervals, settings)
        result = first_failure(result, st)
        t0 = t0 + align_intervals * interval
    y_end, _, logs, _, st, _ = benettin_steps(vector_field, y, args, t0, interval, n_intervals,
                                              settings, tangent=tangent)
    result = first_failure(result, st)
    exponent = exponent_from_growth(logs, interval, discard=0.0)
    return LyapunovResult(jnp.where(result == RESULTS.successful, exponent, jnp.nan), logs,
                          y_end, result, interval)


def largest_lyapunov(vector_field, y0, args, *, interval, n_intervals: int,
                     transient_intervals: int = 0, align_intervals: int = 10, t0=0.0,
                     settings: SolverSettings = SolverSettings()) -> LyapunovResult:
    """Largest Lyapunov exponent of y' = f(t, y, args) by Benettin's method.

    **Arguments:**
    - `vector_field`: any f(t, y, args) (autonomous or periodically forced).
    - `y0`: initial state; `args`: passed to f.
    - `interval`: renormalisation interval (for forced systems: the forcing period, so the
      result also equals the exponent of the stroboscopic map divided by T; for
      autonomous flows any interval of the order of the flow's correlation time).
    - `n_intervals`: number of intervals averaged; `transient_intervals`: intervals
      integrated first (without the tangent) to reach the attractor;
      `align_intervals`: intervals integrated with the tangent vector, renormalised but
      not counted, so that it has turned towards the most unstable direction first.
    - `settings`: `SolverSettings` (tolerances also apply to the tangent vector).

    **Returns:** `LyapunovResult` with `exponent` in 1/(time unit of f) (NaN if the solve
    failed; see `result`, a `RESULTS` item), the per-interval `log_growth` of the counted
    intervals, and `confidence_interval()` from independent segments.
    """
    if n_intervals < 1:
        raise ValueError(f"n_intervals must be >= 1, got {n_intervals}")
    if int(align_intervals) < 0 or int(transient_intervals) < 0:
        raise ValueError("align_intervals and transient_intervals must be >= 0, got "
                         f"{align_intervals} and {transient_intervals}")
    return _lyapunov_core(vector_field, y0, args, jnp.asarray(t0, dtype=float),
                          jnp.asarray(interval, dtype=float), int(transient_intervals),
                          int(align_intervals), int(n_intervals), settings)
