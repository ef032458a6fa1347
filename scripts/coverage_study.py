"""Coverage study of the identification's 95 % intervals (docs/COVERAGE.md).

For N seeded replicates, the records of the bundled preload-loss test (data/generate.py:
five 100 N stepped sines at 150, 400, 700, 1700 and 2500 Hz, 0.5 s each, and one 5 N burst
chirp 50-2500 Hz over 1 s, at 2000 r/min, 10.24 kHz) are synthesised afresh from the truth
(data/worn.toml) with new seeds (sensor noise, start phases, distortion phases and drift all
re-drawn), fitted as the README's example fits them (`identification.identify`,
`PRELOAD_FIT`, the default preset as prior with the default priors, 3 starts, profile
"auto"), and for each parameter the script records whether the 95 % interval covers the
truth, the z-score log(value / truth) / scaled_std, convergence and time.

    python scripts/coverage_study.py                      # 120 replicates (~3.5 min, 2 cores)
    python scripts/coverage_study.py --quick              # 10 replicates, a check
    python scripts/coverage_study.py --design linear      # diagnosis designs, see DESIGNS
    python scripts/coverage_study.py --report-only        # tables and figure from the file
    python scripts/coverage_study.py --replicates 1000 --workers 8   # on a local Dask
                    # cluster, a batch of replicates a chunk (or --scheduler ADDRESS)

Every replicate is appended as one JSON line to out/coverage/<design>.jsonl (flushed and
fsynced per line); a rerun skips the seeds already there, so an interrupted study resumes.
The summary (per parameter and pooled: coverage with its Clopper-Pearson 95 % interval, mean
and std of z, fraction converged, times) is printed and written to
out/coverage/<design>_summary.{json,md}; `--figure PATH` draws the z histograms.
Results: docs/COVERAGE.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import platform
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bsfs_jax.cli import setup_jax  # noqa: E402

setup_jax()  # 64-bit, the persistent compilation cache, one BLAS thread

import numpy as np  # noqa: E402
import study_cluster  # noqa: E402

import bsfs_jax  # noqa: E402
import identification as idn  # noqa: E402
from bsfs_jax.files import write_atomic  # noqa: E402
from identification.measurement import is_frf

FS = 10240.0
SPEED = 2000.0
SINES = (150.0, 400.0, 700.0, 1700.0, 2500.0)  # data/generate.py WORN
SINE_FORCE, SINE_S = 100.0, 0.5
CHIRP = dict(force=5.0, duration=1.0, start=50.0, stop=2500.0)  # data/generate.py CHIRP
TRUTH_FILE = ROOT / "data" / "worn.toml"
OUT = ROOT / "out" / "coverage"
Z95 = 1.959963984540054

GENTLE = dict(chirp_force=1.0, sine_force={700.0: 30.0})
# name: (what it is, overrides). Overrides: chirp_force [N], sine_force {Hz: N},
# effects (TestEffects fields), source "synth" (simulate the nonlinear model) or "linear"
# (the truth's linearised model at the bundled records' forces plus Gaussian noise at their
# stated standard errors: no model error at all).
DESIGNS = {
    "bundled": ("the bundled preload-loss design (data/generate.py)", {}),
    "noiseless": ("the bundled design with 120 dB sensor SNR (bias of the model and "
                  "estimators; z and coverage meaningless)",
                  dict(effects=dict(accel_snr_db=120.0, force_snr_db=120.0))),
    "noise-free": ("the bundled design's records without sensor noise (same seeds: same phases, "
                   "distortion and drift), weighted with the noisy records' stated standard "
                   "errors: the fit's error is then model and estimator error alone, and z "
                   "is that bias in units of the stated std",
                   dict(source="noise-free")),
    "linear": ("linear-Gaussian data: the truth's linearised model at the bundled records' "
               "forces + Gaussian noise at their stated standard errors", dict(source="linear")),
    "coh0": ("the bundled records (same seeds), chirp FRF kept at every line: "
             "estimate_frf(min_coherence=0) instead of the default 0.5",
             dict(min_coherence=0.0)),
    "gentle": ("the bundled design with a 1 N chirp (instead of 5 N) and the 700 Hz sine at "
               "30 N (instead of 100 N): joint amplitudes well inside the linear range",
               GENTLE),
    "random": ("the bundled design with its chirp replaced by a 2 s random record (5 N RMS, "
               "50-2500 Hz; a Hann-windowed Welch FRF, whose neighbouring lines' errors are "
               "correlated)", dict(excitation="random", chirp_duration=2.0)),
    "random-only": ("a 2 s random record alone (2 N RMS, 50-2500 Hz, a Hann-windowed Welch "
                    "FRF), no sines", dict(excitation="random", chirp_duration=2.0,
                                          chirp_force=2.0, sines=())),
    "gentle-noise-free": ("the 'gentle' design's records without sensor noise, weighted with "
                          "the noisy records' standard errors (as 'noise-free')",
                          dict(GENTLE, source="noise-free")),
}


def truth_params():
    return bsfs_jax.load_params(TRUTH_FILE).replace("thermal.speed_rpm", SPEED)


def record_seeds(replicate: int) -> list[int]:
    """Seeds of the chirp and the five sines of a replicate (disjoint from the bundled
    records' 2000-2004 and 2100)."""
    return [1_000_000 + 10 * replicate + j for j in range(1 + len(SINES))]


def synth_records(truth, replicate: int, over: dict):
    """The replicate's records (chirp first, then the sines), synthesised from the truth."""
    return synth_batch(truth, [replicate], over)[0]


def synth_batch(truth, replicates: list[int], over: dict) -> list[list]:
    """The records of several replicates: each record's simulations for all of them as one
    vmapped integration (`identification.synthesize_many`; the same records as one by one,
    to the integration tolerance)."""
    eff = dataclasses.replace(idn.TestEffects(), **over.get("effects", {}))
    seeds = [record_seeds(k) for k in replicates]
    per_record = [idn.synthesize_many(
        truth, None, over.get("chirp_force", CHIRP["force"]), [s[0] for s in seeds],
        duration_s=over.get("chirp_duration", CHIRP["duration"]), sample_rate_hz=FS,
        excitation=over.get("excitation", "chirp"),
        start_hz=CHIRP["start"], stop_hz=CHIRP["stop"], effects=eff)]
    for j, f in enumerate(over.get("sines", SINES)):
        force = over.get("sine_force", {}).get(f, SINE_FORCE)
        per_record.append(idn.synthesize_many(truth, f, force, [s[j + 1] for s in seeds],
                                              duration_s=SINE_S, sample_rate_hz=FS,
                                              effects=eff))
    return [list(recs) for recs in zip(*per_record)]


_TEMPLATE = {}


def linear_data(truth, replicate: int):
    """Linear-Gaussian replicate of the bundled records' measurement data.

    Sines: true force = the bundled record's force harmonics; measured force = that + noise
    at its stated std; acceleration = the truth's linearised accelerance x true force + noise
    at its stated std (errors in both channels, as the fit's weights assume). Chirp FRF: the
    truth's linearised accelerance + noise at the stated std of each line.
    """
    if not _TEMPLATE:
        data = [idn.measurement_data(r) for r in
                idn.load_records(idn.bundled_records("preload-loss"))]
        pb = idn.Problem(data, truth, idn.PRELOAD_FIT, model="linear", priors=None)
        _TEMPLATE.update(data=data, model=pb.model_harmonics(np.zeros(pb.n_params)))
    rng = np.random.default_rng(record_seeds(replicate)[0])
    out = []
    for d, m in zip(_TEMPLATE["data"], _TEMPLATE["model"]):
        if is_frf(d):
            sd = np.sqrt(d.variance)
            noise = rng.normal(size=sd.shape) * sd
            out.append(dataclasses.replace(d, accelerance=m + noise[:, 0] + 1j * noise[:, 1]))
        else:
            fa, fv = np.sqrt(d.acceleration_var), np.sqrt(d.force_var)
            na, nf = rng.normal(size=fa.shape) * fa, rng.normal(size=fv.shape) * fv
            out.append(dataclasses.replace(
                d, acceleration=m + na[:, 0] + 1j * na[:, 1],
                force=d.force + nf[:, 0] + 1j * nf[:, 1]))
    return out


def noise_free_data(truth, replicate: int, over: dict, records=None):
    """The replicate's measurement data with the values of noise-free records (sensor SNR
    300 dB, same seeds) and the standard errors of the noisy ones (`records`: the noisy
    records, if already made)."""
    base = {k: v for k, v in over.items() if k != "source"}
    noisy = [idn.measurement_data(r) for r in (records or synth_records(truth, replicate, base))]
    clean = [idn.measurement_data(r) for r in synth_records(
        truth, replicate, dict(base, effects=dict(accel_snr_db=300.0, force_snr_db=300.0)))]
    return with_clean_values(noisy, clean)


def with_clean_values(noisy, clean) -> list:
    """Measurement data with the values of `clean` (noise-free records of the same seeds)
    and the standard errors of `noisy` (FRF lines interpolated onto the noisy ones' lines)."""
    out = []
    for d, c in zip(noisy, clean):
        if is_frf(d):
            h = np.interp(d.frequency_hz, c.frequency_hz, c.accelerance.real) + 1j * np.interp(
                d.frequency_hz, c.frequency_hz, c.accelerance.imag)
            out.append(dataclasses.replace(d, accelerance=h))
        else:
            out.append(dataclasses.replace(d, acceleration=c.acceleration, force=c.force,
                                           frequency_hz=c.frequency_hz,
                                           force_rate=c.force_rate,
                                           force_rate2=c.force_rate2))
    return out


def batch_records(truth, design: str, replicates: list[int]) -> list:
    """What `run_replicate` needs of each replicate before its fit: its synthetic records
    (batched), or None where the design makes its data otherwise."""
    over = DESIGNS[design][1]
    if over.get("source") == "linear":
        return [None] * len(replicates)
    base = {k: v for k, v in over.items() if k != "source"}
    return synth_batch(truth, replicates, base)


def fit_data(data, prior):
    """`identify` on measurement data (what it does after loading the records)."""
    pb = idn.Problem(data, prior, idn.PRELOAD_FIT)
    res = idn.fit(pb, starts=3)
    pb = res.problem  # models and left-out chirp lines as chosen at the estimate
    unc = idn.uncertainty(res)
    profile = "nonlinear" not in pb.models
    if profile:
        unc, _ = idn.profile_intervals(res, unc)
    return pb, res, unc, profile


def frf_arrays(data) -> dict:
    """What the FRF-variance and bias diagnostics need from a replicate's measurement data."""
    out = {}
    for d in data:
        if is_frf(d):
            out.update(frf_f=d.frequency_hz, frf_h=d.accelerance, frf_var=d.variance[:, 0])
        else:
            k = f"sine{d.record.frequency_hz:g}"
            out[k + "_freq"] = np.asarray(d.frequency_hz)
            out[k + "_force"], out[k + "_acc"] = d.force, d.acceleration
            out[k + "_force_var"], out[k + "_acc_var"] = d.force_var, d.acceleration_var
    return out


def run_replicate(truth, prior, design: str, replicate: int, frf_dir: Path | None,
                  records=None, synth_s: float | None = None) -> dict:
    """One replicate: its data (from `records` where `batch_records` made them), the fit
    and the row of the results file."""
    over = DESIGNS[design][1]
    t0 = time.perf_counter()
    if over.get("source") == "linear":
        data = linear_data(truth, replicate)
    elif over.get("source") == "noise-free":
        data = noise_free_data(truth, replicate, over, records)
    else:
        recs = records or synth_records(truth, replicate, over)
        data = [idn.estimate_frf(r, min_coherence=over["min_coherence"])
                if "min_coherence" in over and r.excitation != "sine"
                else idn.measurement_data(r) for r in recs]
    t1 = time.perf_counter()
    t0 -= synth_s or 0.0  # the replicate's share of its batch's synthesis
    pb, res, unc, profiled = fit_data(data, prior)
    t2 = time.perf_counter()
    if frf_dir is not None:
        frf_dir.mkdir(parents=True, exist_ok=True)
        arrays = frf_arrays(data)

        def write(tmp):
            with open(tmp, "wb") as fh:  # a file object: savez adds no ".npz" to it
                np.savez_compressed(fh, **arrays)

        write_atomic(frf_dir / f"r{replicate:04d}.npz", write)
    true_values = np.asarray([float(np.asarray(truth.get(k))) for k in pb.keys])
    z = np.log(unc.values / true_values) / unc.scaled_std
    lo, hi = unc.ci95[:, 0], unc.ci95[:, 1]
    params = {}
    for i, n in enumerate(pb.names):
        params[n] = dict(truth=float(true_values[i]), value=float(unc.values[i]),
                         scaled_std=float(unc.scaled_std[i]), ci95=[float(lo[i]), float(hi[i])],
                         ci_method=unc.ci_method[i],
                         covers=bool(lo[i] <= true_values[i] <= hi[i]),
                         covers_linearised=bool(abs(z[i]) <= Z95), z=float(z[i]),
                         determined=bool(unc.determined[i]),
                         line_widening=float(unc.noise.get("line_widening", [1.0] * len(
                             pb.names))[i]))
    return dict(replicate=replicate, seeds=record_seeds(replicate), design=design,
                params=params, converged=bool(res.converged),
                remaining_step=float(res.remaining_step), iterations=int(res.steps),
                starts_same_minimum=res.starts_agreeing,
                noise_scale=unc.noise.get("noise_scale"), scaled_by=unc.noise["scaled_by"],
                chi2=unc.noise["chi2"], dof=unc.noise["dof"], models=list(pb.models),
                amplitude_ratios=[float(a) for a in pb.amplitude_ratios], profiled=profiled,
                model_choice=res.model_choice,
                chirp_lines_left_out=int(sum(m.sum() for m in pb.frf_left_out.values())),
                synth_s=t1 - t0, fit_s=t2 - t1)


# ----------------------------------------------------------------------------- the file


def read_done(path: Path) -> list[dict]:
    """Complete lines of the JSON lines file (a torn last line is ignored and rewritten)."""
    if not path.exists():
        return []
    rows, good = [], 0
    raw = path.read_bytes()
    for line in raw.splitlines(keepends=True):
        if not line.endswith(b"\n"):
            break
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break
        good += len(line)
    if good != len(raw):  # drop a torn tail so that appends start on a fresh line
        with open(path, "r+b") as fh:
            fh.truncate(good)
    return rows


def append_line(path: Path, row: dict) -> None:
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(row) + "\n")
        fh.flush()
        os.fsync(fh.fileno())


