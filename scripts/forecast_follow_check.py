"""Check of the forecast: the FRC's peak and folds followed to the draws, against the same
points located afresh by continuation at each draw.

For an identification folder with saved draws (`bsfs identify`, refits.npz or
posterior.npz), the forecast's FRC at `--force` is continued at the estimate and its
peak and folds are followed to every draw in one batch (`bsfs_jax.design.follow_point`,
what `bsfs predict` does). At the first N draws the FRC is then continued afresh over
the same band and its peak and folds located again (`locate_peak`, about 3.5 s each on
the 2-core machine). Printed per quantity: the largest difference between the two, in
the quantity's unit and as a fraction of the followed values' 95 % range, and the 95 %
ranges over the N draws both ways.

    python scripts/forecast_follow_check.py --from ID_DIR [--force 100] [-n 40]
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
from bsfs_jax.design import OrbitSettings, point_hint  # noqa: E402
from identification._forecast_frc_draws import points_at_draws  # noqa: E402
from identification._forecast_run import _band, _folds, frc_settings, locate_peak  # noqa: E402
from identification._liftoff import linear_liftoff  # noqa: E402

NAMES = ("peak_frequency_hz", "peak_amplitude_um", "fold_up_hz", "fold_down_hz")


def located(branch):
    up, down = _folds(branch)
    return [branch.peak.p, branch.peak.amplitude * 1e6,
            np.nan if up is None else up.p, np.nan if down is None else down.p]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="source", required=True, type=Path)
    ap.add_argument("--force", type=float, default=100.0)
    ap.add_argument("-n", type=int, default=40)
    args = ap.parse_args(argv)
    ident = idn.load_identified(args.source)
    if ident.draws is None:
        print(f"{args.source}: no usable draws ({ident.draws_note})")
        return 1
    settings = OrbitSettings()
    _, _, start, stop = _band(ident, settings, None, None)
    settings = frc_settings(settings, args.force, linear_liftoff(ident, start, stop)[1][0])
    hint, branch = locate_peak(ident.params_at(ident.theta), args.force, start, stop,
                               settings)
    up, down = _folds(branch)
    hints = [hint] + [point_hint(f.point, branch) for f in (up, down) if f is not None]
    t = time.perf_counter()
    out = points_at_draws(ident, args.force, hints, [True] + [False] * (len(hints) - 1))
    print(f"{type(branch.method).__name__} branch at {args.force:g} N; followed "
          f"{len(hints)} points to {len(ident.draws)} {ident.draws_kind} in "
          f"{time.perf_counter() - t:.1f} s; not followed at "
          f"{int(np.sum(np.isnan(out[..., 1])))} (point, draw) pairs", flush=True)
    followed = np.full((len(ident.draws), 4), np.nan)
    followed[:, 0], followed[:, 1] = out[0, :, 1], out[0, :, 0] * 1e6
    for k in range(1, len(hints)):
        followed[:, k + 1] = out[k, :, 1]
    n = min(args.n, len(ident.draws))
    fresh = []
    t = time.perf_counter()
    for k in range(n):
        fresh.append(located(locate_peak(ident.params_at(ident.draws[k]), args.force, start,
                                         stop, settings)[1]))
        if (k + 1) % 10 == 0:
            print(f"located afresh at {k + 1}/{n} draws ({time.perf_counter() - t:.0f} s)",
                  flush=True)
    fresh = np.array(fresh)
    for j, name in enumerate(NAMES):
        f, a = followed[:n, j], fresh[:, j]
        both = np.isfinite(f) & np.isfinite(a)
        width = np.subtract(*np.percentile(followed[:, j], [97.5, 2.5]))
        if not np.any(np.isfinite(a)) and not np.any(np.isfinite(f)):
            print(f"{name}: no such point")
            continue
        diff = np.max(np.abs(f[both] - a[both])) if np.any(both) else np.nan
        print(f"{name}: followed and located at {int(np.sum(both))}/{n} draws (located only "
              f"{int(np.sum(np.isfinite(a) & ~np.isfinite(f)))}, followed only "
              f"{int(np.sum(np.isfinite(f) & ~np.isfinite(a)))}); largest difference "
              f"{diff:.3g} = {diff / width:.2g} of the 95 % range over all draws "
              f"({width:.4g}); 95 % range over these {n}: followed "
              f"{np.percentile(f[both], [2.5, 97.5]).round(4).tolist()}, located "
              f"{np.percentile(a[both], [2.5, 97.5]).round(4).tolist()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
