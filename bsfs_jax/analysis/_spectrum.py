"""FFT amplitude spectra (one-sided, physical units) of uniformly sampled signals.

Works on numpy and JAX arrays alike (traceable), so sweeps can reduce a response to its
spectrum inside `jit` and keep only the spectrum.
"""

import jax
import jax.numpy as jnp
import numpy as np

_WINDOWS = ("hann", "rect")


def window_array(name: str, n: int):
    """The window samples (length n) for `name` in ("hann", "rect")."""
    if name == "hann":
        # Periodic Hann: exactly periodic over the record, so a signal with an integer
        # number of cycles in the record keeps its lines on bin centres.
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)
    if name == "rect":
        return np.ones(n)
    raise ValueError(f"unknown window '{name}'; choose one of {_WINDOWS}")


def amplitude_spectrum(x, dt, *, window: str = "hann"):
    """One-sided amplitude spectrum of samples `x` (time along the last axis).

    **Arguments:**
    - `x`: (..., n) samples, e.g. displacement [m] at spacing `dt` [s].
    - `dt`: sample spacing [s] (a scalar).
    - `window`: "hann" (default; amplitude-corrected by its coherent gain) or "rect".

    **Returns:** `(freqs_hz, amplitude)` with `freqs_hz` (n//2 + 1,) in Hz and
    `amplitude` (..., n//2 + 1) in the units of `x`: a sinusoid A sin(2 pi f t) with f on a
    bin centre shows a peak of A. Bin 0 holds the absolute mean (the record's mean is removed
    before windowing, so the offset does not leak into the low bins).
    """
    xp = jnp if not isinstance(x, np.ndarray) else np
    n = x.shape[-1]
    w = window_array(window, n)
    mean = xp.mean(x, axis=-1, keepdims=True)
    spec = xp.fft.rfft((x - mean) * w, axis=-1)
    amp = 2.0 * xp.abs(spec) / float(np.sum(w))
    if xp is np:
        amp = amp.copy()
        amp[..., 0] = np.abs(mean[..., 0])
    else:
        amp = amp.at[..., 0].set(jnp.abs(mean[..., 0]))
    try:
        freqs = np.fft.rfftfreq(n, d=float(dt))
    except (TypeError, jax.errors.ConcretizationTypeError):  # traced spacing
        freqs = jnp.arange(n // 2 + 1) / (n * dt)
    return freqs, amp


def line_fraction(amplitude, *, lines: int = 12, halfwidth: int = 2):
    """Fraction of the (non-DC) spectral power held by the `lines` strongest peaks.

    Each peak takes its +-`halfwidth` neighbouring bins (the Hann main lobe). Close to 1 for
    periodic and quasi-periodic signals (discrete lines), clearly lower for chaos
    (broadband). numpy only: used by the classifier after a sweep.
    """
    p = np.asarray(amplitude, dtype=float)[1:] ** 2
    total = float(np.sum(p))
    if not np.isfinite(total) or total <= 0.0:
        return float("nan")
    taken = np.zeros(p.shape, dtype=bool)
    work = p.copy()
    for _ in range(lines):
        k = int(np.argmax(work))
        if work[k] <= 0.0:
            break
        lo, hi = max(0, k - halfwidth), min(p.size, k + halfwidth + 1)
        taken[lo:hi] = True
        work[lo:hi] = 0.0
    return float(np.sum(p[taken]) / total)
