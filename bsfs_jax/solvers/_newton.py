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
    `steps`: Newton iterations taken; `result`: a `RESULTS` item; `lu`: the LU factors
    (`jax.scipy.linalg.lu_factor`) of `jacobian` where `keep_lu` asked for them, else
    None."""

    value: jax.Array
    residual: jax.Array
    jacobian: jax.Array
    steps: jax.Array
    result: RESULTS
    lu: tuple | None = None


def residual_and_jacobian(fn, u, data):
    """(F(u), dF/du) in one forward-mode pass: F's tangents along every unit vector, with
    F itself from the same (unbatched) primal computation. (`jacfwd(..., has_aux=True)`
    returning F as its aux traced F a second time: a second copy of a shooting residual's
    ODE solve in every program.)"""
    def push(t):
        return jax.jvp(lambda v: fn(v, data), (u,), (t,))

    f, jac = jax.vmap(push, out_axes=(None, -1))(jnp.eye(u.shape[0], dtype=u.dtype))
    return f, jac


def _chord(fn, u0, data, lu, tol_abs, max_steps):
    """Chord iterations u <- u - J0^{-1} F(u) with the LU factors of a matrix J0; stops at
    the tolerance, after `max_steps`, or as soon as the residual fails to halve (then the
    last iterate that did halve it is kept).

    One residual in the loop body (each pass evaluates F at the current iterate, then
    accepts it or steps on), so the compiled program holds F once."""
    inf = jnp.asarray(jnp.inf, dtype=jnp.result_type(float))

    def cond(c):
        return ~c[4]

    def body(c):
        u, u_prev, norm_prev, k, _ = c
        f = fn(u, data)
        norm = jnp.max(jnp.abs(f))
        slow = ~(norm <= 0.5 * norm_prev)  # also a non-finite residual
        # A slow iterate is dropped for the last good one (at k = 0 nothing is slow).
        u_keep = jnp.where(slow, u_prev, u)
        stop = slow | (norm <= tol_abs) | (k >= max_steps)
        u_next = jnp.where(stop, u_keep, u - jax.scipy.linalg.lu_solve(lu, f))
        return u_next, u_keep, norm, k + jnp.where(stop, 0, 1), stop

    u, _, _, k, _ = jax.lax.while_loop(
        cond, body, (u0, u0, inf, jnp.asarray(0), jnp.asarray(False)))
    return u, k


def newton(fn, u0, data, *, tol: float, max_steps: int, max_halvings: int = 4,
           chord_lu=None, chord_steps: int = 8, keep_lu: bool = False,
           jacobian_fn=None) -> NewtonSolution:
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
    - `keep_lu`: also return the LU factors of that Jacobian (the continuation's next
      tangent and chord matrix); they are computed anyway, except at the last point.
    - `jacobian_fn`: (F(u), dF/du) = jacobian_fn(u, data), where the caller assembles the
      Jacobian more cheaply than forward mode through `fn` (default: forward mode).

    The loop evaluates F and dF/du once per pass, at the trial point, and then accepts it
    (converged, out of steps, singular) or takes the next step, or halves the step when F
    is not finite there; so the program holds one copy of the Jacobian's computation.
    """
    u0 = jax.lax.stop_gradient(u0)
    data = jax.lax.stop_gradient(data)
    size = jnp.maximum(1.0, jnp.max(jnp.abs(u0)))
    tol_abs = tol * size
    chord_taken = jnp.asarray(0)
    if chord_lu is not None:
        u0, chord_taken = _chord(fn, u0, data, jax.lax.stop_gradient(chord_lu), tol_abs,
                                 chord_steps)
    n = u0.shape[0]
    dtype = jnp.result_type(float)

    def factor(jac):
        return jax.scipy.linalg.lu_factor(jac)

    def no_factor(jac):
        return jnp.full_like(jac, jnp.nan), jnp.arange(n, dtype=jnp.int32)

    # carry: base point, step direction, step length, halvings, iterations, finished,
    # singular, and F, dF/du and its LU at the last accepted point.
    def cond(c):
        return ~c[5]

    def body(c):
        base, du, step, halvings, k, _, _, f_old, jac_old, lu_old = c
        u = base + step * du
        f, jac = (residual_and_jacobian(fn, u, data) if jacobian_fn is None
                  else jacobian_fn(u, data))
        finite = jnp.all(jnp.isfinite(f))
        # A non-finite trial residual (after the first point) halves the step.
        retry = ~finite & (k > 0) & (halvings < max_halvings)
        done = jnp.max(jnp.abs(f)) <= tol_abs
        finished = ~retry & (done | ~finite | (k >= max_steps))
        lu = jax.lax.cond(retry | (finished & (not keep_lu)), no_factor, factor, jac)
        du_new = jax.scipy.linalg.lu_solve(lu, -f)
        singular = ~retry & ~finished & ~jnp.all(jnp.isfinite(du_new))
        finished = finished | singular
        accept = ~retry
        return (jnp.where(accept, u, base), jnp.where(accept, du_new, du),
                jnp.where(accept, 1.0, 0.5 * step), jnp.where(accept, 0, halvings + 1),
                k + jnp.where(accept & ~finished, 1, 0), finished, singular,
                jnp.where(accept, f, f_old), jnp.where(accept, jac, jac_old),
                jax.tree.map(lambda a, b: jnp.where(accept, a, b), lu, lu_old))

    zeros = jnp.zeros((n, n), dtype=dtype)
    init = (u0, jnp.zeros(n, dtype=dtype), jnp.asarray(1.0, dtype=dtype), jnp.asarray(0),
            jnp.asarray(0), jnp.asarray(False), jnp.asarray(False),
            jnp.zeros(n, dtype=dtype), zeros, no_factor(zeros))
    u, _, _, _, k, _, singular, f, jac, lu = jax.lax.while_loop(cond, body, init)
    finite = jnp.all(jnp.isfinite(f)) & jnp.all(jnp.isfinite(u))
    norm = jnp.max(jnp.abs(f))
    result = RESULTS.where((norm <= tol_abs) & finite, RESULTS.successful,
                           RESULTS.where(singular, RESULTS.singular_jacobian,
                                         RESULTS.where(finite, RESULTS.newton_failed,
                                                       RESULTS.non_finite)))
    return NewtonSolution(u, norm, jac, k + chord_taken, result, lu if keep_lu else None)
