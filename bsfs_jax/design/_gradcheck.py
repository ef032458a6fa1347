"""Exact gradients checked against central differences: the one home of the probe that
`bsfs sensitivity` and `bsfs optimize` run by default.

An exact (implicit) gradient is compared on its largest entries with central differences
of the same metric. Entries are compared as d m / d ln p_i = p_i dm/dp_i (the metric's
unit), which stays defined where the metric is zero, and each difference is measured
against the difference quotient itself, or against `NEGLIGIBLE` times the larger of the
metric and its largest entry where the quotient is smaller than that (an entry that
changes the metric by less than 1e-3 % per 1 % is noise-dominated in any quotient).
A check that was not made is reported as such, never as passed.
"""

import numpy as np

from ..params import BallScrewParams
from ._orbit import OrbitSettings
from ._sensitivity import (
    IMPLICIT_AD,
    SensitivityResult,
    finite_difference_sensitivities,
    sensitivities,
)

#: Largest relative disagreement that passes (differences of orbit metrics carry ~1e-4 of
#: noise from the solver tolerances; a wrong derivative is off by far more).
FD_TOLERANCE = 1e-2
#: |d ln m / d ln p| below which an entry is compared absolutely (see the module docstring).
NEGLIGIBLE = 1e-3
#: Entries probed by default: the largest ones, which drive the verdicts and the optimiser.
PROBED = 2


def log_sensitivities(result: SensitivityResult) -> np.ndarray:
    """d m / d ln p_i = p_i dm/dp_i in the metric's unit, one per name of `result`."""
    return np.asarray(result.values, dtype=float) * np.asarray(result.gradient, dtype=float)


def largest_entries(result: SensitivityResult, k: int = PROBED) -> tuple:
    """Names of the `k` entries of largest |d m / d ln p| (non-finite entries last)."""
    size = np.abs(log_sensitivities(result))
    order = np.argsort(-np.where(np.isfinite(size), size, -1.0), kind="stable")
    return tuple(result.names[i] for i in order[:k])


def compare_gradients(exact: SensitivityResult, other: SensitivityResult, *,
            tolerance: float = FD_TOLERANCE) -> dict:
    """Compare the entries of `exact` named in `other` (central differences) with `other`.

    Returns {"checked", "exact_normalised", "fd_normalised", "relative_difference",
    "passed", "tolerance", "method", "summary"}; "passed" is False for any non-finite
    difference.
    """
    idx = [list(exact.names).index(n) for n in other.names]
    e = log_sensitivities(exact)
    d = log_sensitivities(other)
    finite_e = e[np.isfinite(e)]
    ref = max(abs(float(exact.value)), float(np.max(np.abs(finite_e))) if finite_e.size else 0.0)
    scale = np.maximum(np.maximum(np.abs(d), NEGLIGIBLE * ref), 1e-300)
    with np.errstate(invalid="ignore"):
        rel = np.abs(e[idx] - d) / scale
    worst = float(np.max(rel)) if rel.size else float("nan")
    passed = bool(np.isfinite(worst) and worst <= tolerance)
    names = list(other.names)
    where = ", ".join(names) if len(names) <= 3 else f"{len(names)} parameters"
    summary = (f"{'agrees' if passed else 'DISAGREES'} with central differences on {where} "
               f"(largest relative difference {worst:.1e}, tolerance {tolerance:g})")
    if not passed:
        summary += "; do not use these gradients before finding the cause"
    return {"checked": names,
            "exact_normalised": [float(exact.normalised[i]) for i in idx],
            "fd_normalised": [float(x) for x in other.normalised],
            "relative_difference": [float(x) if np.isfinite(x) else None for x in rel],
            "passed": passed, "tolerance": tolerance, "method": other.method,
            "summary": summary}


def gradient_not_checked(reason: str = "--no-fd-probe") -> dict:
    """The record of a check that was skipped (never reported as passed)."""
    return {"checked": [], "passed": None,
            "summary": f"not checked ({reason}): the gradients are unverified"}


def probe_gradient(metric_name: str, params: BallScrewParams, exact: SensitivityResult, *,
          k: int = PROBED, frequency_hz=None, force_n=None,
          settings: OrbitSettings = OrbitSettings()) -> dict:
    """Central differences of the `k` largest entries of `exact` (a `SensitivityResult`
    of `metric_name` at `params`), compared with it (see `compare_gradients`)."""
    fd = finite_difference_sensitivities(metric_name, params, exact.names,
                                         frequency_hz=frequency_hz, force_n=force_n,
                                         settings=settings, only=largest_entries(exact, k),
                                         gradient_program=exact.method == IMPLICIT_AD)
    return compare_gradients(exact, fd)


def check_gradient(metric_name: str, params: BallScrewParams, names, *, k: int = PROBED,
                   frequency_hz=None, force_n=None,
                   settings: OrbitSettings = OrbitSettings()) -> dict:
    """The exact gradient of `metric_name` with respect to `names` at `params`, probed on
    its `k` largest entries by central differences: the `compare_gradients` record, plus
    the metric's "value" and "unit"."""
    exact = sensitivities(metric_name, params, names, frequency_hz=frequency_hz,
                          force_n=force_n, settings=settings)
    out = probe_gradient(metric_name, params, exact, k=k, frequency_hz=frequency_hz,
                         force_n=force_n, settings=settings)
    return {"value": exact.value, "unit": exact.unit, **out}
