"""Records of the sizes users bring: no hang, no program that grows with the record.

The line screening of a chirp's FRF once ran two batched LAPACK solves side by side over
every line; above about 2000 lines jaxlib's CPU thread pool deadlocked on them (a 4 s chirp
at 0.25 Hz resolution has 7600). The per-test timeout (pyproject.toml) turns a hang into a
failure.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
from bsfs_jax._numerics import solve_small


def test_solve_small_equals_lapack_with_pivoting():
    rng = np.random.default_rng(3)
    for n in (1, 3, 6, 12):
        a = rng.normal(size=(40, n, n)) + 1j * rng.normal(size=(40, n, n))
        if n > 1:
            a[:, 0, 0] = 0.0  # the first pivot must come from another row
        b = rng.normal(size=(40, n, 2)) + 1j * rng.normal(size=(40, n, 2))
        x = np.asarray(solve_small(a, b))
        ref = np.linalg.solve(a, b)
        assert np.max(np.abs(x - ref)) <= 1e-12 * np.max(np.abs(ref))
        # the residual, independent of numpy's answer
        assert np.max(np.abs(a @ x - b)) <= 1e-12 * np.max(np.abs(b))


def test_solve_small_gradient_matches_finite_differences():
    def f(s):
        a = jnp.array([[s, 1.0, 0.5], [2.0, 3.0, 1.0], [0.1, -1.0, 4.0]])
        return jnp.sum(solve_small(a, jnp.ones((3, 1))) ** 2)

    eps = 1e-6
    fd = (f(0.5 + eps) - f(0.5 - eps)) / (2 * eps)
    assert abs(float(jax.grad(f)(0.5)) - float(fd)) < 1e-7 * max(1.0, abs(float(fd)))


@pytest.mark.timeout(120)
def test_chirp_line_screening_of_a_long_record_returns():
    """The vmapped linearisation error over 8192 lines (a 4 s chirp at 10 kHz has 7600)
    returns, and equals the per-line values computed in small batches."""
    from identification._measurement import linearisation_error

    system = bsfs_jax.build_system(bsfs_jax.preset("default"))
    f = jax.jit(jax.vmap(linearisation_error, in_axes=(None, 0, 0)))
    n = 8192
    freq = jnp.linspace(100.0, 2000.0, n)
    force = jnp.full((n, 1), 5.0 + 0.0j)
    big = np.asarray(f(system, freq, force))
    assert np.all(np.isfinite(big))
    idx = np.array([0, 1000, 4000, 8191])
    small = np.asarray(f(system, freq[idx], force[idx]))
    np.testing.assert_allclose(big[idx], small, rtol=1e-10, atol=0)
