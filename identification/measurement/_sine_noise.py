"""The sensor noise of a stepped-sine record, from its spectrum between the harmonic lines.

A sine record's harmonics are fitted up to `N_HARMONICS`; everything else in the
residual used to count as noise. A record whose joints open or impact is rich in
harmonics above those, and that is signal: a 3000 N record's acceleration residual
was 10-84 times the sensor's noise (robustness drives 16 and 17, docs/ROBUSTNESS.md),
so its harmonics were weighted 100-7000 times too lightly. Here the noise
is read where there is nothing but noise: a Blackman-Harris spectrum of the residual,
in the passband, away from every harmonic line (and from those that fold back from above
half the sample rate). The noise is taken as white within the passband.
"""

from __future__ import annotations

import numpy as np

#: Bins left out either side of a harmonic line in the band (the window's main lobe is
#: +-4 bins; the drift's slow modulation stays inside it) and of a folded one.
GUARD_BINS = 8
GUARD_FOLDED_BINS = 5
#: Fewer bins than this between the lines: the residual's plain variance is used.
MIN_BINS = 256
#: The passband: this fraction of a stated anti-alias cutoff, else of the sample rate.
PASSBAND_OF_CUTOFF = 0.8
PASSBAND_OF_RATE = 0.35
#: The estimate is the mean of the lowest 90 % of the bins' powers (robust to a weak line
#: the guards miss); for exponential powers that is (1 - (1 + ln 10) / 10) / 0.9 = 0.744
#: of their mean.
TRIM = 0.9
_TRIMMED_MEAN = (1.0 - (1.0 + np.log(10.0)) / 10.0) / TRIM

_BH = (0.35875, 0.48829, 0.14128, 0.01168)  # 4-term Blackman-Harris (sidelobes -92 dB)


def noise_variance(resid: np.ndarray, f: float, fs: float,
                   cutoff_hz: float | None = None) -> float | None:
    """Variance of white noise in `resid` (a sine fit's residual at `fs` Hz; excitation
    `f` Hz) from the bins between the harmonic lines below the passband's top, or None
    where fewer than `MIN_BINS` bins remain."""
    n = resid.size
    ph = 2 * np.pi * np.arange(n) / n
    w = _BH[0] - _BH[1] * np.cos(ph) + _BH[2] * np.cos(2 * ph) - _BH[3] * np.cos(3 * ph)
    power = np.abs(np.fft.rfft(resid * w)) ** 2
    df = fs / n
    top = PASSBAND_OF_CUTOFF * cutoff_hz if cutoff_hz else PASSBAND_OF_RATE * fs
    keep = np.zeros(power.size, bool)
    keep[GUARD_BINS + 1:min(power.size, int(top / df))] = True
    k = np.arange(1, int((fs + top) / f) + 1)
    folded = np.abs((k * f + fs / 2) % fs - fs / 2)  # where each harmonic lands
    centre = np.rint(folded / df).astype(int)
    for direct, guard in ((True, GUARD_BINS), (False, GUARD_FOLDED_BINS)):
        c = centre[(k * f <= fs / 2) == direct]
        for g in range(-guard, guard + 1):
            i = c + g
            keep[i[(i >= 0) & (i < power.size)]] = False
    p = np.sort(power[keep])
    if p.size < MIN_BINS:
        return None
    mean = float(np.mean(p[:int(TRIM * p.size)])) / _TRIMMED_MEAN
    return mean / float(w @ w)
