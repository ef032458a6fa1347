"""Gauss-Newton uncertainty, correlations and identifiability of a fit.

With noise-weighted residuals r(theta) and Jacobian J at the optimum, the covariance of the
scaled parameters (log-values, offsets in um) is s^2 (J^T J)^-1 with the noise variance
estimated from the fit, s^2 = |r|^2 / (n - p). It is computed through the SVD
J = U S V^T: a direction v_i of the scaled parameters is determined to sqrt(s^2) / S_i, so
tiny singular values name the combinations the data cannot determine.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax

from ._fit import FitResult
from ._measurement import receptance

NULL_RTOL = 1e-12
IDENTIFIABLE_STD = 0.1  # a combination counts as identified if its std < 0.1 (10 % / 0.1 um)


@dataclasses.dataclass
class Uncertainty:
    names: tuple
    units: tuple
    values: np.ndarray
    std: np.ndarray  # file units
    ci95: np.ndarray  # (p, 2) file units
    scaled_std: np.ndarray  # std of log-value (relative) or of the offset [um]
    correlation: np.ndarray
    singular_values: np.ndarray  # of the scaled Jacobian, descending
    directions: np.ndarray  # (p, p) columns: right singular vectors
    direction_std: np.ndarray  # std of each direction's combination
    noise_scale: float  # s = sqrt(|r|^2 / (n - p)); about 1 when the noise model holds
    dof: int
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


def _log_jacobian_scale(problem, theta):
    """d(scaled value)/d theta: sech^2(theta / b) for both transforms."""
    from ._fit import LOG_BOUND_FACTOR, OFFSET_BOUND_UM

    log = np.asarray([t == "log" for t in problem.transforms])
    b = np.where(log, np.log(LOG_BOUND_FACTOR), OFFSET_BOUND_UM)
    return 1.0 / np.cosh(np.asarray(theta) / b) ** 2


def static_compliance(problem, theta, speed):
    """Static compliance at the nut x_n / P [m/N] for the fitted parameters at `speed`."""
    system = bsfs_jax.build_system(problem.params_at(theta, speed))
    return jnp.real(receptance(system, jnp.zeros(1))[0, 2])


@eqx.filter_jit
def _compliance_jit(box, theta):
    return jax.value_and_grad(lambda th: static_compliance(box.problem, th, box.speed))(theta)


class _Box(eqx.Module):
    problem: object = eqx.field(static=True)
    speed: float = eqx.field(static=True)


def _compliance_grad(problem, theta, speed):
    return _compliance_jit(_Box(problem, float(speed)), theta)


def uncertainty(result: FitResult) -> Uncertainty:
    """Standard errors, 95 % intervals, correlations and identifiability of a `FitResult`."""
    problem = result.problem
    r, jac = result.residual, result.jacobian
    used = problem.used_mask()
    r, jac = r[used], jac[used]
    n, p = jac.shape
    dof = max(n - p, 1)
    s2 = float(r @ r) / dof
    d = _log_jacobian_scale(problem, result.theta)
    js = jac / d[None, :]  # Jacobian w.r.t. the scaled parameters (log-value / um)
    _, sv, vt = np.linalg.svd(js, full_matrices=False)
    # Directions below NULL_RTOL are numerically null (round-off level): the data carry no
    # information on them at all. They get infinite variance; quantities orthogonal to them
    # in exact arithmetic (e.g. the compliance) are propagated through the others only.
    null = sv <= sv[0] * NULL_RTOL
    inv_sv2 = np.where(null, 0.0, 1.0 / np.where(null, 1.0, sv) ** 2)
    cov = s2 * (vt.T * inv_sv2[None, :]) @ vt
    cov_finite = cov.copy()
    if np.any(null):
        touched = np.any(np.abs(vt[null]) > 1e-3, axis=0)
        cov[touched, :] = np.inf
        cov[:, touched] = np.inf
    scaled_std = np.sqrt(np.abs(np.diag(cov)))
    values = result.values
    log = np.asarray([t == "log" for t in problem.transforms])
    std = np.where(log, values * scaled_std, scaled_std)
    with np.errstate(over="ignore", invalid="ignore"):
        lo = np.where(log, values * np.exp(-1.96 * scaled_std), values - 1.96 * scaled_std)
        hi = np.where(log, values * np.exp(1.96 * scaled_std), values + 1.96 * scaled_std)
    fs = np.sqrt(np.abs(np.diag(cov_finite)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_finite / np.outer(fs, fs)
    direction_std = np.sqrt(s2) / np.where(sv > 0, sv, np.nan)
    # Series compliance with its standard error, per speed (gradient through the model).
    comp = {}
    theta = jnp.asarray(result.theta)
    cov_theta = cov_finite / np.outer(d, d)
    for s in problem.speeds:
        c, g = _compliance_grad(problem, theta, s)
        g = np.asarray(g)
        var = float(g @ cov_theta @ g)
        comp[f"{s:g}"] = dict(compliance_nm_per_n=float(c) * 1e9,
                              std_nm_per_n=float(np.sqrt(max(var, 0.0))) * 1e9,
                              stiffness_n_per_um=1e-6 / float(c),
                              relative_std=float(np.sqrt(max(var, 0.0)) / abs(float(c))))
    return Uncertainty(problem.names, problem.units, values, std, np.stack([lo, hi], 1),
                       scaled_std, corr, sv, vt.T, direction_std, float(np.sqrt(s2)), dof, comp)
