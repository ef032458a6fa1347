"""Shooting and Floquet stability on systems with known answers (generic vector fields)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.solvers import (
    SHOOTING_SETTINGS,
    SolverError,
    classify_multipliers,
    floquet_multipliers,
    shoot,
    transient_state,
)

from .textbook import (
    duffing,
    linear_oscillator,
    linear_oscillator_eigenvalues,
    linear_oscillator_response,
)

# A weakly hardening Duffing oscillator away from its fold region: one stable T-orbit.
DUFFING = (0.1, 1.0, 0.05, 0.3, 1.1)  # delta, alpha, beta, gamma, omega
ONES = jnp.ones(2)


def test_linear_oscillator_multipliers_are_exp_lambda_t():
    zeta, w0, f0, omega = 0.05, 1.0, 1.0, 1.3
    period = 2 * np.pi / omega
    # The linear oscillator is the Duffing field with beta = 0 (shares its compiled code).
    as_duffing = (2 * zeta * w0, w0 * w0, 0.0, f0, omega)
    np.testing.assert_allclose(duffing(0.4, jnp.array([0.3, -0.2]), as_duffing),
                               linear_oscillator(0.4, jnp.array([0.3, -0.2]),
                                                 (zeta, w0, f0, omega)), rtol=1e-14)
    orbit = shoot(duffing, jnp.zeros(2), as_duffing, period, scale=ONES)
    expected = np.exp(np.asarray(linear_oscillator_eigenvalues(zeta, w0)) * period)
    got = np.asarray(orbit.multipliers)
    # Same set of complex numbers (a conjugate pair: compare sorted by imaginary part).
    np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(expected), atol=1e-9)
    np.testing.assert_allclose(orbit.state, linear_oscillator_response(zeta, w0, f0, omega),
                               rtol=1e-8, atol=1e-10)
    assert bool(orbit.converged) and float(orbit.residual) < 1e-8
    assert bool(orbit.stable)
    # floquet_multipliers at any state of a linear system gives the same spectrum.
    mu = floquet_multipliers(duffing, jnp.array([0.3, -0.2]), as_duffing, period)
    np.testing.assert_allclose(np.sort_complex(np.asarray(mu)), np.sort_complex(expected),
                               atol=1e-9)
    # The monodromy matrix is exp(A T) of the homogeneous system.
    a = np.array([[0.0, 1.0], [-w0**2, -2 * zeta * w0]])
    lam, vec = np.linalg.eig(a)
    expm = (vec @ np.diag(np.exp(lam * period)) @ np.linalg.inv(vec)).real
    np.testing.assert_allclose(orbit.monodromy, expm, atol=1e-9)


def test_shooting_agrees_with_long_simulation():
    period = 2 * np.pi / DUFFING[4]
    # Transient from rest: |mu| = exp(-delta T / 2) = 0.75 per period, so after 200
    # periods the transient is below 1e-24 of its start. Integrated at the tight shooting
    # tolerances, so that the comparison tests the orbit, not the simulation's error.
    settled = transient_state(duffing, jnp.zeros(2), DUFFING, period, 200,
                              settings=SHOOTING_SETTINGS)
    orbit = shoot(duffing, jnp.array([0.5, 0.0]), DUFFING, period, scale=ONES)
    np.testing.assert_allclose(orbit.state, settled, rtol=0, atol=1e-8)
    assert bool(orbit.stable)
    # det M = exp(-delta T) (Liouville) for any orbit of the damped Duffing oscillator.
    np.testing.assert_allclose(np.prod(np.asarray(orbit.multipliers)).real,
                               np.exp(-DUFFING[0] * period), rtol=1e-8)


def test_orbit_derivative_matches_finite_differences():
    """d state / d (gamma, omega) by the implicit function theorem vs central differences."""
    base = np.array([DUFFING[3], DUFFING[4]])
    guess = shoot(duffing, jnp.array([0.5, 0.0]), DUFFING, 2 * np.pi / DUFFING[4],
                  scale=ONES).state

    def orbit_state(theta):
        gamma, omega = theta[0], theta[1]
        args = (DUFFING[0], DUFFING[1], DUFFING[2], gamma, omega)
        return shoot(duffing, guess, args, 2 * jnp.pi / omega, scale=ONES).state

    jac = np.asarray(jax.jacfwd(orbit_state)(jnp.asarray(base)))
    h = 1e-5
    fd = np.stack([(np.asarray(orbit_state(jnp.asarray(base + h * e)))
                    - np.asarray(orbit_state(jnp.asarray(base - h * e)))) / (2 * h)
                   for e in np.eye(2)], axis=1)
    assert np.all(np.isfinite(jac)) and np.max(np.abs(jac)) > 0.1
    np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-6)


def test_shoot_reports_failure():
    # Two Newton steps from a poor guess of a strongly nonlinear orbit cannot converge.
    args = (0.02, 1.0, 5.0, 2.0, 1.1)
    with pytest.raises(SolverError, match="shooting did not converge"):
        shoot(duffing, jnp.array([3.0, -2.0]), args, 2 * np.pi / 1.1, scale=ONES,
              max_steps=2)
    with pytest.raises(ValueError, match="y_guess must be finite"):
        shoot(duffing, jnp.array([np.nan, 0.0]), args, 2 * np.pi / 1.1)
    with pytest.raises(ValueError, match="n_periods"):
        shoot(duffing, jnp.zeros(2), args, 1.0, n_periods=0)


def test_classify_multipliers():
    assert classify_multipliers(np.array([0.5, 0.2j])) == "stable"
    assert classify_multipliers(np.array([1.2, 0.1])) == "unstable"
    assert classify_multipliers(np.array([1.0 + 1e-5, 0.3])) == "fold"
    assert classify_multipliers(np.array([-0.9999, 0.3])) == "period-doubling"
    ns = np.exp(1j * 0.7) * (1 + 1e-5)
    assert classify_multipliers(np.array([ns, np.conj(ns)])) == "neimark-sacker"
    assert classify_multipliers(np.array([np.nan, 0.1])) == "invalid"
    labels = classify_multipliers(np.array([[0.5, 0.1], [-1.0, 0.2], [2.0, 0.1]]))
    assert labels.shape == (3,) and list(labels) == ["stable", "period-doubling", "unstable"]
