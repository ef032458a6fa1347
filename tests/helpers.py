"""Shared test helpers: tree comparison, finite differences, period measurement."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def tree_allclose(x, y, *, rtol=1e-5, atol=1e-8):
    """True when two pytrees have the same structure, types and close leaves."""
    return bool(eqx.tree_equal(x, y, typematch=True, rtol=rtol, atol=atol))


def assert_x64():
    """Finite differences at step sqrt(eps) are meaningless in float32: refuse to run."""
    assert jax.config.jax_enable_x64, "finite-difference checks need jax_enable_x64"
    assert jnp.zeros(()).dtype == jnp.float64


def fd_step(x, scale=None):
    """Central-difference step eps = sqrt(machine eps) * scale (optimistix's choice).

    The truncation error of a central difference is O(h^2 f''') and the round-off error is
    O(eps |f| / h); for smooth f the total is smallest near h = eps^(1/3), but for
    functions computed to a relative accuracy well above eps (an adaptive ODE solve) the
    noise term dominates, and h = sqrt(eps) * scale keeps both terms well below 1e-4.
    `scale` defaults to max(|x|, 1) in the variable's own units.
    """
    assert_x64()
    if scale is None:
        scale = max(abs(float(x)), 1.0)
    return float(np.sqrt(np.finfo(np.float64).eps) * scale)


def finite_difference(fn, x, *, scale=None):
    """Central finite-difference gradient of a scalar function of a 1-D array `x`.

    `scale` (scalar or per-component array) sets the step of each component as
    sqrt(eps) * scale; by default max(|x_i|, 1). Returns a numpy array like `x`.
    """
    assert_x64()
    x = np.asarray(x, dtype=np.float64)
    scales = np.broadcast_to(
        np.maximum(np.abs(x), 1.0) if scale is None else np.asarray(scale, dtype=float), x.shape
    )
    grad = np.empty_like(x)
    for i in range(x.size):
        h = fd_step(x[i], scales[i])
        e = np.zeros_like(x)
        e[i] = h
        grad[i] = (float(fn(jnp.asarray(x + e))) - float(fn(jnp.asarray(x - e)))) / (2 * h)
    return grad


def finite_difference_jvp(fn, x, tangent, *, scale=1.0):
    """Central finite-difference directional derivative of `fn` (any pytree output)."""
    assert_x64()
    h = fd_step(0.0, scale)
    x = jnp.asarray(x)
    plus = fn(x + h * tangent)
    minus = fn(x - h * tangent)
    return jax.tree_util.tree_map(lambda a, b: (a - b) / (2 * h), plus, minus)


def relative_error(a, b):
    """max |a - b| / max |b| (norm-wise relative error; safe near zero crossings of b)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def upward_crossings(t, x, v):
    """Times where x crosses 0 upwards, located on the cubic Hermite interpolant.

    `t`, `x`, `v` are samples of a trajectory and its exact derivative; using `v` makes
    each located time accurate to O(h^4), far better than linear interpolation.
    """
    t, x, v = (np.asarray(a, dtype=float) for a in (t, x, v))
    idx = np.flatnonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))
    out = []
    for i in idx:
        h = t[i + 1] - t[i]
        x0, x1, m0, m1 = x[i], x[i + 1], v[i] * h, v[i + 1] * h

        def p(s):
            return ((2 * s**3 - 3 * s**2 + 1) * x0 + (s**3 - 2 * s**2 + s) * m0
                    + (-2 * s**3 + 3 * s**2) * x1 + (s**3 - s**2) * m1)

        def dp(s):
            return ((6 * s**2 - 6 * s) * x0 + (3 * s**2 - 4 * s + 1) * m0
                    + (-6 * s**2 + 6 * s) * x1 + (3 * s**2 - 2 * s) * m1)

        s = x0 / (x0 - x1)  # linear guess, then Newton on the cubic
        for _ in range(20):
            s = s - p(s) / dp(s)
        out.append(t[i] + s * h)
    return np.asarray(out)


def measured_period(t, x, v):
    """Mean period from the first to the last upward zero crossing."""
    c = upward_crossings(t, x, v)
    assert c.size >= 3, "too few oscillations to measure a period"
    return (c[-1] - c[0]) / (c.size - 1)
