"""The FRC's located peak and folds followed to other parameters, without continuation.

A located branch point (`PeakHint`: the FRC peak or a fold, on the estimate's continued
branch) is the solution of an extended system in x = (v, t), v the orbit unknowns and
the frequency, t the branch's tangent there:

    E(x; theta) = [ R(v; theta),          the orbit (n - 1 equations)
                    R_v(v; theta) t,      t is tangent to the branch (n - 1)
                    t* . t - 1,           its scale (t*: the located tangent)
                    c(v; theta) . t ]     the point is extremal along the branch

with c = grad_v A / A* (the nut amplitude's rate along the branch vanishes: the peak)
or c = e_p (the frequency's rate vanishes: a fold). E is regular at a non-degenerate
peak and at a simple fold (for a fold it is the Moore-Spence system in the branch's own
coordinates). Each evaluation costs the residual and two directional derivatives (one
through R, one through A); no second derivatives are formed.

At other parameters theta the point is found by chord Newton from the located one with
E's Jacobian at the estimate, factored once (`follow_start`), so that one compiled
program follows the point to many theta (vmapped). A lane has converged when the step
moves the point's frequency (and, at the peak, its amplitude) by less than
`FOLLOW_STEP_TOL` of their values, the orbit residual R is below `FOLLOW_RESIDUAL_TOL`
and the rest of E below `FOLLOW_EXTENDED_TOL` (scaled units of the continuation).
The residual tolerances are loose on purpose: where a joint loses contact the orbit's
force is only C^1, and the derivatives of a shooting residual through the adaptive
integrator (the R_v t rows) carry noise of about 1e-7 from one evaluation to the next
(the step sequence changes). Newton's steps then jitter the tangent and, through it, the
orbit (R at 1e-7 to 5e-7) while the frequency and amplitude stay put: on the bundled
worn drive at 100 N, over 30 steps at a refit 2 sd from the estimate, the peak's
frequency within 5e-5 Hz (its interval is 0.46 Hz wide) and its amplitude within 2e-10
of itself; a fold's frequency within 1e-9 Hz at the estimate. A lane that does not
converge in `FOLLOW_MAX_STEPS` steps reports failure rather than a value: a fold that
disappears between the estimate and theta (a cusp crossed) is one such lane.
"""

import diffrax as dfx
import jax
import jax.numpy as jnp

from ..machine import BSFSFamily
from ..model import vector_field
from ..solvers import family_amplitudes, family_residual
from ._orbit import orbit_samples

#: Chord steps a lane may take. The chord matrix is the estimate's, so a draw far from it
#: converges slowly: with the damper c_b 50 % up (about ten standard deviations on the
#: bundled worn drive) the peak, 7 Hz away, took more than 30 steps and its lane failed or
#: not by round-off (a change of 3e-16 in the records' variances decided it); with 60 it
#: is followed to the point located afresh (3e-6 Hz). Lanes near the estimate stop after a
#: few steps either way; a lane that cannot converge (a fold gone) runs to the cap.
FOLLOW_MAX_STEPS = 60
FOLLOW_STEP_TOL = 1e-7
FOLLOW_RESIDUAL_TOL = 1e-6
FOLLOW_EXTENDED_TOL = 1e-5


def _functions(params, force_n, hint):
    """(R(v), A(v)): the hint's orbit residual and the nut amplitude at `params` (the
    model built once, `BSFSFamily.prepare`), forward-mode through the ODE solves."""
    family = BSFSFamily(params, hint.frequency_hz, force_n).prepare()
    ode = dfx.ForwardMode()

    def residual(v):
        return family_residual(family, vector_field, hint.method, hint.scale, hint.p_scale,
                               1, v, ode)

    def amplitude(v):
        return family_amplitudes(family, vector_field, hint.method, hint.scale,
                                 hint.p_scale, 1, v, ode)[2]

    return residual, amplitude


