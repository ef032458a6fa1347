"""Textbook vector fields with known answers, shared by the validation tests.

All are plain diffrax vector fields f(t, y, args) -> dy/dt, generic over the analyses:

- `duffing`: x'' + delta x' + alpha x + beta x^3 = gamma cos(omega t),
  y = (x, x'), args = (delta, alpha, beta, gamma, omega); forcing period 2 pi / omega.
- `linear_oscillator`: x'' + 2 zeta w0 x' + w0^2 x = f0 cos(omega t),
  y = (x, x'), args = (zeta, w0, f0, omega); the Duffing oscillator with beta = 0.
- `lorenz`: the Lorenz system, y = (x, y, z), args = (sigma, rho, beta); the classic
  chaotic parameters (10, 28, 8/3) have largest Lyapunov exponent ~0.906.
"""

import jax.numpy as jnp

#: Classic Lorenz parameters (sigma, rho, beta).
LORENZ_CLASSIC = (10.0, 28.0, 8.0 / 3.0)
#: Largest Lyapunov exponent of the classic Lorenz attractor (Sprott 2003: 0.9056).
LORENZ_LYAPUNOV = 0.9056


def duffing(t, y, args):
    """Forced Duffing oscillator x'' + delta x' + alpha x + beta x^3 = gamma cos(omega t)."""
    delta, alpha, beta, gamma, omega = args
    x, v = y[0], y[1]
    acc = gamma * jnp.cos(omega * t) - delta * v - alpha * x - beta * x * x * x
    return jnp.stack([v, acc])


def duffing_period(args):
    """Forcing period 2 pi / omega of `duffing`."""
    return 2.0 * jnp.pi / args[4]


def linear_oscillator(t, y, args):
    """Damped forced linear oscillator x'' + 2 zeta w0 x' + w0^2 x = f0 cos(omega t)."""
    zeta, w0, f0, omega = args
    x, v = y[0], y[1]
    acc = f0 * jnp.cos(omega * t) - 2.0 * zeta * w0 * v - w0 * w0 * x
    return jnp.stack([v, acc])


def linear_oscillator_eigenvalues(zeta, w0):
    """Eigenvalues of the homogeneous linear oscillator (complex, underdamped if zeta < 1)."""
    disc = jnp.sqrt(jnp.asarray(zeta * zeta - 1.0, dtype=complex))
    return jnp.stack([w0 * (-zeta + disc), w0 * (-zeta - disc)])


def linear_oscillator_response(zeta, w0, f0, omega):
    """Closed-form steady state (x(0), x'(0)) of `linear_oscillator` at t = 0."""
    h = f0 / (w0 * w0 - omega * omega + 2j * zeta * w0 * omega)  # x = Re(h e^{i w t})
    return jnp.stack([jnp.real(h), jnp.real(1j * omega * h)])


def lorenz(t, y, args):
    """Lorenz system x' = sigma (y - x), y' = x (rho - z) - y, z' = x y - beta z."""
    sigma, rho, beta = args
    x, yy, z = y[0], y[1], y[2]
    return jnp.stack([sigma * (yy - x), x * (rho - z) - yy, x * yy - beta * z])


def van_der_pol(t, y, args):
    """Forced van der Pol oscillator x'' - mu (1 - x^2) x' + x = a cos(omega t),
    args = (mu, a, omega). Weak forcing away from the locking tongues leaves the limit
    cycle beside the forcing: a 2-torus, quasi-periodic at the strobe."""
    mu, a, omega = args
    x, v = y[0], y[1]
    return jnp.stack([v, a * jnp.cos(omega * t) + mu * (1.0 - x * x) * v - x])
