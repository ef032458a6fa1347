"""Periodic orbits of time-periodic systems: shooting, the monodromy matrix and Floquet stability.

Generic over any diffrax vector field f(t, y, args) that is T-periodic in t (a forced
system with forcing period T). The period map Phi^n advances a state from t = 0 to
t = n T; a periodic orbit of period n T is a root of Phi^n(y) - y, found here by Newton's
method (optimistix) on *scaled* variables z = y / scale so that states of very different
magnitudes (the BSFS: ~1e-6 m and ~1e-2 m/s) are equally well resolved. The Jacobian of
the period map comes from forward-mode differentiation through the solver
(`diffrax.ForwardMode()`), and the orbit is differentiable in `args` by the implicit
function theorem (`optimistix.ImplicitAdjoint`).
"""

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._integrate import SolverError, SolverSettings, integrate, is_concrete

#: Default relative Newton tolerance on the scaled residual |Phi^n(y) - y| / scale.
DEFAULT_TOL = 1e-8

#: Default ODE settings for shooting and continuation. Newton needs a period map that is
#: smooth well below its tolerance; adaptive step selection makes the computed map jump by
#: about its global error (~1e-6 relative for Tsit5 at rtol 1e-8 on the BSFS, whose contact
#: kinks force many rejected steps). An 8th-order solver at rtol 1e-11 brings that below
#: 1e-9 at a similar number of steps. The integration runs in scaled variables (y / scale),
#: so atol is relative to the typical magnitude of each component.
SHOOTING_SETTINGS = SolverSettings(rtol=1e-11, atol=1e-13, solver="dopri8")


class PeriodicOrbit(eqx.Module):
    """A periodic orbit y(t + n T) = y(t) of a T-periodic system.

    - `state`: the state on the orbit at t = 0 (mod T), in the system's units;
    - `period`: the forcing period T [s or time unit]; the orbit's period is n T;
    - `n_periods`: n (1 for a T-periodic orbit, 2 after a period doubling, ...);
    - `multipliers`: Floquet multipliers (eigenvalues of the monodromy matrix), complex,
      sorted by modulus, largest first; the orbit is stable when all have modulus < 1;
    - `residual`: max-norm of (Phi^n(state) - state) / scale at the returned state;
    - `converged`: whether Newton met its tolerance (a bool array);
    - `monodromy`: d Phi^n / d y at the state, in the system's units;
    - `scale`: the variable scaling used by the solve;
    - `newton_steps`: the number of Newton iterations taken.
    """

    state: jax.Array
    period: jax.Array
    multipliers: jax.Array
    residual: jax.Array
    converged: jax.Array
    monodromy: jax.Array
    scale: jax.Array
    newton_steps: jax.Array
    n_periods: int = eqx.field(static=True, default=1)

    @property
    def stable(self):
        """True where every Floquet multiplier lies inside the unit circle."""
        return jnp.max(jnp.abs(self.multipliers), axis=-1) < 1.0


def float_leaves_to_arrays(tree):
    """Turn Python floats in `tree` into 0-d arrays (so jit traces them, not recompiles).

    Python ints and bools are left alone: they may set shapes or control flow.
    """
    def conv(x):
        if isinstance(x, float | complex) and not isinstance(x, bool):
            return jnp.asarray(x)
        return x

    return jax.tree_util.tree_map(conv, tree)


def default_scale(y_guess):
    """Per-component scale from a guess: |y_i|, floored at 1e-3 max|y| (ones if all zero)."""
    y = jnp.abs(jnp.asarray(y_guess, dtype=float))
    peak = jnp.max(y)
    floor = jnp.where(peak > 0, 1e-3 * peak, 1.0)
    return jnp.maximum(y, jnp.broadcast_to(floor, y.shape))


def period_map(vector_field, y0, args, period, n_periods: int = 1,
               settings: SolverSettings = SolverSettings()):
    """Phi^n(y0): the state at t = n T starting from y0 at t = 0 (traceable, jacfwd-able).

    Uses `diffrax.ForwardMode()`, so `jax.jacfwd`/`jax.linearize` work through it. A failed
    solve returns NaN (see `integrate`).
    """
    t1 = n_periods * jnp.asarray(period, dtype=float)
    res = integrate(vector_field, y0, args, jnp.zeros_like(t1), t1, t1[None], settings,
                    adjoint=dfx.ForwardMode())
    return res.ys[0]


