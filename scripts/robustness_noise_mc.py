"""Are a record's weights honest? Sensor noise replicated on one record at the truth.

For a drive of `robustness_study.py` (same seeds) the problem is built as in
`robustness_step_check.py` (models chosen at the truth). One record is then synthesised
again without sensor noise (the same phases, distortion and drift) and replicated with
new sensor noise at the study's 40 dB, as `identification.synthesize` adds it; each
replicate goes through the measurement pipeline (`measurement_data`: frequency refinement,
harmonic fit, weights) and its weighted residual at the truth is computed with the
problem's own model. Honest weights give that residual the identity covariance, and each
parameter's part of the Gauss-Newton step, (C J_r^T w)_i / sd_i, the variance of the
record's information share (diag(C J_r^T J_r C) / sd^2): the printed ratio is 1. The
mean of the part over the replicates, in its own standard deviations, is the record's
model error at the truth (0 for an exact model).

    python scripts/robustness_noise_mc.py --drive 16 --record 5            # sine at 0.95 f1
    python scripts/robustness_noise_mc.py --drive 16 --record 5 --noise force
    python scripts/robustness_noise_mc.py --drive 16 --record 0            # the chirp
    python scripts/robustness_noise_mc.py --drives 40 --record all --replicates 15
                          # every record at once: the records' part of the step per drive

Records: 0 the chirp, 1-8 the 100 N sines at robustness_study.RATIOS x f1, 9-10 the
3000 N sines. `--noise force` / `acc` replicates one sensor's noise only (the other
sensor's weight is then about zero). Docs: docs/ROBUSTNESS.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import robustness_study as rs  # noqa: E402
from robustness_step_check import problem_at_truth  # noqa: E402

import identification as idn  # noqa: E402
from identification import _model  # noqa: E402
from identification._groups import sine_variance  # noqa: E402


def _problem_at_truth(drive: int, draw: str):
    pb, theta, params = problem_at_truth(drive, draw)
    _, jac = pb.rj(theta)
    cov = np.linalg.inv(jac.T @ jac)
    clean, _ = rs.synth(params, drive, dataclasses.replace(rs.EFFECTS, accel_snr_db=300.0,
                                                           force_snr_db=300.0))
    return pb, theta, jac, cov, clean


def _sine_residual(pb, theta, i):
    """w(HarmonicData) for sine record i: its weighted residual at theta, (Re rows, Im rows)
    of the used harmonics, with the problem's model driven by the replicate's force."""
    fd, st = pb.fit_data, pb.structure
    gi, _, _, sel = pb.layout[i]
    j, g = int(sel), fd.groups[gi]

    @jax.jit
    def weighted(freq, force, acc, scale, rate, rate2):
        new = [jnp.asarray(getattr(g, k)).at[j].set(v) for k, v in (
            ("sine_freq", freq), ("sine_force", force), ("sine_acc", acc),
            ("sine_scale", scale), ("sine_rate", rate), ("sine_rate2", rate2))]
        gg = eqx.tree_at(lambda q: (q.sine_freq, q.sine_force, q.sine_acc, q.sine_scale,
                                    q.sine_rate, q.sine_rate2), g, tuple(new))
        groups = list(fd.groups)
        groups[gi] = gg
        data = eqx.tree_at(lambda q: q.groups, fd, type(fd.groups)(groups))
        d = acc - _model.predict(jnp.asarray(theta), data, st)[gi][0][j]
        return jnp.concatenate([jnp.real(d) / scale[:, 0], jnp.imag(d) / scale[:, 1]])

    def w(d):
        var = sine_variance(pb, i, d)
        freq = d.frequency_hz * d.harmonics
        scale = np.where((freq <= pb.max_harmonic_hz)[:, None], np.sqrt(var), np.inf)
        zero = np.zeros(freq.size, complex)
        rate = zero if d.force_rate is None else d.force_rate
        rate2 = zero if d.force_rate2 is None else d.force_rate2
        out = np.asarray(weighted(freq, d.force, d.acceleration, scale, rate, rate2))
        ok = np.concatenate([np.isfinite(scale[:, 0]), np.isfinite(scale[:, 1])])
        return out[ok], None

    return w


def _frf_residual(pb, theta, i):
    """w(FRFData) for FRF record i: the weighted residual of the lines the problem uses
    that the replicate has too (line selection depends on the data), and their rows."""
    model = np.asarray(pb.model_harmonics(theta)[i])
    f0 = np.asarray(pb.data[i].frequency_hz)
    keep = ~np.asarray(pb.frf_left_out.get(i, np.zeros(f0.size, bool)))
    row = np.cumsum(keep) - 1
    n = int(keep.sum())

    def w(d):
        pos = {round(float(x), 6): k for k, x in enumerate(np.asarray(d.frequency_hz))}
        idx = [k for k in range(f0.size) if keep[k] and round(float(f0[k]), 6) in pos]
        ri = [pos[round(float(f0[k]), 6)] for k in idx]
        h, v = np.asarray(d.accelerance)[ri], np.asarray(d.variance)[ri]
        out = np.concatenate([np.real(h - model[idx]) / np.sqrt(v[:, 0]),
                              np.imag(h - model[idx]) / np.sqrt(v[:, 1])])
        return out, np.concatenate([row[idx], n + row[idx]])

    return w


def replicate(drive: int, record: int, replicates: int, noise: str = "both",
              draw: str = "uniform", seed: int = 1) -> dict:
    pb, theta, jac, cov, clean = _problem_at_truth(drive, draw)
    sd = np.sqrt(np.diag(cov))
    rows = pb.record_slices()[record]
    jr = jac[rows][pb.used_mask()[rows]]
    is_frf = pb.layout[record][1] == 1
    w_of = (_frf_residual if is_frf else _sine_residual)(pb, theta, record)
    c = clean[record]
    rng = np.random.default_rng(seed)
    parts, z2, ws = [], [], []
    for _ in range(replicates):
        w, sub = w_of(idn.measurement_data(_noisy(c, rng, noise)))
        j = jr if sub is None else jr[sub]
        share = np.diag(cov @ j.T @ j @ cov) / sd ** 2
        parts.append(cov @ j.T @ w / sd / np.sqrt(share))
        z2.append(float(np.mean(w ** 2)))
        ws.append(w)
    parts = np.asarray(parts)
    out = dict(drive=drive, record=record, name=pb.data[record].name,
               model=pb.models[record], noise=noise, replicates=replicates,
               mean_z2=float(np.mean(z2)), names=list(pb.names),
               ratio=[float(x) for x in parts.var(axis=0)],
               part_mean=[float(x) for x in parts.mean(axis=0)])
    if not is_frf:
        m = np.cov(np.asarray(ws).T)
        out["cov_eigenvalues"] = [float(x) for x in np.linalg.eigvalsh(np.atleast_2d(m))]
        out["residual_mean"] = [float(x) for x in np.mean(ws, axis=0)]
    return out


def _noisy(c, rng, noise: str = "both"):
    """Record `c` (noise-free) with new sensor noise at the study's SNR, as `synthesize`
    adds it."""
    rms = lambda x: float(np.sqrt(np.mean((x - np.mean(x)) ** 2)))
    s_f = rms(c.force) * 10 ** (-rs.EFFECTS.force_snr_db / 20) * (noise != "acc")
    s_a = rms(c.acceleration) * 10 ** (-rs.EFFECTS.accel_snr_db / 20) * (noise != "force")
    return dataclasses.replace(c, force=c.force + rng.normal(0, s_f, c.force.size),
                               acceleration=c.acceleration
                               + rng.normal(0, s_a, c.acceleration.size))


def replicate_drive(drive: int, replicates: int, draw: str = "uniform",
                    seed: int = 1) -> dict:
    """Every record's sensor noise replicated at once: the mean square over the replicates
    of the records' part of the step (their sum; honest weights: the records' share of the
    information, `share`), and of the sum of each record's part squared (`diag`)."""
    pb, theta, jac, cov, clean = _problem_at_truth(drive, draw)
    sd = np.sqrt(np.diag(cov))
    used = pb.used_mask()
    recs = []
    for i, rows in enumerate(pb.record_slices()):
        fn = _frf_residual if pb.layout[i][1] == 1 else _sine_residual
        recs.append((jac[rows][used[rows]], fn(pb, theta, i)))
    jd = np.concatenate([j for j, _ in recs])
    share = np.diag(cov @ jd.T @ jd @ cov) / sd ** 2
    rng = np.random.default_rng(seed)
    tot, diag = [], []
    for _ in range(replicates):
        parts = []
        for (jr, w_of), c in zip(recs, clean):
            w, sub = w_of(idn.measurement_data(_noisy(c, rng)))
            parts.append(cov @ (jr if sub is None else jr[sub]).T @ w / sd)
        parts = np.asarray(parts)
        tot.append(parts.sum(axis=0))
        diag.append((parts ** 2).sum(axis=0))
    return dict(drive=drive, names=list(pb.names), replicates=replicates,
                total_ms=[float(x) for x in np.mean(np.square(tot), axis=0)],
                diag_ms=[float(x) for x in np.mean(diag, axis=0)],
                share=[float(x) for x in share])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", type=int, action="append",
                    help="a drive (repeatable); or --drives N for drives 0..N-1")
    ap.add_argument("--drives", type=int, default=None)
    ap.add_argument("--record", default=None,
                    help="record index, or 'all': every record's noise at once")
    ap.add_argument("--replicates", type=int, default=200)
    ap.add_argument("--noise", choices=("both", "force", "acc"), default="both")
    ap.add_argument("--draw", choices=("uniform", "prior"), default="uniform")
    args = ap.parse_args(argv)
    drives = args.drive or (list(range(args.drives)) if args.drives else None)
    if not drives or args.record is None:
        ap.error("give --drive (or --drives) and --record")
    if args.record == "all":
        rows = []
        for drive in drives:
            rows.append(replicate_drive(drive, args.replicates, args.draw))
            print(f"drive {drive}: records' part, mean square over "
                  f"{args.replicates} replicates (honest: its share): " + ", ".join(
                      f"{n} {x:.2f} ({s:.2f})" for n, x, s in zip(
                          rows[-1]["names"], rows[-1]["total_ms"], rows[-1]["share"])),
                  flush=True)
        names = rows[0]["names"]
        mean = lambda k: np.mean([r[k] for r in rows], axis=0)
        print(f"{len(rows)} drives: " + ", ".join(
            f"{n} {x:.2f} ({s:.2f})" for n, x, s in zip(names, mean("total_ms"),
                                                        mean("share"))))
        return 0
    for drive in drives:
        o = replicate(drive, int(args.record), args.replicates, args.noise, args.draw)
        print(f"drive {drive}, record {args.record} ({o['name']}, {o['model']}), "
              f"{o['noise']} noise, {o['replicates']} replicates: mean z^2 "
              f"{o['mean_z2']:.3f}")
        if "cov_eigenvalues" in o:
            print("  covariance of the weighted residual, eigenvalues: "
                  + ", ".join(f"{x:.2f}" for x in o["cov_eigenvalues"])
                  + "; its mean: " + ", ".join(f"{x:+.2f}" for x in o["residual_mean"]))
        print("  variance of each parameter's part / its share (1: honest): " + ", ".join(
            f"{n} {x:.2f}" for n, x in zip(o["names"], o["ratio"])))
        print("  mean of each part / sqrt(share) (0: no error at the truth but noise): "
              + ", ".join(f"{n} {x:+.2f}" for n, x in zip(o["names"], o["part_mean"])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
