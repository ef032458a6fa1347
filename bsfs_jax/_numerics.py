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