def _system(functions, hint, peak_weight, amplitude_ref):
    """E(x) of the module docstring, with the amplitude at x's orbit; `peak_weight` 1:
    the peak, 0: a fold (traced, so that the peak and the folds share one program)."""
    residual, amplitude = functions
    t_star = jax.lax.stop_gradient(hint.tangent)

    def extended(x):
        """(E(x), the nut amplitude at x's orbit)."""
        n = x.shape[0] // 2
        v, t = x[:n], x[n:]
        r, r_t = jax.jvp(residual, (v,), (t,))
        a, a_t = jax.jvp(amplitude, (v,), (t,))
        rate = peak_weight * a_t / amplitude_ref + (1.0 - peak_weight) * t[-1]
        return jnp.concatenate([r, r_t, jnp.dot(t_star, t)[None] - 1.0, rate[None]]), a

    return extended


def _located(functions, hint):
    """(x0, amplitude_ref): x0 = (v*, t0) at the located point, t0 the tangent of R_v at
    v* scaled to t* . t0 = 1, and the nut amplitude there."""
    residual, amplitude = functions
    v_star = jax.lax.stop_gradient(hint.v)
    t_star = jax.lax.stop_gradient(hint.tangent)
    e_last = jnp.zeros(v_star.shape[0]).at[-1].set(1.0)
    t0 = jnp.linalg.solve(jnp.concatenate([jax.jacfwd(residual)(v_star), t_star[None]]),
                          e_last)
    return jnp.concatenate([v_star, t0]), amplitude(v_star)


def follow_start(params, force_n, hint, peak_weight):
    """(x0, lu, piv, amplitude_ref) at the located point (`_located`), with E's Jacobian
    there, factored."""
    functions = _functions(params, force_n, hint)
    x0, amplitude_ref = _located(functions, hint)
    extended = _system(functions, hint, peak_weight, amplitude_ref)
    lu, piv = jax.scipy.linalg.lu_factor(jax.jacfwd(lambda x: extended(x)[0])(x0))
    return x0, lu, piv, amplitude_ref


def follow_start_and_gradient(params_at, theta, force_n, hint, peak_weight):
    """(start, gradient): `follow_start` at `params_at(theta)` (theta: p values, the
    estimate), and the (2, p) gradient d(nut amplitude [m], frequency [Hz]) / d theta of
    the located point `hint` there.

    The point moves with theta on E(x; theta) = 0, so by the implicit function theorem
    dx/dtheta = -E_x^-1 E_theta; the amplitude's total derivative adds A_v dv/dtheta to
    its explicit A_theta. E_x, E_theta, A_x and A_theta come from one forward-mode pass
    over (x, theta) together (2n + p tangents), so that a program holds one
    second-order instance of the orbit's integration for the factored Jacobian and the
    gradient (separate passes traced and compiled it twice). At the peak this is the
    peak amplitude's and the peak frequency's gradient, at a fold the fold frequency's
    (the Moore-Spence derivative): the same values as the hyperplane system's
    (`frc_point_values`) and the peak's augmented one (`frc_peak_frequency_value`)."""
    x0, amplitude_ref = _located(_functions(params_at(theta), force_n, hint), hint)
    m = x0.shape[0]
    n = m // 2

    def extended(z):
        functions = _functions(params_at(z[m:]), force_n, hint)
        return _system(functions, hint, peak_weight, amplitude_ref)(z[:m])

    e_z, a_z = jax.jacfwd(extended)(jnp.concatenate([x0, jnp.asarray(theta, x0.dtype)]))
    lu, piv = jax.scipy.linalg.lu_factor(e_z[:, :m])
    dx = -jax.scipy.linalg.lu_solve((lu, piv), e_z[:, m:])
    gradient = jnp.stack([a_z[m:] + a_z[:n] @ dx[:n], dx[n - 1] * hint.p_scale])
    return (x0, lu, piv, amplitude_ref), gradient


