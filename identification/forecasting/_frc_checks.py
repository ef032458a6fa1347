"""The FRC quantities' second-order checks (`_forecast_run`): by the model itself at the
identification's draws (`from_draws`), else by probes along the covariance's least
determined directions (`probe_steps`, `from_probes`). See `_forecast.py` for the
intervals."""

from __future__ import annotations

import numpy as np

from ._intervals import (
    SECOND_ORDER_TOL,
    Z95,
    Identified,
    Quantity,
    _checked,
    _quantity,
    _std,
    floored,
)


def from_draws(name, unit, value, grad, ident: Identified, at, *, scale=1.0,
               method="delta") -> Quantity:
    """A costly quantity (FRC peak, folds) with its exact gradient g, checked by the model
    itself at each of the identification's draws theta_k (`at`: q(theta_k), every one
    finite). The linear model's error there, e_k = q(theta_k) - q_hat - g . delta_k, is
    the second-order term and beyond, measured rather than modelled: where std(e) is at
    most `SECOND_ORDER_TOL` of std(g . delta) the delta interval stands; else the
    interval is the 2.5-97.5 % range of q(theta_k) and the value their median (method
    "model at each draw, ..."), the model at the estimate kept as `plug_in`, each side at
    least the delta half-width from the value (`extra["floor"]` says where that applied):
    the bootstrap refits under-disperse along the dampers (docs/ROBUSTNESS.md: 0.87-0.90
    of the linearised widths), which dominate the FRC quantities: over replicates 0-99
    of the coverage study their ranges were 0.91-0.97 of the delta width (medians) while
    the errors, in delta standard deviations, scattered with std 1.00-1.04; unfloored,
    three of the four covered 91-92 % (docs/COVERAGE.md)."""
    g = np.asarray(grad, float)
    v = float(value)
    at = np.asarray(at, float)
    lin = (ident.draws - ident.theta) @ g
    sd_lin, sd_err = float(np.std(lin)), float(np.std(at - v - lin))
    ratio = sd_err / sd_lin if sd_lin > 0 else (0.0 if sd_err == 0 else np.inf)
    extra = dict(second_order=ratio, second_order_from=f"{len(at)} {ident.draws_kind}")
    if ratio <= SECOND_ORDER_TOL:
        sd = _std(g, ident)
        return _quantity(name, unit, v, [v - Z95 * sd, v + Z95 * sd], method, g, ident,
                         scale, extra)
    lo, median, hi = np.percentile(at, [2.5, 50.0, 97.5])
    extra.update(draws=len(at), draws_std=float(np.std(at)) * scale, plug_in=v * scale,
                 draws_ci95=[float(lo) * scale, float(hi) * scale])
    lo, hi = floored(lo, median, hi, _std(g, ident), extra)
    return _quantity(name, unit, median, [lo, hi],
                     f"model at each draw, {ident.draws_kind or 'posterior draws'}", g, ident,
                     scale, extra)


def probe_steps(ident: Identified, k: int = 3) -> np.ndarray:
    """(k, p): 1.96 sqrt(lambda_i) u_i along the covariance's k least determined directions
    (largest eigenvalues): where the second-order terms of a quantity are largest."""
    w, v = np.linalg.eigh(ident.covariance)
    order = np.argsort(w)[::-1][:k]
    return np.stack([Z95 * np.sqrt(max(w[i], 0.0)) * v[:, i] for i in order])


def from_probes(name, unit, value, grad, ident: Identified, steps, at_plus, at_minus, *,
                scale=1.0, method="delta", exact=None) -> Quantity:
    """A costly quantity (FRC peak, folds) with its exact gradient, checked at the probes
    theta_hat +- steps[i] (`probe_steps`; `at_plus`/`at_minus`: q there, None where the
    quantity does not exist there, e.g. a fold gone).

    The second differences d_i = q(+) + q(-) - 2 q_hat give the quantity's curvature along
    each probed direction, the Hessian H = sum_i d_i s_i s_i^T / |s_i|^4 restricted to
    them, and `_checked` decides with it (method "quadratic (probed)" where doubtful).
    Where the quantity vanishes at a probe (a fold appears or disappears inside the
    interval), the side it moves to there is left open (method "probed: vanishes").
    `exact`: as `_checked`'s (the located point followed to each draw)."""
    g = np.asarray(grad, float)
    v = float(value)
    gone = [(i, sgn) for i in range(len(steps))
            for sgn, q in ((1.0, at_plus[i]), (-1.0, at_minus[i])) if q is None]
    extra = dict(probes=len(steps))
    if gone:
        sd = _std(g, ident)
        ci = [v - Z95 * sd, v + Z95 * sd]
        for i, sgn in gone:
            ci[1 if sgn * float(g @ steps[i]) >= 0 else 0] = None
        extra["vanishes_at_probes"] = len(gone)
        return _quantity(name, unit, v, ci, "probed: vanishes", g, ident, scale, extra)
    d = np.array([at_plus[i] + at_minus[i] - 2 * v for i in range(len(steps))], float)
    slope = np.array([(at_plus[i] - at_minus[i]) / 2 for i in range(len(steps))], float)
    lin = steps @ g
    sd = _std(g, ident)
    extra["probe_slope_error"] = (float(np.max(np.abs(slope - lin)) / (Z95 * sd))
                                  if sd > 0 else None)
    norm2 = np.sum(steps**2, axis=1)
    h = np.einsum("i,ij,ik->jk", d / norm2**2, steps, steps)
    return _checked(name, unit, v, g, h, ident, scale, method, "quadratic (probed)", extra,
                    approximate=True, exact=exact)
