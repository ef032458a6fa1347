"""Records -> harmonic data: the data side of the measurement model.

A steady-state sine record is reduced to the complex Fourier coefficients of
force and acceleration at the excitation frequency and its harmonics k = 1..H. They are
estimated by linear least squares over the *whole* record, with each harmonic allowed a
slow quadratic envelope (Legendre polynomials in time) and the DC allowed a quadratic
drift. The envelope's mean is the coefficient used; the leftover residual gives the noise
variance and hence the standard error of every coefficient. This is period-synchronous
averaging done optimally: it uses every sample, it tolerates a slowly drifting shaker
and it gives honest weights. (Away from a resonance the drift appears identically in force
and acceleration of a quasi-linear system; near a lightly damped one the response lags the
force's envelope by the group delay, which the model carries through the force envelope's
mean rates of change, `_linear.drift_terms`.) The frequency is refined
by minimising the force fit's residual around the header value.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..records import Record, antialias_cutoff_hz, antialias_response, estimate_frf
from ._sine_noise import noise_variance

N_HARMONICS = 3
DRIFT_ORDER = 2
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
    cutoff = antialias_cutoff_hz(record.meta)
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


def is_frf(d) -> bool:
    """Whether a measured datum is an FRF (`FrfRecord`) rather than a sine's
    `HarmonicData`."""
    return hasattr(d, "accelerance")


def measurement_data(record):
    """Sine `Record` -> `HarmonicData`; chirp/random `Record` -> its estimated FRF; an FRF
    record or a sine's `HarmonicData` is used as it is."""
    if is_frf(record) or isinstance(record, HarmonicData):
        return record
    if getattr(record, "excitation", "sine") != "sine":
        return estimate_frf(record)
    return harmonic_analysis(record)
