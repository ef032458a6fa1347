"""Generic adaptive integration of any diffrax vector field f(t, y, args).

The solvers and analyses of this package are generic: the BSFS, Duffing and Lorenz
systems all go through `integrate`. Failures never pass silently: each run returns a
`RESULTS` item (see `_results.py`; `RESULTS.successful` is the only good one), a concrete
failure raises a `SolverError` that names the cause, the run's settings and what to try
(`throw=True`, or `check_result` afterwards), and a failed run's states are NaN.
"""

import dataclasses

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._fused import integrate_fused
from ._results import RESULTS, result_codes, result_message


class SolverError(RuntimeError):
    """An integration failed; the message names the cause and the settings of the run."""


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """Numerical settings (static: a change recompiles). Defaults suit the BSFS in SI units.

    - `rtol`, `atol`: local error tolerances of the adaptive step-size controller.
    - `max_steps`: hard cap on steps per solve (diffrax semantics).
    - `solver`: diffrax's "tsit5" (default), "dopri5", "dopri8" or "kvaerno5" (stiff); or
      "dopri5-fused" / "dopri8-fused", the fast forward-mode loops of `_fused.py` (with a
      reverse-mode `adjoint`, `integrate` runs diffrax's Dopri5 / Dopri8 instead).
    - `dt0`: initial step [s], or None to let diffrax choose.
    """

    rtol: float = 1e-8
    atol: float = 1e-12
    max_steps: int = 1_000_000
    solver: str = "tsit5"
    dt0: float | None = None

    def describe(self) -> str:
        return (f"solver={self.solver}, rtol={self.rtol:g}, atol={self.atol:g}, "
                f"max_steps={self.max_steps}")


_SOLVERS = {
    "tsit5": dfx.Tsit5,
    "dopri5": dfx.Dopri5,
    "dopri8": dfx.Dopri8,
    "kvaerno5": dfx.Kvaerno5,
}


FUSED = "dopri5-fused"
#: The fused loops by name, and the diffrax solver each stands for under reverse mode.
FUSED_SOLVERS = {FUSED: "dopri5", "dopri8-fused": "dopri8"}


def make_solver(name: str):
    try:
        return _SOLVERS[name]()
    except KeyError:
        raise ValueError(f"unknown solver '{name}'; choose one of "
                         f"{sorted(_SOLVERS) + sorted(FUSED_SOLVERS)}") from None


def _reverse(adjoint) -> bool:
    return adjoint is not None and not isinstance(adjoint, dfx.ForwardMode)


class IntegrationResult(eqx.Module):
    """The outcome of `integrate`.

    - `ts`: the save times; `ys`: the states at `ts` (NaN where the run failed);
    - `result`: a `RESULTS` item (`RESULTS.successful`, `max_steps_reached`, `non_finite`,
      `step_size_failed`, or `invalid_input` for a non-finite `y0`; batched under `vmap`);
    - `num_steps`: accepted + rejected steps.
    """

    ts: jax.Array
    ys: jax.Array
    result: RESULTS
    num_steps: jax.Array

    @property
    def ok(self) -> jax.Array:
        """Bool array: `result == RESULTS.successful`."""
        return self.result == RESULTS.successful


