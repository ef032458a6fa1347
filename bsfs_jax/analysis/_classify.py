"""Motion classification from samples alone: period-n, quasi-periodic or chaotic.

These labels are *candidates*: they read the samples as they are and cannot tell a
periodic orbit still shedding a lightly damped mode from a torus. `_verify.py` turns
them into verified labels (an orbit with its multipliers, or an exponent with its
confidence interval) or "unresolved"; sweeps report the verified labels.

Three pieces of evidence are combined (numpy, after the sweep):

1. *Stroboscopic clustering.* The Poincare samples s_k (scaled per coordinate by the
   response amplitude) repeat with period n if max_k |s_{k+n} - s_k| < `tol` for the
   smallest such n <= `max_period` (at least two repetitions must be seen).
2. *The largest Lyapunov exponent* lambda (tangent dynamics, Benettin). Non-periodic
   motion with lambda T > `lyapunov_tol` (growth per forcing period) is chaotic; with
   lambda T <= `lyapunov_tol` it is quasi-periodic (a torus has lambda = 0).
3. *The spectrum.* The fraction of power in the strongest lines: discrete spectra
   (periodic, quasi-periodic) put nearly all power in a few lines, chaos is broadband.
   When no exponent is available the spectrum decides between quasi-periodic and chaotic;
   when both are available the result records whether they agree.
"""

import dataclasses

import numpy as np

from ..solvers import result_ok
from ._spectrum import amplitude_spectrum, line_fraction

PERIODIC, QUASI_PERIODIC, CHAOTIC, FAILED = "periodic", "quasi-periodic", "chaotic", "failed"
SETTLING = "settling"


@dataclasses.dataclass(frozen=True)
class ClassifierSettings:
    """Thresholds of `classify_motion` (dimensionless).

    - `max_period`: largest n looked for in period-n (needs >= 2n + 1 strobe samples).
    - `tol`: repetition tolerance, relative to each coordinate's amplitude.
    - `lyapunov_tol`: threshold on lambda T, the exponent *per forcing period* (the
      growth of the stroboscopic map per iterate), not on lambda in 1/s: a fixed rate
      would call a slowly decaying mode "zero" at high forcing frequencies. For an
      autonomous flow (no forcing) pass lambda times the sampling interval used as "T".
    - `line_fraction_min`: spectral power fraction in the `lines` strongest lines above
      which a spectrum counts as discrete (quasi-periodic) rather than broadband.
    """

    max_period: int = 16
    tol: float = 1e-3
    lyapunov_tol: float = 0.02
    line_fraction_min: float = 0.99
    lines: int = 16


@dataclasses.dataclass(frozen=True)
class Motion:
    """Classification of one response.

    `kind` is "periodic", "quasi-periodic", "chaotic", "settling" or "failed"; `period` is n for
    period-n motion (else 0); `label` is e.g. "period-3"; `lyapunov_per_period` is lambda T
    (NaN if not given); `line_fraction` the spectral evidence; `consistent` says whether
    the spectrum agrees with the decision (None when it could not be checked);
    `converged` is False for a response still settling onto a stable periodic orbit
    (lambda T < -`lyapunov_tol` but the samples do not repeat within `tol`): label
    "period-1 (settling)" (kind "periodic") when they repeat within 10 x `tol`, else
    kind "settling", label "periodic (settling)", period 0 (unresolved).
    """

    kind: str
    period: int
    label: str
    lyapunov_per_period: float
    line_fraction: float
    consistent: bool | None
    converged: bool = True

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def strobe_period(strobe, *, scale=None, max_period: int = 16, tol: float = 1e-3) -> int:
    """Smallest n <= max_period with s_{k+n} = s_k (within tol x scale) for all k; 0 if none.

    `strobe` is (k,) or (k, d); `scale` (d,) per-coordinate scale (default: the larger of
    the samples' peak-to-peak and RMS, so that a noisy fixed point counts as period-1).
    """
    s = np.asarray(strobe, dtype=float)
    if s.ndim == 1:
        s = s[:, None]
    if not np.all(np.isfinite(s)):
        return 0
    if scale is None:
        scale = np.maximum(np.ptp(s, axis=0), np.sqrt(np.mean(s * s, axis=0)))
    scale = np.asarray(scale, dtype=float) * np.ones(s.shape[1])
    floor = 1e-12 + 1e-9 * np.max(np.abs(s), axis=0)
    z = s / np.maximum(scale, floor)
    k = s.shape[0]
    for n in range(1, max_period + 1):
        if 2 * n + 1 > k:
            break
        if np.max(np.abs(z[n:] - z[:-n])) < tol:
            return n
    return 0


