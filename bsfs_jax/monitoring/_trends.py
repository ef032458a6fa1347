"""Trend models and their weights: small numpy/scipy statistics.

Every fit weights test i by `base_i + theta * shape_i`: `base_i` is the test's own
variance (its standard error squared, 0 when unknown) and `theta` the between-test
scatter (shape 1) or the Wiener diffusion (shape = hours between tests), estimated so
that the weighted chi-square equals its degrees of freedom (Paule-Mandel).
"""

import dataclasses

import numpy as np
from scipy import optimize, stats

_TINY = 1e-24


def _floor(y) -> float:
    return _TINY * (float(np.mean(np.square(y))) + 1.0)


def _chi2(X, y, var):
    sw = 1.0 / np.sqrt(var)
    beta = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]
    r = y - X @ beta
    return float(np.sum(r * r / var)), beta


def scatter_term(X, y, base, shape) -> float:
    """theta >= 0 with sum r^2 / (base + theta shape) = n - p at the weighted LS fit
    (0 when the tests' own errors already explain the spread)."""
    n, p = X.shape
    dof = n - p
    if dof <= 0:
        return 0.0
    floor = _floor(y)
    q = lambda th: _chi2(X, y, base + th * shape + floor)[0] - dof
    if np.all(base > 0) and q(0.0) <= 0:
        return 0.0
    if not np.any(base > 0):  # chi2 = RSS(weights 1/shape) / theta
        rss = _chi2(X, y, shape)[0]
        return rss / dof
    hi = float(np.var(y) / np.mean(shape)) + float(np.max(base / shape)) + floor
    while q(hi) > 0:
        hi *= 10.0
    return float(optimize.brentq(q, 0.0, hi, xtol=1e-14 * hi, rtol=1e-12))


@dataclasses.dataclass(frozen=True)
class Fit:
    """One trend model fitted to a segment of tests.

    `kind`: "linear" (y = a + b (t - t0)), "exponential" (y = sign exp(a + b (t - t0))) or
    "wiener" (increments with drift b per hour and diffusion `scatter` per hour, by REML;
    `posterior`: its (diffusion, scatter, drift) posterior on a grid, see
    `_wiener_posterior`, which the time-to-limit draws use).
    `params` (2,), `cov` (2, 2): a (unit, or log-unit) and b (per hour); `scatter`:
    between-test variance (unit^2) or Wiener diffusion (unit^2 / h); `dof`: n - 2;
    `loglik`, `aicc`: of the tests after the first (so all models see the same data)."""

    kind: str
    t0: float
    params: np.ndarray
    cov: np.ndarray
    scatter: float
    dof: int
    loglik: float
    aicc: float
    sign: float = 1.0
    last_t: float = 0.0
    last_y: float = 0.0
    last_var: float = 0.0
    mean_base: float = 0.0
    scatter_dof: float = 0.0
    posterior: tuple | None = dataclasses.field(default=None, compare=False, repr=False)

    def mean(self, t, params=None):
        """The trend at hours `t` (array), with `params` (..., 2) if given."""
        p = self.params if params is None else params
        a, b = p[..., 0], p[..., 1]
        t = np.asarray(t, float)
        if self.kind == "linear":
            return a + b * (t - self.t0)
        if self.kind == "exponential":
            return self.sign * np.exp(a + b * (t - self.t0))
        return self.last_y + b * (t - self.last_t)

    def band(self, t, level: float = 0.95):
        """(mean, lower, upper) of the `level` prediction band of a new test at hours `t`."""
        t = np.asarray(t, float)
        m = self.mean(t)
        q = stats.t.ppf(0.5 + level / 2, max(self.dof, 1))
        if self.kind == "wiener":
            dt = np.maximum(t - self.last_t, 0.0)
            var = (self.cov[1, 1] * dt**2 + self.scatter * dt + self.last_var
                   + self.mean_base)
        else:
            g = np.stack([np.ones_like(t), t - self.t0], -1)
            if self.kind == "exponential":
                g = g * m[..., None]
            var = np.einsum("...i,ij,...j->...", g, self.cov, g) + self.scatter + self.mean_base
        half = q * np.sqrt(np.maximum(var, 0.0))
        return m, m - half, m + half