def integrate(vector_field, y0, args, t0, t1, ts, settings: SolverSettings = SolverSettings(),
              *, adjoint=None, progress: bool = False, throw: bool = True) -> IntegrationResult:
    """Integrate y' = f(t, y, args) from t0 to t1, saving at `ts` (inside [t0, t1]).

    Pure and traceable (jit/vmap/grad). The result carries a `RESULTS` item, and failed or
    non-finite states are replaced by NaN so that they cannot be mistaken for data.

    **Arguments:**
    - `vector_field`: f(t, y, args) -> dy/dt.
    - `y0`: initial state array.
    - `args`: passed through to f (parameters as pytrees, so they can be differentiated).
    - `t0`, `t1`: time span [s]; `ts`: save times, increasing, within [t0, t1].
    - `settings`: `SolverSettings` (static).
    - `adjoint`: a diffrax adjoint; default `RecursiveCheckpointAdjoint` (reverse mode).
      Use `diffrax.ForwardMode()` for `jax.jacfwd` / Levenberg-Marquardt.
    - `progress`: show a tqdm progress bar (host callback; for CLI runs).
    - `throw`: raise `SolverError` (naming the cause and the settings) when the result is
      concrete and not successful. Under jit/vmap (a traced result) nothing is raised:
      inspect `result` yourself.
    """
    if settings.solver in FUSED_SOLVERS and _reverse(adjoint):
        settings = dataclasses.replace(settings, solver=FUSED_SOLVERS[settings.solver])
    if settings.solver in FUSED_SOLVERS:
        ys, result, steps = integrate_fused(vector_field, y0, args, t0, t1, ts, settings.rtol,
                                            settings.atol, settings.max_steps,
                                            FUSED_SOLVERS[settings.solver])
        ts_out = jnp.asarray(ts)
    else:
        ts_out, ys, result, steps = _integrate_diffrax(vector_field, y0, args, t0, t1, ts,
                                                       settings, adjoint, progress)
    # A non-finite initial state is the caller's error, whatever the loop made of it.
    result = RESULTS.where(jnp.all(jnp.isfinite(jnp.asarray(y0))), result,
                           RESULTS.invalid_input)
    ys = jnp.where(result == RESULTS.successful, ys, jnp.nan)
    out = IntegrationResult(ts_out, ys, result, steps)
    if throw:
        check_result(out.result, settings)
    return out


def _integrate_diffrax(vector_field, y0, args, t0, t1, ts, settings, adjoint, progress):
    """(ts, ys, result, num_steps) of diffrax's diffeqsolve, failures mapped to `RESULTS`."""
    solver = make_solver(settings.solver)
    controller = dfx.PIDController(rtol=settings.rtol, atol=settings.atol)
    kwargs = {}
    if progress:
        kwargs["progress_meter"] = dfx.TqdmProgressMeter(refresh_steps=200)
    sol = dfx.diffeqsolve(
        dfx.ODETerm(vector_field), solver, t0, t1, settings.dt0, y0, args,
        saveat=dfx.SaveAt(ts=ts), stepsize_controller=controller,
        max_steps=settings.max_steps, adjoint=adjoint or dfx.RecursiveCheckpointAdjoint(),
        throw=False, **kwargs,
    )
    finite = jnp.all(jnp.isfinite(sol.ys))
    result = RESULTS.promote(sol.result)
    # Any other failure of diffrax's loop is the step-size controller giving up.
    failed = RESULTS.where(result == RESULTS.max_steps_reached, result,
                           RESULTS.where(finite, RESULTS.step_size_failed, RESULTS.non_finite))
    result = RESULTS.where(result == RESULTS.successful,
                           RESULTS.where(finite, RESULTS.successful, RESULTS.non_finite), failed)
    return sol.ts, sol.ys, result, sol.stats["num_steps"]


def is_concrete(tree) -> bool:
    """True when no leaf of `tree` is a tracer (so values can be inspected in Python)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def check_result(result, settings: SolverSettings, context: str = ""):
    """Raise `SolverError` if any entry of a (possibly batched) `RESULTS` item is not
    successful (concrete values only).

    Under `jit`/`vmap` (a traced result) this returns unchanged: inspect `result` yourself
    (a failed run's states are NaN).

    **Arguments:**
    - `result`: a `RESULTS` item, e.g. `IntegrationResult.result` or `Trajectory.result`.
    - `settings`: the `SolverSettings` of the run (named in the message).
    - `context`: what was run (excitation, horizon), named in the message.
    """
    if not is_concrete(result):
        return
    codes = np.atleast_1d(result_codes(result)).ravel()
    bad = np.flatnonzero(codes != result_codes(RESULTS.successful))
    if bad.size:
        first = jax.tree_util.tree_map(lambda v: np.asarray(np.ravel(v)[bad[0]]), result)
        where = f" (first of {bad.size} failed runs: index {bad[0]})" if codes.size > 1 else ""
        message = result_message(first)
        if bool(first == RESULTS.max_steps_reached):
            message = f"{message.rstrip('.')} (or shorten the horizon, or loosen rtol/atol)"
        raise SolverError(
            f"simulation failed{where}: {message.rstrip('.')}. "
            f"Run settings: {context}{'; ' if context else ''}{settings.describe()}."
        )
