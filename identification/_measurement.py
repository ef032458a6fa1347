"""Measurement model: records -> harmonic data, and parameters -> predicted harmonics.

**Data side.** A steady-state sine record is reduced to the complex Fourier coefficients of
force and acceleration at the excitation frequency and its harmonics k = 1..H. They are
estimated by linear least squares over the *whole* record, with each harmonic allowed a
slow quadratic envelope (Legendre polynomials in time) and the DC allowed a quadratic
drift. The envelope's mean is the coefficient used; the leftover residual gives the noise
variance and hence the standard error of every coefficient. This is period-synchronous
averaging done optimally: it uses every sample, it tolerates a slowly drifting shaker
and it gives honest weights. (Away from a resonance the drift appears identically in force
and acceleration of a quasi-linear system; near a lightly damped one the response lags the
force's envelope by the group delay, which the model carries through the force envelope's
mean rates of change, `drift_terms`.) The frequency is refined
by minimising the force fit's residual around the header value.

**Model side.** The model is driven by the measured force harmonics (`HarmonicForcing`)
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

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from bsfs_jax.machine import tangent_matrices

from ._antialias import cutoff_hz as antialias_cutoff
from ._antialias import response as antialias_response
from ._records import Record
from ._sine_noise import noise_variance

N_HARMONICS = 3
DRIFT_ORDER = 2
NONLINEAR_SAMPLES = 64
#: The least noise variance a sine record is credited with, relative to its power (120 dB).
NOISE_FLOOR = 1e-12


@dataclasses.dataclass(frozen=True)
class HarmonicData:
    """Harmonic content of one record (numpy, SI).

    - `frequency_hz`: refined excitation frequency; `harmonics`: (H,) k = 1..H;
    - `force`, `acceleration`: (H,) complex coefficients c_k, signal = Re(sum c_k e^{i k w t});
    - `force_var`, `acceleration_var`: (H, 2) variances of (Re c_k, Im c_k);
    - `force_noise`, `acceleration_noise`: the sensors' noise RMS, read between the harmonic
      lines of the fits' residuals (`_sine_noise.py`) [N, m/s^2];
    - `force_dc`, `acceleration_dc`: mean offsets; `n_samples`; `record`;
    - `force_rate`, `force_rate2`: (H,) complex means over the record of the first and
      second time derivatives of each force harmonic's envelope [N/s, N/s^2] (the drifting
      shaker; `drift_terms`). None: a steady force (zeros).
    """

    frequency_hz: float
    harmonics: np.ndarray
    force: np.ndarray
    acceleration: np.ndarray
    force_var: np.ndarray
    acceleration_var: np.ndarray
    force_noise: float
    acceleration_noise: float
    force_dc: float
    acceleration_dc: float
    n_samples: int
    record: Record
    force_rate: np.ndarray | None = None
    force_rate2: np.ndarray | None = None

    @property
    def name(self) -> str:
        return self.record.name

    @property
    def speed_rpm(self) -> float:
        return self.record.speed_rpm


def _design(t, f, n_harm, drift_order):
    tau = 2.0 * (t - t[0]) / (t[-1] - t[0]) - 1.0
    legendre = np.polynomial.legendre.legvander(tau, drift_order)  # (N, Q+1)
    cols = [legendre]
    for k in range(1, n_harm + 1):
        arg = 2 * np.pi * k * f * t
        cols.append(legendre * np.cos(arg)[:, None])
        cols.append(legendre * np.sin(arg)[:, None])
    return np.concatenate(cols, axis=1)


def _fit(x, t, f, n_harm, drift_order):
    a = _design(t, f, n_harm, drift_order)
    # Normal equations: the Legendre x harmonic basis is well conditioned over a record.
    # (einsum, not BLAS: multithreaded BLAS is very slow on a shared, loaded 2-core machine)
    ata_inv = np.linalg.inv(np.einsum("ij,ik->jk", a, a))
    coef = ata_inv @ np.einsum("ij,i->j", a, x)
    resid = x - np.einsum("ij,j->i", a, coef)
    dof = x.size - a.shape[1]
    s2 = float(resid @ resid) / dof
    return coef, s2 * np.diag(ata_inv), s2, resid


def _blocks(x, n_harm, drift_order):
    """(H, 2, Q+1) per harmonic: its cos then its sin block of Legendre coefficients (the
    layout of `_design`'s columns after the DC block)."""
    q1 = drift_order + 1
    return np.asarray(x)[q1:q1 + 2 * q1 * n_harm].reshape(n_harm, 2, q1)


def _unpack(coef, cov_diag, n_harm, drift_order):
    """(DC, (H,) complex mean coefficients, (H, 2) their variances, (H, Q+1) complex
    envelopes in Legendre coefficients: a cos + b sin = Re((a - i b) e^{i w t}))."""
    b = _blocks(coef, n_harm, drift_order)
    env = b[:, 0] - 1j * b[:, 1]
    var = np.ascontiguousarray(_blocks(cov_diag, n_harm, drift_order)[:, :, 0])
    return coef[0], np.ascontiguousarray(env[:, 0]), var, env


def _envelope_rates(env, duration):
    """(H,) complex means over the record of d/dt and d^2/dt^2 of each harmonic's fitted
    envelope (`env`: (H, Q+1) Legendre coefficients). With tau = 2 (t - t0) / T - 1 the
    envelope is sum_q c_q P_q(tau), and over [-1, 1] the mean of P_q' is 1 for odd q (else
    0) and the mean of P_q'' is q (q + 1) / 2 for even q (else 0)."""
    q = np.arange(env.shape[1])
    d1 = (2.0 / duration) * (q % 2 == 1)
    d2 = (2.0 / duration) ** 2 * np.where(q % 2 == 0, q * (q + 1) / 2.0, 0.0)
    return env @ d1, env @ d2


def refine_frequency(record: Record, n_harmonics: int = N_HARMONICS) -> float:
    """Excitation frequency [Hz] minimising the force fit residual near the header value."""
    t, x = record.time, record.force
    half_bin = 0.5 / record.duration
    f0 = record.frequency_hz
    # Fundamental + DC only: cheap, and the fundamental dominates the frequency estimate.
    obj = lambda f: _fit(x, t, f, 1, 0)[2]
    f, fun = _golden_section(obj, f0 - half_bin, f0 + half_bin, 1e-7 * f0)
    return float(f) if fun <= obj(f0) else f0


def _golden_section(fn, lo, hi, xtol):
    """(x, fn(x)) minimising a unimodal `fn` on [lo, hi] to within `xtol` (golden section:
    within half a frequency bin the force fit's residual has a single minimum)."""
    g = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = fn(c), fn(d)
    while b - a > xtol:
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = fn(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = fn(d)
    return (c, fc) if fc <= fd else (d, fd)


def harmonic_analysis(record: Record, n_harmonics: int = N_HARMONICS,
                      drift_order: int = DRIFT_ORDER) -> HarmonicData:
    """Fourier coefficients (with standard errors) of force and acceleration of a record."""
    f = refine_frequency(record, n_harmonics)
    t = record.time
    out = {}
    cutoff = antialias_cutoff(record.meta)
    for name, x in (("force", record.force), ("acceleration", record.acceleration)):
        coef, cov_diag, s2, resid = _fit(x, t, f, n_harmonics, drift_order)
        # The noise between the harmonic lines: the residual also holds the harmonics
        # above n_harmonics, which are signal (`_sine_noise.py`).
        # Floored at 120 dB below the record's power: no sensor is cleaner, and a
        # noise-free synthetic record would otherwise get weights of round-off.
        s2_lines = noise_variance(resid, f, record.sample_rate_hz, cutoff)
        if s2_lines is not None and s2 > 0:
            s2_lines = max(s2_lines, NOISE_FLOOR * float(np.mean((x - np.mean(x)) ** 2)))
            cov_diag, s2 = cov_diag * (s2_lines / s2), s2_lines
        out[name] = (*_unpack(coef, cov_diag, n_harmonics, drift_order), float(np.sqrt(s2)))
    (fdc, fc, fvar, fenv, fn), (adc, ac, avar, _, an) = out["force"], out["acceleration"]
    harmonics = np.arange(1, n_harmonics + 1)
    rates = _envelope_rates(fenv, t[-1] - t[0])
    h = antialias_response(record.meta, f * harmonics)
    if h is not None:  # what the structure saw: the stated filter divided out
        fc, ac, rates = fc / h, ac / h, tuple(r / h for r in rates)
        fvar, avar = (v / np.abs(h)[:, None] ** 2 for v in (fvar, avar))
    return HarmonicData(f, harmonics, fc, ac, fvar, avar, fn, an, float(fdc), float(adc),
                        int(t.size), record, *rates)


# ----------------------------------------------------------------------------- model side


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


def waveform(coeffs, frequency_hz, t):
    """Re(sum_k c_k exp(i k w t)) for complex coefficients (numpy)."""
    k = np.arange(1, len(coeffs) + 1)
    return np.real(np.exp(2j * np.pi * frequency_hz * np.outer(t, k)) @ np.asarray(coeffs))