def _aicc(loglik: float, n: int, k: int = 3) -> float:
    aic = -2.0 * loglik + 2 * k
    return aic + (2.0 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else 0.0)


def _inc_cov(t, base, scatter, diffusion, floor):
    """Covariance (n-1, n-1) of the increments of tests with variances base + scatter
    (independent) on a Wiener path of `diffusion` per hour."""
    v = base + scatter + floor
    c = np.diag(diffusion * np.diff(t) + v[1:] + v[:-1])
    i = np.arange(len(t) - 2)
    c[i, i + 1] = c[i + 1, i] = -v[1:-1]
    return c


def _gls(d, X, C):
    """(beta, cov of beta, Gaussian log-likelihood) of d ~ N(X beta, C)."""
    L = np.linalg.cholesky(C)
    Xw, dw = np.linalg.solve(L, X), np.linalg.solve(L, d)
    beta = np.linalg.lstsq(Xw, dw, rcond=None)[0]
    r = dw - Xw @ beta
    ll = -0.5 * (len(d) * np.log(2 * np.pi) + 2 * np.sum(np.log(np.diag(L))) + r @ r)
    return beta, np.linalg.pinv(Xw.T @ Xw), float(ll)


def _inc_loglik(t, y, mean, base, scatter, diffusion=0.0) -> float:
    """Log-likelihood of the increments (all models are compared on the same data)."""
    d = np.diff(y) - np.diff(mean)
    C = _inc_cov(t, base, scatter, diffusion, _floor(y))
    return _gls(d, np.zeros((len(d), 0)), C)[2]


def fit_linear(t, y, base) -> Fit:
    """Weighted line with between-test scatter; t, y, base: (n,) hours, unit, unit^2."""
    t0 = float(t[0])
    X = np.stack([np.ones_like(t), t - t0], 1)
    th = scatter_term(X, y, base, np.ones_like(t))
    var = base + th + _floor(y)
    sw = 1.0 / np.sqrt(var)
    beta = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]
    cov = np.linalg.pinv((X * sw[:, None]).T @ (X * sw[:, None]))
    ll = _inc_loglik(t, y, X @ beta, base, th)
    return Fit("linear", t0, beta, cov, th, len(t) - 2, ll, _aicc(ll, len(t) - 1),
               last_t=float(t[-1]), mean_base=float(np.mean(base)))


def fit_exponential(t, y, base) -> Fit | None:
    """y = sign exp(a + b (t - t0)), weighted, with scatter; None when y changes sign."""
    if not (np.all(y > 0) or np.all(y < 0)):
        return None
    sign = float(np.sign(y[0]))
    t0 = float(t[0])
    tau = t - t0
    X = np.stack([np.ones_like(t), tau], 1)
    z = np.log(sign * y)
    p = np.linalg.lstsq(X, z, rcond=None)[0]
    th = 0.0
    floor = _floor(y)
    for _ in range(30):
        var = base + th + floor
        res = optimize.least_squares(
            lambda q: (sign * np.exp(q[0] + q[1] * tau) - y) / np.sqrt(var), p,
            method="lm", xtol=1e-14, ftol=1e-14)
        p_new = res.x
        r = y - sign * np.exp(p_new[0] + p_new[1] * tau)
        dof = len(t) - 2
        q = lambda s: float(np.sum(r * r / (base + s + floor))) - dof
        if dof <= 0 or (np.all(base > 0) and q(0.0) <= 0):
            th_new = 0.0
        elif not np.any(base > 0):
            th_new = float(np.sum(r * r)) / dof
        else:
            hi = float(np.var(y)) + float(np.max(base)) + floor
            while q(hi) > 0:
                hi *= 10.0
            th_new = float(optimize.brentq(q, 0.0, hi, xtol=1e-14 * hi, rtol=1e-12))
        done = abs(th_new - th) <= 1e-9 * (th + floor) and np.allclose(p_new, p, rtol=1e-10)
        p, th = p_new, th_new
        if done:
            break
    var = base + th + floor
    m = sign * np.exp(p[0] + p[1] * tau)
    J = np.stack([m, m * tau], 1) / np.sqrt(var)[:, None]
    cov = np.linalg.pinv(J.T @ J)
    ll = _inc_loglik(t, y, m, base, th)
    return Fit("exponential", t0, p, cov, th, len(t) - 2, ll, _aicc(ll, len(t) - 1), sign,
               last_t=float(t[-1]), mean_base=float(np.mean(base)))


