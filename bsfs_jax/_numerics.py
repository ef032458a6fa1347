"""Small numerical helpers shared by every layer (numpy and JAX arrays alike)."""

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
