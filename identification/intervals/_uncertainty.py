"""Posterior uncertainty of a fit: what the data determine and what the prior does.

Scaled parameters theta (log-values, offsets in um; see `fit.Problem`). With the data
Jacobian J_d (noise-weighted rows) and prior standard deviations sigma, the posterior
information is I = J_d^T J_d + diag(1 / sigma^2) (without priors only the first term), and
the covariance is I^-1, times s^2 where the residuals show model error (below).

- **Determined or prior-dominated.** A parameter is *determined by the data* when the
  records alone, with no prior on any parameter, pin it to within half its prior standard
  deviation (`DETERMINED_RATIO`) and to better than `IDENTIFIABLE_STD` (10 %, or 0.1 um,
  the threshold `plan-test` uses). Otherwise it is *prior-dominated*: the records fix at
  most combinations of it with others (the series compliance of the paper's test), or fix
  it only loosely, and its value leans on the priors. The data's share of each posterior
  variance is reported too.
  Without priors a parameter is determined when its standard error is below
  `IDENTIFIABLE_STD` (10 %, or 0.1 um); directions without any information have infinite
  variance, and their parameters are "not determined" (no interval is printed).
- **Noise level.** The weights are the records' own noise estimates (thousands of samples
  each). The fit's chi-square is compared with its degrees of freedom n - p_eff
  (p_eff = trace of the data's share of the information) only where n - p_eff >=
  `MIN_DOF`; where the residuals exceed the noise (chi-square tail probability below
  `MODEL_ERROR_P`) the covariance is scaled by s^2 = chi^2 / dof and the report says so.
  With fewer degrees of freedom that check cannot be made and the report says so. A
  record whose own noise estimate has too few degrees of freedom makes the uncertainty
  not estimable at all.
- **Neighbouring FRF lines** whose errors are correlated (a Hann-windowed Welch FRF) carry
  less information than independent lines; their covariance is the sandwich of
  `_lines.py`, which widens each parameter's standard error by its own factor (>= 1) and
  the report says so.
- **Intervals** are 95 % and in file units: value exp(+-1.96 sigma) for log-parameters
  (always positive), value +- 1.96 sigma for offsets; where the linearisation is doubtful
  they are replaced by profile-likelihood intervals (`_profile.py`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..fitting import NO_INFORMATION_STD, FitResult, informative
from ..measurement import compliance_and_gradient, is_frf
from ._lines import widening

IDENTIFIABLE_STD = 0.1  # without priors: determined if std < 0.1 (10 % / 0.1 um)
DETERMINED_RATIO = 0.5  # with priors: determined if posterior std <= 0.5 prior std
MIN_DOF = 5
MODEL_ERROR_P = 1e-3
MIN_RECORD_DOF = 30
Z95 = 1.959963984540054


@dataclasses.dataclass
class Uncertainty:
    names: tuple
    units: tuple
    values: np.ndarray
    std: np.ndarray  # file units (log-parameters: value x relative std); inf: none
    ci95: np.ndarray  # (p, 2) file units; nan where not determined without priors
    ci_method: list  # per parameter: "linearised" or "profile"
    scaled_std: np.ndarray  # std of theta (relative, or um)
    prior_sigma: np.ndarray | None
    determined: np.ndarray  # bool per parameter
    data_share: np.ndarray | None  # 1 - posterior var / prior var (with priors)
    correlation: np.ndarray
    covariance: np.ndarray  # of theta
    singular_values: np.ndarray  # of the data Jacobian, descending
    directions: np.ndarray  # (p, p) columns: right singular vectors
    direction_std: np.ndarray  # std of each direction's combination (data only)
    noise: dict  # chi2, dof, noise_scale, checked, model_error, scaled_by, estimable, text
    compliance: dict  # static compliance at the nut per speed

    def combination_text(self, i: int, threshold: float = 0.15) -> str:
        v = self.directions[:, i]
        v = v * np.sign(v[np.argmax(np.abs(v))])
        terms = []
        for j in np.argsort(-np.abs(v)):
            if abs(v[j]) < threshold:
                continue
            what = self.names[j] if self.units[j] == "um" else f"log {self.names[j]}"
            terms.append(f"{v[j]:+.2f} {what}")
        return " ".join(terms) if terms else "(spread over all parameters)"

    def identifiable(self) -> list[bool]:
        return [bool(s < IDENTIFIABLE_STD) for s in self.direction_std]

    def status(self, i: int) -> str:
        if self.determined[i]:
            return "determined by the data"
        return "prior-dominated" if self.prior_sigma is not None else "not determined"


def _record_dof(problem) -> list[str]:
    """Records whose own noise estimate rests on too few degrees of freedom."""
    bad = []
    for d in problem.data:
        if is_frf(d):
            # Welch estimates carry their degrees of freedom (averages - 1); a single-frame
            # chirp estimate takes its noise from +-25 neighbouring lines; a file's FRF
            # states its standard errors (or coherence and averages; the loader insists).
            dof = float(d.meta.get("variance_dof", MIN_RECORD_DOF))
            if dof < 1:
                bad.append(f"{d.name} (its FRF variances rest on {dof:g} degrees of freedom)")
        elif d.n_samples - (2 * d.harmonics.size + 1) * 3 < MIN_RECORD_DOF:
            bad.append(f"{d.name} ({d.n_samples} samples)")
    return bad


def _data_only_std(j_d, scale):
    """Marginal std of each theta from the records alone (no prior on any parameter)."""
    p = j_d.shape[1]
    if not j_d.size:
        return np.full(p, np.inf)
    _, sv, vt = np.linalg.svd(j_d, full_matrices=False)
    null = ~informative(sv, NO_INFORMATION_STD)
    var = (vt.T**2 * np.where(null, 0.0, 1.0 / np.where(null, 1.0, sv) ** 2)[None, :]).sum(1)
    touched = np.any(np.abs(vt[null]) > 1e-3, axis=0) if np.any(null) else np.zeros(p, bool)
    if sv.size < p:  # fewer data than parameters: the missing directions are null too
        touched = np.ones(p, bool)
    return np.where(touched, np.inf, np.sqrt(scale * var))


def _noise_check(problem, r_d, j_d, info_inv):
    n = r_d.size
    hat = float(np.sum((j_d @ info_inv) * j_d)) if n else 0.0  # trace(J A J^T), no n x n
    dof = n - hat
    chi2 = float(r_d @ r_d)
    out = dict(chi2=chi2, n_data=int(n), effective_parameters=float(hat), dof=float(dof),
               checked=False, model_error=False, scaled_by=1.0, noise_scale=None)
    bad = _record_dof(problem)
    out["estimable"] = not bad
    if bad:
        out["text"] = ("the uncertainty cannot be estimated: the noise level of "
                       + ", ".join(bad) + " rests on too few samples")
        return out
    if dof < MIN_DOF:
        out["text"] = (f"the goodness of fit cannot be checked ({n} data values for "
                       f"{hat:.1f} effective parameters, {dof:.1f} degrees of freedom < "
                       f"{MIN_DOF}); the intervals rest on the records' own noise estimates")
        return out
    from scipy.special import chdtrc  # the chi-square tail (scipy.stats' chi2.sf)

    p = float(chdtrc(dof, chi2))
    s = float(np.sqrt(chi2 / dof))
    out.update(checked=True, noise_scale=s, p_value=p, model_error=bool(p < MODEL_ERROR_P))
    if out["model_error"]:
        out["scaled_by"] = s * s
        out["text"] = (f"the residuals exceed the records' noise (noise scale {s:.2f}, "
                       f"chi-square tail probability {p:.1e}): model error; the intervals are "
                       f"widened by {s:.2f}")
    else:
        out["text"] = (f"residuals at the noise level (noise scale {s:.2f} on {dof:.0f} "
                       f"degrees of freedom, tail probability {p:.2f})")
    return out


def uncertainty(result: FitResult) -> Uncertainty:
    """Posterior standard errors, intervals, determined/prior-dominated flags, compliance."""
    pb = result.problem
    n_d = pb.used_mask().size
    used = pb.used_mask()
    r_d = result.residual[:n_d][used]
    j_d = result.jacobian[:n_d][used]
    p = pb.n_params
    prior_sigma = pb.prior_sigma
    info = j_d.T @ j_d
    if prior_sigma is not None:
        info = info + np.diag(1.0 / prior_sigma**2)
    w, v = np.linalg.eigh(info)
    # eigenvalues of the information are squared singular values
    max_std = NO_INFORMATION_STD if prior_sigma is None else None
    null = ~informative(np.sqrt(np.clip(w[::-1], 0.0, None)), max_std)[::-1]
    inv_w = np.where(null, 0.0, 1.0 / np.where(null, 1.0, w))
    info_inv = (v * inv_w[None, :]) @ v.T
    noise = _noise_check(pb, r_d, j_d, info_inv)
    factor, correlated = widening(pb, result.residual[:n_d], result.jacobian[:n_d], info_inv)
    noise["line_widening"] = factor.tolist()
    if correlated and noise["estimable"]:
        rho = ", ".join(f"{r:.2f} in {name}" for name, r in correlated.items())
        noise["text"] += (f"; neighbouring FRF lines' errors are correlated (lag-1 "
                          f"correlation {rho}): the intervals are widened by up to "
                          f"{float(factor.max()):.2f} x")
    cov = noise["scaled_by"] * (factor[:, None] * info_inv * factor[None, :])
    scaled_std = np.sqrt(np.abs(np.diag(cov)))
    if np.any(null):  # parameters touched by a direction without information
        touched = np.any(np.abs(v[:, null]) > 1e-3, axis=1)
        scaled_std = np.where(touched, np.inf, scaled_std)
    if not noise["estimable"]:
        scaled_std = np.full(p, np.inf)
    values = result.values
    log = pb.is_log
    std = np.where(log, values * scaled_std, scaled_std)
    with np.errstate(over="ignore", invalid="ignore"):
        lo = np.where(log, values * np.exp(-Z95 * scaled_std), values - Z95 * scaled_std)
        hi = np.where(log, values * np.exp(Z95 * scaled_std), values + Z95 * scaled_std)
    ci = np.stack([lo, hi], 1)
    ci[~np.isfinite(scaled_std)] = np.nan
    data_std = _data_only_std(j_d, noise["scaled_by"]) * factor
    if prior_sigma is not None:
        determined = data_std <= np.minimum(DETERMINED_RATIO * prior_sigma, IDENTIFIABLE_STD)
        share = np.clip(1.0 - (scaled_std / prior_sigma) ** 2, 0.0, 1.0)
    else:
        determined = data_std < IDENTIFIABLE_STD
        share = None
    fs = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(fs, fs)
    _, sv, vt = np.linalg.svd(j_d, full_matrices=False) if j_d.size else (None, np.ones(p),
                                                                          np.eye(p))
    with np.errstate(divide="ignore"):
        direction_std = np.sqrt(noise["scaled_by"]) / np.where(sv > 0, sv, 0.0)
    comp = {}
    cs, gs = compliance_and_gradient(jnp.asarray(result.theta), pb.fit_data, pb.structure)
    for k, s in enumerate(pb.speeds):
        c, g = float(cs[k]), np.asarray(gs[k])
        var = float(g @ cov @ g) if noise["estimable"] else float("inf")
        sd = float(np.sqrt(max(var, 0.0)))
        comp[f"{s:g}"] = dict(compliance_nm_per_n=float(c) * 1e9, std_nm_per_n=sd * 1e9,
                              stiffness_n_per_um=1e-6 / float(c),
                              relative_std=sd / abs(float(c)))
    return Uncertainty(pb.names, pb.units, values, std, ci, ["linearised"] * p, scaled_std,
                       prior_sigma, np.asarray(determined & noise["estimable"]), share, corr,
                       cov, sv, vt.T, direction_std, noise, comp)
