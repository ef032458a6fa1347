"""Newton's method with a dense Jacobian, the one root-finder of the orbit engine.

Used by the periodic-orbit methods (shooting, harmonic balance) and by the continuation's
corrector, so that every orbit of the package is converged by the same rule:

    converged  <=>  max|F(u)| <= tol * max(1, max|u|)

on unknowns u that the caller has scaled to order one. The Jacobian is formed by
forward-mode differentiation (`jax.jacfwd`) together with F in one pass, and the Jacobian
at the returned point is handed back, so callers get the Newton matrix of the solution
for free (Floquet multipliers, implicit derivatives, the continuation tangent).

A Newton step whose residual is not finite is halved (up to `max_halvings` times) before
it is taken: a trial state beyond the validity of the model (a diverged integration)
then does not end the solve. Everything is pure and works under `jit` and `vmap`; the
solve itself is not differentiated (callers attach implicit derivatives, see
`_implicit.py`).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._results import RESULTS


class NewtonSolution(eqx.Module):
    """`value`: the last iterate; `residual`: max|F(value)|; `jacobian`: dF/du at `value`;
    `steps`: Newton iterations taken; `result`: a `RESULTS` item."""

    value: jax.Array
    residual: jax.Array
    jacobian: jax.Array
    steps: jax.Array
    result: RESULTS


def residual_and_jacobian(fn, u, data):
    """(F(u), dF/du) in one forward-mode pass."""
    jac, f = jax.jacfwd(lambda v: (fn(v, data), fn(v, data)), has_aux=True)(u)
    return f, jac


def _chord(fn, u0, data, lu, tol_abs, max_steps):
    """Chord iterations u <- u - J0^{-1} F(u) with the LU factors of a matrix J0; stops at
    the tolerance, after `max_steps`, or as soon as the residual fails to halve."""
    f0 = fn(u0, data)

    def cond(c):
        u, f, k, slow = c
        return (k < max_steps) & (jnp.max(jnp.abs(f)) > tol_abs) & ~slow

    def body(c):
        u, f, k, _ = c
        u_new = u - jax.scipy.linalg.lu_solve(lu, f)
        f_new = fn(u_new, data)
        slow = ~(jnp.max(jnp.abs(f_new)) <= 0.5 * jnp.max(jnp.abs(f)))
        keep = jnp.all(jnp.isfinite(f_new)) & ~slow
        return (jnp.where(keep, u_new, u), jnp.where(keep, f_new, f), k + 1, slow)

    u, _, k, _ = jax.lax.while_loop(cond, body, (u0, f0, jnp.asarray(0), jnp.asarray(False)))
    return u, k


def newton(fn, u0, data, *, tol: float, max_steps: int, max_halvings: int = 4,
           chord_lu=None, chord_steps: int = 8) -> NewtonSolution:
    """Solve F(u, data) = 0 from `u0` (dense Newton; see the module docstring).

    **Arguments:**
    - `fn`: F(u, data) -> array of the same size as u.
    - `u0`: the start; `data`: passed through (a pytree; not differentiated here).
    - `tol`: relative tolerance; `max_steps`: most iterations; `max_halvings`: most step
      halvings when a trial residual is not finite.
    - `chord_lu`: LU factors (`jax.scipy.linalg.lu_factor`) of an approximate dF/du near
      the root (the continuation passes those of the previous point). Then up to
      `chord_steps` chord iterations come first (each costs one residual, no Jacobian and
      no factorisation), and Newton takes over where they stall. The returned Jacobian is
      always evaluated at the returned point.
    """
    u0 = jax.lax.stop_gradient(u0)
    data = jax.lax.stop_gradient(data)
    size = jnp.maximum(1.0, jnp.max(jnp.abs(u0)))
    chord_taken = jnp.asarray(0)
    if chord_lu is not None:
        u0, chord_taken = _chord(fn, u0, data, jax.lax.stop_gradient(chord_lu), tol * size,
                                 chord_steps)
    f0, j0 = residual_and_jacobian(fn, u0, data)

    def norm(f):
        return jnp.max(jnp.abs(f))

    def done(f):
        return norm(f) <= tol * size

    def cond(carry):
        u, f, jac, k, stuck = carry
        return (k < max_steps) & ~done(f) & jnp.all(jnp.isfinite(f)) & ~stuck

    def body(carry):
        u, f, jac, k, _ = carry
        du = jnp.linalg.solve(jac, -f)
        singular = ~jnp.all(jnp.isfinite(du))
        du = jnp.where(singular, 0.0, du)

        def trial(c):
            step, _, _, h = c
            f_new, j_new = residual_and_jacobian(fn, u + step * du, data)
            return step * 0.5, f_new, j_new, h + 1

        def bad(c):
            _, f_new, _, h = c
            return (h == 0) | (~jnp.all(jnp.isfinite(f_new)) & (h <= max_halvings))

        step, f_new, j_new, _ = jax.lax.while_loop(
            bad, trial, (jnp.asarray(1.0), f, jac, jnp.asarray(0)))
        u_new = u + 2.0 * step * du
        return u_new, f_new, j_new, k + 1, singular

    u, f, jac, k, singular = jax.lax.while_loop(
        cond, body, (u0, f0, j0, jnp.asarray(0), jnp.asarray(False)))
    finite = jnp.all(jnp.isfinite(f)) & jnp.all(jnp.isfinite(u))
    result = RESULTS.where(done(f) & finite, RESULTS.successful,
                           RESULTS.where(singular, RESULTS.singular_jacobian,
                                         RESULTS.where(finite, RESULTS.newton_failed,
                                                       RESULTS.non_finite)))
    return NewtonSolution(u, norm(f), jac, k + chord_taken, result)