class _Scaled(eqx.Module):
    """z' = f(t, z * scale, args) / scale: the vector field in scaled variables.

    The step-size controller then sees states of order one in every component, so a
    single rtol/atol controls the error of, e.g., micrometre displacements and m/s
    velocities alike (and the period map is smooth enough for Newton to tight tolerances).
    """

    vector_field: object = eqx.field(static=True)

    def __call__(self, t, z, data):
        args, scale = data
        return self.vector_field(t, z * scale, args) / scale


def scaled_period_map(vector_field, z0, args, period, scale, n_periods: int = 1,
                      settings: SolverSettings = SolverSettings()):
    """Phi^n in scaled variables: z -> Phi^n(z scale) / scale, integrated in z."""
    return period_map(_Scaled(vector_field), z0, (args, scale), period, n_periods, settings)


def _flow_core(vector_field, y0, args, period, n_periods, settings):
    t1 = n_periods * period
    res = integrate(vector_field, y0, args, jnp.zeros_like(t1), t1, t1[None], settings)
    return res.ys[0], res.status


_flow_jit = eqx.filter_jit(_flow_core)


def transient_state(vector_field, y0, args, period, n_periods: int,
                    settings: SolverSettings = SolverSettings()):
    """The state at t = n T from y0 at t = 0: the end of a transient, a guess for `shoot`.

    Raises `SolverError` if the integration fails. `n_periods` is traced (no recompile
    when it changes).
    """
    y_end, status = _flow_jit(vector_field, jnp.asarray(y0, dtype=float),
                              float_leaves_to_arrays(args), jnp.asarray(period, dtype=float),
                              jnp.asarray(n_periods, dtype=float), settings)
    if int(status) != 0:
        from ._integrate import STATUS_MESSAGES

        raise SolverError(f"transient of {n_periods} periods failed: "
                          f"{STATUS_MESSAGES.get(int(status))}; {settings.describe()}")
    return y_end


def _sorted_eigvals(matrix):
    mu = jnp.linalg.eigvals(matrix)
    return mu[jnp.argsort(-jnp.abs(mu))]


def _shoot_core(vector_field, y_guess, args, period, scale, n_periods, settings, tol,
                max_steps):
    def residual(z, params):
        a, t = params
        return scaled_period_map(vector_field, z, a, t, scale, n_periods, settings) - z

    z0 = y_guess / scale
    # Relative tolerance: |F| <= tol * size with size = max(1, |z|), so that an orbit much
    # larger than `scale` is not asked for more digits than the integration resolves.
    size = jax.lax.stop_gradient(jnp.maximum(1.0, jnp.max(jnp.abs(z0))))
    solver = optx.Newton(rtol=tol, atol=tol * size)
    sol = optx.root_find(residual, solver, z0, args=(args, period), max_steps=max_steps,
                         throw=False)
    z = sol.value
    state = z * scale
    res = jnp.max(jnp.abs(residual(z, (args, period))))
    z_fixed = jax.lax.stop_gradient(z)
    m_scaled = jax.jacfwd(lambda v: scaled_period_map(vector_field, v, args, period, scale,
                                                      n_periods, settings))(z_fixed)
    monodromy = m_scaled * scale[:, None] / scale[None, :]
    multipliers = _sorted_eigvals(m_scaled)
    converged = (res <= 10 * tol * size) & jnp.all(jnp.isfinite(state))
    return PeriodicOrbit(state, period, multipliers, res, converged, monodromy, scale,
                         sol.stats["num_steps"], n_periods)


_shoot_jit = eqx.filter_jit(_shoot_core)


