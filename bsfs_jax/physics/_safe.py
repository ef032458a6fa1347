"""Numerically safe elementwise helpers shared by the contact laws."""

import jax.numpy as jnp


def pos_pow(x, p):
    """`max(x, 0) ** p` with finite derivatives of every order everywhere.

    The inner `where` swaps in a placeholder of 1.0 (not 0.0) where `x <= 0`, so the
    untaken branch never evaluates `0 ** (p - k)`; the outer `where` then returns 0.
    For p = 3/2 the value and first derivative are continuous at 0 (C1 contact law).
    """
    x = jnp.asarray(x)
    pos = x > 0
    return jnp.where(pos, jnp.where(pos, x, 1.0) ** p, 0.0)