# ----------------------------------------------------------------------------- summary


def binom_ci(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a proportion."""
    from scipy.stats import beta

    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def summarize(rows: list[dict]) -> dict:
    names = list(rows[0]["params"])
    out = dict(replicates=len(rows), parameters={})
    pooled_cov, pooled_z = [], []
    for n in names:
        cov = np.asarray([r["params"][n]["covers"] for r in rows])
        z = np.asarray([r["params"][n]["z"] for r in rows])
        rel = np.asarray([r["params"][n]["value"] / r["params"][n]["truth"] - 1 for r in rows])
        sd = np.asarray([r["params"][n]["scaled_std"] for r in rows])
        k = int(cov.sum())
        out["parameters"][n] = dict(
            covered=k, coverage=k / cov.size, coverage_ci95=binom_ci(k, cov.size),
            coverage_linearised=float(np.mean(np.abs(z) <= Z95)),
            z_mean=float(z.mean()), z_mean_se=float(z.std(ddof=1) / np.sqrt(z.size)),
            z_std=float(z.std(ddof=1)), rel_error_mean=float(rel.mean()),
            rel_error_std=float(rel.std(ddof=1)), stated_rel_std_median=float(np.median(sd)),
            profiled_share=float(np.mean([r["params"][n]["ci_method"] == "profile"
                                          for r in rows])),
            # z had the intervals not been widened for correlated FRF lines (rows of
            # earlier files carry no factor: 1)
            z_std_unwidened=float((z * np.asarray([r["params"][n].get("line_widening", 1.0)
                                                   for r in rows])).std(ddof=1)),
            line_widening_median=float(np.median([r["params"][n].get("line_widening", 1.0)
                                                  for r in rows])))
        pooled_cov.append(cov)
        pooled_z.append(z)
    c, z = np.concatenate(pooled_cov), np.concatenate(pooled_z)
    k = int(c.sum())
    out["pooled"] = dict(covered=k, total=int(c.size), coverage=k / c.size,
                         coverage_ci95=binom_ci(k, c.size), z_mean=float(z.mean()),
                         z_std=float(z.std(ddof=1)))
    allc = np.all(np.stack(pooled_cov), axis=0)
    out["all_covered"] = float(allc.mean())
    out["converged"] = float(np.mean([r["converged"] for r in rows]))
    out["noise_scale_median"] = float(np.median([r["noise_scale"] or np.nan for r in rows]))
    out["model_error_flagged"] = float(np.mean([r["scaled_by"] != 1.0 for r in rows]))
    out["seconds_median"] = dict(synth=float(np.median([r["synth_s"] for r in rows])),
                                 fit=float(np.median([r["fit_s"] for r in rows])))
    out["models"] = sorted({",".join(r["models"]) for r in rows})
    return out


def markdown(s: dict, design: str) -> str:
    lines = [f"Design `{design}`: {DESIGNS[design][0]}; {s['replicates']} replicates.", "",
             "| parameter | coverage | 95 % CI of coverage | mean z | std z | "
             "mean rel. error | std rel. error | median stated rel. std |",
             "|---|---|---|---|---|---|---|---|"]
    for n, p in s["parameters"].items():
        lo, hi = p["coverage_ci95"]
        lines.append(f"| {n} | {100 * p['coverage']:.1f} % ({p['covered']}/{s['replicates']}) "
                     f"| {100 * lo:.1f}-{100 * hi:.1f} % | {p['z_mean']:+.2f} +- "
                     f"{p['z_mean_se']:.2f} | {p['z_std']:.2f} | "
                     f"{100 * p['rel_error_mean']:+.3f} % | {100 * p['rel_error_std']:.3f} % | "
                     f"{100 * p['stated_rel_std_median']:.3f} % |")
    p = s["pooled"]
    lo, hi = p["coverage_ci95"]
    lines.append(f"| pooled | {100 * p['coverage']:.1f} % ({p['covered']}/{p['total']}) | "
                 f"{100 * lo:.1f}-{100 * hi:.1f} % | {p['z_mean']:+.2f} | {p['z_std']:.2f} "
                 "| | | |")
    lines += ["", f"All five covered at once: {100 * s['all_covered']:.1f} %; converged: "
              f"{100 * s['converged']:.1f} %; median noise scale {s['noise_scale_median']:.3f}; "
              f"model error flagged (intervals widened): {100 * s['model_error_flagged']:.1f} %; "
              f"median time per replicate: synthesis {s['seconds_median']['synth']:.1f} s, "
              f"fit {s['seconds_median']['fit']:.1f} s."]
    wid = {n: p for n, p in s["parameters"].items() if p.get("line_widening_median", 1.0) > 1}
    if wid:
        lines += ["", "Widened for correlated FRF lines (median factor on the standard "
                  "error; std z had they not been): " + "; ".join(
                      f"{n} {p['line_widening_median']:.2f} ({p['z_std_unwidened']:.2f})"
                      for n, p in wid.items()) + "."]
    return "\n".join(lines) + "\n"


UNITS = {"nut_preload": "nut preload [N]", "bearing_preload": "bearing preload [N]",
         "c_b": "bearing damping c_b [N s/m]", "c_s": "screw damping c_s [N s/m]",
         "c_n": "nut-joint damping c_n [N s/m]"}


def figure(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(rows[0]["params"])
    fig, axes = plt.subplots(1, len(names), figsize=(3.1 * len(names), 3.2), sharey=True)
    x = np.linspace(-4.5, 4.5, 200)
    bins = np.linspace(-4.5, 4.5, 19)
    for ax, n in zip(axes, names):
        z = np.asarray([r["params"][n]["z"] for r in rows])
        cov = np.mean([r["params"][n]["covers"] for r in rows])
        ax.hist(np.clip(z, -4.49, 4.49), bins=bins, density=True, color="tab:blue", alpha=0.6,
                label="replicates")
        ax.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", lw=1.2, label="N(0, 1)")
        for s in (-Z95, Z95):
            ax.axvline(s, color="0.5", ls=":", lw=0.8)
        truth = rows[0]["params"][n]["truth"]
        ax.set_title(f"{UNITS.get(n, n)}\ntruth {truth:g}", fontsize=9)
        ax.set_xlabel("z = ln(estimate / truth) / stated std", fontsize=8)
        ax.text(0.03, 0.97, f"mean {z.mean():+.2f}\nstd {z.std(ddof=1):.2f}\n"
                f"coverage {100 * cov:.0f} %", transform=ax.transAxes, va="top", fontsize=8)
    axes[0].set_ylabel("density")
    axes[-1].legend(fontsize=7, loc="upper right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- diagnosis


def diagnose(data_dir: Path) -> str:
    """The measurement data across replicates against the truth's linearised model and the
    standard errors the records state: is the scatter what the weights say, and is there a
    bias (model error) that no single replicate can see?

    Chirp FRF lines: per band, the mean of (actual variance across replicates) / (mean stated
    variance), and the bias of the mean FRF from the linear model in units of the stated std
    of one replicate. Sine harmonics: the residual A - G_lin F at the truth (G_lin: linear
    accelerance), its scatter / stated std, and its mean / stated std, per harmonic.
    """
    from identification.measurement import linear_acceleration

    files = sorted(data_dir.glob("r*.npz"))
    if len(files) < 5:
        return f"{data_dir}: {len(files)} replicate data file(s); need at least 5\n"
    z = [dict(np.load(f)) for f in files]
    system = bsfs_jax.build_system(truth_params())

    def glin(freq):
        return np.asarray(linear_acceleration(system, np.asarray(freq, float),
                                              np.ones(np.shape(freq), complex)))

    lines = [f"{len(files)} replicates from {data_dir}", "",
             "Chirp FRF lines (H1, single frame): actual / stated variance and bias "
             "(mean over replicates - linear model) / stated std of one replicate", "",
             "| band [Hz] | lines | var ratio Re | var ratio Im | mean bias/std Re | "
             "mean bias/std Im | max abs bias/std |", "|---|---|---|---|---|---|---|"]
    # Lines on the 1/duration grid; a line dropped in a replicate (coherence) is left out there.
    f = np.unique(np.concatenate([r["frf_f"] for r in z]))
    h = np.full((len(z), f.size), np.nan, complex)
    var = np.full((len(z), f.size), np.nan)
    for i, r in enumerate(z):
        idx = np.searchsorted(f, r["frf_f"])
        h[i, idx], var[i, idx] = r["frf_h"], r["frf_var"]
    n_ok = np.sum(np.isfinite(var), 0)
    sd = np.sqrt(np.nanmean(var, 0))
    g = glin(f)
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = (np.nanmean(h, 0) - g) / sd
        vr = np.nanvar(h.real, 0, ddof=1) / np.nanmean(var, 0)
        vi = np.nanvar(h.imag, 0, ddof=1) / np.nanmean(var, 0)
    good = n_ok >= max(5, len(z) // 2)
    f, g, bias, vr, vi = f[good], g[good], bias[good], vr[good], vi[good]
    peak = f[np.argmax(np.abs(g))]
    bands = [(50, 500), (500, 900), (900, peak - 60), (peak - 60, peak - 15),
             (peak - 15, peak + 15), (peak + 15, peak + 60), (peak + 60, 1600), (1600, 2500)]
    for lo, hi in bands:
        m = (f >= lo) & (f < hi)
        if not m.any():
            continue
        lines.append(f"| {lo:.0f}-{hi:.0f} | {m.sum()} | {vr[m].mean():.2f} | {vi[m].mean():.2f} "
                     f"| {bias.real[m].mean():+.2f} | {bias.imag[m].mean():+.2f} | "
                     f"{np.abs(bias[m]).max():.2f} |")
    lines += ["", f"(linear-model resonance of the truth: {peak:.0f} Hz; lines kept in at "
              f"least half the replicates)", "",
              "Sine harmonics: residual A - G_lin F at the truth",
              "", "| record | harmonic | scatter / stated std | mean / stated std (Re, Im) | "
              "mean / stated std of one replicate's fundamental |", "|---|---|---|---|---|"]
    for key in sorted(k[:-5] for k in z[0] if k.startswith("sine") and k.endswith("_freq")):
        n_h = z[0][key + "_acc"].size
        freq = np.stack([r[key + "_freq"] * np.arange(1, n_h + 1) for r in z])
        gg = np.stack([glin(fr) for fr in freq])
        res = np.stack([r[key + "_acc"] for r in z]) - gg * np.stack([r[key + "_force"]
                                                                      for r in z])
        var = np.stack([r[key + "_acc_var"] for r in z]) + np.abs(gg)[..., None] ** 2 * np.stack(
            [r[key + "_force_var"] for r in z])
        sdv = np.sqrt(var)
        # rotate each residual to the phase of its force fundamental (phases are random)
        rot = np.exp(-1j * np.angle(np.stack([r[key + "_force"][0] for r in z])))[:, None]
        rr = res * rot
        for k in range(freq.shape[1]):
            if freq[0, k] > 0.25 * FS:
                continue
            zr = rr[:, k].real / sdv[:, k, 0]
            zi = rr[:, k].imag / sdv[:, k, 1]
            scat = np.sqrt(0.5 * ((res[:, k].real / sdv[:, k, 0]) ** 2
                                  + (res[:, k].imag / sdv[:, k, 1]) ** 2).mean())
            lines.append(f"| {key} | {k + 1} | {scat:.2f} | {zr.mean():+.2f}, {zi.mean():+.2f} "
                         f"| {'' if k else f'{np.hypot(zr.mean(), zi.mean()):.2f}'} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- main


def batch_rows(truth, prior, design: str, batch: list[int]) -> list[dict]:
    """The rows of a batch of replicates (their records synthesised together, then each
    fitted): a unit of work on a cluster (`study_cluster.run_units`), the same rows as
    `_run_here`'s."""
    t = time.perf_counter()
    recs = batch_records(truth, design, batch)
    share = (time.perf_counter() - t) / len(batch)
    return [run_replicate(truth, prior, design, k, None, rec, share)
            for k, rec in zip(batch, recs)]


def _run_here(truth, prior, design: str, batches: list, frf_dir, keep) -> None:
    """Every batch in this process, `keep(row)` for each replicate: the next batch's
    records are synthesised in a second thread while this batch is fitted (jax releases
    the GIL while it computes: two cores, both busy)."""
    pool = ThreadPoolExecutor(max_workers=1)

    def synth(batch):
        t = time.perf_counter()
        recs = batch_records(truth, design, batch)
        return recs, (time.perf_counter() - t) / len(batch)

    future = pool.submit(synth, batches[0])
    for b, batch in enumerate(batches):
        recs, share = future.result()
        if b + 1 < len(batches):
            future = pool.submit(synth, batches[b + 1])
        for k, rec in zip(batch, recs):
            keep(run_replicate(truth, prior, design, k, frf_dir, rec, share))
    pool.shutdown()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=120)
    ap.add_argument("--quick", action="store_true", help="10 replicates (a check)")
    ap.add_argument("--batch", type=int, default=8,
                    help="replicates synthesised together (one vmapped integration per record)")
    ap.add_argument("--design", choices=list(DESIGNS), default="bundled")
    ap.add_argument("--out", type=Path, default=None,
                    help="JSON lines file (default out/coverage/<design>.jsonl)")
    ap.add_argument("--save-frf", action="store_true",
                    help="keep each replicate's FRF and harmonics (out/coverage/<design>_data/)")
    ap.add_argument("--figure", type=Path, default=None, help="z histograms (PNG)")
    ap.add_argument("--report-only", action="store_true", help="summarise the file, fit nothing")
    ap.add_argument("--diagnose", action="store_true",
                    help="compare the saved data (--save-frf) with the linear model and the "
                         "stated standard errors")
    study_cluster.add_args(ap)
    args = ap.parse_args(argv)
    if args.save_frf and (args.workers or args.scheduler):
        raise SystemExit("--save-frf writes each replicate's data where it is fitted: run it "
                         "without --workers/--scheduler")
    if args.diagnose:
        text = diagnose(OUT / f"{args.design}_data")
        print(text)
        (OUT / f"{args.design}_diagnosis.md").write_text(text)
        return 0
    n = 10 if args.quick else args.replicates
    path = args.out or OUT / f"{args.design}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = read_done(path)
    done = {r["replicate"] for r in rows}
    todo = [k for k in range(n) if k not in done]
    print(f"{path}: {len(done)} replicate(s) done, {len(todo)} to run "
          f"({DESIGNS[args.design][0]})", flush=True)
    if todo and not args.report_only:
        truth, prior = truth_params(), bsfs_jax.preset()
        frf_dir = OUT / f"{args.design}_data" if args.save_frf else None
        t_start = time.perf_counter()
        batches = [todo[i:i + args.batch] for i in range(0, len(todo), args.batch)]
        count = iter(range(1, len(todo) + 1))

        def keep(row):
            row["host"] = platform.node()
            append_line(path, row)
            rows.append(row)
            j = next(count)
            el = time.perf_counter() - t_start
            eta = el / j * (len(todo) - j)
            zs = " ".join(f"{p['z']:+.2f}" for p in row["params"].values())
            print(f"[{j}/{len(todo)}] replicate {row['replicate']}: z = {zs}  covered "
                  f"{sum(p['covers'] for p in row['params'].values())}/"
                  f"{len(row['params'])}  conv {row['converged']}  synth "
                  f"{row['synth_s']:.1f} s fit {row['fit_s']:.1f} s  (elapsed {el:.0f} s, "
                  f"ETA {eta:.0f} s)", flush=True)

        cluster = study_cluster.open_from(args)
        if cluster is None:
            _run_here(truth, prior, args.design, batches, frf_dir, keep)
        else:
            with cluster:
                one = functools.partial(batch_rows, truth, prior, args.design)
                study_cluster.run_units(one, batches, lambda _, out: [keep(r) for r in out],
                                        cluster)
        print(f"{len(todo)} replicates in {time.perf_counter() - t_start:.0f} s", flush=True)
    rows = sorted((r for r in rows if r["replicate"] < n), key=lambda r: r["replicate"])
    if not rows:
        return 0
    s = summarize(rows)
    md = markdown(s, args.design)
    print(md)
    base = path.with_suffix("")
    Path(f"{base}_summary.json").write_text(json.dumps(s, indent=1) + "\n")
    Path(f"{base}_summary.md").write_text(md)
    if args.figure:
        figure(rows, args.figure, f"{len(rows)} replicates, design '{args.design}': z-scores "
               "of the fitted parameters against N(0, 1)")
        print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
