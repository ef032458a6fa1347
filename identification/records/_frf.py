"""FRF records and FRF estimation from chirp and random time records.

**Random records: H1 with Welch averaging** (scipy.signal `welch`/`csd`, Hann window, 50 %
overlap): H1 = S_fa / S_ff, coherence g^2 = |S_fa|^2 / (S_ff S_aa). H1 is the right
estimator here because the noise that matters is on the output (accelerometer noise and
unmodelled response), while the force is measured at the drive point with a far better
signal-to-noise ratio; H1 is unbiased by output noise, H2 would be biased by it. Each line's
variance is the Bendat & Piersol random error (`frf_variance`) with the effective number of
averages: overlapping Hann segments are correlated (Welch's correction, n_eff = K /
(1 + 2 sum_j (1 - j/K) rho_j^2), rho_1 = 1/3 at 50 % overlap), and the coherence estimated
from n_eff segments leaves n_eff - 1 degrees of freedom for the noise. scipy is already a
dependency and these are the estimators a modal analyser runs (pyFRF wraps the same ones);
a time-domain fit would need the nonlinear model at every sample and a model of the rig's
noise, while the FRF reduces the record to lines with known variances, as the harmonic
analysis does for sines.

**Chirp records: single-frame H1 over the whole record** (rectangular window). A burst chirp
starts and ends at rest, so the record's DFTs satisfy A(f) = H(f) F(f) exactly: no
leakage and no window bias. Welch averaging suits stationary excitation only; on a 0.5 s
chirp through the ~1.1 kHz resonance (damping 1.1 %) it biased the peak by about 12 % and
moved it by one 10 Hz line, and only 91-95 % of lines fell within 3 sigma (measured). The
single-frame noise variance comes from the record itself: rectangular-window DFT lines
carry independent noise, while H is smooth over a few lines, so the 4th difference of H
across lines estimates the noise power (curvature bias ~ (df / half-power bandwidth)^4),
fitted over +-50 lines as output noise plus the force sensor's noise seen through H
(`_numerator_noise`). Measured on the same chirps: 98-99 % of lines within 3 sigma,
mean squared z-score 1.0-1.1, resonance on the right line; on 40 chirps through a 1.1 kHz
resonance at 35/40 dB the mean squared error over the stated variance is ~1 at the peak
and on its flanks (output noise alone: 1.47 at the peak, 0.78 on the flanks).
`method="welch"` gives the Welch estimate for a chirp anyway (e.g. a periodic chirp).

A sine record is refused: use `harmonic_analysis`. Only lines in the excited band (chirp:
start_hz..stop_hz; random: where S_ff is within 20 dB of its maximum, and inside the
header's band if given) and below 0.4 x the sample rate (the anti-alias filter's band) are
kept; lines with coherence below `min_coherence` are dropped and counted in `meta`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._records import FRF_EXCITATIONS, Record, RecordError, check_numbers, excitation_of

USABLE_FRACTION = 0.4  # of the sample rate: the anti-alias filter's pass band
RANDOM_BAND_DB = 20.0
MIN_SEGMENTS = 4
DIFF_STENCIL = np.array([1.0, -4.0, 6.0, -4.0, 1.0])
NOISE_HALF_WIDTH = 50  # lines each side in the single-frame noise estimate: +-25 left
# the variance estimate scattered enough that mean z^2 was 1.054 (1/x is convex), which the
# chi-square check of thousands of lines flags as model error; +-50: 1.024 (40 chirps)
AT_REST_RATIO = 0.5  # force RMS in the first/last 1 % over the whole record's, at most


@dataclasses.dataclass(frozen=True)
class FrfRecord:
    """A measured FRF: worktable acceleration over exciter force (SI).

    - `frequency_hz` (L,): strictly increasing, positive line frequencies;
    - `accelerance` (L,) complex [(m/s^2)/N], with the e^{+i w t} convention of
      `bsfs_jax.linear_frf`: accelerance = -(2 pi f)^2 H_nn;
    - `variance` (L, 2): variances of (Re, Im) of each line;
    - `coherence` (L,) or None; `n_averages`: averages behind the estimate (1 for a
      single-frame estimate);
    - `speed_rpm`, `ambient_c`: the thermal state of the test;
    - `meta`: every header key; `source`: the file (or record) it came from;
    - `excitation`: "chirp", "random", "hammer" or "frf" (unknown);
    - `force_amplitude_n`: the force level (peak for chirp/hammer, RMS for random; see
      `meta["force_level"]`), to judge whether the linear model holds; None if unknown.
    """

    frequency_hz: np.ndarray
    accelerance: np.ndarray
    variance: np.ndarray
    coherence: np.ndarray | None
    n_averages: int
    speed_rpm: float
    ambient_c: float
    meta: dict
    source: str
    excitation: str = "frf"
    force_amplitude_n: float | None = None

    @property
    def name(self) -> str:
        return Path(self.source).stem

    @property
    def std(self) -> np.ndarray:
        """(L, 2) standard errors of (Re, Im)."""
        return np.sqrt(self.variance)

    @property
    def receptance(self) -> np.ndarray:
        """x_n / P [m/N] = accelerance / -(2 pi f)^2 (compare with `bsfs_jax.linear_frf`)."""
        return self.accelerance / -(2.0 * np.pi * self.frequency_hz) ** 2

    def summary(self) -> str:
        f = self.frequency_hz
        rms = " RMS" if self.meta.get("force_level") == "rms" else ""
        force = "" if self.force_amplitude_n is None else f", {self.force_amplitude_n:g} N{rms}"
        dropped = self.meta.get("dropped_lines")
        tail = f", {int(dropped)} lines dropped ({self.meta.get('dropped_why')})" if dropped else ""
        return (f"{self.name}: FRF ({self.excitation}{force}), {f.size} lines "
                f"{f[0]:g}-{f[-1]:g} Hz, {self.n_averages} average(s), "
                f"{self.speed_rpm:g} r/min{tail}")


def frf_variance(accelerance, coherence, n_averages) -> np.ndarray:
    """(L, 2) variances of (Re, Im) of an H1 estimate from its coherence and averages.

    The random error of H1 with output noise (Bendat & Piersol): the complex error is
    circular, var|H| / |H|^2 = var(phase) = (1 - g^2) / (2 n g^2); Re and Im (the radial and
    tangential parts, in any rotation) each carry that same variance, |H|^2 (1 - g^2) /
    (2 n g^2). `n` counts independent averages.
    """
    h2 = np.abs(np.asarray(accelerance)) ** 2
    g2 = np.clip(np.asarray(coherence, float), 1e-12, 1.0)
    v = h2 * (1.0 - g2) / (2.0 * float(n_averages) * g2)
    return np.stack([v, v], axis=-1)





def finish_frf(path, f, h, std, coherence, meta: dict, where_of, *,
               line_hint="above the column header") -> FrfRecord:
    """All checks of an FRF that do not depend on the file format. `std`: (L, 2) standard
    errors of (Re, Im) or None; `where_of(i)` names line i."""
    kind = excitation_of(path, meta, FRF_EXCITATIONS, default="frf")
    check_numbers(path, meta, ("speed_rpm", "ambient_c"), line_hint=line_hint)
    n_avg = meta.get("n_averages")
    if n_avg is not None and (not isinstance(n_avg, float) or n_avg < 1 or n_avg != int(n_avg)):
        raise RecordError(f"{path}: header 'n_averages = {n_avg}' must be a whole number >= 1.")
    level = None
    for key, how in (("force_amplitude_n", "peak"), ("force_rms_n", "rms")):
        if key in meta:
            check_numbers(path, meta, (key,), positive=(key,), line_hint=line_hint)
            level = float(meta[key])
            meta.setdefault("force_level", how)
    if f.size < 2:
        raise RecordError(f"{path}: {f.size} frequency line(s); an FRF needs at least two.")
    for name, x in (("frequency_hz", f), ("re/im", h)):
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise RecordError(f"{where_of(bad[0])}: {name} is not finite ({bad.size} such "
                              "line(s)). Re-export the FRF without them; the loader never "
                              "drops lines.")
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise RecordError(f"{where_of(bad[0])}: frequency_hz = {f[bad[0]]:g} is not positive. "
                          "Remove the DC line (and any below it).")
    df = np.diff(f)
    bad = np.flatnonzero(df <= 0)
    if bad.size:
        i = bad[0] + 1
        what = "repeats" if df[bad[0]] == 0 else "is below"
        raise RecordError(f"{where_of(i)}: frequency_hz = {f[i]:g} {what} the previous line's "
                          f"{f[i - 1]:g}. Frequencies must increase strictly: sort the lines "
                          "and keep one per frequency.")
    if coherence is not None:
        bad = np.flatnonzero(~(np.isfinite(coherence) & (coherence > 0) & (coherence <= 1)))
        if bad.size:
            raise RecordError(f"{where_of(bad[0])}: coherence = {coherence[bad[0]]:g} is not in "
                              "(0, 1]. Fix the export (or drop the coherence column).")
    if std is not None:
        bad = np.flatnonzero(~(np.isfinite(std) & (std > 0)).all(axis=1))
        if bad.size:
            raise RecordError(f"{where_of(bad[0])}: standard error {std[bad[0]]} is not a "
                              "positive number. Every line needs std_re, std_im > 0.")
        variance = np.asarray(std, float) ** 2
    elif coherence is not None and n_avg is not None:
        variance = frf_variance(h, coherence, n_avg)
    else:
        raise RecordError(
            f"{path}: the FRF's uncertainty is missing. Add the standard errors (std_re, std_im), "
            "or the coherence and the number of averages (n_averages) it was estimated from.")
    return FrfRecord(np.asarray(f, float), np.asarray(h, complex), variance,
                     None if coherence is None else np.asarray(coherence, float),
                     int(n_avg) if n_avg is not None else 1, float(meta["speed_rpm"]),
                     float(meta["ambient_c"]), dict(meta), str(path), kind, level)


# ----------------------------------------------------------------------------- estimation


def estimate_frf(record: Record, *, nperseg: int | None = None, band=None,
                 method: str = "auto", min_coherence: float = 0.5) -> FrfRecord:
    """The accelerance of a chirp or random `Record` (see the module docstring).

    - `nperseg`: Welch segment length (default: the largest power of two giving >= 8
      segments, at least 256 samples);
    - `band`: (lo, hi) [Hz] to keep instead of the excited band (still below 0.4 fs);
    - `method`: "auto" (single-frame for chirp, Welch for random), "welch", "single-frame";
    - `min_coherence`: lines below it are dropped (the count is in `meta["dropped_lines"]`).
    Raises `RecordError` for a sine record or when no line is left.
    """
    src = record.source
    if record.excitation == "sine":
        raise RecordError(f"{src}: a sine record has no broadband FRF; use harmonic_analysis "
                          "for sines (the stepped-sine fit reads them directly).")
    if method not in ("auto", "welch", "single-frame"):
        raise ValueError(f"method must be 'auto', 'welch' or 'single-frame', got {method!r}")
    if method == "auto":
        method = "single-frame" if record.excitation == "chirp" else "welch"
    fs = record.sample_rate_hz
    force = record.force - np.mean(record.force)
    acc = record.acceleration - np.mean(record.acceleration)
    if method == "welch":
        f, h, var, coh, n_avg, info = _welch(src, force, acc, fs, nperseg)
    else:
        _check_at_rest(src, force)
        f, h, var, coh, n_avg, info = _single_frame(force, acc, fs)
    keep = _band(record, f, info.pop("s_ff"), band) & np.isfinite(var).all(axis=1)
    in_band = int(np.count_nonzero(keep))
    keep &= coh >= min_coherence
    if not keep.any():
        raise RecordError(f"{src}: no line of the excited band has coherence >= "
                          f"{min_coherence:g} ({in_band} line(s) in the band). Raise the force, "
                          "record longer or check the channels.")
    # The estimate's own keys first (file headers with little room, UFF, keep those).
    meta = dict(force_level="rms" if record.excitation == "random" else "peak",
                estimator=method, dropped_lines=float(in_band - np.count_nonzero(keep)),
                dropped_why=f"coherence < {min_coherence:g}", record=record.name, **info)
    meta.update({k: v for k, v in record.meta.items() if k not in meta and k not in
                 ("kind", "frequency_hz", "force_range_n", "acceleration_range_m_s2")})
    source = str(Path(src).with_name(f"{Path(src).stem}_frf"))
    return FrfRecord(f[keep], h[keep], var[keep], coh[keep], n_avg, record.speed_rpm,
                     record.ambient_c, meta, source, record.excitation,
                     record.force_amplitude_n)


def _welch(src, force, acc, fs, nperseg):
    from scipy.signal import csd, get_window, welch

    n = force.size
    if nperseg is None:
        nperseg = max(256, 1 << int(np.floor(np.log2(2 * n / 9))))
    nperseg = int(min(nperseg, n))
    step = nperseg // 2
    k = (n - nperseg) // step + 1
    if k < MIN_SEGMENTS:
        raise RecordError(f"{src}: nperseg = {nperseg} leaves {k} Welch segment(s) of "
                          f"{n} samples; use nperseg <= {2 * n // (MIN_SEGMENTS + 1)} or record "
                          "longer.")
    kw = dict(fs=fs, window="hann", nperseg=nperseg, noverlap=nperseg - step,
              detrend="constant")
    f, s_ff = welch(force, **kw)
    _, s_aa = welch(acc, **kw)
    _, s_fa = csd(force, acc, **kw)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = s_fa / s_ff
        coh = np.abs(s_fa) ** 2 / (s_ff * s_aa)
    w = get_window("hann", nperseg)
    rho2 = [(np.dot(w[j * step:], w[:nperseg - j * step]) / np.dot(w, w)) ** 2
            for j in range(1, min(k, nperseg // step + 1))]
    n_eff = k / (1.0 + 2.0 * sum((1.0 - j / k) * r for j, r in enumerate(rho2, start=1)))
    var = frf_variance(h, coh, n_eff - 1.0)
    info = dict(s_ff=s_ff, nperseg=float(nperseg), segments=float(k),
                variance_dof=float(n_eff - 1.0), window="hann", overlap=0.5)
    return f, h, var, coh, k, info


def _check_at_rest(src, force):
    m = max(8, force.size // 100)
    rms = np.sqrt(np.mean(force ** 2))
    ends = max(np.sqrt(np.mean(force[:m] ** 2)), np.sqrt(np.mean(force[-m:] ** 2)))
    if ends > AT_REST_RATIO * rms:
        raise RecordError(
            f"{src}: the force does not start and end at rest (RMS in the first/last 1 % is "
            f"{100 * ends / rms:.0f} % of the record's); the single-frame chirp estimate needs a "
            "burst chirp with tapered ends. Use estimate_frf(..., method='welch') for a "
            "continuous sweep.")


def _single_frame(force, acc, fs):
    n = force.size
    big_f = np.fft.rfft(force)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.fft.rfft(acc) / big_f
        inv_f2 = 1.0 / np.abs(big_f) ** 2
    # Noise power of each line's numerator A - H F from the 4th difference of H: output
    # noise (a) plus the force sensor's noise through H (b |H|^2), fitted over +-50 lines.
    ok = np.isfinite(h) & np.isfinite(inv_f2) & (f > 0)
    q = _numerator_noise(np.where(ok, h, 0.0), np.where(ok, inv_f2, 0.0), ok)
    with np.errstate(divide="ignore", invalid="ignore"):
        var_c = q * inv_f2 / 2.0  # per component (Re, Im)
        coh = np.abs(h) ** 2 / (np.abs(h) ** 2 + 2.0 * var_c)
    var = np.stack([var_c, var_c], axis=-1)
    s_ff = np.abs(big_f) ** 2
    return f, h, var, np.nan_to_num(coh), 1, dict(
        s_ff=s_ff, window="rectangular",
        noise_estimate="4th difference, output + force noise, +-50 lines")


def _numerator_noise(h, inv_f2, ok):
    """Noise power q_k of each DFT line's A_k - H_k F_k, the error of H_k times F_k.

    With noise on both channels q_k = a + b |H_k|^2: the accelerometer's noise (a) and the
    force sensor's seen through the FRF (b). The 4th difference e_k = sum_j c_j H_{k+j} has
    E|e_k|^2 = a D0_k + b D1_k, D0_k = sum c_j^2 / |F_{k+j}|^2 and D1_k the same with
    |H_{k+j}|^2 in the numerator, so y = |e|^2 / D0 is regressed on r = D1 / D0 (a line,
    a and b >= 0): first unweighted over +-NOISE_HALF_WIDTH lines, then twice weighted by
    1 / (a + b r)^2 (y is a scaled chi-square with 2 degrees of freedom), b over four
    times as many lines (the force sensor's noise is broadband; the peak's few lines alone
    left the variance 0.3-0.4 uncertain there), a over +-NOISE_HALF_WIDTH. q is kept above
    a tenth of the flat local mean of y, so no line gets a vanishing variance.

    Output noise alone (a flat q, as before) averaged |H|^2's rise into the flanks: on
    chirps through a 1 % resonance with 40 dB on both channels the mean squared error over
    the stated variance was 1.8-2.8 at the peak and 0.4-0.6 on the flanks; now 0.97-1.08
    in every band (tests/test_frf.py; docs/COVERAGE.md for the drive's own chirp).
    """
    c2 = DIFF_STENCIL ** 2
    e = np.convolve(h, DIFF_STENCIL, mode="same")
    d0 = np.convolve(inv_f2, c2, mode="same")
    d1 = np.convolve(inv_f2 * np.abs(h) ** 2, c2, mode="same")
    valid = np.convolve(ok.astype(float), np.ones(5), mode="same") > 4.5
    hw = NOISE_HALF_WIDTH
    with np.errstate(divide="ignore", invalid="ignore"):
        y = np.where(valid, np.abs(e) ** 2 / d0, 0.0)
        r = np.where(valid, d1 / d0, 0.0)
        w = valid.astype(float)
        a, b = _line_fit(y, r, w, hw)
        for _ in range(2):
            pred = a + b * r
            w = np.where(valid & (pred > 0), 1.0 / np.where(pred > 0, pred, 1.0) ** 2, 0.0)
            _, b = _line_fit(y, r, w, 4 * hw)
            a = np.clip(np.nan_to_num(_box(w * (y - b * r), hw) / _box(w, hw)), 0.0, None)
        flat = _box(y, hw) / _box(valid.astype(float), hw)  # the old flat estimate
        return np.maximum(a + b * np.abs(h) ** 2, 0.1 * flat)


def _box(x, half_width):
    return np.convolve(x, np.ones(2 * half_width + 1), mode="same")


def _line_fit(y, r, w, half_width):
    """Weighted least-squares y ~ a + b r in a box around every line, a and b >= 0."""
    sw, swr, swrr, swy, swry = (_box(x, half_width) for x in (w, w * r, w * r * r, w * y,
                                                              w * r * y))
    det = sw * swrr - swr ** 2
    b = np.where(det > 1e-12 * swrr * sw, (sw * swry - swr * swy) / det, 0.0)
    b = np.clip(np.nan_to_num(b), 0.0, None)
    a = (swy - b * swr) / sw
    through_origin = a < 0.0  # no output noise left: b alone, fitted through zero
    b = np.where(through_origin, swry / np.where(swrr > 0, swrr, 1.0), b)
    return np.where(through_origin, 0.0, a), b


def _band(record, f, s_ff, band):
    fs = record.sample_rate_hz
    keep = (f > 0) & (f < USABLE_FRACTION * fs)
    if band is not None:
        lo, hi = (float(b) for b in band)
        if not 0 <= lo < hi:
            raise ValueError(f"band must be (lo, hi) with 0 <= lo < hi, got {band}")
        return keep & (f >= lo) & (f <= hi)
    if record.start_hz is not None and record.stop_hz is not None:
        keep &= (f >= record.start_hz) & (f <= record.stop_hz)
    if record.excitation == "random":
        peak = np.max(np.where(keep, s_ff, 0.0))
        keep &= s_ff >= peak * 10.0 ** (-RANDOM_BAND_DB / 10.0)
    return keep
