"""Posterior samples by NUTS (blackjax), as a check on the linearised intervals.

The linearised covariance (`_uncertainty.py`) and the profile likelihood (`_profile.py`)
describe the posterior near its mode. Where the posterior is skewed or curved (parameters
the data barely determine, a prior-dominated direction leaning on a determined one), a
sample of the posterior itself says how far those intervals can be trusted. This module
draws it with the No-U-Turn sampler in the fit's own coordinates theta (log-values, offsets
in um), where the posterior is closest to Gaussian:

    log p(theta | data) = -1/2 |r_data(theta)|^2 / s - 1/2 |theta / sigma|^2 + const

with r_data the noise-weighted data residual, s the noise-scale factor the uncertainty
applied (1 unless the chi-square check widened the intervals) and sigma the priors (the
sampler needs them: without priors an undetermined direction is an improper posterior).

The sampler runs in whitened coordinates w, theta = theta_hat + L w with L L^T the linearised
covariance. Chains start at w ~ N(0, I); each runs its own window adaptation (step size and
diagonal mass matrix), then draws `samples` states. The
evidence reported with the result: split R-hat (Gelman-Rubin) and bulk effective sample
size per parameter, and the count of divergent transitions. The sample is *converged* when
every R-hat < 1.01, every ESS >= 100 per chain and nothing diverged (the thresholds of
Vehtari et al. 2021); otherwise the report says "not converged" and the intervals are not
used for anything.

The orbit model is differentiated in forward mode only (`ImplicitForward`), so problems
with periodic-orbit records are refused; linear and first-order records are plain JAX.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..measurement import require_x64, residual

RHAT_MAX = 1.01
ESS_PER_CHAIN_MIN = 100
MIN_DRAWS = 100  # warm-up steps and draws per chain, at least


@dataclasses.dataclass
class Posterior:
    names: tuple
    units: tuple
    samples: np.ndarray  # (chains, draws, p) file-unit values
    mean: np.ndarray
    std: np.ndarray
    ci95: np.ndarray  # (p, 2) 2.5 and 97.5 percentiles
    rhat: np.ndarray
    ess: np.ndarray
    divergences: int
    converged: bool
    seconds: float

    def as_dict(self) -> dict:
        return dict(
            method="NUTS (blackjax) in log-parameters with window adaptation; "
                   f"{self.samples.shape[0]} chains x {self.samples.shape[1]} draws",
            converged=self.converged,
            criteria=f"split R-hat < {RHAT_MAX}, bulk ESS >= {ESS_PER_CHAIN_MIN} per chain, "
                     "no divergent transitions",
            divergences=self.divergences, seconds=self.seconds,
            parameters={n: dict(mean=float(self.mean[i]), std=float(self.std[i]),
                                ci95=[float(x) for x in self.ci95[i]],
                                rhat=float(self.rhat[i]), ess=float(self.ess[i]),
                                unit=self.units[i])
                        for i, n in enumerate(self.names)})


def posterior(result, unc, *, samples: int = 1000, warmup: int = 500, chains: int = 4,
              seed: int = 0) -> Posterior:
    """NUTS sample of the fit's posterior (see the module docstring).

    `result`: a `FitResult`; `unc`: its `Uncertainty` (start jitter, noise scale).
    Raises ValueError where the sampler cannot apply (no priors, periodic-orbit records).
    """
    require_x64("identification.posterior")
    from blackjax.diagnostics import effective_sample_size, potential_scale_reduction

    pb = result.problem
    if pb.prior_sigma is None:
        raise ValueError("the posterior sample needs priors (without them an undetermined "
                         "parameter has an improper posterior); drop --no-priors")
    if "nonlinear" in pb.models:
        raise ValueError("the posterior sample needs records on the linear or first-order "
                         "model; periodic-orbit records are differentiated in forward mode "
                         "only")
    if samples < MIN_DRAWS or warmup < MIN_DRAWS or chains < 2:
        raise ValueError(f"use at least 2 chains, {MIN_DRAWS} warm-up steps and "
                         f"{MIN_DRAWS} draws per chain")
    t0 = time.perf_counter()
    scale = float(unc.noise.get("scaled_by", 1.0))

    # Whitened coordinates: theta = theta_hat + L w with L L^T the linearised covariance, so
    # that a near-Gaussian posterior is near N(0, I) whatever its correlations (the paper
    # test's compliance direction is 1e4 times narrower than its prior-dominated ones).
    cov = np.asarray(unc.covariance)
    chol = jnp.asarray(np.linalg.cholesky(cov + 1e-12 * np.eye(cov.shape[0])
                                          * np.max(np.diag(cov))))
    centre = jnp.asarray(result.theta)

    rng = np.random.default_rng(seed)
    starts = rng.normal(size=(chains, cov.shape[0]))
    keys = jax.random.split(jax.random.PRNGKey(seed), chains)
    pos, div = _run(keys, jnp.asarray(starts), centre, chol, jnp.asarray(scale), pb.fit_data,
                    pb.structure, warmup, samples)
    theta = np.asarray(result.theta)[None, None, :] + np.asarray(pos) @ np.asarray(chol).T
    rhat = np.asarray(potential_scale_reduction(jnp.asarray(theta), chain_axis=0,
                                                sample_axis=1))
    ess = np.asarray(effective_sample_size(jnp.asarray(theta), chain_axis=0, sample_axis=1))
    values = np.asarray(pb.values(theta.reshape(-1, theta.shape[-1]))).reshape(theta.shape)
    flat = values.reshape(-1, values.shape[-1])
    divergences = int(np.sum(np.asarray(div)))
    converged = bool(np.all(rhat < RHAT_MAX) and np.all(ess >= ESS_PER_CHAIN_MIN * chains)
                     and divergences == 0)
    return Posterior(pb.names, pb.units, values, flat.mean(0), flat.std(0, ddof=1),
                     np.percentile(flat, [2.5, 97.5], axis=0).T, rhat, ess, divergences,
                     converged, time.perf_counter() - t0)


@eqx.filter_jit
def _run(keys, starts, centre, chol, scale, fit_data, structure, warmup: int, samples: int):
    """Every chain's adaptation and draws in one program; the fit's data, the centre, the
    whitening and the noise scale are traced, so it compiles once per layout."""
    import blackjax

    p = centre.shape[0]

    def logdensity(w):
        r = residual(centre + chol @ w, fit_data, structure)
        return -0.5 * (jnp.sum(r[:-p] ** 2) / scale + jnp.sum(r[-p:] ** 2))

    def one(key, start):
        k_warm, k_draw = jax.random.split(key)
        adapt = blackjax.window_adaptation(blackjax.nuts, logdensity, initial_step_size=0.5,
                                           target_acceptance_rate=0.95)
        (state, params), _ = adapt.run(k_warm, start, num_steps=warmup)
        kernel = blackjax.nuts(logdensity, **params).step

        def step(state, key):
            state, info = kernel(key, state)
            return state, (state.position, info.is_divergent)

        _, (pos, div) = jax.lax.scan(step, state, jax.random.split(k_draw, samples))
        return pos, div

    return jax.vmap(one)(keys, starts)


def posterior_text(post: dict, report: dict) -> str:
    """Summary lines: the sample's evidence, and how its 95 % intervals compare with the
    report's (largest relative difference of an interval end)."""
    head = (f"Posterior by NUTS ({post['method'].split('; ')[-1]}, {post['seconds']:.0f} s): ")
    rhat = max(p["rhat"] for p in post["parameters"].values())
    ess = min(p["ess"] for p in post["parameters"].values())
    evidence = (f"largest R-hat {rhat:.3f}, smallest effective sample size {ess:.0f}, "
                f"{post['divergences']} divergent transitions")
    if not post["converged"]:
        return head + f"NOT converged ({evidence}; needs {post['criteria']}): not used."
    diffs = []
    for name, p in post["parameters"].items():
        ci = report["parameters"][name]["ci95"]
        if ci and None not in ci and all(np.isfinite(ci)):
            diffs.append((max(abs(a - b) / max(abs(b), 1e-300) for a, b in zip(p["ci95"], ci)),
                          name))
    worst = max(diffs) if diffs else None
    agree = ("" if worst is None else
             f"; its 95 % intervals differ from the reported ones by at most "
             f"{100 * worst[0]:.1f} % ({worst[1]})")
    return head + f"converged ({evidence}){agree}."