def follow_point(params, force_n, hint, peak_weight, start):
    """(nut amplitude [m], frequency [Hz], converged) of the located point `hint` followed
    to `params` by chord Newton from `start` (`follow_start` at the estimate). Traceable
    and vmappable over `params`; a lane that does not converge in `FOLLOW_MAX_STEPS`
    steps, or whose residual stays above `FOLLOW_RESIDUAL_TOL`, says so."""
    x, ok, amplitude = _follow(params, force_n, hint, peak_weight, start)
    n = x.shape[0] // 2
    return amplitude, x[n - 1] * hint.p_scale, ok


def follow_to(params, force_n, hint, peak_weight, start):
    """(x, converged): the point x = (v, t) that `follow_point` reaches (v: the orbit
    unknowns and the scaled frequency). `start` may carry another first point in place of
    the located one (`follow_start`'s x0: the chord matrix stays the estimate's), e.g. the
    point followed to a nearby force; its convergence test is relative to that point."""
    return _follow(params, force_n, hint, peak_weight, start)[:2]


def _follow(params, force_n, hint, peak_weight, start):
    """(x, converged, nut amplitude at x): `follow_to`'s point and its amplitude."""
    x0, lu, piv, amplitude_ref = start
    functions = _functions(params, force_n, hint)
    extended = _system(functions, hint, peak_weight, amplitude_ref)
    n = x0.shape[0] // 2
    # a step's largest move of the point for it to count as converged; a fold's
    # amplitude is not its quantity (and moves along the fold's null direction)
    step_tol = FOLLOW_STEP_TOL / jnp.stack([1.0, peak_weight])

    def converged(e, q, q_before, x):
        a = jnp.abs(e)
        return (jnp.all(jnp.abs(q - q_before) <= step_tol)
                & (jnp.max(a[:n - 1]) <= FOLLOW_RESIDUAL_TOL)
                & (jnp.max(a[n - 1:]) <= FOLLOW_EXTENDED_TOL) & jnp.all(jnp.isfinite(x)))

    # Each pass steps from the point it holds (pass 0: a zero step, the first point) and
    # evaluates E there, which also gives the amplitude and the point's (frequency,
    # amplitude) relative to the first point's, q. After the pass whose point has
    # converged (E small, and the step that led there moved it by less than
    # FOLLOW_STEP_TOL), or that reached FOLLOW_MAX_STEPS steps, one more pass takes the
    # point one step further (the test bounds the last step's move, this step's is
    # smaller again) and ends the loop. E is traced, and compiled, once: in the loop.
    def body(carry):
        k, x, e, q, _, stop, ok, _ = carry
        x_new = x - jax.scipy.linalg.lu_solve((lu, piv), e)
        e_new, a_new = extended(x_new)
        q_new = jnp.stack([x_new[n - 1] / x0[n - 1], a_new / amplitude_ref])
        ok_new = jnp.where(stop, ok & jnp.all(jnp.isfinite(x_new)),
                           converged(e_new, q_new, q, x_new))
        return (k + 1, x_new, e_new, q_new, a_new,
                stop | ok_new | (k >= FOLLOW_MAX_STEPS), ok_new, stop)

    inf = jnp.full(2, jnp.inf, x0.dtype)
    carry = (0, x0, jnp.zeros_like(x0), inf, amplitude_ref, jnp.asarray(False),
             jnp.asarray(False), jnp.asarray(False))
    _, x, _, _, amplitude, _, ok, _ = jax.lax.while_loop(lambda c: ~c[-1], body, carry)
    return x, ok, amplitude


def orbit_samples_at(params, force_n, hint, v):
    """(ys (K, 6) [SI], system): the orbit with unknowns `v` (a point of `follow_to`) as
    the hint's method's uniform samples over one period."""
    return orbit_samples(BSFSFamily(params, hint.frequency_hz, force_n).prepare(), hint, v,
                         dfx.ForwardMode())
