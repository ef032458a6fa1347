"""The measurement model's linear side: parameters -> predicted harmonics of the nut.

The model is driven by the measured force harmonics (`HarmonicForcing`)
and its output is the worktable acceleration x_n''. Two steady-state models:

- `linear`: A_k = -(k w)^2 H_nn(k w) F_k with the linearised receptance
  `bsfs_jax.linear_frf` about the (thermally offset) equilibrium. Exact in the small-force
  limit and costs one 3x3 solve per harmonic; at the paper's 100 N it agrees with the
  nonlinear steady state to about 1e-5 relative (measured, see the report), far below the
  noise of the coefficients (about 2e-4 relative for 2 s at 35 dB).
- `nonlinear`: the periodic orbit of the full Eq. 31 under the measured force harmonics,
  by harmonic balance from the record's own measured state (`_orbit_model.py`: the model,
  its accuracy, and which branch near a fold). Needed near the resonance and when the force
  reaches the joint nonlinearity (the 3000 N records): at 1150 Hz / 100 N the linear model
  is 3 % off, at 3000 N / 150 Hz 2 %.

- `first-order`: the linear model plus one chord step of harmonic balance
  (`linearisation_error`): the weakly nonlinear case at the cost of 64 force evaluations
  per record, with the same Jacobian machinery as the linear model.

Choice per record (`Problem(model="auto")`, `_choice.py`): the simplest of the three whose
predicted error is below 0.1 standard errors of the record's harmonics. Comparing in the
harmonic domain is equivalent to comparing steady-state time samples (Parseval) once the
record is stationary, but reduces 20 000 samples to 6 numbers with known standard errors
and needs the model's steady state for one period only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bsfs_jax.machine import tangent_matrices

NONLINEAR_SAMPLES = 64


def _matrices(system):
    """(K, C, M) of the model linearised about x = 0 (`bsfs_jax.machine.tangent_matrices`;
    see `receptance`)."""
    k, c, m = tangent_matrices(system)
    return k, c, jnp.diag(m)


def _dynamic_stiffness(system, frequencies_hz):
    """(Z (L, 3, 3) = K - w^2 M + i w C per line, w (L,) [rad/s], C, M) of the model
    linearised about x = 0 (`_matrices`), at the flattened frequencies."""
    k, c, m = _matrices(system)
    w = 2.0 * jnp.pi * jnp.atleast_1d(frequencies_hz).reshape(-1)
    return k[None] - (w**2)[:, None, None] * m[None] + 1j * w[:, None, None] * c[None], w, c, m


def receptance(system, frequencies_hz):
    """Complex receptance x_j / P [m/N], shape (len(f), 3), linearised about x = 0.

    The same quantity as `bsfs_jax.linear_frf`, but the linearisation point is the
    unforced equilibrium x = 0, which is exact for this model (both halves of each
    preloaded pair carry the same thermal offset, so F(0) = 0; checked in the tests against
    `bsfs_jax.equilibrium`). Skipping the Newton solve keeps the residual finite when a
    trial parameter set of the optimiser loses the preload (singular stiffness -> inf, which
    the optimiser rejects) instead of raising inside the implicit derivative of the solve.
    """
    # Z, one 3 x 3 per line; x = Z^-1 e_3 is the third column of the adjugate over the
    # determinant (expanded along the third row). Elementwise over the lines: about 5x
    # faster than a batched LU with its Jacobian (identification's hot loop) and equal to
    # it to round-off (tests/test_identification.py).
    z = _dynamic_stiffness(system, frequencies_hz)[0]
    a0 = z[:, 0, 1] * z[:, 1, 2] - z[:, 0, 2] * z[:, 1, 1]
    a1 = z[:, 0, 2] * z[:, 1, 0] - z[:, 0, 0] * z[:, 1, 2]
    a2 = z[:, 0, 0] * z[:, 1, 1] - z[:, 0, 1] * z[:, 1, 0]
    det = z[:, 2, 0] * a0 + z[:, 2, 1] * a1 + z[:, 2, 2] * a2
    return jnp.stack([a0, a1, a2], axis=1) / det[:, None]


def linear_acceleration(system, frequencies_hz, force_coeffs):
    """Model acceleration harmonics [m/s^2] (complex, same shape as `force_coeffs`).

    `frequencies_hz` (..., H) are the harmonic frequencies k f, `force_coeffs` the complex
    force coefficients there; uses the linearised receptance of the nut mass.
    """
    shape = frequencies_hz.shape
    h = receptance(system, frequencies_hz.reshape(-1))[:, 2].reshape(shape)
    w = 2.0 * jnp.pi * frequencies_hz
    return -(w**2) * h * force_coeffs


def drift_terms(system, frequencies_hz, rate, rate2):
    """Correction [m/s^2] to the mean acceleration harmonics of a record whose force
    envelope drifts (complex, the shape of `frequencies_hz`).

    For a force Re(c(t) e^{i w t}) with a slowly varying envelope c(t), the response's
    envelope is G(w) c - i G'(w) c' - G''(w) c'' / 2 + ..., G the accelerance and ' the
    derivative in w [rad/s] (expand G(w + d) with d c -> -i dc/dt). The record's mean
    coefficients (`harmonic_analysis`) therefore differ from G times the mean force by the
    last two terms with c', c'' replaced by their means over the record (`rate`, `rate2`:
    `HarmonicData.force_rate`, `force_rate2`). Near a lightly damped resonance G'/G is about
    1 / (zeta w), the response's group delay: a 3 % drift over half a second then moves the
    mean harmonic by several of its standard errors. Uses the linearised accelerance for
    every model (for the periodic orbit it is the first-order term of the drift's effect).
    """
    # In closed form, per line (a third of the program of nested jvps through
    # `receptance`): with Z = K - w^2 M + i w C and X = Z^-1 e_3 the nut's receptance,
    # X' = -Z^-1 Z' X and X'' = -Z^-1 (2 Z' X' + Z'' X), Z' = i C - 2 w M, Z'' = -2 M;
    # G = -w^2 X_3, so G' = -2 w X_3 - w^2 X_3' and G'' = -2 X_3 - 4 w X_3' - w^2 X_3''.
    z, w, c, m = _dynamic_stiffness(system, frequencies_hz)
    inv = _inverse3(z)
    x = inv[:, :, 2]
    dz = 1j * c[None] - 2.0 * w[:, None, None] * m[None]
    x1 = -jnp.einsum("lij,ljk,lk->li", inv, dz, x)
    x2 = -jnp.einsum("lij,lj->li", inv, 2.0 * jnp.einsum("lij,lj->li", dz, x1)
                     - 2.0 * jnp.einsum("ij,lj->li", m, x))
    g1 = -2.0 * w * x[:, 2] - w**2 * x1[:, 2]
    g2 = -2.0 * x[:, 2] - 4.0 * w * x1[:, 2] - w**2 * x2[:, 2]
    shape = frequencies_hz.shape
    return -1j * g1.reshape(shape) * rate - 0.5 * g2.reshape(shape) * rate2


def _inverse3(z):
    """(L, 3, 3) inverses of 3 x 3 matrices by their adjugates (elementwise)."""
    cof = lambda i, j: (z[:, (i + 1) % 3, (j + 1) % 3] * z[:, (i + 2) % 3, (j + 2) % 3]
                        - z[:, (i + 1) % 3, (j + 2) % 3] * z[:, (i + 2) % 3, (j + 1) % 3])
    adj = jnp.stack([jnp.stack([cof(j, i) for j in range(3)], axis=-1) for i in range(3)],
                    axis=1)  # adj[i, j] = cofactor(j, i)
    det = jnp.sum(z[:, 0, :] * adj[:, :, 0], axis=-1)
    return adj / det[:, None, None]


def linearisation_error(system, frequency_hz, force_coeffs, samples: int = NONLINEAR_SAMPLES,
                        steps: int = 1):
    """Correction to `linear_acceleration` [m/s^2] for the joints' nonlinearity (complex (H,)).

    Harmonic balance on the harmonics k = 1..H of the force and the mean, solved by the
    chord method from the linear steady state (`chord_corrections`, on the orbit engine's
    AFT residual): the restoring forces are evaluated along the current response at
    `samples` points per period, and each step corrects the harmonics by the linearised
    system's dynamic stiffness, on harmonic k (K - (k w)^2 M + i k w C)^(-1), and the mean
    by K^(-1). The result is -(k w)^2 times the total correction of the nut's harmonics.
    `steps=1` is first order in the nonlinearity (the "first-order" measurement model, and
    the predicted error of the linear one); the difference between 2 and 1 steps estimates
    the first-order model's own error. The harmonics above H are left out: for strong
    nonlinearity use the periodic orbit (`nonlinear_acceleration`).
    """
    return chord_corrections(system, frequency_hz, force_coeffs, steps, samples)[-1]


def chord_corrections(system, frequency_hz, force_coeffs, steps: int,
                      samples: int = NONLINEAR_SAMPLES):
    """`linearisation_error` after 1, 2, ..., `steps` chord steps, stacked (steps, H): one
    iteration gives every step (the model choice needs the first two).

    The orbit engine's harmonic balance (`HarmonicBalance.chord`: its AFT residual on
    `samples` points per period, harmonics 1..H of the force and the mean) on the model's
    vector field driven by the measured force harmonics, with the chord matrix of the
    model linearised at rest (`bsfs_jax.machine.tangent_matrices`). From zero its first
    iterate is the linear steady state; each later one corrects for the joints'
    nonlinearity, the mean displacement included.
    """
    from bsfs_jax import HarmonicForcing, vector_field
    from bsfs_jax.solvers import HarmonicBalance

    h = force_coeffs.shape[-1]
    # Finite for the fit's padded records too (frequency and force 0; masked out after a
    # vmap over every record, where a NaN would still poison the gradient).
    live = frequency_hz > 0
    frequency_hz = jnp.where(live, frequency_hz, 1.0)
    k_mat, c_mat, m = tangent_matrices(system)
    inv_m = 1.0 / m
    jac = jnp.block([[jnp.zeros((3, 3)), jnp.eye(3)],
                     [-inv_m[:, None] * k_mat, -inv_m[:, None] * c_mat]])
    omega = 2.0 * jnp.pi * frequency_hz
    size = jnp.max(jnp.abs(force_coeffs)) / (jnp.abs(k_mat[0, 0]) + 1.0)
    # A displacement scale [m] for the scaled unknowns; the iterates do not depend on it,
    # so no gradient flows through it.
    size = jax.lax.stop_gradient(jnp.where(size > 0, size, 1e-6))
    scale = jnp.concatenate([jnp.full(3, size), jnp.full(3, size * omega)])
    jac_scaled = jac * scale[None, :] / scale[:, None]
    forcing = HarmonicForcing(frequency_hz, jnp.real(force_coeffs), -jnp.imag(force_coeffs))
    method = HarmonicBalance(harmonics=h, time_samples=samples)
    period = 1.0 / frequency_hz
    z = method.chord(vector_field, jnp.zeros(6 * (2 * h + 1)), (system, forcing), period, 1,
                     scale, jac_scaled, steps + 1)
    # Nut displacement harmonics X_k = scale * (a_k - i b_k) of each iterate.
    a = z[:, 6:6 + 6 * h].reshape(-1, h, 6)[..., 2]
    b = z[:, 6 + 6 * h:].reshape(-1, h, 6)[..., 2]
    x = scale[2] * (a - 1j * b)
    w = omega * jnp.arange(1, h + 1)
    return jnp.where(live, -(w**2)[None] * (x[1:] - x[:1]), 0.0)
