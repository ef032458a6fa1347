"""An adaptive Dormand-Prince 5(4) integrator compiled with numba, for benchmark B1.

Built to match diffrax's `Dopri5` + `PIDController` as closely as possible:
- Dormand-Prince 5(4) tableau, FSAL, 5th-order solution propagated;
- error norm: RMS over components of err_i / (atol + rtol max(|y0_i|, |y1_i|));
- I-controller: accept if norm < 1; factor = clip(0.9 norm^(-1/5), 0.2, 10) after an
  accepted step and clip(..., 0.2, 0.9) after a rejected one (diffrax's defaults with
  error order 5);
- initial step: the Hairer-Wanner heuristic diffrax uses.
Sample times t = kT are hit exactly by shortening the step that would cross them
(diffrax interpolates instead; the handful of extra short steps is negligible).

The vector field is the BSFS of `scipy_model.py`, compiled.
"""

import math

import numba
import numpy as np
from scipy_model import BEAR, KS, NUT

# Dormand-Prince coefficients.
A21 = 1 / 5
A31, A32 = 3 / 40, 9 / 40
A41, A42, A43 = 44 / 45, -56 / 15, 32 / 9
A51, A52, A53, A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
A61, A62, A63, A64, A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
B1, B3, B4, B5, B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
E1, E3, E4, E5, E6, E7 = (71 / 57600, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525,
                          -1 / 40)
C2, C3, C4, C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9


@numba.njit(cache=True, fastmath=False)
def _pair(u, c, base):
    coeff, axial, radial_sq, reach, cos_h = c[base], c[base + 1], c[base + 2], c[base + 3], \
        c[base + 4]
    f = 0.0
    for side in (1.0, -1.0):
        a_s = axial + side * u / cos_h
        a_len = math.sqrt(a_s * a_s + radial_sq)
        d = a_len - reach
        if d > 0.0:
            f += side * coeff * d * math.sqrt(d) * a_s / a_len
    return f


@numba.njit(cache=True)
def bsfs_rhs(t, y, c, frequency, force, out):
    xb, xs, xn, vb, vs, vn = y[0], y[1], y[2], y[3], y[4], y[5]
    fb = _pair(xb, c, BEAR)
    fs = c[KS] * (xs - xb)
    fn = _pair(xn - xs, c, NUT)
    db, ds, dn = c[3] * vb, c[4] * (vs - vb), c[5] * (vn - vs)
    p = force * math.sin(2.0 * math.pi * frequency * t)
    out[0], out[1], out[2] = vb, vs, vn
    out[3] = -(fb + db - fs - ds) / c[0]
    out[4] = -(fs + ds - fn - dn) / c[1]
    out[5] = (p - fn - dn) / c[2]


@numba.njit(cache=True)
def _rms(v):
    s = 0.0
    for x in v:
        s += x * x
    return math.sqrt(s / v.size)


@numba.njit(cache=True)
def _initial_step(t0, y0, f0, c, frequency, force, rtol, atol):
    n = y0.size
    scale = atol + np.abs(y0) * rtol
    d0 = _rms(y0 / scale)
    d1 = _rms(f0 / scale)
    if d0 < 1e-5 or d1 < 1e-5:
        h0 = 1e-6
    else:
        h0 = 0.01 * d0 / d1
    y1 = y0 + h0 * f0
    f1 = np.empty(n)
    bsfs_rhs(t0 + h0, y1, c, frequency, force, f1)
    d2 = _rms((f1 - f0) / scale) / h0
    max_d = max(d1, d2)
    if max_d <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max_d) ** (1.0 / 5.0)
    return min(100 * h0, h1)


@numba.njit(cache=True)
def dopri5_strobe(c, frequency, force, y0, transient_periods, samples, rtol, atol,
                  max_steps):
    """Integrate from t = 0 to (transient + samples) T; states at t = kT, k >= transient.

    Returns (strobe (samples + 1, 6), accepted + rejected steps, status: 0 ok, 1 max steps,
    2 non-finite)."""
    return dopri5_sampled(c, frequency, force, y0, transient_periods, samples, 1, rtol, atol,
                          max_steps)


