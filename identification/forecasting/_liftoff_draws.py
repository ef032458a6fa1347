"""The lift-off force on the nonlinear orbits by the model itself at each saved draw.

At the estimate, a joint's lift-off force F* is where its smallest contact deformation
over the orbit at the FRC peak, m(F, theta), reaches zero (`_liftoff.py`: a secant in the
force, the peak located afresh by continuation at each force). At a draw theta_k the same
secant runs inside one vmapped program, the peak not located afresh but followed
(`bsfs_jax.design.follow_to`: chord Newton on the peak's extended system, the chord
matrix the estimate's at F*) from the estimate's peak to (theta_k, F), and from each
secant step's point to the next. The secant starts at the delta prediction
F* + g . (theta_k - theta_hat) and stops as the search at the estimate does
(`LIFTOFF_RTOL`, `LIFTOFF_FTOL`). A lane whose point cannot be followed, or whose secant
does not stop in `LIFTOFF_STEPS` steps, gives NaN, not a value.
"""

from __future__ import annotations

import numpy as np

import bsfs_jax
from bsfs_jax.machine import JOINTS

from ._batches import draw_batches, lane_parts, run_batches
from ._frc_draws import BATCH_ROUND

FIRST_STEP = 1e-3  # the secant's second force: the first times (1 + FIRST_STEP)
# The lift-off secant (here and at the estimate, `_liftoff.search_on_orbits`): at most
# this many steps; stop where the deformation is this fraction of the first two ...
LIFTOFF_STEPS = 8
LIFTOFF_RTOL = 1e-4
# ... or where a secant step moves the force by less than this fraction of it: the
# deformation at the located peak carries noise of about 1e-4 um (the continuation's
# tolerances), which on coverage replicate 78 kept the nut's secant hopping within 0.004 N
# of 102.506 N without meeting the test above (its lift-off's std: 0.55 N).
LIFTOFF_FTOL = 1e-4


def joint_deformations(ys, system, joint):
    """The contact deformations [m] of both sides of joint `joint` (a name in `JOINTS` or
    its traced index) at the orbit samples `ys` (K, 6), flattened."""
    import jax.numpy as jnp

    from bsfs_jax.physics import contact_deformations

    both = {"bearing": jnp.stack(contact_deformations(ys[:, 0], system.bearing)).ravel(),
            "nut": jnp.stack(contact_deformations(ys[:, 2] - ys[:, 1], system.nut)).ravel()}
    return both[joint] if isinstance(joint, str) else jnp.where(
        jnp.asarray(joint) == JOINTS.index("bearing"), both["bearing"], both["nut"])


def min_deformation_at(params, force, hint, v, joint):
    """The smallest contact deformation [m] of joint `joint` (traced index into `JOINTS`)
    over the orbit with unknowns `v` (`design.orbit_samples_at`)."""
    from bsfs_jax.design.building import orbit_samples_at

    return joint_deformations(*orbit_samples_at(params, force, hint, v), joint).min()


@bsfs_jax.cached_jit
def _liftoff_lanes(coords, theta, thetas, f_star, grad, hint, joint):
    """(n, 4): (F*, converged, every point followed, secant steps) at each row of
    `thetas`, from the estimate's F* `f_star` with gradient `grad` and its FRC peak
    `hint`."""
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design.building import follow_start, follow_to

    x0, lu, piv, amplitude_ref = follow_start(coords.at(theta), f_star, hint, 1.0)
    n = x0.shape[0] // 2

    def lane(th):
        params = coords.at(th)

        def m(force, x_from):
            x, ok = follow_to(params, force, hint, 1.0, (x_from, lu, piv, amplitude_ref))
            return min_deformation_at(params, force, hint, x[:n], joint), x, ok

        # One loop evaluates m at every force, the secant's two starting forces included
        # (pass 0: the delta prediction f0; pass 1: f0 (1 + FIRST_STEP); then the secant
        # steps): m is traced, and compiled, once instead of three times.
        f_first = f_star + jnp.dot(grad, th - theta)

        def stopped(fa, ma, fb, mb, scale):
            return (jnp.abs(mb) < LIFTOFF_RTOL * scale) | (
                jnp.abs(fb - fa) < LIFTOFF_FTOL * jnp.abs(fb))

        def cond(carry):
            j, fa, ma, fb, mb, scale, _, ok = carry
            return (j < 2) | ((j - 2 < LIFTOFF_STEPS) & ok & ~stopped(fa, ma, fb, mb, scale))

        def body(carry):
            j, fa, ma, fb, mb, scale, x, ok = carry
            secant = fb - mb * (fb - fa) / (mb - ma)
            f = jnp.where(j == 0, f_first, jnp.where(j == 1, fb * (1.0 + FIRST_STEP), secant))
            m_f, x_f, ok_f = m(f, x)
            scale = jnp.where(j == 1, jnp.abs(mb) + jnp.abs(m_f), scale)
            fa, ma = jnp.where(j == 0, f, fb), jnp.where(j == 0, m_f, mb)
            return j + 1, fa, ma, f, m_f, scale, x_f, ok & ok_f & jnp.isfinite(f)

        nan = jnp.asarray(jnp.nan, x0.dtype)
        carry = (0, nan, nan, nan, nan, nan, x0, jnp.asarray(True))
        j, fa, ma, fb, mb, scale, _, ok = jax.lax.while_loop(cond, body, carry)
        return jnp.stack([fb, (ok & stopped(fa, ma, fb, mb, scale)).astype(float),
                          ok.astype(float), (j - 2).astype(float)])

    return jax.vmap(lane)(thetas)


def _calls(ident, hint, f_star, grad, joint) -> list:
    """`_liftoff_lanes`' arguments for each batch of the draws (`draw_batches`, padded
    and cut for `run_batches`' threads as the FRC points' are: each lane costs its
    follows)."""
    import jax.numpy as jnp

    head = (ident.coordinates, jnp.asarray(ident.theta, float))
    tail = (jnp.asarray(f_star, float), jnp.asarray(grad, float), hint,
            jnp.asarray(joint, jnp.int32))
    return [(*head, jnp.asarray(thetas, float), *tail)
            for thetas in draw_batches(ident, BATCH_ROUND, lane_parts(ident))]


def prefetch_liftoff(ident, hint, joint: int) -> None:
    """Start compiling, on the background thread, the program that `liftoff_at_draws`
    will call for a hint of `hint`'s layout (its values do not matter): `nonlinear_liftoff`
    calls it at the search's first located peak, so that the program compiles while the
    search runs on."""
    if ident.cluster is not None:
        return  # the workers compile it
    _liftoff_lanes.prefetch_now(*_calls(ident, hint, 1.0, np.zeros(len(ident.theta)),
                                        joint)[0])


def liftoff_at_draws(ident, hint, f_star: float, grad, joint: int, *,
                     details: bool = False) -> np.ndarray:
    """(n,): joint `JOINTS[joint]`'s lift-off force [N] on the nonlinear orbits at each of
    the identification's n draws; NaN where the model failed there. `details`: the
    program's (n, 4) columns instead (`_liftoff_lanes`)."""
    calls = _calls(ident, hint, f_star, grad, joint)
    out = np.concatenate(run_batches(_liftoff_lanes, calls, ident.cluster))[:len(ident.draws)]
    return out if details else np.where(out[:, 1] > 0.5, out[:, 0], np.nan)
