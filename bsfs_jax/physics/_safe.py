"""Numerically safe elementwise helpers shared by the contact laws."""

import jax
import jax.numpy as jnp


def pos_pow(x, p, fast=False):
    """`max(x, 0) ** p` with finite derivatives of every order everywhere.

    The inner `where` swaps in a placeholder of 1.0 (not 0.0) where `x <= 0`, so the
    untaken branch never evaluates `0 ** (p - k)`; the outer `where` then returns 0.
    For p = 3/2 the value and first derivative are continuous at 0 (C1 contact law).
    `fast` (p = 3/2 only): the square root as x * rsqrt(x), a few ulp from the correctly
    rounded form, for the GPU kernel (see `physics.pair_force`).
    """
    x = jnp.asarray(x)
    pos = x > 0
    safe = jnp.where(pos, x, 1.0)
    if p == 1.5 and fast:
        value = safe * (safe * jax.lax.rsqrt(safe))
    elif p == 1.5:  # the Hertz law: x sqrt(x) is much cheaper than a general power
        value = safe * jnp.sqrt(safe)
    elif p == 2.5:
        value = safe * safe * jnp.sqrt(safe)
    else:
        value = safe**p
    return jnp.where(pos, value, 0.0)
