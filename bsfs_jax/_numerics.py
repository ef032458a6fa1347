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


# Taylor coefficients of sin(z) = z (1 + z^2 (c1 + z^2 (c2 + ...))), (-1)^k / (2k + 1)!,
# enough terms for |z| <= pi / 2 to a few ulp (the first one left out: 1.2e-18).
_SIN_TAYLOR = tuple((-1.0) ** k / float(np.prod(np.arange(1, 2 * k + 2, dtype=float)))
                    for k in range(1, 12))


def sin_turns(x):
    """sin(2 pi x) for float64 `x` in turns, without a branch: the argument reduced to
    [-1/4, 1/4] turn by exact subtractions, then an odd Taylor polynomial (a few ulp).

    For the per-lane GPU kernel, where the library sine's slow-path branch for large
    arguments splits a step into short basic blocks; a sinusoid's phase in turns (f t) is
    reduced exactly, where 2 pi f t already carries its own rounding."""
    r = x - jnp.floor(x + 0.5)  # [-1/2, 1/2]
    r = jnp.where(r > 0.25, 0.5 - r, jnp.where(r < -0.25, -0.5 - r, r))  # [-1/4, 1/4]
    z = (2.0 * np.pi) * r
    z2 = z * z
    poly = _SIN_TAYLOR[-1]
    for c in _SIN_TAYLOR[-2::-1]:
        poly = c + z2 * poly
    return z + z * (z2 * poly)



def solve_small(a, b):
    """x with a x = b for small square systems, by Gaussian elimination with partial
    pivoting written in plain array operations (no LAPACK call).

    `a` (..., n, n) and `b` (..., n, m), real or complex, with broadcasting batch axes;
    returns x (..., n, m). Meant for n up to about 12 inside `vmap` over many lines or
    records: it compiles to elementwise code that XLA fuses, where `jnp.linalg.solve`
    becomes LAPACK custom calls. Batched LAPACK calls on jaxlib's CPU backend (0.10) split
    a large batch over XLA's intra-op thread pool and block a pool thread until the pieces
    finish; two such calls running at once on a 2-thread pool wait on each other for ever
    (the hang of a 4 s chirp's line screening). Differentiable (the pivot choice is
    piecewise constant). A singular `a` gives inf or NaN, as a division by a zero pivot.
    """
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    n = a.shape[-1]
    dtype = jnp.result_type(a, b)
    batch = jnp.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    a = jnp.broadcast_to(a, batch + a.shape[-2:]).astype(dtype)
    b = jnp.broadcast_to(b, batch + b.shape[-2:]).astype(dtype)
    aug = jnp.concatenate([a, b], axis=-1)  # (..., n, n + m)
    rows = jnp.arange(n).reshape((1,) * len(batch) + (n,))  # explicit ranks throughout
    for k in range(n):
        size = jnp.where(rows >= k, jnp.abs(aug[..., :, k]), -1.0)
        p = jnp.argmax(size, axis=-1)  # (...,) the pivot row
        row_k = aug[..., k, :]
        row_p = jnp.take_along_axis(aug, p[..., None, None], axis=-2)[..., 0, :]
        aug = jnp.where((rows == p[..., None])[..., None], row_k[..., None, :], aug)
        aug = aug.at[..., k, :].set(row_p)
        factor = jnp.where(rows > k, aug[..., :, k] / row_p[..., k, None], 0.0)
        aug = aug - factor[..., :, None] * row_p[..., None, :]
    x = [None] * n
    for k in reversed(range(n)):
        acc = aug[..., k, n:]
        for j in range(k + 1, n):
            acc = acc - aug[..., k, j, None] * x[j]
        x[k] = acc / aug[..., k, k, None]
    return jnp.stack(x, axis=-2)