def classify_motion(strobe, *, signal=None, spectrum=None, lyapunov_per_period=None,
                    scale=None, result=None,
                    settings: ClassifierSettings = ClassifierSettings()) -> Motion:
    """Classify one steady response.

    **Arguments:**
    - `strobe`: (k,) or (k, d) stroboscopic (Poincare) samples, transient removed.
    - `signal`: optional densely sampled response (1-D) for the spectral evidence; default
      the first coordinate of `strobe` (a map's orbit).
    - `spectrum`: optional one-sided amplitude spectrum (from `amplitude_spectrum`) used
      instead of computing one from `signal`.
    - `lyapunov_per_period`: lambda T of the largest exponent, if computed.
    - `scale`: per-coordinate amplitude used to judge repetition (default: strobe spread).
    - `result`: the solver's `RESULTS` item of the run (concrete; anything but
      `RESULTS.successful` gives kind "failed"); None: judge from the samples only.
    """
    lyap = float("nan") if lyapunov_per_period is None else float(lyapunov_per_period)
    s = np.asarray(strobe, dtype=float)
    failed = result is not None and not np.all(result_ok(result))
    if failed or not np.all(np.isfinite(s)):
        return Motion(FAILED, 0, FAILED, lyap, float("nan"), None)
    sig = s if s.ndim == 1 else s[:, 0]
    if signal is not None:
        sig = np.asarray(signal, dtype=float)
    if spectrum is None and sig.size >= 8:
        spectrum = amplitude_spectrum(sig, 1.0)[1]
    if spectrum is not None and np.all(np.isfinite(spectrum)):
        # At most a tenth of the bins may count as lines, so short records stay meaningful.
        lines = max(1, min(settings.lines, np.size(spectrum) // 10))
        frac = line_fraction(spectrum, lines=lines)
    else:
        frac = float("nan")
    discrete = None if not np.isfinite(frac) else bool(frac >= settings.line_fraction_min)
    n = strobe_period(s, scale=scale, max_period=settings.max_period, tol=settings.tol)
    if n:
        return Motion(PERIODIC, n, f"period-{n}", lyap, frac, discrete)
    if np.isfinite(lyap) and lyap < -settings.lyapunov_tol:
        # Contracting: the attractor is a stable periodic orbit, not reached within `tol`
        # (the transient was too short for the slowest decaying mode). A decaying mode
        # beating with the forcing can mimic period-q patterns at loose tolerances, so only
        # period-1 is accepted loosely; otherwise the period is left unresolved.
        if strobe_period(s, scale=scale, max_period=1, tol=10 * settings.tol):
            return Motion(PERIODIC, 1, "period-1 (settling)", lyap, frac, discrete,
                          converged=False)
        return Motion(SETTLING, 0, "periodic (settling)", lyap, frac, discrete,
                      converged=False)
    if np.isfinite(lyap):
        chaotic = lyap > settings.lyapunov_tol
        consistent = None if discrete is None else (discrete != chaotic)
    elif discrete is not None:
        chaotic = not discrete
        consistent = None
    else:
        return Motion("non-periodic", 0, "non-periodic", lyap, frac, None)
    kind = CHAOTIC if chaotic else QUASI_PERIODIC
    return Motion(kind, 0, kind, lyap, frac, consistent)
