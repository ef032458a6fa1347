"""Model error of the forecast's modal quantities (docs/COVERAGE.md, the forecast's study).

For a few replicates of the bundled preload-loss design, the records are made again
without sensor noise (the same seeds, so the same phases, shaker distortion and drift;
`coverage_study.noise_free_data`, weighted with the noisy records' standard errors),
identified as `bsfs identify` does (PRELOAD_FIT, default prior) and the forecast's modal
quantities (natural frequency, damping ratio, static stiffness) computed on the estimate.
Their offsets from the truth's values, in units of the delta method's std, are the model
error that remains without noise; the reported value (a median where the second-order
check switched to the quadratic model) and the plug-in value are both printed, with the
fitted parameters' z.

    python scripts/forecast_noise_free.py              # replicates 0-3 (~1 min each)
    python scripts/forecast_noise_free.py 0 5 9        # these replicates
    python scripts/forecast_noise_free.py --noisy 0    # the noisy records instead

The truth's values come from out/forecast-coverage/100N_truth.json (written by
scripts/forecast_coverage.py; copy docs/data/forecast_coverage_100N_truth.json there).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from bsfs_jax.cli._common import setup_jax  # noqa: E402

setup_jax()

import numpy as np  # noqa: E402
from coverage_study import noise_free_data, synth_records, truth_params  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402

TRUTH = ROOT / "out" / "forecast-coverage" / "100N_truth.json"


def identified(data, prior):
    """`identify` on measurement data, as an `Identified` (what a forecast reads)."""
    from identification._report import check_model

    res = idn.fit(idn.Problem(data, prior, idn.PRELOAD_FIT), starts=3, model_check=False)
    res, branch = check_model(res)
    unc = idn.uncertainty(res)
    unc, lin = idn.profile_intervals(res, unc)
    ir = idn.IdentificationResult(res.problem, res, unc, data, 0.0, lin, branch)
    return ir, idn.identified_from_result(ir)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("replicates", nargs="*", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--noisy", action="store_true", help="the noisy records instead")
    args = ap.parse_args(argv)
    if not TRUTH.is_file():
        print(f"{TRUTH}: missing; run scripts/forecast_coverage.py first or copy "
              "docs/data/forecast_coverage_100N_truth.json there", file=sys.stderr)
        return 2
    from identification._forecast_run import _modal

    truth, prior = truth_params(), bsfs_jax.preset()
    tv = json.loads(TRUTH.read_text())
    for k in args.replicates:
        data = ([idn.measurement_data(r) for r in synth_records(truth, k, {})] if args.noisy
                else noise_free_data(truth, k, {}))
        ir, ident = identified(data, prior)
        quantities, _ = _modal(ident)
        row = {}
        for q in quantities:
            sd = q.extra["std"]
            plug = q.extra.get("plug_in", q.value)
            row[q.name] = dict(z=(q.value - tv[q.name]) / sd,
                               z_plug_in=(plug - tv[q.name]) / sd, method=q.method)
        u, pb = ir.uncertainty, ir.problem
        zp = {n: float(np.log(v / float(np.asarray(truth.get(key)))) / s)
              for n, key, v, s in zip(pb.names, pb.keys, u.values, u.scaled_std)}
        print(json.dumps(dict(replicate=k, records="noisy" if args.noisy else "noise-free",
                              quantities=row, parameters_z=zp)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
