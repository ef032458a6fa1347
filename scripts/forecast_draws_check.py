"""The forecast's modal quantities three ways, on one identification with posterior draws.

    bsfs identify --data preload-loss --fit nut_preload,bearing_preload,c_b,c_s,c_n \
        --posterior 500 --out out/pl_post
    python scripts/forecast_draws_check.py --from out/pl_post

For each of f1, the damping ratio and the static stiffness it prints:
- what `bsfs predict` reports with the identification's NUTS draws and without them
  (Gaussian draws of the Laplace covariance; the method, the value, the interval, the
  delta std and the second-order ratio that chose the quadratic model);
- the exact model over the NUTS draws and over Gaussian draws: median, 2.5-97.5 %, std.

The NUTS draws follow the posterior's own shape; the Gaussian ones are the Laplace
approximation in the fitted coordinates (log-values). Where the data pin a combination of
parameters along a curved valley (the damping ratio: a sum of exponentials of the log
dampers), the Gaussian's straight valley crosses the quantity's level sets, and its draws
spread and shift the quantity where the posterior does not (docs/COVERAGE.md, 2026-11-27).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

NAMES = ("natural_frequency_1_hz", "damping_ratio_1", "static_stiffness_n_per_um")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="folder", type=Path, required=True,
                    help="a `bsfs identify --posterior N --out DIR` folder")
    ap.add_argument("--gaussian-draws", type=int, default=2000)
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import bsfs_jax
    from identification._forecast import load_identified
    from identification._forecast_run import forecast_modal

    ident = load_identified(args.folder)
    if ident.draws is None:
        print(f"{args.folder}: no usable posterior draws ({ident.draws_note}); run "
              "`bsfs identify --posterior N` first", file=sys.stderr)
        return 2
    for label, idd in (("predict, NUTS draws", ident),
                       ("predict, Gaussian draws", dataclasses.replace(ident, draws=None))):
        for q in forecast_modal(idd)["quantities"]:
            if q.name in NAMES:
                print(f"{label:<26}{q.name:<28}{q.value:.7g}  [{q.ci95[0]:.7g}, "
                      f"{q.ci95[1]:.7g}]  {q.method}; delta std {q.extra['std']:.3g}, "
                      f"second order {q.extra['second_order']:.2f}")
    coords = ident.coordinates

    def quantities(th):
        m = bsfs_jax.modes(bsfs_jax.build_system(coords.at(th)))
        return jnp.stack([m.frequencies_hz[0], m.damping_ratios[0],
                          m.static_stiffness * 1e-6])  # N/um, as the forecast reports it

    program = jax.jit(jax.vmap(quantities))
    rng = np.random.default_rng(0)
    gauss = rng.multivariate_normal(ident.theta, ident.covariance, size=args.gaussian_draws,
                                    method="eigh")
    plug_in = np.asarray(quantities(jnp.asarray(ident.theta)))
    for label, draws in (("model, NUTS draws", ident.draws), ("model, Gaussian draws", gauss)):
        q = np.asarray(program(jnp.asarray(draws)))
        for k, name in enumerate(NAMES):
            lo, med, hi = np.percentile(q[:, k], [2.5, 50, 97.5])
            print(f"{label:<26}{name:<28}{med:.7g}  [{lo:.7g}, {hi:.7g}]  std "
                  f"{q[:, k].std():.3g}; plug-in {plug_in[k]:.7g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
