"""One sweep point, traceable: what each point of a sweep returns.

`_point` integrates the transient and the recorded periods (with the tangent dynamics when
`SweepConfig.lyapunov`); `_reduce` turns recorded samples into the same outputs (used by the
work-queue engine, which records the samples itself). Both return a dict of fixed-size
arrays: strobe (periods + 1, n), amplitude/mean/peak (n,), spectrum (bins,), lyapunov (),
log_growth (periods,), status (), num_steps (), end_state (n,), period ().
"""

import equinox as eqx
import jax.numpy as jnp

from .._numerics import half_range
from ..solvers import RESULTS, integrate, result_code
from ._lyapunov import benettin_steps, exponent_from_growth, first_failure
from ._spectrum import amplitude_spectrum
from ._sweep_problem import OK, SweepConfig, SweepProblem


def _point(problem: SweepProblem, value, y_start, n_transient, cfg: SweepConfig):
    """Steady response at one parameter value: a dict of fixed-size arrays."""
    args, period = problem.setup(problem.data, value)
    # (+ 0 * n_transient: under vmap the period is then batched like the transient. With a
    # batched transient but an unbatched period, diffrax's check that the save times lie
    # in [t0, t1] failed inside the Lyapunov scan although they did; seen on the CPU.)
    period = jnp.asarray(period, dtype=float) + 0.0 * n_transient
    settings = cfg.settings
    n_states = problem.n_states
    P, spp = cfg.periods, cfg.samples_per_period
    align = cfg.lyapunov_align_periods if cfg.lyapunov else 0
    t_plain = (n_transient - align) * period
    t1 = n_transient * period
    res = integrate(problem.vector_field, y_start, args, 0.0, t_plain, jnp.stack([t_plain]),
                    settings, throw=False)
    y = res.ys[-1]
    if cfg.lyapunov:
        tangent, steps_a = None, 0
        if align:
            y, tangent, _, _, st_a, steps_a = benettin_steps(
                problem.vector_field, y, args, t_plain, period, align, settings)
            res = eqx.tree_at(lambda r: r.result, res, first_failure(res.result, st_a))
        y_end, _, logs, samples, result2, steps2 = benettin_steps(
            problem.vector_field, y, args, t1, period, P, settings, tangent=tangent,
            ts_per_interval=spp)
        steps2 = steps2 + steps_a
        lyap = exponent_from_growth(logs, period, discard=0.0 if align else 0.25)
    else:
        frac = jnp.arange(1, P * spp + 1, dtype=float) / spp
        ts = t1 + period * frac
        res2 = integrate(problem.vector_field, y, args, t1, ts[-1], ts, settings, throw=False)
        samples = res2.ys.reshape(P, spp, n_states)
        y_end, result2, steps2 = res2.ys[-1], res2.result, res2.num_steps
        logs = jnp.full((P,), jnp.nan)
        lyap = jnp.asarray(jnp.nan)
    result = first_failure(res.result, result2)
    flat = samples.reshape(P * spp, n_states)
    ok = result == RESULTS.successful
    flat = jnp.where(ok, flat, jnp.nan)
    strobe = jnp.concatenate([y[None, :], samples[:, -1, :]], axis=0)
    strobe = jnp.where(ok, strobe, jnp.nan)
    _, spectrum = amplitude_spectrum(flat[:, problem.observe], period / spp, window=cfg.window)
    return {
        "strobe": strobe,
        "amplitude": half_range(flat, axis=0),
        "mean": jnp.mean(flat, axis=0),
        "peak": jnp.max(jnp.abs(flat), axis=0),
        "spectrum": spectrum,
        "lyapunov": jnp.where(ok, lyap, jnp.nan),
        "log_growth": jnp.where(ok, logs, jnp.nan),
        "status": result_code(result),
        "num_steps": res.num_steps + steps2,
        "end_state": jnp.where(ok, y_end, jnp.nan),
        "period": period,
    }


def _reduce(problem, cfg: SweepConfig, samples, y_start, y_end, status, steps, period):
    """Per-point outputs from the recorded samples (P, spp, n); `status` a result code."""
    P, spp, n_states = cfg.periods, cfg.samples_per_period, problem.n_states
    ok = status == OK
    flat = jnp.where(ok, samples.reshape(P * spp, n_states), jnp.nan)
    strobe = jnp.concatenate([y_start[None, :], samples[:, -1, :]], axis=0)
    _, spectrum = amplitude_spectrum(flat[:, problem.observe], period / spp, window=cfg.window)
    return {
        "strobe": jnp.where(ok, strobe, jnp.nan),
        "amplitude": half_range(flat, axis=0),
        "mean": jnp.mean(flat, axis=0),
        "peak": jnp.max(jnp.abs(flat), axis=0),
        "spectrum": spectrum,
        "lyapunov": jnp.asarray(jnp.nan),
        "log_growth": jnp.full((P,), jnp.nan),
        "status": status,
        "num_steps": steps,
        "end_state": jnp.where(ok, y_end, jnp.nan),
        "period": period,
    }
