"""Merging an FRF's adjacent lines: a long record's FRF at the resolution the fit needs.

A single-frame estimate of a 120 s chirp has a line every 1/120 Hz: 288 000 lines over
50-2500 Hz, where the drive's narrowest resonance is about 2 zeta f = 20 Hz wide. The lines
carry the same information as far fewer merged ones, and the fit's cost and memory grow
with their count. `merge_lines` replaces each run of k adjacent lines by their
inverse-variance weighted mean (value and frequency), with the variance of that mean:
unbiased where the accelerance is linear across the run, and no information lost where it
is constant. The curvature error of a run of width w at a resonance of half-power width B
is of order (w / B)^2 / 24 of the peak value; `merge_lines` reports w / B's bound with the
merge (`meta["merged_width_hz"]`) so that a reader can judge it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

# The line count above which `identify` merges an FRF's lines (`--max-lines`): a Welch FRF
# of a 60 s random record at 25.6 kHz (23 000 lines) is kept as it is; a single-frame FRF
# of a 120 s chirp (288 000) is merged in runs of 9.
MAX_LINES = 32768


def merge_factor(n_lines: int, max_lines: int | None) -> int:
    """Lines per merged run that bring `n_lines` to at most `max_lines` (1: none; None or
    0: no limit)."""
    if not max_lines or n_lines <= max_lines:
        return 1
    return -(-n_lines // int(max_lines))


def merge_lines(frf, k: int):
    """`frf` (an `FrfRecord`) with each run of `k` adjacent lines replaced by their
    inverse-variance weighted mean; the runs are consecutive lines of the record as kept
    (the last run may be shorter). Returns `frf` itself for k <= 1."""
    if k <= 1:
        return frf
    n = frf.frequency_hz.size
    starts = np.arange(0, n, k)
    var = np.asarray(frf.variance, float)
    w = 1.0 / np.mean(var, axis=1)  # one weight per line: Re and Im alike
    sw = np.add.reduceat(w, starts)

    def mean(x):
        return np.add.reduceat(w * x, starts) / sw

    freq = mean(np.asarray(frf.frequency_hz, float))
    acc = mean(np.asarray(frf.accelerance).real) + 1j * mean(np.asarray(frf.accelerance).imag)
    # Var(sum w x / sum w) = sum w^2 var / (sum w)^2, per component
    new_var = np.stack([np.add.reduceat(w**2 * var[:, c], starts) / sw**2 for c in (0, 1)],
                       axis=1)
    coh = None if frf.coherence is None else mean(np.asarray(frf.coherence, float))
    width = float(np.max(np.maximum.reduceat(frf.frequency_hz, starts)
                         - np.minimum.reduceat(frf.frequency_hz, starts)))
    meta = dict(frf.meta, merged_lines=float(k), merged_from=float(n),
                merged_width_hz=width)
    return dataclasses.replace(frf, frequency_hz=freq, accelerance=acc, variance=new_var,
                               coherence=coh, meta=meta)
