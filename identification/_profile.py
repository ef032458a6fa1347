"""Profile-likelihood intervals where the linearised covariance is doubtful.

Check. If the cost were quadratic, moving parameter i by t of its standard errors while the
others follow their conditional optimum (the path theta_hat + t C e_i / sigma_i) would
raise 2 x cost by exactly t^2. The cost is evaluated on that path at t = +-1.96; where it
rises by less than 3.84 (1 - `LINEAR_TOL`) or more than 3.84 (1 + `LINEAR_TOL`), the
linearised interval is doubtful on that side. (The path is only the first-order guess of
the conditional optimum: where the valley curves, the path's cost rises faster than the
profile's.) So a doubtful side is checked with the profile itself at t = 1.96 (below), and
only where that too is off by more than `LINEAR_TOL` is the interval's end searched.

Profile. For a doubtful parameter the others are re-optimised with theta_i held (the same
host-side Levenberg-Marquardt as the fit, on the same compiled residual and Jacobian),
and the end of the 95 % interval is where the profile's 2 x cost exceeds the optimum's by
3.84 (chi-square, 1 degree of freedom), found by a secant search in t. A profile that
stays below 3.84 out to `MAX_T` standard errors leaves that side open: the parameter is
then not determined.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._fit import full_used_mask, no_information_std
from ._lm import levenberg_marquardt
from ._uncertainty import Z95, Uncertainty

LINEAR_TOL = 0.1
LEVEL = Z95**2  # 3.84
MAX_T = 8.0


def held_cost(problem, theta_start, i, value, rows=None):
    """2 x cost with theta_i held at `value` and the others re-optimised (host LM)."""
    start = np.asarray(theta_start, float).copy()
    start[i] = value
    held = np.arange(start.size) == i
    out = levenberg_marquardt(problem.rj, start, held=held, max_steps=60, tol=1e-3, rows=rows,
                              max_std=no_information_std(problem))
    return out.theta, 2.0 * out.cost


def _two_cost(problem, theta):
    r, _ = problem.rj(theta)
    return float(r @ r) if np.all(np.isfinite(r)) else float("inf")


def linearity_check(result, unc: Uncertainty) -> np.ndarray:
    """(p, 2) rise of 2 x cost at t = -1.96 and +1.96 along each parameter's path, / 3.84."""
    pb = result.problem
    base = 2.0 * result.cost  # the fit's own 2 x cost at the optimum (no re-evaluation)
    out = np.full((pb.n_params, 2), np.nan)
    cov = unc.covariance
    for i in range(pb.n_params):
        s = np.sqrt(cov[i, i])
        if not (np.isfinite(s) and s > 0 and np.isfinite(unc.scaled_std[i])):
            continue
        path = cov[:, i] / s
        for k, t in enumerate((-Z95, Z95)):
            out[i, k] = (_two_cost(pb, result.theta + t * path) - base) / LEVEL
    return out


def _rise_fn(pb, result, unc, i, sign):
    """t -> rise of the profile's 2 x cost at theta_i = theta_hat_i + sign t sigma_i."""
    base = 2.0 * result.cost  # the fit's own 2 x cost at the optimum (no re-evaluation)
    s = unc.scaled_std[i]
    cov = unc.covariance
    rows = full_used_mask(pb)

    def rise(t):
        start = result.theta + sign * t * cov[:, i] / s
        _, c = held_cost(pb, start, i, result.theta[i] + sign * t * s, rows)
        return (c - base) if np.isfinite(c) else np.inf

    return rise


def _profile_end(rise, r1):
    """t > 0 where the profile's rise reaches 3.84 (r1 = rise at 1.96), or inf if never."""
    t0, r0 = 0.0, 0.0
    t1 = Z95
    for _ in range(12):
        if abs(r1 - LEVEL) < 1e-3 * LEVEL:
            return t1
        if r1 < LEVEL:  # not there yet: extrapolate outwards (rise ~ t^2)
            t_new = t1 * np.sqrt(LEVEL / max(r1, 1e-12)) if r1 > 0 else 2 * t1
            t_new = min(t_new, 2.0 * t1)
            if t1 >= MAX_T:
                return np.inf
            t0, r0, t1 = t1, r1, min(t_new, MAX_T)
        else:  # bracketed between t0 and t1: secant on sqrt(rise)
            a, b = np.sqrt(max(r0, 0.0)), np.sqrt(r1)
            t_new = t0 + (t1 - t0) * (np.sqrt(LEVEL) - a) / max(b - a, 1e-12)
            t_new = min(max(t_new, t0 + 0.05 * (t1 - t0)), t1 - 0.05 * (t1 - t0))
            r_new = rise(t_new)
            if r_new < LEVEL:
                t0, r0 = t_new, r_new
                continue
            t1, r1 = t_new, r_new
            continue
        r1 = rise(t1)
    return t1


def profile_intervals(result, unc: Uncertainty, *, force: bool = False) -> tuple:
    """(updated `Uncertainty`, table (p, 2) of the profile's rise at -+1.96 sigma / 3.84).

    Sides whose conditional-path rise is within `LINEAR_TOL` of 3.84 keep the linearised
    end (table: the path's rise); the others get the held profile at 1.96 sigma, and where
    that is off by more than `LINEAR_TOL` too, the profile end replaces the linearised one.
    `force`: profile every side.
    """
    pb = result.problem
    table = linearity_check(result, unc)
    finite = np.isfinite(unc.scaled_std)
    if not unc.noise["estimable"]:
        return unc, table
    ci = unc.ci95.copy()
    method = list(unc.ci_method)
    determined = unc.determined.copy()
    log = pb.is_log
    for i in np.nonzero(finite)[0]:
        for k, sign in enumerate((-1.0, 1.0)):
            if not force and abs(table[i, k] - 1.0) <= LINEAR_TOL:
                continue
            rise = _rise_fn(pb, result, unc, i, sign)
            r1 = rise(Z95)
            table[i, k] = r1 / LEVEL
            if not force and abs(table[i, k] - 1.0) <= LINEAR_TOL:
                continue
            t = _profile_end(rise, r1)
            method[i] = "profile"
            if not np.isfinite(t):
                ci[i, k] = 0.0 if log[i] and sign < 0 else sign * np.inf
                determined[i] = False
                continue
            th = result.theta[i] + sign * t * unc.scaled_std[i]
            ci[i, k] = (pb.prior_values[i] * np.exp(th) if log[i]
                        else pb.prior_values[i] + th)
    return dataclasses.replace(unc, ci95=ci, ci_method=method, determined=determined), table
