"""Verdicts of a long-run block without a periodic orbit (the verifier's quasi-periodic and
chaotic evidence, `_verify.py`): drift between consecutive blocks, the exponent's interval,
the spectrum's line fraction, the rotation number and the closed-curve test."""

import numpy as np

from . import _evidence as ev
from ._orbit_trials import scale_of
from ._spectrum import amplitude_spectrum, line_fraction

QUASI_PERIODIC, CHAOTIC, UNRESOLVED = "quasi-periodic", "chaotic", "unresolved"


def block_verdict(ver, k, value, strobe, amp, lam, signal, period, prev, s):
    """Verdict of a non-periodic block (None: keep integrating); `lam` = (mean, low, high)
    of lambda T over the block (`_evidence.exponent_interval`)."""
    mean, lo, hi = lam
    res = {"lyapunov_per_period": mean, "lyapunov_low": lo, "lyapunov_high": hi,
           "amplitude": amp[ver.obs]}
    if prev is None or not np.isfinite(mean):
        return None
    p_strobe, p_amp, _ = prev
    # Drift: the section's mean and spread change between consecutive blocks by more
    # than `drift_tol` of the amplitude plus their sampling error (a chaotic section's
    # block statistics fluctuate; a decaying transient's spread shrinks steadily).
    sc = scale_of(np.maximum(amp, p_amp), strobe[-1])
    spread = np.maximum(strobe.std(0), p_strobe.std(0))
    noise = 3.0 * spread * np.sqrt(2.0 * s.segments / strobe.shape[0])
    d_mean = np.abs(strobe.mean(0) - p_strobe.mean(0))
    d_std = np.abs(strobe.std(0) - p_strobe.std(0))
    if np.any(d_mean > s.drift_tol * sc + noise) or np.any(d_std > s.drift_tol * sc + noise):
        return None
    if hi < -s.lyapunov_zero / 10:
        return None  # contracting: an orbit should be reached; keep going
    _, spec = amplitude_spectrum(signal, period / s.block_samples)
    frac = line_fraction(spec, lines=max(1, min(16, spec.size // 10)))
    res["line_fraction"] = frac
    if lo > 0:
        if frac < s.line_fraction_min:
            return {**res, "motion": CHAOTIC, "verified": True,
                    "reason": f"lambda T = {mean:.4f} in [{lo:.4f}, {hi:.4f}] (95 %) > 0, "
                              f"broadband spectrum (line fraction {frac:.3f})"}
        return {**res, "motion": UNRESOLVED, "verified": False,
                "reason": f"lambda T = {mean:.4f} in [{lo:.4f}, {hi:.4f}] > 0, but the "
                          f"spectrum is discrete (line fraction {frac:.3f})"}
    if not (lo <= 0 <= hi and max(abs(lo), abs(hi)) <= s.lyapunov_zero):
        return {**res, "motion": UNRESOLVED, "verified": False,
                "reason": f"lambda T = {mean:.4f} in [{lo:.4f}, {hi:.4f}]: neither zero "
                          f"within {s.lyapunov_zero} nor positive"}
    rho = ev.rotation_number(strobe)
    err = ev.closed_curve_error(strobe)
    lock = ev.locked_to(rho, s.max_period, s.rotation_tol)
    res.update(rotation_number=rho, curve_error=err)
    if lock is not None or not err <= s.curve_tol:
        why = (f"rotation number {rho:.4f} locked to {lock[0]}/{lock[1]}" if lock else
               f"section is not one smooth closed curve (error {err:.3f})")
        return {**res, "motion": UNRESOLVED, "verified": False,
                "reason": f"lambda T = {mean:.4f} in [{lo:.4f}, {hi:.4f}] ~ 0, but {why}"}
    found, _ = ver.try_orbits([(k, value, strobe, amp, period,
                                tuple(range(2, s.max_period + 1)))])
    if found:
        return found[k]
    return {**res, "motion": QUASI_PERIODIC, "verified": True,
            "reason": f"lambda T = {mean:.4f} in [{lo:.4f}, {hi:.4f}] (95 %) ~ 0, rotation "
                      f"number {rho:.4f} not locked (q <= {s.max_period}), closed curve "
                      f"(error {err:.3f}), no stable orbit of period <= {s.max_period}"}
