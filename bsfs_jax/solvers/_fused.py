"""Fused Dormand-Prince loops, 5(4) and 8(7): the fast path for forward (non-reverse-mode)
runs.

Why this exists: for a 6-state system the work per step is tiny, so the cost is the
integrator's bookkeeping. diffrax's general loop (solver/controller/saving/event layers)
measured about 2.5x the per-step time of this single fused `lax.while_loop` on the 2-core
CPU (BENCHMARKS.md). Sweeps, Poincare maps and Lyapunov runs do not need reverse-mode
gradients, so they can take this path with `SolverSettings(solver="dopri5-fused")`.

Same method and controller as diffrax's `Dopri5` + `PIDController` (I-control, safety
0.9, factors in [0.2, 10], RMS error norm of err / (atol + rtol max(|y0|, |y1|))), so
the results agree with diffrax to the tolerance (tested). Save times are hit exactly by
clipping steps to them (no interpolation error). Works under jit, vmap, jvp and jacfwd;
`jax.grad` (reverse mode) is not supported by `lax.while_loop` - use a diffrax solver.

The 8(7) loop ("dopri8-fused") steps with diffrax's own `Dopri8` tableau (Prince & Dormand
1981; 13 stages per step, first same as last) and the I-controller with exponent 1/8; its
step sizes are held out of forward-mode derivatives (as diffrax's controller does), so
`jax.jvp` through it gives the variational equations of the steps taken, not the step-size
rule's own derivative. Measured on the BSFS period map (2-core CPU): a third to a quarter
of diffrax's time per call, but its program compiles in about four times as long (the
13 stages unrolled: 6.8 s against 1.6 s for a residual with its Jacobian; a loop over
the stages compiles in 1.2 s but runs no faster than diffrax). So it pays where a program
is called thousands of times (`bsfs map`'s row continuations), not where a few calls
follow a cold compilation.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._results import RESULTS

# Dormand & Prince (1980) 5(4) tableau.
_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
_A = (
    (),
    (1 / 5,),
    (3 / 40, 9 / 40),
    (44 / 45, -56 / 15, 32 / 9),
    (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
    (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
)
_B5 = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0])
_B4 = np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100,
                1 / 40])
_E = _B5 - _B4


def _dopri8_tableau():
    """(A, C, B, E) of diffrax's `Dopri8` (14 stages; the last, at c = 1 with the
    solution's weights, is the next step's first)."""
    import diffrax as dfx

    tab = dfx.Dopri8.tableau
    a = ((),) + tuple(tuple(float(v) for v in row) for row in tab.a_lower)
    c = np.concatenate([[0.0], np.asarray(tab.c, dtype=float)])
    b, e = np.asarray(tab.b_sol, dtype=float), np.asarray(tab.b_error, dtype=float)
    assert np.allclose(a[-1], b[:-1], rtol=0, atol=1e-15) and c[-1] == 1.0 and b[-1] == 0.0
    return a, c, b, e


@functools.cache
def _method(name: str):
    """(A, C, B, E, controller exponent, steps held out of derivatives) of "dopri5" or
    "dopri8"."""
    if name == "dopri5":
        return _A, _C, _B5, _E, 0.2, False
    return (*_dopri8_tableau(), 1 / 8, True)


def _rms(x):
    return jnp.sqrt(jnp.mean(x * x))


def first_step(d0, d1, span):
    """The initial step from d0 = RMS(y0 / scale), d1 = RMS(f0 / scale) (Hairer-Wanner's
    first guess, as diffrax), at most `span`; elementwise (shared with `_lanes.py`)."""
    h0 = jnp.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / jnp.where(d1 > 0, d1, 1.0))
    return jnp.minimum(h0, span)


def controller(en, finite, h, h_eff, clipped, fast=False, exponent=0.2):
    """(accept, next step) of the I-controller from the error norm `en` of a step of
    length `h_eff` (`h` before clipping onto a save time); elementwise (shared with
    `_lanes.py`). `fast`: `en` is the squared norm (no square root taken) and the factor's
    power is taken in float32 (about 1e-7 relative on the next step size, which only the
    step sequence sees), for the GPU kernel, where a float64 square root or power is a
    long software sequence."""
    accept = finite & (en <= 1.0)
    if fast:
        e32 = jnp.clip(en, 1e-20, 1e30).astype(jnp.float32)
        power = jnp.exp2(-0.1 * jnp.log2(e32)).astype(en.dtype)
    else:
        power = jnp.maximum(en, 1e-10) ** (-exponent)
    factor = jnp.where(finite, jnp.clip(0.9 * power, 0.2, 10.0), 0.2)
    h_prop = h_eff * factor
    # After a step shortened to hit a save time, do not let the short step shrink h.
    h_new = jnp.where(accept & clipped, jnp.maximum(h_prop, jnp.minimum(h, h_prop * 10)),
                      h_prop)
    return accept, h_new


def integrate_fused(vector_field, y0, args, t0, t1, ts, rtol, atol, max_steps,
                    method: str = "dopri5"):
    """(ys at ts, result, num_steps): `result` a `RESULTS` item (`successful`,
    `max_steps_reached`, `non_finite` or `step_size_failed`). `method`: "dopri5" or
    "dopri8".

    An outer `lax.scan` over the save times runs an inner `while_loop` of adaptive steps up
    to each one (the last step clipped to land on it), so no large output buffer is carried
    through the stepping loop.
    """
    ts = jnp.asarray(ts, dtype=float)
    y0 = jnp.asarray(y0, dtype=float)
    t0 = jnp.asarray(t0, dtype=float)
    t1 = jnp.asarray(t1, dtype=float)
    eps = 64 * jnp.finfo(ts.dtype).eps * jnp.maximum(jnp.abs(t1), jnp.abs(t0))
    f0 = vector_field(t0, y0, args)
    scale0 = atol + rtol * jnp.abs(y0)
    a, c, b, e, exponent, frozen = _method(method)
    stages = len(c)
    hold = jax.lax.stop_gradient if frozen else (lambda x: x)
    h0 = hold(first_step(_rms(y0 / scale0), _rms(f0 / scale0), t1 - t0))

    def step(s, target):
        t, y, h, k1, n, result = s
        clipped = t + h >= target
        h_eff = jnp.where(clipped, target - t, h)
        ks = [k1]
        for i in range(1, stages):
            yi = y + h_eff * sum(a[i][j] * ks[j] for j in range(i) if a[i][j] != 0.0)
            ks.append(vector_field(t + c[i] * h_eff, yi, args))
        y_new = y + h_eff * sum(b[j] * ks[j] for j in range(stages - 1) if b[j] != 0.0)
        err = h_eff * sum(e[j] * ks[j] for j in range(stages) if e[j] != 0.0)
        scale = atol + rtol * jnp.maximum(jnp.abs(y), jnp.abs(y_new))
        en = _rms(err / scale)
        finite = jnp.isfinite(en) & jnp.all(jnp.isfinite(y_new))
        accept, h_new = controller(hold(en), finite, h, hold(h_eff), clipped,
                                   exponent=exponent)
        t_new = jnp.where(clipped, target, t + h_eff)
        # A step size that underflows, or is NaN (a non-finite start), ends the run.
        tiny = ~(h_new >= 1e-14 * jnp.maximum(jnp.abs(t), 1e-3))
        failure = RESULTS.where(jnp.all(jnp.isfinite(y)), RESULTS.step_size_failed,
                                RESULTS.non_finite)
        result = RESULTS.where(tiny, failure, result)
        result = RESULTS.where((n + 1 >= max_steps) & ~(accept & (t_new >= target)),
                               RESULTS.max_steps_reached, result)
        return (jnp.where(accept, t_new, t), jnp.where(accept, y_new, y), h_new,
                jnp.where(accept, ks[-1], k1), n + 1, result)

    def advance(s, target):
        """Step until t reaches `target` (or a failure)."""
        return jax.lax.while_loop(lambda s: (s[0] < target) & (s[5] == RESULTS.successful),
                                  lambda s: step(s, target), s)

    def save(s, t_save):
        # Save times before t0 take the initial state; one a few ulps past t1 counts as t1.
        valid = t_save <= t1 + eps
        target = jnp.clip(t_save, t0, t1)
        s = advance(s, target)
        y = jnp.where(valid & (s[5] == RESULTS.successful), s[1], jnp.nan)
        return s, y

    state = (t0, y0, h0, f0, jnp.asarray(0), RESULTS.successful)
    # The run's end as one more save time of the same scan (not a second `advance` after
    # it): the program then holds the step once, not twice (its compile time), for the
    # same steps.
    state, ys = jax.lax.scan(save, state, jnp.append(ts, t1))
    ys = ys[:-1]
    # Save times past t1 cannot be reached.
    result = RESULTS.where((state[5] == RESULTS.successful) & jnp.any(ts > t1 + eps),
                           RESULTS.step_size_failed, state[5])
    return ys, result, state[4]
