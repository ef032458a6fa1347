"""Correlated errors between neighbouring FRF lines, and how much they widen the intervals.

The fit weighs every FRF line as an independent measurement. An FRF estimated with a
tapered window is not: a Hann window (Welch, 50 % overlap) spreads each frequency over
three DFT bins, so the errors of neighbouring lines are correlated (white noise: adjacent
bins of a Hann-windowed DFT correlate with coefficient 2/3 in the complex spectrum; the
residuals of a fitted random record show about 0.4 in their real parts), and the data hold
fewer independent lines than they seem to. Treated as independent, n such lines claim
about 1 + 2 rho_1 + 2 rho_2 ... times the information they carry, and the intervals come
out too narrow by the square root of that (about 1.35 for a Hann-windowed Welch FRF).

The fit itself stays as it is (its estimate is still consistent); its covariance becomes
the sandwich A^-1 B A^-1, A the information the fit assumes and B = A + the cross terms
of the correlated lines: for each FRF record and lag k = 1..`MAX_LAG`, the 2 x 2
correlation R_k of a line's standardised (real, imaginary) residual with the line k
further on, estimated from the residuals at the estimate, and B gains
sum_i G_i^T R_k G_(i+k) + its transpose, G_i the line's (2, p) Jacobian rows. Only
correlations beyond `SIGNIFICANCE` of their own sampling error count (an FRF from a
rectangular window, a single-frame chirp, gets exactly no widening), only records of at
least `MIN_LINES` used lines are examined, and a parameter's interval is only ever
widened (`widening` returns factors >= 1).
"""

from __future__ import annotations

import numpy as np

from ..measurement import is_frf

MAX_LAG = 3
MIN_LINES = 100
SIGNIFICANCE = 4.0  # standard errors (1 / sqrt(pairs)) a correlation must exceed


def _record_lines(problem, i, residual, jacobian, used):
    """(z (n, 2), G (n, 2, p), line used (n,)) of FRF record i, lines in frequency order."""
    rows = np.asarray(problem.layout[i][2])
    n = rows.size // 2
    re, im = rows[:n], rows[n:]
    ok = used[re] & used[im]
    z = np.stack([residual[re], residual[im]], 1) * ok[:, None]
    G = np.stack([jacobian[re], jacobian[im]], 1) * ok[:, None, None]
    return z, G, ok


def lag_correlations(z, ok, max_lag: int = MAX_LAG) -> np.ndarray:
    """(max_lag, 2, 2) correlation of (re, im) at line i with line i + k, k = 1..max_lag,
    from the used lines' standardised residuals `z` (n, 2); entries within `SIGNIFICANCE`
    standard errors of zero are set to zero."""
    n_ok = int(ok.sum())
    c0 = (z.T @ z) / max(n_ok, 1)
    d = np.sqrt(np.maximum(np.diag(c0), 1e-300))
    out = np.zeros((max_lag, 2, 2))
    for k in range(1, max_lag + 1):
        pairs = int(np.sum(ok[:-k] & ok[k:]))
        if pairs < MIN_LINES // 2:
            continue
        ck = (z[:-k].T @ z[k:]) / pairs / np.outer(d, d)
        out[k - 1] = np.where(np.abs(ck) > SIGNIFICANCE / np.sqrt(pairs), ck, 0.0)
    return out


def widening(problem, residual, jacobian, info_inv) -> tuple[np.ndarray, dict]:
    """(factor (p,) >= 1 on each parameter's standard error, {record name: lag-1
    correlation of the real parts, for the records where any correlation counted}).

    `residual`, `jacobian`: the fit's data rows (noise-weighted, padding included, so the
    problem's layout indexes them); `info_inv` (p, p): the covariance the fit assumes."""
    residual = np.asarray(residual)
    jacobian = np.asarray(jacobian)
    used = np.asarray(problem.used_mask())
    p = info_inv.shape[0]
    extra = np.zeros((p, p))
    found = {}
    for i, d in enumerate(problem.data):
        if not is_frf(d):
            continue
        z, G, ok = _record_lines(problem, i, residual, jacobian, used)
        if ok.sum() < MIN_LINES:
            continue
        R = lag_correlations(z, ok)
        if not np.any(R):
            continue
        found[d.name] = float(R[0, 0, 0])
        for k in range(1, R.shape[0] + 1):
            if not np.any(R[k - 1]):
                continue
            bk = np.einsum("nap,ab,nbq->pq", G[:-k], R[k - 1], G[k:])
            extra += bk + bk.T
    if not found:
        return np.ones(p), {}
    cov = info_inv + info_inv @ extra @ info_inv
    base = np.diag(info_inv)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(base > 0, np.diag(cov) / base, 1.0)
    return np.sqrt(np.maximum(np.nan_to_num(ratio, nan=1.0), 1.0)), found
