"""Check of the forecast: the lift-off force on the nonlinear orbits at each draw, by the
vmapped program that `bsfs predict` runs (`identification/_liftoff_draws.py`: the FRC
peak followed, a secant in the force), against the search at the estimate run afresh at
the draw (`_liftoff.search_on_orbits`: the peak located by continuation at every force,
about 10-20 s per draw on the 2-core machine).

Printed per joint: at how many of the draws the program converged (and why not), its
seconds, and over the first N draws the largest difference from the search afresh, in N
and as a fraction of the draws' 95 % range.

    python scripts/liftoff_draws_check.py --from ID_DIR [--force 100] [-n 10]
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bsfs_jax.cli._common import setup_jax  # noqa: E402

setup_jax()

import numpy as np  # noqa: E402

import identification as idn  # noqa: E402
from bsfs_jax.design import OrbitSettings  # noqa: E402
from bsfs_jax.machine import JOINTS  # noqa: E402
from identification._forecast_run import _band  # noqa: E402
from identification._liftoff import linear_liftoff, search_on_orbits  # noqa: E402
from identification._liftoff_draws import liftoff_at_draws  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", required=True, type=Path)
    ap.add_argument("-n", type=int, default=10)
    args = ap.parse_args(argv)
    ident = idn.load_identified(args.source)
    if ident.draws is None:
        print(f"{args.source}: no usable draws ({ident.draws_note})")
        return 1
    _, _, start, stop = _band(ident, OrbitSettings(), None, None)
    per_joint = linear_liftoff(ident, start, stop)[0]
    first = int(np.argmin([q.value for q in per_joint]))
    # the starts of `nonlinear_liftoff`: below the first joint's linearised value, above
    # the second's
    for k, (f0, f1) in ((first, (0.9, 0.95)), (1 - first, (1.0, 1.05))):
        joint, lin = JOINTS[k], per_joint[k].value
        f_star, hint, g_f, g_theta = search_on_orbits(ident, ident.theta, joint, f0 * lin,
                                                      f1 * lin, start, stop)
        grad = -g_theta / g_f
        t = time.perf_counter()
        out = liftoff_at_draws(ident, hint, f_star, grad, k, details=True)
        seconds = time.perf_counter() - t
        ok = out[:, 1] > 0.5
        print(f"{joint}: F* = {f_star:.4f} N at the estimate; the program converged at "
              f"{int(ok.sum())}/{len(ok)} draws in {seconds:.1f} s (first call); failed: "
              f"point not followed {int(np.sum(out[:, 2] < 0.5))}, secant not stopped "
              f"{int(np.sum((out[:, 2] > 0.5) & ~ok))}; secant steps "
              f"{np.bincount(out[:, 3].astype(int)).tolist()}", flush=True)
        width = np.subtract(*np.percentile(out[ok, 0], [97.5, 2.5]))
        diffs = []
        for i in range(min(args.n, len(ok))):
            pred = f_star + float(grad @ (ident.draws[i] - ident.theta))
            try:
                fresh = search_on_orbits(ident, ident.draws[i], joint, 0.99 * pred, pred,
                                         start, stop)[0]
            except Exception as exc:  # noqa: BLE001 - reported
                print(f"  draw {i}: the search afresh failed ({exc})")
                continue
            diffs.append(abs(out[i, 0] - fresh) if ok[i] else np.nan)
            print(f"  draw {i}: program {out[i, 0]:.5f} N ({'converged' if ok[i] else 'FAILED'}"
                  f"), afresh {fresh:.5f} N", flush=True)
        d = np.array(diffs)
        if not np.any(np.isfinite(d)):
            continue
        print(f"{joint}: largest difference {np.nanmax(d):.2g} N = "
              f"{np.nanmax(d) / width:.2g} of the 95 % range over the draws ({width:.3f} N)",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
