"""A record's stated anti-alias filter, and the measured harmonics corrected for it.

A data acquisition system filters both channels before sampling. For a linear model the
filter cancels in acceleration over force; for a periodic orbit it does not: the orbit
makes its k-th harmonic from the force's fundamental, so the model sees the fundamental
turned by the filter's phase at w and shifted k times, while the measured k-th harmonic
carries the filter's phase at k w. A linear-phase (constant-delay) filter, as in most
delta-sigma front ends, gives the same shift and needs nothing. A Butterworth filter does
not: 8th order at 0.4 fs, phase(3 w) - 3 phase(w) is -10 degrees at 841 Hz
(docs/ROBUSTNESS.md), several standard errors of a strong third harmonic.

Header keys of a time record (all optional; without them the harmonics are used as
measured):

- `antialias_filter`: `butterworth`, or `none` / `linear-phase` (nothing to correct);
- `antialias_order` (1-20) and `antialias_cutoff_hz` (the -3 dB frequency), for
  `butterworth`;
- `antialias_design_rate_hz`: the sample rate of a digital Butterworth filter (bilinear,
  as `scipy.signal.butter(..., fs=)`), e.g. the oversampled rate before decimation;
  without it the filter is analog.

`harmonic_analysis` divides each channel's k-th coefficient (and its envelope rates) by
the filter's response H(k f) and its variances by |H(k f)|^2: the force and acceleration
that the structure saw, which is what the model computes.
"""

from __future__ import annotations

import numpy as np

KINDS = ("butterworth", "none", "linear-phase")
MAX_ORDER = 20


def filter_problem(meta: dict) -> str | None:
    """What is wrong with a record's anti-alias keys (naming the key and the fix), or
    None."""
    if not any(k.startswith("antialias_") for k in meta):
        return None
    kind = _kind(meta)
    if kind not in KINDS:
        return (f"header 'antialias_filter = {meta.get('antialias_filter')}'"
                f" is not one of {', '.join(KINDS)}; state the acquisition's "
                "anti-alias filter or leave the antialias_* keys out.")
    if kind != "butterworth":
        return None
    order = meta.get("antialias_order")
    if not _finite(order) or order != int(order) or not 1 <= order <= MAX_ORDER:
        return (f"header 'antialias_order = {order}' must be an integer "
                f"1-{MAX_ORDER} for a Butterworth anti-alias filter.")
    cutoff = meta.get("antialias_cutoff_hz")
    if not _finite(cutoff) or not cutoff > 0:
        return (f"header 'antialias_cutoff_hz = {cutoff}' must be a "
                "positive frequency in Hz (the filter's -3 dB point).")
    rate = meta.get("antialias_design_rate_hz")
    if rate is not None and (not _finite(rate) or not rate > 2 * cutoff):
        return (f"header 'antialias_design_rate_hz = {rate}' must be above "
                f"twice antialias_cutoff_hz ({2 * cutoff:g} Hz); leave it out for "
                "an analog filter.")
    return None


def _kind(meta: dict) -> str:
    return str(meta.get("antialias_filter", "none")).strip().lower()


def cutoff_hz(meta: dict) -> float | None:
    """The stated filter's cutoff [Hz], or None where no filter is stated."""
    c = meta.get("antialias_cutoff_hz")
    return float(c) if _kind(meta) != "none" and _finite(c) else None


def _finite(x) -> bool:
    return isinstance(x, float) and bool(np.isfinite(x))


def response(meta: dict, frequencies_hz) -> np.ndarray | None:
    """The stated filter's complex response at `frequencies_hz`, or None (nothing stated,
    or a filter with nothing to correct). In closed form (no scipy.signal import on the
    command's path): the analog Butterworth H(s) = prod(-p_k) / prod(s - p_k), its poles
    p_k = w_c exp(i pi (2k + n + 1) / (2n)); a digital one (bilinear, as
    `scipy.signal.butter(..., fs=)`) is the analog one at the prewarped frequencies
    s = i 2 fs tan(pi f / fs), w_c = 2 fs tan(pi f_c / fs)."""
    if _kind(meta) != "butterworth":
        return None
    n, cutoff = int(meta["antialias_order"]), float(meta["antialias_cutoff_hz"])
    f = np.asarray(frequencies_hz, float)
    rate = meta.get("antialias_design_rate_hz")
    if rate is None:
        wc, s = 2 * np.pi * cutoff, 2j * np.pi * f
    else:
        rate = float(rate)
        wc, s = 2 * rate * np.tan(np.pi * cutoff / rate), 2j * rate * np.tan(np.pi * f / rate)
    poles = wc * np.exp(1j * np.pi * (2 * np.arange(n) + n + 1) / (2 * n))
    return np.prod(-poles) / np.prod(s[:, None] - poles, axis=1)
