"""The forecast's lift-off forces against the other orbit method.

`bsfs predict` finds each joint's lift-off force on harmonic-balance orbits at the FRC
peak. This script takes those forces for an identification folder and evaluates each
joint's smallest contact deformation at the located peak again with the FRC continued by
shooting, 2 % below and above the force: the orbits should be closed below and open
above. It also prints the deformation at the force itself by both methods, and the force
error that their difference implies (difference / d(deformation)/d(force)).

    python scripts/liftoff_shooting_check.py --from out/preload-loss   # ~2 min, 2 cores
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bsfs_jax.cli._common import setup_jax  # noqa: E402

setup_jax()

import identification as idn  # noqa: E402
from bsfs_jax.design import OrbitSettings  # noqa: E402
from identification._forecast import locate_peak  # noqa: E402
from identification._forecast_run import _band  # noqa: E402
from identification._liftoff import (  # noqa: E402
    LIFTOFF_HARMONICS,
    LIFTOFF_SETTINGS_TOL,
    min_deformation,
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--from", dest="folder", required=True, help="bsfs identify --out DIR")
    args = ap.parse_args(argv)
    ident = idn.load_identified(args.folder)
    fc = idn.forecast_liftoff(ident)
    lo, hi = _band(ident, OrbitSettings(), None, None)[2:]
    params = ident.params_at(ident.theta)
    methods = {"hb": OrbitSettings(frc_method="hb", frc_tol=LIFTOFF_SETTINGS_TOL,
                                   frc_harmonics=LIFTOFF_HARMONICS),
               "shooting": OrbitSettings(frc_method="shooting")}
    for q in fc["per_joint_liftoff"]:
        joint = q.name.split("_")[2]
        if q.value is None:
            print(f"{joint}: not determined ({q.reason})")
            continue
        f_star = q.extra.get("plug_in", q.value)
        print(f"{joint}: lift-off {f_star:.3f} N (linearised {q.extra['linearised_n']:.3f} N, "
              f"95 % interval {q.ci95[0]:.2f}-{q.ci95[1]:.2f} N)")
        at = {}
        for name, settings in methods.items():
            hint, _ = locate_peak(params, f_star, lo, hi, settings)
            m, (_, g_f) = min_deformation(ident.coordinates, ident.theta, f_star, hint, joint)
            at[name] = (float(m), float(g_f))
            print(f"  {name:8s} at {f_star:.3f} N: smallest deformation {float(m) * 1e6:+.5f} um")
        (m_hb, _), (m_sh, g_sh) = at["hb"], at["shooting"]
        print(f"  methods differ by {abs(m_hb - m_sh) * 1e6:.5f} um: "
              f"{abs(m_hb - m_sh) / abs(g_sh):.4f} N in force")
        for factor in (0.98, 1.02):
            hint, _ = locate_peak(params, factor * f_star, lo, hi, methods["shooting"])
            m, _ = min_deformation(ident.coordinates, ident.theta, factor * f_star, hint,
                                   joint)
            state = "closed" if float(m) > 0 else "open"
            print(f"  shooting at {factor:.2f} x: {float(m) * 1e6:+.5f} um ({state})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
