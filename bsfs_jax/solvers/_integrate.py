"""Generic adaptive integration of any diffrax vector field f(t, y, args).

The solvers and analyses of this package are generic: the BSFS, Duffing and Lorenz
systems all go through `integrate`. Failures never pass silently: each run returns a
status code (see `STATUS_MESSAGES`), and `check_status` turns a bad one into a
`SolverError` that names the cause, the run's settings and what to try.
"""

import dataclasses

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

OK, MAX_STEPS, NON_FINITE, SOLVER_FAILED = 0, 1, 2, 3
STATUS_MESSAGES = {
    OK: "successful",
    MAX_STEPS: "the maximum number of solver steps was reached; raise max_steps, shorten "
    "the horizon, or loosen rtol/atol",
    NON_FINITE: "the state became non-finite (NaN or inf); the response diverged, check "
    "for unphysical parameters or a too-large force",
    SOLVER_FAILED: "the step-size controller failed (step size underflow or a non-finite "
    "step); loosen rtol/atol or check the parameters",
}


class SolverError(RuntimeError):
    """An integration failed; the message names the cause and the settings of the run."""


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """Numerical settings (static: a change recompiles). Defaults suit the BSFS in SI units.

    - `rtol`, `atol`: local error tolerances of the adaptive step-size controller.
    - `max_steps`: hard cap on steps per solve (diffrax semantics).
    - `solver`: diffrax's "tsit5" (default), "dopri5", "dopri8" or "kvaerno5" (stiff); or
      "dopri5-fused", the fast forward-only path of `_fused.py` (no reverse-mode gradients).
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


def make_solver(name: str):
    try:
        return _SOLVERS[name]()
    except KeyError:
        raise ValueError(f"unknown solver '{name}'; choose one of "
                         f"{sorted(_SOLVERS) + [FUSED]}") from None


class IntegrationResult(eqx.Module):
    """States at the requested times, status code and number of accepted+rejected steps."""

    ts: jax.Array
    ys: jax.Array
    status: jax.Array
    num_steps: jax.Array


def integrate(vector_field, y0, args, t0, t1, ts, settings: SolverSettings = SolverSettings(),
              *, adjoint=None, progress: bool = False) -> IntegrationResult:
    """Integrate y' = f(t, y, args) from t0 to t1, saving at `ts` (inside [t0, t1]).

    Pure and traceable (jit/vmap/grad). Never raises on a failed solve: the result
    carries `status` (0 = ok) and failed or non-finite states are replaced by NaN so that
    they cannot be mistaken for data. Use `check_status` outside of transforms.

    **Arguments:**
    - `vector_field`: f(t, y, args) -> dy/dt.
    - `y0`: initial state array.
    - `args`: passed through to f (parameters as pytrees, so they can be differentiated).
    - `t0`, `t1`: time span [s]; `ts`: save times, increasing, within [t0, t1].
    - `settings`: `SolverSettings` (static).
    - `adjoint`: a diffrax adjoint; default `RecursiveCheckpointAdjoint` (reverse mode).
      Use `diffrax.ForwardMode()` for `jax.jacfwd` / Levenberg-Marquardt.
    - `progress`: show a tqdm progress bar (host callback; for CLI runs).
    """
    if settings.solver == FUSED:
        from ._fused import integrate_fused

        ys, status, steps = integrate_fused(vector_field, y0, args, t0, t1, ts, settings.rtol,
                                            settings.atol, settings.max_steps)
        return IntegrationResult(jnp.asarray(ts), jnp.where(status == OK, ys, jnp.nan), status,
                                 steps)
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
    status = jnp.where(
        sol.result == dfx.RESULTS.successful,
        jnp.where(finite, OK, NON_FINITE),
        jnp.where(sol.result == dfx.RESULTS.max_steps_reached, MAX_STEPS,
                  jnp.where(finite, SOLVER_FAILED, NON_FINITE)),
    )
    ys = jnp.where(status == OK, sol.ys, jnp.nan)
    return IntegrationResult(sol.ts, ys, status, sol.stats["num_steps"])


def is_concrete(tree) -> bool:
    """True when no leaf of `tree` is a tracer (so values can be inspected in Python)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(tree))


def check_status(status, settings: SolverSettings, context: str = ""):
    """Raise `SolverError` if any entry of `status` is not OK (concrete values only).

    Under `jit`/`vmap` (traced status) this returns unchanged: inspect `status` yourself
    (a failed run's states are NaN).
    """
    if not is_concrete(status):
        return
    codes = np.atleast_1d(np.asarray(status))
    bad = np.flatnonzero(codes != OK)
    if bad.size:
        code = int(codes[bad[0]])
        where = f" (first of {bad.size} failed runs: index {bad[0]})" if codes.size > 1 else ""
        raise SolverError(
            f"simulation failed{where}: {STATUS_MESSAGES.get(code, f'status {code}')}. "
            f"Run settings: {context}{'; ' if context else ''}{settings.describe()}."
        )