@numba.njit(cache=True)
def dopri5_sampled(c, frequency, force, y0, transient_periods, periods, samples_per_period,
                   rtol, atol, max_steps):
    """As `dopri5_strobe`, with `samples_per_period` samples per period: states at
    t = k T / samples_per_period for k = transient x spp .. (transient + periods) x spp
    (every spp-th is stroboscopic; with spp = 1 this is `dopri5_strobe`, step for step).

    Returns (samples (periods x spp + 1, 6), steps, status)."""
    n = y0.size
    spp = samples_per_period
    period = 1.0 / frequency
    samples = periods * spp
    transient_periods = transient_periods * spp
    strobe = np.full((samples + 1, n), np.nan)
    y = y0.copy()
    t = 0.0
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    k5 = np.empty(n)
    k6 = np.empty(n)
    k7 = np.empty(n)
    yt = np.empty(n)
    bsfs_rhs(t, y, c, frequency, force, k1)
    h = _initial_step(t, y, k1, c, frequency, force, rtol, atol)
    steps = 0
    next_k = transient_periods
    t_next = next_k * period / spp
    if next_k == 0:
        strobe[0] = y
        next_k += 1
        t_next = next_k * period / spp
    while next_k <= transient_periods + samples:
        if steps >= max_steps:
            return strobe, steps, 1
        hit = t + h >= t_next
        hh = t_next - t if hit else h
        for i in range(n):
            yt[i] = y[i] + hh * A21 * k1[i]
        bsfs_rhs(t + C2 * hh, yt, c, frequency, force, k2)
        for i in range(n):
            yt[i] = y[i] + hh * (A31 * k1[i] + A32 * k2[i])
        bsfs_rhs(t + C3 * hh, yt, c, frequency, force, k3)
        for i in range(n):
            yt[i] = y[i] + hh * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i])
        bsfs_rhs(t + C4 * hh, yt, c, frequency, force, k4)
        for i in range(n):
            yt[i] = y[i] + hh * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i])
        bsfs_rhs(t + C5 * hh, yt, c, frequency, force, k5)
        for i in range(n):
            yt[i] = y[i] + hh * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i]
                                 + A65 * k5[i])
        bsfs_rhs(t + hh, yt, c, frequency, force, k6)
        for i in range(n):
            yt[i] = y[i] + hh * (B1 * k1[i] + B3 * k3[i] + B4 * k4[i] + B5 * k5[i]
                                 + B6 * k6[i])
        bsfs_rhs(t + hh, yt, c, frequency, force, k7)
        err = 0.0
        for i in range(n):
            e = hh * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i]
                      + E7 * k7[i])
            sc = atol + rtol * max(abs(y[i]), abs(yt[i]))
            err += (e / sc) ** 2
        err = math.sqrt(err / n)
        steps += 1
        if not math.isfinite(err):
            if hh < 1e-300:
                return strobe, steps, 2
            h = 0.2 * hh
            continue
        inv = 1.0 / err if err > 0 else 1e300
        if err < 1.0:
            t = t_next if hit else t + hh
            for i in range(n):
                y[i] = yt[i]
                k1[i] = k7[i]
            factor = min(10.0, max(1.0, 0.9 * inv ** 0.2))
            if hit:
                strobe[next_k - transient_periods] = y
                next_k += 1
                t_next = next_k * period / spp
                # keep the controller's proposal for the step that was cut short
                h = max(h, hh * factor) if hh < h else hh * factor
            else:
                h = hh * factor
        else:
            h = hh * min(0.9, max(0.2, 0.9 * inv ** 0.2))
    return strobe, steps, 0


def sweep_numba(c, frequencies, force, transient_periods, samples, rtol, atol,
                max_steps=50_000_000):
    """Cold sweep: one run from rest per frequency. Returns (strobe (N, S+1, 6), steps, status)."""
    out = np.empty((len(frequencies), samples + 1, 6))
    steps = np.zeros(len(frequencies), dtype=np.int64)
    status = np.zeros(len(frequencies), dtype=np.int64)
    for i, f in enumerate(frequencies):
        out[i], steps[i], status[i] = dopri5_strobe(c, float(f), float(force), np.zeros(6),
                                                    transient_periods, samples, rtol, atol,
                                                    max_steps)
    return out, steps, status


@numba.njit(parallel=True, cache=True)
def _sweep_parallel(c, frequencies, force, transient_periods, samples, rtol, atol,
                    max_steps):
    n = frequencies.size
    out = np.empty((n, samples + 1, 6))
    steps = np.zeros(n, dtype=np.int64)
    status = np.zeros(n, dtype=np.int64)
    for i in numba.prange(n):
        s, k, st = dopri5_strobe(c, frequencies[i], force, np.zeros(6), transient_periods,
                                 samples, rtol, atol, max_steps)
        out[i] = s
        steps[i] = k
        status[i] = st
    return out, steps, status


def sweep_numba_parallel(c, frequencies, force, transient_periods, samples, rtol, atol,
                         max_steps=50_000_000):
    """As `sweep_numba`, with the points spread over all cores (numba prange)."""
    return _sweep_parallel(c, np.asarray(frequencies, dtype=float), float(force),
                           int(transient_periods), int(samples), rtol, atol, max_steps)


@numba.njit(parallel=True, cache=True)
def _brute_parallel(c, frequencies, force, transients, periods, spp, rtol, atol, max_steps):
    n = frequencies.size
    out = np.empty((n, periods * spp + 1, 6))
    steps = np.zeros(n, dtype=np.int64)
    status = np.zeros(n, dtype=np.int64)
    for i in numba.prange(n):
        s, k, st = dopri5_sampled(c, frequencies[i], force, np.zeros(6), transients[i],
                                  periods, spp, rtol, atol, max_steps)
        out[i] = s
        steps[i] = k
        status[i] = st
    return out, steps, status


def brute_force_numba(c, frequencies, force, transients, periods, samples_per_period, rtol,
                      atol, max_steps=500_000_000, parallel=False):
    """Cold runs from rest with a transient per point (`transients` (N,) periods), then
    `periods` recorded periods at `samples_per_period` samples each; one core, or prange
    over all cores with `parallel`. Returns (samples (N, periods x spp + 1, 6), steps,
    status)."""
    f = np.asarray(frequencies, dtype=float)
    tr = np.asarray(transients, dtype=np.int64)
    if parallel:
        return _brute_parallel(c, f, float(force), tr, int(periods), int(samples_per_period),
                               rtol, atol, max_steps)
    out = np.empty((f.size, periods * samples_per_period + 1, 6))
    steps = np.zeros(f.size, dtype=np.int64)
    status = np.zeros(f.size, dtype=np.int64)
    for i in range(f.size):
        out[i], steps[i], status[i] = dopri5_sampled(c, float(f[i]), float(force), np.zeros(6),
                                                     int(tr[i]), int(periods),
                                                     int(samples_per_period), rtol, atol,
                                                     max_steps)
    return out, steps, status