def _wiener_nll(t, d, X, base, s0, scale, fl, restricted):
    """Negative (restricted) log-likelihood of the increments d at log variances u =
    (log diffusion share, log scatter share) of s0; the drift by GLS (profiled out)."""

    def nll(u):
        C = _inc_cov(t, base, s0 * np.exp(u[1]), s0 * np.exp(u[0]) / scale, fl)
        try:
            _, cov, ll = _gls(d, X, C)
        except np.linalg.LinAlgError:
            return np.inf
        if restricted:  # REML: - 1/2 log |X' C^-1 X| = + 1/2 log |cov of the drift|
            ll = ll + 0.5 * float(np.linalg.slogdet(cov)[1])
        return -ll

    return nll


def _minimise(nll):
    best = None
    for u0 in ([-1.0, -1.0], [-1.0, -20.0], [-20.0, -1.0]):
        r = optimize.minimize(nll, u0, method="L-BFGS-B", bounds=[(-30, 5), (-30, 5)])
        if best is None or r.fun < best.fun:
            best = r
    return best


def _log_variance_dof(nll, u, cap: float) -> float:
    """Degrees of freedom nu of a scaled inverse chi-square for the diffusion, matched to
    the curvature of the restricted likelihood in its log (var log sigma^2 ~ 2 / nu),
    with the scatter profiled out; at most `cap`, at least 2."""
    h = 0.05
    f0 = nll(u)
    H = np.empty((2, 2))
    e = np.eye(2) * h
    for i in range(2):
        for j in range(2):
            H[i, j] = (nll(u + e[i] + e[j]) - nll(u + e[i] - e[j]) - nll(u - e[i] + e[j])
                       + nll(u - e[i] - e[j])) / (4 * h * h)
    if not np.all(np.isfinite(H)) or not np.isfinite(f0):
        return 2.0
    if H[1, 1] > 1e-8:  # the scatter profiled out: the Schur complement
        info = H[0, 0] - H[0, 1] ** 2 / H[1, 1]
    else:
        info = H[0, 0]
    if not info > 0:
        return 2.0
    return float(np.clip(2.0 * info, 2.0, cap))


#: Grid of the Wiener fit's (diffusion, scatter) posterior: points per axis.
GRID = (48, 24)


