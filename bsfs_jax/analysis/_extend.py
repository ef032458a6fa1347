"""Batched continuation of sampled trajectories with their tangent dynamics (the verifier's
long runs): blocks of forcing periods, each recording the stroboscopic points, the
per-period tangent growth (Benettin) and a few samples per period for a spectrum."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._programs import cached_jit
from ..solvers import RESULTS, SolverSettings, result_code
from ._lyapunov import benettin_steps


@dataclasses.dataclass(frozen=True)
class Block:
    """Host arrays of one block for B points: `state`, `tangent` (B, d) at its end;
    `log_growth` (B, m); `samples` (B, m, spp, d) at t = (j + k/spp) T; `status` (B,)."""

    state: object
    tangent: object
    log_growth: object
    samples: object
    status: object
    steps: object


@cached_jit
def _block(vector_field, setup, data, values, y, v, periods: int, spp: int,
           settings: SolverSettings):
    def one(value, y0, v0):
        args, period = setup(data, value)
        period = jnp.asarray(period, dtype=float)
        # The forcing is T-periodic, so every block may start at t = 0.
        y_end, v_end, logs, samples, result, steps = benettin_steps(
            vector_field, y0, args, 0.0, period, periods, settings, tangent=v0,
            ts_per_interval=spp)
        ok = result == RESULTS.successful
        return (jnp.where(ok, y_end, jnp.nan), v_end, jnp.where(ok, logs, jnp.nan),
                jnp.where(ok, samples, jnp.nan), result_code(result), steps)

    return jax.vmap(one)(values, y, v)


def run_block(problem, values, y, v, *, periods: int, samples_per_period: int,
              settings: SolverSettings, pad_to: int = 0) -> Block:
    """Integrate B trajectories of `problem` (a `SweepProblem`) for `periods` forcing
    periods from states `y` (B, d) at phase 0 with unit tangents `v` (B, d). `pad_to` > B:
    run that many lanes (the last trajectory repeated), so blocks of any B share one
    program (a wide verification's)."""
    values, y, v = (np.asarray(a, dtype=float) for a in (values, y, v))
    B = values.shape[0]
    if pad_to > B:
        rep = np.concatenate([np.arange(B), np.full(pad_to - B, B - 1)])
        values, y, v = values[rep], y[rep], v[rep]
    out = _block(problem.vector_field, problem.setup, problem.data,
                 *(jnp.asarray(a, dtype=float) for a in (values, y, v)), int(periods),
                 int(samples_per_period), settings)  # (with dtype: no staging program)
    return Block(*(np.asarray(a)[:B] for a in out))
