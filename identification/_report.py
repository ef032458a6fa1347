"""The end-to-end identification run and its report (dict for report.json, text summary)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

import bsfs_jax

from ._fit import DEFAULT_FIT, FitResult, Problem, fit
from ._measurement import harmonic_analysis
from ._records import load_records
from ._uncertainty import IDENTIFIABLE_STD, Uncertainty, uncertainty

DATA_DIR = Path(__file__).resolve().parent.parent / "data"


def bundled_records(name: str = "paper-test") -> list[Path]:
    """Paths of a bundled synthetic data set: "paper-test" or "stepped-sine"."""
    folder = DATA_DIR / name
    files = sorted(folder.glob("*.csv"))
    if not files:
        raise FileNotFoundError(f"no bundled records in '{folder}' (run data/generate.py)")
    return files


@dataclasses.dataclass
class IdentificationResult:
    problem: Problem
    fit: FitResult
    uncertainty: Uncertainty
    data: list
    seconds: float

    def params(self, speed=None):
        """Identified `BallScrewParams` at `speed` (default: the first speed of the data)."""
        speed = self.problem.speeds[0] if speed is None else speed
        return self.problem.params_at(np.asarray(self.fit.theta), speed)

    def model_harmonics(self):
        return self.problem.model_harmonics(self.fit.theta)


def identify(records, prior=None, fit_names=DEFAULT_FIT, *, model: str = "auto",
             starts: int = 4, seed: int = 0, max_steps: int = 100) -> IdentificationResult:
    """Load records (paths or `Record`s), fit, and compute the uncertainty."""
    t0 = time.perf_counter()
    from ._records import Record

    recs = [r for r in records if isinstance(r, Record)]
    paths = [r for r in records if not isinstance(r, Record)]
    recs += load_records(paths) if paths else []
    data = [harmonic_analysis(r) for r in recs]
    prior = bsfs_jax.preset() if prior is None else prior
    problem = Problem(data, prior, fit_names, model=model)
    result = fit(problem, starts=starts, seed=seed, max_steps=max_steps)
    unc = uncertainty(result)
    return IdentificationResult(problem, result, unc, data, time.perf_counter() - t0)


def _record_rows(res: IdentificationResult):
    pb = res.problem
    model = res.model_harmonics()
    slices = pb.record_slices()
    used = pb.used_mask()
    rows = []
    for i, d in enumerate(res.data):
        keep = d.frequency_hz * d.harmonics <= pb.max_harmonic_hz
        diff = (d.acceleration - model[i])[keep]
        r = res.fit.residual[slices[i]][used[slices[i]]]
        rows.append(dict(
            name=d.name, file=d.record.source, frequency_hz=d.frequency_hz,
            force_amplitude_n=d.record.force_amplitude_n, speed_rpm=d.speed_rpm,
            model=pb.models[i], amplitude_ratio=pb.amplitude_ratios[i],
            harmonics_used=int(np.count_nonzero(keep)),
            rms_residual_m_s2=float(np.sqrt(np.sum(np.abs(diff) ** 2) / 2)),
            acceleration_rms_m_s2=float(np.sqrt(np.sum(np.abs(d.acceleration) ** 2) / 2)),
            noise_rms_m_s2=d.acceleration_noise,
            normalized_rms=float(np.sqrt(np.mean(r**2))) if r.size else None,
            fundamental_error_rel=float(abs(diff[0]) / abs(d.acceleration[0])),
        ))
    return rows


def report_dict(res: IdentificationResult) -> dict:
    pb, fr, u = res.problem, res.fit, res.uncertainty
    params = {}
    for i, name in enumerate(pb.names):
        rel = float(u.scaled_std[i]) if pb.units[i] != "um" else None
        params[name] = dict(
            key=pb.keys[i], speed_rpm=pb.param_speeds[i], value=float(u.values[i]),
            std=float(u.std[i]), ci95=[float(u.ci95[i, 0]), float(u.ci95[i, 1])],
            unit=pb.units[i], prior=float(pb.prior_values[i]), relative_std=rel,
            identified=bool(u.scaled_std[i] < IDENTIFIABLE_STD),
        )
    sv = u.singular_values
    directions = [dict(singular_value=float(sv[i] / sv[0]), std=float(u.direction_std[i]),
                       combination=u.combination_text(i),
                       identified=bool(u.direction_std[i] < IDENTIFIABLE_STD))
                  for i in range(len(sv))]
    grad = fr.jacobian.T @ fr.residual
    return dict(
        synthetic_data=any(str(d.record.meta.get("synthetic", "")).lower() == "true"
                           for d in res.data),
        parameters=params,
        records=_record_rows(res),
        correlation=dict(names=list(pb.names), matrix=u.correlation.tolist()),
        identifiability=dict(
            scaled_singular_values=(sv / sv[0]).tolist(),
            threshold_std=IDENTIFIABLE_STD,
            note="scaled parameters: log-values (relative) and offsets in um; a combination "
                 f"is identified when its standard error is below {IDENTIFIABLE_STD}",
            directions=directions,
        ),
        series_compliance=u.compliance,
        fit=dict(
            iterations=fr.steps, converged=fr.converged, cost=fr.cost,
            noise_scale=u.noise_scale, dof=u.dof, gradient_max=float(np.max(np.abs(grad))),
            starts=[{k: v for k, v in s.items() if k != "theta"} for s in fr.starts],
            seconds=res.seconds, fit_seconds=fr.seconds,
            method="optimistix Levenberg-Marquardt, forward-mode Jacobians, multi-start",
            measurement_model="harmonic domain: Fourier coefficients of force and worktable "
                              "acceleration; linearised FRF or shooting per record",
        ),
        summary=summary_text(res),
    )


def summary_text(res: IdentificationResult) -> str:
    pb, fr, u = res.problem, res.fit, res.uncertainty
    lines = []
    synth = any(str(d.record.meta.get("synthetic", "")).lower() == "true" for d in res.data)
    lines.append(f"Identification from {len(res.data)} record(s)"
                 f"{' (SYNTHETIC data)' if synth else ''}: "
                 + ", ".join(f"{d.frequency_hz:.4g} Hz/{d.record.force_amplitude_n:g} N/"
                             f"{d.speed_rpm:g} rpm" for d in res.data[:6])
                 + (" ..." if len(res.data) > 6 else ""))
    n_nl = sum(m == "nonlinear" for m in pb.models)
    lines.append(f"Model: linearised FRF for {len(pb.models) - n_nl}, nonlinear shooting for "
                 f"{n_nl} record(s); {len(fr.starts)} start(s), best after {fr.steps} LM "
                 f"iterations, optimizer converged: {fr.converged}; "
                 f"{sum(s['same_minimum'] for s in fr.starts)}/{len(fr.starts)} starts reached "
                 f"the same cost; noise scale {u.noise_scale:.2f} (1 = residuals at the noise "
                 f"level); {res.seconds:.1f} s.")
    lines.append("")
    lines.append(f"{'parameter':<22}{'value':>12}{'std':>11}   {'95% CI':<24}{'unit':<10}")
    for i, name in enumerate(pb.names):
        v, s = u.values[i], u.std[i]
        lo, hi = u.ci95[i]
        det = "" if u.scaled_std[i] < IDENTIFIABLE_STD else "  NOT DETERMINED"
        ci = f"[{lo:.4g}, {hi:.4g}]" if np.isfinite(lo) and np.isfinite(hi) else "[-, -]"
        lines.append(f"{name:<22}{v:>12.4g}{s:>11.3g}   {ci:<24}{pb.units[i]:<10}{det}")
    lines.append("")
    sv = u.singular_values / u.singular_values[0]
    lines.append("Scaled singular values: " + ", ".join(f"{x:.2g}" for x in sv))
    ident = u.identifiable()
    lines.append(f"Identified combinations ({sum(ident)} of {len(ident)}; std < "
                 f"{IDENTIFIABLE_STD:g}):")
    for i in range(len(sv)):
        if ident[i]:
            lines.append(f"  [{u.direction_std[i]:.2g}] {u.combination_text(i)}")
    if not all(ident):
        lines.append("Not identifiable from these records:")
        for i in range(len(sv)):
            if not ident[i]:
                lines.append(f"  [{u.direction_std[i]:.2g}] {u.combination_text(i)}")
    for speed, c in u.compliance.items():
        lines.append(f"Series (static) compliance at {speed} rpm: "
                     f"{c['compliance_nm_per_n']:.4f} +- {c['std_nm_per_n']:.2g} nm/N "
                     f"({100 * c['relative_std']:.3g} %), i.e. stiffness "
                     f"{c['stiffness_n_per_um']:.2f} N/um")
    ds = u.direction_std
    if sum(ident) <= 1 or (ds.size > 1 and ds[1] > 100 * ds[0]):
        lines.append(
            f"=> Essentially ONE combination is determined: the series compliance (to "
            f"{100 * ds[0]:.2g} %). The next-best combination is {ds[1] / ds[0]:.0f}x less "
            f"certain ({100 * ds[1]:.2g} %); it rests on a phase lag of ~1e-3 rad, so any "
            "unmodelled sensor phase error would bias it. The split between bearing, screw "
            "and nut, the damping and the thermal offsets are not determined by this "
            "quasi-static test. Run `bsfs plan-test` for a test that separates them.")
    return "\n".join(lines)


def write_identified(res: IdentificationResult, out_dir) -> list[Path]:
    """identified.toml (first speed) and, for per-speed offsets, one file per extra speed."""
    out_dir = Path(out_dir)
    pb = res.problem
    per_speed = any(s is not None for s in pb.param_speeds)
    paths = []
    for j, speed in enumerate(pb.speeds):
        if j and not per_speed:
            break
        name = "identified.toml" if j == 0 else f"identified_{speed:g}rpm.toml"
        header = ("Identified by `bsfs identify` from "
                  + ", ".join(Path(d.record.source).name for d in res.data)
                  + f"\nfitted: {', '.join(pb.names)}; speed {speed:g} r/min"
                  + "\nsee report.json for standard errors and identifiability")
        paths.append(bsfs_jax.save_params(res.params(speed), out_dir / name, header=header,
                                          overwrite=True))
    return paths