def _wiener_posterior(t, d, base, fl):
    """Posterior of (diffusion per hour, scatter) of a Wiener fit on a grid: the restricted
    likelihood of the increments (the drift integrated out under a flat prior) times flat
    priors on both variances, so a diffusion estimated near 0 still carries its upper
    uncertainty. Returns (sig2 (G,), tau2 (G,), drift mean (G,), drift variance (G,),
    probabilities (G,), cell widths (2,), the last test's own variance)."""
    dt = np.diff(t)
    vd = float(np.var(d)) + float(np.mean(base)) + fl
    s_hi, t_hi = 6.0 * vd / float(np.mean(dt)), 1.5 * vd
    ns, nt = GRID
    sg = (np.arange(ns) + 0.5) * s_hi / ns
    tg = (np.arange(nt) + 0.5) * t_hi / nt
    S, T = np.meshgrid(sg, tg, indexing="ij")
    S, T = S.ravel(), T.ravel()
    m = len(d)
    v = base[None, :] + T[:, None] + fl  # (G, n)
    C = np.zeros((len(S), m, m))
    i = np.arange(m)
    C[:, i, i] = S[:, None] * dt[None, :] + v[:, 1:] + v[:, :-1]
    j = np.arange(m - 1)
    C[:, j, j + 1] = C[:, j + 1, j] = -v[:, 1:-1]
    L = np.linalg.cholesky(C)
    rhs = np.broadcast_to(np.stack([dt, d], 1), (len(S), m, 2))
    W = np.linalg.solve(L, rhs)
    xw, dw = W[..., 0], W[..., 1]
    xtx = np.sum(xw * xw, 1)
    xty = np.sum(xw * dw, 1)
    r2 = np.sum(dw * dw, 1) - xty**2 / xtx
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), 1)
    ll = -0.5 * (logdet + r2 + np.log(xtx))
    w = np.exp(ll - ll.max())
    return (S, T, xty / xtx, 1.0 / xtx, w / w.sum(), np.array([s_hi / ns, t_hi / nt]),
            float(base[-1]))


def fit_wiener(t, y, base, reml: bool = True) -> Fit | None:
    """Wiener process with drift plus independent test scatter, fitted to the increments
    (their full covariance; drift by GLS); None below 4 tests. The diffusion per hour and
    the scatter are estimated by restricted maximum likelihood (REML, the drift profiled
    out: unbiased where maximum likelihood gives the two variances too little over 10-40
    tests) unless `reml` is False; `loglik`/`aicc` are always the maximum likelihood's, so
    the models are compared on the same footing. `scatter_dof`: degrees of freedom of the
    diffusion estimate (scaled inverse chi-square matched to the REML curvature), used
    by the time-to-limit draws. The level now is the last test's (its variance: the
    test's own plus the scatter)."""
    if len(t) < 4:
        return None
    d, dt = np.diff(y), np.diff(t)
    X = dt[:, None]
    s0 = float(np.var(d)) + float(np.mean(base)) + _floor(y)
    fl = _floor(y)
    scale = float(np.mean(dt))
    ml = _wiener_nll(t, d, X, base, s0, scale, fl, False)
    best_ml = _minimise(ml)
    n = len(t) - 1
    nu = float(max(len(t) - 2, 1))
    if reml:
        rl = _wiener_nll(t, d, X, base, s0, scale, fl, True)
        best = _minimise(rl)
        nu = _log_variance_dof(rl, best.x, nu)
        try:
            post = _wiener_posterior(t, d, base, fl)
        except np.linalg.LinAlgError:
            post = None
        if post is not None and not np.all(np.isfinite(post[4])):
            post = None
    else:
        post = None
        best = best_ml
    sig2 = s0 * np.exp(best.x[0]) / scale
    tau2 = s0 * np.exp(best.x[1])
    mu, cov, _ = _gls(d, X, _inc_cov(t, base, tau2, sig2, fl))
    ll = -float(best_ml.fun)
    k = 3
    aicc = -2 * ll + 2 * k + (2.0 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else 0.0)
    return Fit("wiener", float(t[0]), np.array([float(y[-1]), float(mu[0])]),
               np.diag([float(base[-1] + tau2), float(cov[0, 0])]), sig2, len(t) - 2, ll,
               aicc, last_t=float(t[-1]), last_y=float(y[-1]),
               last_var=float(base[-1] + tau2), mean_base=float(np.mean(base) + tau2),
               scatter_dof=nu, posterior=post)


def fit_models(t, y, base) -> dict[str, Fit]:
    """Every model that applies to the segment, by name."""
    fits = {"linear": fit_linear(t, y, base), "exponential": fit_exponential(t, y, base),
            "wiener": fit_wiener(t, y, base)}
    return {k: f for k, f in fits.items() if f is not None and np.isfinite(f.aicc)}