def shoot(vector_field, y_guess, args, period, *, n_periods: int = 1,
          settings: SolverSettings = SHOOTING_SETTINGS, max_steps: int = 30,
          scale=None, tol: float = DEFAULT_TOL, throw: bool = True) -> PeriodicOrbit:
    """Find a periodic orbit of period n T of y' = f(t, y, args) by Newton shooting.

    **Main arguments:**
    - `vector_field`: f(t, y, args), T-periodic in t.
    - `y_guess`: a state near the orbit at t = 0 (mod T), e.g. the end of a transient.
    - `args`: the vector field's parameters. The orbit is differentiable in them in forward
      mode (`jax.jvp`, `jax.jacfwd`): d state / d args follows from the implicit function
      theorem (`optimistix.ImplicitAdjoint`), never through the Newton iterations. Reverse
      mode (`jax.grad`) is not supported: the period map is differentiated with
      `diffrax.ForwardMode()`, whose while loop cannot be transposed.
    - `period`: the forcing period T.
    - `n_periods`: look for an orbit of period n T (subharmonics after period doubling).

    **Other arguments:**
    - `settings`: ODE `SolverSettings` (static: a change recompiles).
    - `max_steps`: maximum number of Newton iterations.
    - `scale`: per-component variable scale (same shape as the state); Newton works on
      y / scale. Default: `default_scale(y_guess)`. Give typical magnitudes when the guess
      is poor (e.g. zero).
    - `tol`: relative Newton tolerance: converged when the scaled residual
      max|Phi^n(y) - y| / scale <= 10 tol max(1, max|y_guess / scale|).
    - `throw`: raise `SolverError` when Newton did not converge (concrete values only; under
      jit/vmap/jacfwd inspect `orbit.converged`).

    **Returns:** a `PeriodicOrbit` with the Floquet multipliers and monodromy matrix.
    """
    if int(n_periods) < 1:
        raise ValueError(f"n_periods must be >= 1, got {n_periods}")
    y_guess = jnp.asarray(y_guess, dtype=float)
    if is_concrete(y_guess) and not bool(jnp.all(jnp.isfinite(y_guess))):
        raise ValueError(f"y_guess must be finite, got {y_guess}")
    scale = default_scale(y_guess) if scale is None else jnp.broadcast_to(
        jnp.asarray(scale, dtype=float), y_guess.shape)
    period = jnp.asarray(period, dtype=float)
    args = float_leaves_to_arrays(args)
    orbit = _shoot_jit(vector_field, y_guess, args, period, scale, int(n_periods), settings,
                       float(tol), int(max_steps))
    if throw and is_concrete(orbit.converged) and not bool(orbit.converged):
        raise SolverError(
            f"shooting did not converge: scaled residual {float(orbit.residual):.3g} "
            f"(relative tol {tol:g}) after {int(orbit.newton_steps)} Newton steps (max_steps="
            f"{max_steps}), period {float(period):.6g}, n_periods {n_periods}. Give a better "
            f"guess (e.g. the end of a transient simulation), a `scale` of typical state "
            f"magnitudes, more max_steps, or check the ODE settings ({settings.describe()}).")
    return orbit


def monodromy_matrix(vector_field, y0, args, period, n_periods: int = 1,
                     settings: SolverSettings = SHOOTING_SETTINGS):
    """d Phi^n / d y0 by forward-mode differentiation through the solver."""
    y0 = jnp.asarray(y0, dtype=float)
    return jax.jacfwd(lambda y: period_map(vector_field, y, args, period, n_periods,
                                           settings))(y0)


_monodromy_jit = eqx.filter_jit(monodromy_matrix)


def floquet_multipliers(vector_field, y0, args, period, n_periods: int = 1,
                        settings: SolverSettings = SHOOTING_SETTINGS):
    """Floquet multipliers (eigenvalues of the monodromy matrix at y0), largest modulus first.

    `y0` should lie on a periodic orbit (see `shoot`); elsewhere this is the spectrum of the
    linearised n-period map at y0.
    """
    y0 = jnp.asarray(y0, dtype=float)
    period = jnp.asarray(period, dtype=float)
    m = _monodromy_jit(vector_field, y0, float_leaves_to_arrays(args), period, int(n_periods),
                       settings)
    return _sorted_eigvals(m)


STABLE, UNSTABLE = "stable", "unstable"
FOLD, PERIOD_DOUBLING, NEIMARK_SACKER = "fold", "period-doubling", "neimark-sacker"
BRANCH_POINT = "branch-point"


def classify_multipliers(multipliers, tol: float = 1e-3):
    """Label an orbit from its Floquet multipliers (numpy, host side).

    A multiplier within `tol` of the unit circle marks a bifurcation: at +1 a fold (or a
    branch point), at -1 a period doubling, a complex pair (|Im| > tol) a Neimark-Sacker
    bifurcation. Otherwise "stable" (all |mu| < 1) or "unstable".

    `multipliers` has shape (N,) or (..., N); returns a str or an array of str of shape (...).
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
