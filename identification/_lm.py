"""Levenberg-Marquardt on the host around one compiled (residual, Jacobian) function.

The fit problems are small (a handful of parameters) and their residual is expensive to
compile (the nonlinear records' periodic orbits with implicit forward derivatives: about
a minute on 2 cores) but cheap to run. One compiled function returning the residual and
its forward-mode Jacobian together therefore serves every step of every start, the
convergence check, the linearity check and the profile likelihood; the p x p linear
algebra of each step runs in numpy. (An `optimistix.least_squares` solve inside `jit`
compiles the model again for each new solve and held-parameter variant; measured on the
bundled stepped-sine set, its compilation took longer than the whole host-side fit.)

The iteration is MINPACK's Levenberg-Marquardt through scipy (robust on the long curved
valleys of these problems, where a simple damping update crawled: on the paper's test two
of three starts did not converge in 100 steps). Success is judged here, not by MINPACK's
tolerances: the remaining Gauss-Newton step, in units of its own standard error (see
`_fit.py`), must be below `tol`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: Without priors (maximum likelihood), a direction whose standard error exceeds this (in
#: log-value, i.e. a factor e, or um) carries no usable information: over one standard
#: error the model is far from linear, the optimiser's steps there are meaningless, and its
#: parameters are reported as not determined. (With priors every direction is informative:
#: the prior bounds its standard error.) Singular values below 1e-10 x the largest are
#: round-off in any case.
NO_INFORMATION_STD = 1.0
NULL_RTOL = 1e-10


def informative(s, max_std: float | None = None) -> np.ndarray:
    """Which singular values (descending, of a noise-weighted Jacobian) carry information."""
    s = np.asarray(s, float)
    if not s.size or not s[0] > 0:
        return np.zeros(s.shape, bool)
    floor = 0.0 if max_std is None else 1.0 / max_std
    return s > max(s[0] * NULL_RTOL, floor)


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


def gn_step_sigma(r, j, max_std: float | None = None) -> float:
    """Largest remaining Gauss-Newton step component / its standard error (SVD of J), over
    the informative directions."""
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(j))):
        return float("inf")
    u, s, _ = np.linalg.svd(j, full_matrices=False)
    keep = informative(s, max_std)
    if not np.any(keep):
        return float("inf")
    return float(np.max(np.abs(u[:, keep].T @ r)))


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
    return LMResult(x, r, j, 0.5 * float(r @ r), done.get("n", 0), count[0],
                    bool(step < tol), reason)
