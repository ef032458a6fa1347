"""MINPACK's Levenberg-Marquardt (scipy) on a problem's compiled residual and Jacobian.

A cross-check only (tests and the identification benchmark): the fit itself is optimistix
(`identification/fitting/_solve.py`). The stopping rule is the fit's own: the remaining Gauss-Newton
step in units of its standard error below `tol`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from identification.fitting._lm import gn_step_sigma, informative


class _Converged(Exception):
    pass


@dataclasses.dataclass
class LMResult:
    theta: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    cost: float
    steps: int
    evaluations: int
    converged: bool
    reason: str


def levenberg_marquardt(rj, theta0, *, held=None, max_steps: int = 100, tol: float = 1e-3,
                        rows=None, max_std: float | None = None) -> LMResult:
    """Minimise 0.5 |r|^2 with `rj(theta) -> (r, J)` (numpy arrays).

    MINPACK's Levenberg-Marquardt (`scipy.optimize.least_squares(method="lm")`, Moré's
    trust-region implementation with Jacobian column scaling), fed by `rj` with the last
    evaluation cached so that residual and Jacobian cost one call together.
    `held`: boolean mask of parameters kept at their `theta0` values (profile likelihood).
    `rows`: boolean mask of residual rows used for the stopping test (rows without data).
    `max_std`: directions less certain than this are left out of the stopping test.
    `max_steps` bounds the iterations (4 x `max_steps` residual evaluations); `steps` in the
    result counts the Jacobian evaluations.
    """
    from scipy.optimize import least_squares

    x0 = np.asarray(theta0, float).copy()
    free = np.ones(x0.size, bool) if held is None else ~np.asarray(held, bool)
    cache = {}
    count = [0]

    def full(z):
        x = x0.copy()
        x[free] = z
        return x

    def call(z):
        key = z.tobytes()
        if key not in cache:
            cache.clear()
            r, j = rj(full(z))
            count[0] += 1
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(j))):
                r = np.where(np.isfinite(r), r, 1e6)
                j = np.where(np.isfinite(j), j, 0.0)
            cache[key] = (r, j)
        return cache[key]

    sel = slice(None) if rows is None else rows
    if x0[free].size == 0:
        r, j = rj(x0)
        return LMResult(x0, r, j, 0.5 * float(r @ r), 0, 1, True, "nothing to fit")
    done = {}

    def jac(z):
        # MINPACK asks for the Jacobian at each accepted point: stop there once the
        # remaining Gauss-Newton step is below tol (its own tolerances would wait for
        # round-off-level changes, which the ODE solver's noise never gives).
        r, j = call(z)
        jf = j[:, free]
        if gn_step_sigma(r[sel], jf[sel], max_std) < tol:
            done["x"] = z.copy()
            raise _Converged
        done["n"] = done.get("n", 0) + 1
        return jf

    kw = dict(xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=max(10, 4 * max_steps),
              x_scale="jac")
    try:
        try:
            out = least_squares(lambda z: call(z)[0], x0[free], jac=jac, method="lm", **kw)
        except ValueError as exc:  # fewer residuals than parameters: MINPACK refuses
            out = least_squares(lambda z: call(z)[0], x0[free], jac=jac, method="trf", **kw)
            out.message = f"{out.message} (trust-region reflective: {exc})"
        x, reason = full(out.x), out.message
    except _Converged:
        x, reason = full(done["x"]), "remaining Gauss-Newton step below tol"
    r, j = call(x[free])
    step = gn_step_sigma(r[sel], j[sel][:, free], max_std)
    if step >= tol and "termination condition" in reason:
        # MINPACK judges progress by the cost, whose round-off hides the last step (on the
        # preload-loss set 1.06e-6 standard errors, a cost change of 5e-13 against a cost
        # of 2248): finish as a user would, with one Gauss-Newton step (no cost compared).
        u, s, vt = np.linalg.svd(j[sel][:, free], full_matrices=False)
        keep = informative(s, max_std)
        z = x[free] - vt[keep].T @ ((u[:, keep].T @ r[sel]) / s[keep])
        x, reason = full(z), reason + "; then one Gauss-Newton step"
        r, j = call(z)
        step = gn_step_sigma(r[sel], j[sel][:, free], max_std)
    return LMResult(x, r, j, 0.5 * float(r @ r), done.get("n", 0), count[0],
                    bool(step < tol), reason)
