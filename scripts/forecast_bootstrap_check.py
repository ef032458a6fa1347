"""Diagnostic of the forecast: the quadratic model's median shift, over Gaussian draws and over
data-domain bootstrap refits, against the exact refits.

The bundled preload-loss test is identified (PRELOAD_FIT); its fit data get Gaussian
noise at their stated standard errors and the prior's centre a draw from the prior (the
randomised-maximum-likelihood refits `bsfs identify --refits` saves,
`identification._refits.perturbed`), and N refits from the estimate run as one batched
optimistix solve (`identification.refit`). For the first natural frequency, the
damping ratio and the static stiffness (exact value, gradient and Hessian in the fitted
coordinates) it prints, in the delta method's standard deviations:

- the median shift and the 95 % width of value + g.delta + delta.H.delta / 2 with delta
  drawn from the covariance (what `bsfs predict` reports where its second-order check
  fires and no posterior draws are saved);
- the same with delta = the refits' offsets from the estimate;
- the exact quantity over the refits.

    python scripts/forecast_bootstrap_check.py [N]      # N refits (default 400, ~1 min)
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import identification as idn  # noqa: E402
from identification._forecast import identified_from_result  # noqa: E402
from identification._forecast_modal import _modal_program  # noqa: E402

NAMES = ("natural_frequency_1_hz", "damping_ratio_1", "static_stiffness")


def main(n: int) -> None:
    res = idn.identify(idn.bundled_records("preload-loss"), None, idn.PRELOAD_FIT,
                       starts=3, profile=False)
    theta = np.asarray(res.fit.theta)
    ident = identified_from_result(res)
    v, jac, hess = (np.asarray(a) for a in _modal_program(ident.coordinates,
                                                          jnp.asarray(theta)))
    cov = ident.covariance
    sd = np.sqrt(np.diag(jac @ cov @ jac.T))
    refits = idn.refit(res, n, seed=1)
    print(f"{n} refits in {refits.seconds:.1f} s, {refits.converged} converged")
    boot = refits.theta
    exact = np.array([np.asarray(_modal_program(ident.coordinates, jnp.asarray(th))[0])
                      for th in boot])
    gauss = np.random.default_rng(7).multivariate_normal(np.zeros(theta.size), cov,
                                                         size=4000, method="eigh")
    for k, name in enumerate(NAMES):
        for label, d in (("Gaussian draws", gauss), ("bootstrap refits", boot - theta)):
            q = v[k] + d @ jac[k] + 0.5 * np.einsum("ni,ij,nj->n", d, hess[k], d)
            lo, med, hi = np.percentile(q, [2.5, 50, 97.5])
            print(f"{name}, quadratic model over {label}: median shift "
                  f"{(med - v[k]) / sd[k]:+.3f} sd, 95 % width {(hi - lo) / (3.92 * sd[k]):.3f}"
                  " of the delta method's")
        lo, med, hi = np.percentile(exact[:, k], [2.5, 50, 97.5])
        print(f"{name}, exact over the refits: median shift {(med - v[k]) / sd[k]:+.3f} sd, "
              f"95 % width {(hi - lo) / (3.92 * sd[k]):.3f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 400)
