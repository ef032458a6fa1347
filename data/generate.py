"""Regenerate the bundled SYNTHETIC exciter records from data/truth.toml (seeded).

    python data/generate.py            # both sets (a few minutes on 2 CPU cores)
    python data/generate.py --only paper-test

Every record is the full nonlinear model (Eq. 31) driven by a distorted, drifting shaker force,
passed through an anti-alias filter, decimated to 10.24 kHz, offset and made noisy
(identification/_synth.py). See data/README.md.
"""

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import bsfs_jax  # noqa: E402
from identification import synthesize, write_record_csv  # noqa: E402

FS = 10240.0
# (set, file stem, frequency [Hz], force [N], speed [r/min], duration [s])
PLAN = [("paper-test", f"paper_{f}hz", float(f), 100.0, 2000.0, 2.0) for f in (100, 120, 150)]
PLAN += [("stepped-sine", f"sine_{f:04d}hz_100n_2000rpm", float(f), 100.0, 2000.0, 0.5)
         for f in (100, 150, 250, 400, 600, 800, 950, 1050, 1150, 1300, 1700, 2500)]
PLAN += [("stepped-sine", f"sine_{f:04d}hz_3000n_2000rpm", float(f), 3000.0, 2000.0, 0.5)
         for f in (150, 300)]
PLAN += [("stepped-sine", f"sine_{f:04d}hz_100n_{rpm}rpm", float(f), 100.0, float(rpm), 0.5)
         for rpm in (1000, 3000) for f in (150, 950)]
# The worn drive (data/worn.toml): a few stepped sines away from the resonance and one
# low-level chirp through it (the preload-loss diagnosis example).
WORN = [("preload-loss", f"sine_{f:04d}hz_100n", float(f), 100.0, 2000.0, 0.5)
        for f in (150, 400, 700, 1700, 2500)]
CHIRP = ("preload-loss", "chirp_50-2500hz_5n", 5.0, 2000.0, 1.0, 50.0, 2500.0)
# A drive with smaller preload losses (data/resonance.toml; first resonance 1128 Hz at
# 2000 r/min) tested through its resonance: stepped sines at 100 N from 150 Hz
# up, two of them within -5 % / +3 % of the resonance, two sines at 3000 N and a chirp.
RESONANCE = [("resonance", f"sine_{f:04d}hz_{n:.0f}n", float(f), float(n), 2000.0, 0.5)
             for f, n in ((150, 100), (400, 100), (700, 100), (950, 100), (1070, 100),
                          (1160, 100), (1400, 100), (2000, 100), (150, 3000), (300, 3000))]
RESONANCE_CHIRP = ("resonance", "chirp_50-2500hz_5n", 5.0, 2000.0, 1.0, 50.0, 2500.0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=["paper-test", "stepped-sine", "preload-loss",
                                       "resonance"])
    args = ap.parse_args(argv)
    truth = bsfs_jax.load_params(HERE / "truth.toml")
    for seed, (group, stem, f, force, rpm, dur) in enumerate(PLAN):
        if args.only and group != args.only:
            continue
        params = truth.replace("thermal.speed_rpm", rpm)
        rec = synthesize(params, f, force, duration_s=dur, sample_rate_hz=FS, seed=1000 + seed)
        rec.meta["source"] = "synthetic: data/generate.py from data/truth.toml"
        path = write_record_csv(HERE / group / f"{stem}.csv", rec, digits=5)
        print(f"{path.relative_to(HERE)}: {rec.summary()}", flush=True)
    if args.only in (None, "resonance"):
        _drive_set(HERE / "resonance.toml", RESONANCE, RESONANCE_CHIRP, 3000)
    if args.only not in (None, "preload-loss"):
        return
    _drive_set(HERE / "worn.toml", WORN, CHIRP, 2000)


def _drive_set(truth_file, sines, chirp, seed0):
    """One drive's records: the sines (seeds seed0 + k) and the chirp (seed0 + 100)."""
    truth = bsfs_jax.load_params(truth_file)
    source = f"synthetic: data/generate.py from data/{truth_file.name}"
    for seed, (group, stem, f, force, rpm, dur) in enumerate(sines):
        (HERE / group).mkdir(exist_ok=True)
        rec = synthesize(truth.replace("thermal.speed_rpm", rpm), f, force, duration_s=dur,
                         sample_rate_hz=FS, seed=seed0 + seed)
        rec.meta["source"] = source
        path = write_record_csv(HERE / group / f"{stem}.csv", rec, digits=5)
        print(f"{path.relative_to(HERE)}: {rec.summary()}", flush=True)
    group, stem, force, rpm, dur, start, stop = chirp
    rec = synthesize(truth.replace("thermal.speed_rpm", rpm), None, force, duration_s=dur,
                     sample_rate_hz=FS, seed=seed0 + 100, excitation="chirp", start_hz=start,
                     stop_hz=stop)
    rec.meta["source"] = source
    path = write_record_csv(HERE / group / f"{stem}.csv", rec, digits=5)
    print(f"{path.relative_to(HERE)}: {rec.summary()}", flush=True)


if __name__ == "__main__":
    main()
