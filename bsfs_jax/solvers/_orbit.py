"""The periodic-orbit engine: one API over shooting and harmonic balance.

    orbit = periodic_orbit(f, y_guess, args, period, method=HarmonicBalance())
    orbit.state, orbit.multipliers, orbit.residual, orbit.error_estimate, orbit.result

`f(t, y, args)` is any vector field that is T-periodic in t (a forced system with forcing
period T); the orbit has period n T (`n_periods`). Both methods solve their residual by the
same Newton (`_newton.py`) on unknowns scaled to order one, report the Floquet
multipliers, the Newton residual and an error estimate, and are differentiable in `args`
and `period` by the implicit function theorem in forward or reverse mode (`adjoint=`,
see `_implicit.py`); a derivative never passes through the transient, the Newton
iterations or the harmonic-count search.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._harmonic import HarmonicBalance
from ._implicit import AbstractOrbitAdjoint, ImplicitForward, ImplicitReverse
from ._integrate import SolverError, is_concrete
from ._newton import newton
from ._results import RESULTS
from ._shooting import Shooting, default_scale, float_leaves_to_arrays

DEFAULT_TOL = 1e-9


class PeriodicOrbit(eqx.Module):
    """A periodic orbit y(t + n T) = y(t) of a T-periodic system.

    - `state`: the state at t = 0 (mod n T), in the system's units;
    - `period`: the forcing period T; the orbit's period is n T (`n_periods`);
    - `multipliers`: Floquet multipliers, complex, largest modulus first (stable when all
      are inside the unit circle); `monodromy`: d Phi^{nT} / d y, in the system's units;
    - `residual`: max-norm of the method's scaled residual at the solution;
    - `error_estimate`: harmonic balance: the time-domain defect of the reconstructed
      orbit (relative, see `_harmonic.py`); shooting: the residual;
    - `result`: a `RESULTS` item (`orbit.converged` is `result == successful`);
    - `unknowns`, `scale`, `method`: the method's scaled unknowns, the state scale and
      the method (e.g. `HarmonicBalance(harmonics=H)` with the H actually used);
    - `newton_steps`.
    """

    state: jax.Array
    period: jax.Array
    multipliers: jax.Array
    monodromy: jax.Array
    residual: jax.Array
    error_estimate: jax.Array
    result: RESULTS
    unknowns: jax.Array
    scale: jax.Array
    newton_steps: jax.Array
    method: object = eqx.field(static=True)
    n_periods: int = eqx.field(static=True, default=1)

    @property
    def converged(self):
        return self.result == RESULTS.successful

    @property
    def stable(self):
        """True where every Floquet multiplier lies inside the unit circle."""
        return jnp.max(jnp.abs(self.multipliers), axis=-1) < 1.0

    def trajectory(self, vector_field, args, ts, adjoint=None):
        """States at times `ts` in [0, n T] (differentiable like the orbit)."""
        adj = (adjoint or ImplicitForward()).ode_adjoint()
        return self.method.trajectory(vector_field, self.unknowns, args, self.period,
                                      self.n_periods, self.scale, jnp.asarray(ts), adj)

    def amplitudes(self, vector_field, args, adjoint=None):
        """Half peak-to-peak of every state component over the orbit (extremes polished
        by Newton's method on the trigonometric interpolant of the samples)."""
        adj = (adjoint or ImplicitForward()).ode_adjoint()
        return orbit_amplitudes(self.method, vector_field, self.unknowns, args, self.period,
                                self.n_periods, self.scale, adj)


def _sorted_eigvals(matrix):
    mu = jnp.linalg.eigvals(matrix)
    return mu[jnp.argsort(-jnp.abs(mu))]


def orbit_amplitudes(method, vector_field, z, args, period, n_periods, scale, ode_adjoint):
    """Half peak-to-peak of each component over the orbit (the method's `amplitudes`)."""
    return method.amplitudes(vector_field, z, args, period, n_periods, scale, ode_adjoint)


class _Residual(eqx.Module):
    """G(u, theta) with theta = (args, period): the method's residual as a callable."""

    method: object = eqx.field(static=True)
    vector_field: object = eqx.field(static=True)
    n_periods: int = eqx.field(static=True)
    scale: jax.Array
    ode_adjoint: object

    def __call__(self, z, theta):
        args, period = theta
        return self.method.residual(self.vector_field, z, args, period, self.n_periods,
                                    self.scale, self.ode_adjoint)


def _solve_core(method, vector_field, z0, args, period, scale, n_periods, tol, max_steps,
                adjoint, stability=True):
    fwd_residual = _Residual(method, vector_field, n_periods, scale, None)
    assembled = None
    if method.assembled_jacobian:
        def assembled(z, theta):
            return method.residual_and_jacobian(vector_field, z, theta[0], theta[1],
                                                n_periods, scale)
    sol = newton(lambda z, th: fwd_residual(z, th), z0, (args, period), tol=tol,
                 max_steps=max_steps, jacobian_fn=assembled)
    z_star = jax.lax.stop_gradient(sol.value)
    d = scale.shape[0]
    if stability:
        m_scaled = method.monodromy(vector_field, z_star, jax.lax.stop_gradient(args),
                                    jax.lax.stop_gradient(period), n_periods, scale,
                                    sol.jacobian)
        multipliers = _sorted_eigvals(m_scaled)
    else:  # not asked for: nan, and no eigenvalue solve (the orbit is never called stable)
        m_scaled = jnp.full((d, d), jnp.nan)
        multipliers = jnp.full((d,), jnp.nan, dtype=jnp.result_type(complex))
    z = adjoint.attach(_Residual(method, vector_field, n_periods, scale,
                                 adjoint.ode_adjoint()),
                       (args, period), z_star, sol.jacobian)
    state = method.initial_state(z, period, n_periods, scale)
    err = method.error_estimate(vector_field, z_star, jax.lax.stop_gradient(args),
                                jax.lax.stop_gradient(period), n_periods, scale,
                                sol.residual)
    result = method.flag_truncation(sol.result, err)
    monodromy = m_scaled * scale[:, None] / scale[None, :]
    return PeriodicOrbit(state, period, multipliers, monodromy, sol.residual,
                         err, result, z, scale, sol.steps, method, n_periods)


_solve_jit = eqx.filter_jit(_solve_core)


def _init_core(method, vector_field, y_guess, args, period, n_periods, scale):
    return method.init(vector_field, y_guess, args, period, n_periods, scale)


_init_jit = eqx.filter_jit(_init_core)


def periodic_orbit(vector_field, y_guess, args, period, *, method=None,
                   n_periods: int = 1, scale=None, unknowns=None, tol: float = DEFAULT_TOL,
                   max_steps: int = 30, adjoint: AbstractOrbitAdjoint = ImplicitForward(),
                   throw: bool = True, stability: bool = True) -> PeriodicOrbit:
    """Find an orbit of period n T of y' = f(t, y, args) (T-periodic in t).

    **Main arguments:**
    - `vector_field`: f(t, y, args).
    - `y_guess`: a state near the orbit at t = 0 (mod T): the end of a transient, or a
      neighbouring orbit's state.
    - `args`: the field's parameters; the orbit is differentiable in them and in `period`.
    - `period`: the forcing period T.
    - `method`: `Shooting(segments=m)` (default) or `HarmonicBalance(harmonics=H)`. With
      harmonic balance and concrete inputs the harmonic count is doubled from H until the
      error estimate is below `method.error_tol` (up to `method.max_harmonics`); under
      `jit`/`vmap` H is fixed and `result` says `harmonics_insufficient` where it fails.

    **Other arguments:**
    - `n_periods`: look for an orbit of period n T (subharmonics).
    - `scale`: typical magnitude of each state component (default from `y_guess`).
    - `unknowns`: the method's scaled unknowns to start from (e.g. a neighbouring orbit's
      `orbit.unknowns`), instead of `y_guess`.
    - `tol`, `max_steps`: Newton's relative tolerance and iteration limit.
    - `adjoint`: `ImplicitForward()` (jvp / jacfwd) or `ImplicitReverse()` (grad / vjp).
    - `throw`: raise `SolverError` when the result is not successful (concrete values only;
      under transforms inspect `orbit.result`).
    - `stability`: compute the monodromy matrix and Floquet multipliers (False: both nan,
      and `orbit.stable` is False; harmonic balance then skips its period map of the
      linearisation, a third of an orbit's compiled program).
    """
    method = Shooting() if method is None else method
    if int(n_periods) < 1:
        raise ValueError(f"n_periods must be >= 1, got {n_periods}")
    y_guess = jnp.asarray(y_guess, dtype=float)
    concrete = is_concrete((y_guess, args, period))
    if concrete and not bool(jnp.all(jnp.isfinite(y_guess))):
        raise ValueError(f"y_guess must be finite, got {y_guess}")
    scale = default_scale(y_guess) if scale is None else jnp.broadcast_to(
        jnp.asarray(scale, dtype=float), y_guess.shape)
    period = jnp.asarray(period, dtype=float)
    args = float_leaves_to_arrays(args)
    n_periods = int(n_periods)
    stop = jax.lax.stop_gradient

    def solve(m, z0):
        return _solve_jit(m, vector_field, stop(z0), args, period, scale, n_periods,
                          float(tol), int(max_steps), adjoint, bool(stability))

    if unknowns is None:
        z0 = _init_jit(method, vector_field, stop(y_guess), stop(args), stop(period),
                       n_periods, scale)
    else:
        z0 = jnp.asarray(unknowns, dtype=float)
    orbit = solve(method, z0)
    if concrete:
        orbit = method.refine(orbit, solve, y_guess.shape[0])
    if throw and is_concrete(orbit.result._value) and not bool(orbit.converged):
        raise SolverError(
            f"periodic orbit ({method.name}) not found: {RESULTS[orbit.result]} (scaled "
            f"residual {float(orbit.residual):.3g}, error estimate "
            f"{float(orbit.error_estimate):.3g}, relative tol {tol:g}, {int(orbit.newton_steps)}"
            f" Newton steps, period {float(period):.6g}, n_periods {n_periods}).")
    return orbit


STABLE, UNSTABLE = "stable", "unstable"
FOLD, PERIOD_DOUBLING, NEIMARK_SACKER = "fold", "period-doubling", "neimark-sacker"
BRANCH_POINT = "branch-point"


def classify_multipliers(multipliers, tol: float = 1e-3):
    """Label an orbit from its Floquet multipliers (numpy, host side).

    A multiplier within `tol` of the unit circle marks a bifurcation: at +1 a fold (or a
    branch point), at -1 a period doubling, a complex pair (|Im| > tol) a Neimark-Sacker
    bifurcation. Otherwise "stable" (all |mu| < 1) or "unstable". Shape (N,) or (..., N).
    """
    mu = np.asarray(multipliers, dtype=complex)
    if mu.ndim == 1:
        return _classify_one(mu, tol)
    flat = mu.reshape(-1, mu.shape[-1])
    return np.array([_classify_one(m, tol) for m in flat], dtype=object).reshape(mu.shape[:-1])


def _classify_one(mu, tol):
    if not np.all(np.isfinite(mu)):
        return "invalid"
    near_circle = np.abs(np.abs(mu) - 1.0) < tol
    if np.any(near_circle & (np.abs(mu - 1.0) < tol)):
        return FOLD
    if np.any(near_circle & (np.abs(mu + 1.0) < tol)):
        return PERIOD_DOUBLING
    if np.any(near_circle & (np.abs(mu.imag) > tol)):
        return NEIMARK_SACKER
    return STABLE if np.max(np.abs(mu)) < 1.0 else UNSTABLE


__all__ = ["PeriodicOrbit", "periodic_orbit", "classify_multipliers", "ImplicitForward",
           "ImplicitReverse", "Shooting", "HarmonicBalance"]
