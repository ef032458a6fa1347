"""The hours at which a fitted trend reaches a limit, as draws from its uncertainty."""

import numpy as np

from ._trends import Fit

#: Parameter draws behind each time-to-limit interval.
DRAWS = 4000

def crossing_draws(fit: Fit, limit: float, falling: bool, rng=None, draws: int = DRAWS):
    """Hours at which the quantity reaches `limit`, drawn from the fit's uncertainty
    (parameters as a multivariate t with the fit's dof; for a Wiener fit also the
    diffusion and the first passage itself). inf where it never does. (draws,)"""
    rng = np.random.default_rng(1) if rng is None else rng
    nu = max(fit.dof, 1)
    chi = np.sqrt(nu / rng.chisquare(nu, draws))
    w, v = np.linalg.eigh((fit.cov + fit.cov.T) / 2)
    root = v * np.sqrt(np.maximum(w, 0.0))
    p = fit.params + (rng.standard_normal((draws, 2)) @ root.T) * chi[:, None]
    toward = -1.0 if falling else 1.0
    if fit.kind == "wiener":
        if fit.posterior is not None:  # (diffusion, scatter, drift) from their posterior
            sg, tg, mg, vg, pg, cell, base_last = fit.posterior
            k = rng.choice(len(pg), draws, p=pg)
            s2 = np.maximum(sg[k] + cell[0] * (rng.random(draws) - 0.5), 0.0)
            t2 = np.maximum(tg[k] + cell[1] * (rng.random(draws) - 0.5), 0.0)
            mu = mg[k] + np.sqrt(vg[k]) * rng.standard_normal(draws)
            x = fit.last_y + np.sqrt(base_last + t2) * rng.standard_normal(draws)
        else:
            x = fit.last_y + np.sqrt(fit.last_var) * rng.standard_normal(draws)
            mu = p[:, 1]
            nu_s = fit.scatter_dof if fit.scatter_dof > 0 else nu
            s2 = fit.scatter * nu_s / rng.chisquare(nu_s, draws)
        gap = toward * (limit - x)  # > 0: still to go
        speed = toward * mu
        out = np.full(draws, np.inf)
        now = gap <= 0
        out[now] = fit.last_t
        go = ~now
        if fit.scatter <= 0:
            ok = go & (speed > 0)
            out[ok] = fit.last_t + gap[ok] / speed[ok]
            return out
        # Passage happens with probability 1 (drift toward) or exp(-2|mu| gap / s2).
        reach = np.where(speed > 0, 1.0,
                         np.exp(-np.clip(2 * np.abs(speed) * gap / np.maximum(s2, 1e-300), 0.0,
                                         700.0)))
        hit = go & (rng.random(draws) < reach)
        m = np.abs(speed[hit])
        g = gap[hit]
        lam = g * g / s2[hit]
        tt = np.where(m > 0, rng.wald(g / np.maximum(m, 1e-300), lam), np.inf)
        out[hit] = fit.last_t + tt
        return out
    a, b = p[:, 0], p[:, 1]
    if fit.kind == "linear":
        with np.errstate(divide="ignore", invalid="ignore"):
            root_t = fit.t0 + (limit - a) / b
        now_val = a + b * (fit.last_t - fit.t0)
    else:
        if limit * fit.sign <= 0:
            return np.full(draws, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            root_t = fit.t0 + (np.log(limit * fit.sign) - a) / b
        now_val = fit.sign * np.exp(a + b * (fit.last_t - fit.t0))
    beyond = toward * (now_val - limit) >= 0
    slope_toward = toward * b * (fit.sign if fit.kind == "exponential" else 1.0) > 0
    out = np.where(slope_toward, root_t, np.inf)
    out = np.where(beyond, np.where(slope_toward, np.minimum(root_t, fit.last_t),
                                    fit.last_t), out)
    return np.where(np.isfinite(out), out, np.inf)
