"""The step test: a level step (a repair, a re-preload, a crash) between two tests, with
the trend allowed to restart after it, calibrated by simulation under two nulls."""

import dataclasses

import numpy as np

from ._trends import _floor, _inc_cov, fit_wiener, scatter_term

#: Null simulations behind each step test's threshold.
STEP_SIMULATIONS = 2000
#: Tests needed on each side of a step.
MIN_SEGMENT = 3

def _scan(X, y, cov, cols, rng, known: bool = False):
    """Max over candidates of the F statistic for adding a candidate's columns to the
    generalised LS fit of X (data covariance `cov` (n, n), or its diagonal (n,)).
    `cols` (K, c, n): the c columns of each of K candidates. Returns (F (K,), threshold at
    95 %, p-value of the max). `known`: the tests' own errors are known, so the residual
    variance is taken as at least `cov` says (the F statistic's denominator floored at 1),
    not fitted down to a lucky small spread."""
    n, p = X.shape
    K, c, _ = cols.shape
    L = np.linalg.cholesky(cov if np.ndim(cov) == 2 else np.diag(cov))
    Xw, yw = np.linalg.solve(L, X), np.linalg.solve(L, y)
    Cw = np.linalg.solve(L, cols.reshape(K * c, n).T).T.reshape(K, c, n)
    M = np.eye(n) - Xw @ np.linalg.pinv(Xw)
    # Each candidate's columns with the trend projected out, as orthonormal rows (K, c, n).
    U = np.swapaxes(np.linalg.qr(np.swapaxes(Cw @ M, 1, 2))[0], 1, 2)
    dof = n - p - c

    def F(E):  # E: (..., n) residuals of the null fit
        g = np.sum(np.einsum("...n,kcn->...kc", E, U) ** 2, -1)
        rss0 = np.sum(E * E, -1, keepdims=True)
        scale = np.maximum(rss0 - g, 1e-300 * rss0 + 1e-300) / dof
        return g / c / (np.maximum(scale, 1.0) if known else scale)

    f = F(M @ yw)
    sims = F(rng.standard_normal((STEP_SIMULATIONS, n)) @ M).max(1)
    return f, float(np.quantile(sims, 0.95)), float(np.mean(sims >= f.max()))


@dataclasses.dataclass(frozen=True)
class Step:
    """A step found between tests `index - 1` and `index` of the scanned segment."""

    index: int
    p_value: float


def find_step(t, y, base, rng=None) -> Step | None:
    """The likelihood-ratio (F) step test. The alternative is what a repair does: a level
    step between two tests and the trend restarting after it (its slope may change). Its
    threshold is simulated under two nulls: a straight trend with scatter, and a Wiener
    process with drift and test scatter (its increments' full covariance, maximum
    likelihood; there the step is one outlying increment and the drift may change after
    it). A step is reported only when both reject at 5 % (each null's max statistic over
    every split), so histories of either kind without a step report one in under 5 % of
    cases. None below 2 x MIN_SEGMENT tests. t, y, base: (n,) hours, unit, unit^2."""
    n = len(t)
    if n < 2 * MIN_SEGMENT:
        return None
    rng = np.random.default_rng(0) if rng is None else rng
    span = max(float(t[-1] - t[0]), 1e-300)
    X = np.stack([np.ones(n), (t - t[0]) / span], 1)
    ks = np.arange(MIN_SEGMENT, n - MIN_SEGMENT + 1)
    after = (np.arange(n)[None, :] >= ks[:, None]).astype(float)  # (K, n)
    since = 0.5 * (t[ks - 1] + t[ks])  # the step's hours, between the two tests
    ramp = after * (t[None, :] - since[:, None]) / span
    th = scatter_term(X, y, base, np.ones(n))
    known = bool(np.all(base > 0))
    f1, thr1, p1 = _scan(X, y, base + th + _floor(y), np.stack([after, ramp], 1), rng, known)
    d, dt = np.diff(y), np.diff(t)
    w = fit_wiener(t, y, base, reml=False)
    tau2 = w.last_var - base[-1]
    jump = (np.arange(n - 1)[None, :] == ks[:, None] - 1).astype(float)  # (K, n - 1)
    drift = after[:, 1:] * dt[None, :] / float(np.mean(dt))
    f2, thr2, p2 = _scan(dt[:, None], d, _inc_cov(t, base, tau2, w.scatter, _floor(y)),
                         np.stack([jump, drift], 1), rng, known)
    if f1.max() <= thr1 or f2.max() <= thr2:
        return None
    j = int(np.argmax(f1 / thr1)) if f1.max() / thr1 >= f2.max() / thr2 else int(
        np.argmax(f2 / thr2))
    return Step(int(ks[j]), max(p1, p2))


def change_points(t, y, base, rng=None) -> list[int]:
    """Indices (into t) of the first test after each step, by binary segmentation."""
    found = []

    def scan(lo, hi):
        s = find_step(t[lo:hi], y[lo:hi], base[lo:hi], rng)
        if s is None:
            return
        k = lo + s.index
        found.append(k)
        scan(lo, k)
        scan(k, hi)

    scan(0, len(t))
    return sorted(found)


