"""Small numerical helpers shared by every layer (numpy and JAX arrays alike)."""

import jax
import jax.numpy as jnp
import numpy as np


def half_range(x, axis=0):
    """Half the peak-to-peak range, 0.5 * (max - min), along `axis` (None: all elements).

    The amplitude of an oscillation everywhere in the package. Works on numpy arrays,
    JAX arrays and tracers (inside `jit`/`vmap`); lists are converted with numpy. NaNs
    propagate.
    """
    if not (hasattr(x, "max") and hasattr(x, "min")):
        x = np.asarray(x)
    return 0.5 * (x.max(axis=axis) - x.min(axis=axis))


def float_array(x):
    """`jnp.asarray(x, dtype=float)` for the modules' field converters, without a compile:
    a Python number or numpy array is converted by numpy and placed on the device by
    `jax.device_put`, where `jnp.asarray` of a Python float (or of a numpy array) compiles a
    small program on a process's first call (about 30 ms of every cold command). Tracers
    and jax arrays as before."""
    if isinstance(x, jax.Array):
        return jnp.asarray(x, dtype=float)
    return jax.device_put(np.asarray(x, dtype=float))


def cofactors_3x3(a):
    """(C, det): the cofactor matrix C of a 3 x 3 matrix (C_ij = (-1)^(i+j) M_ij) and its
    determinant, in closed form. For the model's 3 x 3 systems (the thermal network, the
    static stiffness) this replaces an LU, whose CPU lowering alone loads scipy.linalg
    (0.1 s of every cold start), and it is differentiable everywhere."""
    a = jnp.asarray(a)
    c = jnp.stack([
        jnp.stack([a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1],
                   a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2],
                   a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]]),
        jnp.stack([a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2],
                   a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0],
                   a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]]),
        jnp.stack([a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1],
                   a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2],
                   a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]]),
    ])
    return c, jnp.dot(a[0], c[0])


def solve_3x3(a, b):
    """x with a x = b for a well-conditioned 3 x 3 `a` (Cramer's rule: adj(a) b / det a);
    see `cofactors_3x3`."""
    c, det = cofactors_3x3(a)
    return (c.T @ b) / det
