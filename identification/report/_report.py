"""The end-to-end identification run and its report (dict for report.json, identified.toml)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

import bsfs_jax

from ..fitting import DEFAULT_FIT, FitResult, Problem, check_model, fit, prefetch_check
from ..intervals import (
    DETERMINED_RATIO,
    IDENTIFIABLE_STD,
    Uncertainty,
    profile_intervals,
    uncertainty,
)
from ..measurement import (
    MODEL_ERROR,
    HarmonicData,
    harmonic_analysis,
    is_frf,
    line_bound,
    require_x64,
)
from ..records import MAX_LINES, merge_factor, merge_lines
from ._summary import parameter_rows, summary_text

DATA_DIR = Path(__file__).resolve().parents[2] / "data"


def bundled_records(name: str = "paper-test") -> list[Path]:
    """Paths of a bundled synthetic data set ("paper-test", "stepped-sine", "preload-loss",
    "resonance")."""
    folder = DATA_DIR / name
    files = sorted(p for p in folder.glob("*") if p.suffix in (".csv", ".uff", ".unv"))
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
    linearity: np.ndarray | None = None  # (p, 2) profile check, see _profile.py
    # Per periodic-orbit record (index -> dict): the branch it is fitted on, the evidence,
    # and the orbit model's truncation error (`record_branches`).
    branches: dict = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        """The report as JSON-ready data (`report.json`'s content; `report_dict`)."""
        return report_dict(self)

    def model_labels(self) -> list[str]:
        """Per record: its model, with the branch where it is on the periodic orbit."""
        word = {"single": "single orbit", "upper": "upper branch", "lower": "lower branch",
                "unresolved": "branch unresolved"}
        return [m if i not in self.branches else f"{m}, {word[self.branches[i]['branch']]}"
                for i, m in enumerate(self.problem.models)]

    def params(self, speed=None):
        """Identified `BallScrewParams` at `speed` (default: the first speed of the data)."""
        speed = self.problem.speeds[0] if speed is None else speed
        return self.problem.params_at(np.asarray(self.fit.theta), speed)

    def model_harmonics(self):
        """Model values per record at the estimate (computed once, by `fit`)."""
        if self.fit.model is None:
            self.fit.model = self.problem.model_harmonics(self.fit.theta)
        return self.fit.model


def measurement_data(record):
    """Sine `Record` -> `HarmonicData`; chirp/random `Record` -> its estimated FRF; an FRF
    record or a sine's `HarmonicData` is used as it is."""
    if is_frf(record) or isinstance(record, HarmonicData):
        return record
    if getattr(record, "excitation", "sine") != "sine":
        from ..records import estimate_frf

        return estimate_frf(record)
    return harmonic_analysis(record)


def identify(records, prior=None, fit_names=DEFAULT_FIT, *, model: str = "auto",
             starts: int = 3, seed: int = 0, max_steps: int = 100, priors="default",
             profile="auto", on_models=None, say=None,
             max_lines: int | None = MAX_LINES) -> IdentificationResult:
    """Load records (paths or loaded records), fit, and compute the uncertainty.

    `priors`: "default" (each parameter's default prior, see `FIT_PARAMETERS`), a dict
    {name: sigma} or None (maximum likelihood). `profile`: profile-likelihood intervals
    where the linearised ones are doubtful (True), never (False), or "auto": when every
    record uses a linear model (with periodic-orbit records each profile point costs a
    re-fit of orbits; the report then says the check was skipped). `on_models(problem)`:
    called as `fit`'s, after this function has queued its own background compilations
    (the CLI queues the loading of its figures' modules behind them). `say(text)`, where
    given, is told each step as it starts or ends (records read, lines kept, models
    chosen, fit, intervals): a long record's run is never silent. `max_lines`: an FRF with
    more lines is fitted on runs of adjacent lines merged to at most this many
    (`merge_lines`; None or 0: every line as it is).
    """
    require_x64("identification.identify")
    from ..records import load_records

    say = say or (lambda text: None)
    t0 = time.perf_counter()
    loaded = [r for r in records if not isinstance(r, str | Path)]
    paths = [r for r in records if isinstance(r, str | Path)]
    if paths:
        say(f"reading {len(paths)} record(s): {', '.join(Path(p).name for p in paths)}")
    loaded += load_records(paths) if paths else []
    for r in loaded:
        if hasattr(r, "summary"):
            say(f"read {r.summary()}")
    data = []
    for r in loaded:
        data.append(measurement_data(r))
        if is_frf(data[-1]) and not is_frf(r):
            say(f"FRF estimated: {data[-1].summary()}")
        k = merge_factor(data[-1].frequency_hz.size, max_lines) if is_frf(data[-1]) else 1
        if k > 1:
            data[-1] = merge_lines(data[-1], k)
            d = data[-1]
            say(f"{d.name}: {int(d.meta['merged_from'])} lines merged in runs of {k} to "
                f"{d.frequency_hz.size} (--max-lines {max_lines}; each run at most "
                f"{d.meta['merged_width_hz']:.3g} Hz wide)")
    prior = bsfs_jax.preset() if prior is None else prior
    say(f"choosing the measurement model per record ({len(data)} record(s))")
    problem = Problem(data, prior, fit_names, model=model, priors=priors)
    say(_choice_text(problem))
    say(f"fitting {len(fit_names)} parameter(s) from {starts} start(s)")
    def models_chosen(chosen):
        prefetch_check(chosen)
        if on_models is not None:
            on_models(chosen)

    # The model at the estimate (and its check) comes from the branch kernel below: its
    # fitted orbits are the model's, and no separate program solves them again.
    result = fit(problem, starts=starts, seed=seed, max_steps=max_steps, model_check=False,
                 on_models=models_chosen)
    result, branch = check_model(result)
    problem = result.problem  # the models as chosen at the estimate
    say(f"fit done ({time.perf_counter() - t0:.0f} s); computing the uncertainty")
    unc = uncertainty(result)
    lin = None
    if profile == "auto":
        profile = "nonlinear" not in problem.models
        unc.noise["profile"] = ("checked" if profile else "skipped: records use the periodic "
                                "orbit model (identify(profile=True) or --profile on)")
    else:
        unc.noise["profile"] = "checked" if profile else "skipped (profile off)"
    if profile:
        say("profile-likelihood intervals where the linearised ones are doubtful")
        unc, lin = profile_intervals(result, unc)
    return IdentificationResult(problem, result, unc, data, time.perf_counter() - t0, lin,
                                branch)


def _choice_text(problem) -> str:
    """One line: the model per record and the FRF lines kept."""
    counts: dict = {}
    for m in problem.models:
        counts[m] = counts.get(m, 0) + 1
    text = "models: " + ", ".join(f"{n} {m}" for m, n in counts.items())
    for i, d in enumerate(problem.data):
        if is_frf(d):
            out = int(np.sum(problem.frf_left_out.get(i, False)))
            text += f"; {d.name}: {d.frequency_hz.size - out} of {d.frequency_hz.size} lines kept"
    return text


def _model_errors(z, frf: bool) -> dict:
    """Predicted model errors [standard errors] (None where not computed): the linear
    model's (largest over the lines of an FRF), and a sine record's first-order model's."""
    if z is None:
        return dict(linear_model_error_std=None)
    if frf:
        return dict(linear_model_error_std=float(np.max(z)) if np.size(z) else 0.0)
    return dict(linear_model_error_std=z[0], first_order_model_error_std=z[1])


def _record_rows(res: IdentificationResult):
    pb = res.problem
    model = res.model_harmonics()
    residuals = pb.record_residuals(res.fit.residual)
    rows = []
    for i, d in enumerate(res.data):
        r = residuals[i]
        row = dict(name=d.name, file=d.source if is_frf(d) else d.record.source,
                   speed_rpm=d.speed_rpm, model=pb.models[i],
                   amplitude_ratio=pb.amplitude_ratios[i],
                   **_model_errors(pb.linearisation_z[i], is_frf(d)),
                   normalized_rms=float(np.sqrt(np.mean(r**2))) if r.size else None)
        if is_frf(d):
            f = np.asarray(d.frequency_hz)
            out = pb.frf_left_out.get(i)
            row.update(excitation=d.excitation, lines=int(f.size),
                       band_hz=[float(f.min()), float(f.max())],
                       force_amplitude_n=d.force_amplitude_n,
                       lines_left_out_nonlinear=int(np.count_nonzero(out)) if out is not None
                       else 0,
                       left_out_band_hz=([float(f[out].min()), float(f[out].max())]
                                         if out is not None else None))
        else:
            keep = d.frequency_hz * d.harmonics <= pb.max_harmonic_hz
            diff = (d.acceleration - model[i])[keep]
            row.update(excitation="sine", frequency_hz=d.frequency_hz,
                       force_amplitude_n=d.record.force_amplitude_n,
                       harmonics_used=int(np.count_nonzero(keep)),
                       rms_residual_m_s2=float(np.sqrt(np.sum(np.abs(diff) ** 2) / 2)),
                       acceleration_rms_m_s2=float(np.sqrt(np.sum(np.abs(d.acceleration) ** 2)
                                                           / 2)),
                       noise_rms_m_s2=d.acceleration_noise,
                       fundamental_error_rel=float(abs(diff[0]) / abs(d.acceleration[0])))
        if i in res.branches:
            row.update(res.branches[i])
        rows.append(row)
    return rows


def covariance_block(res: IdentificationResult) -> dict:
    """The posterior covariance of the fitted coordinates theta, and how theta maps to the
    values: what `bsfs predict` carries through the model (NaN where undetermined; the
    JSON writer makes it null)."""
    pb, u = res.problem, res.uncertainty
    finite = np.isfinite(u.scaled_std)
    matrix = np.where(finite[:, None] & finite[None, :], u.covariance, np.nan)
    return dict(
        names=list(pb.names), keys=list(pb.keys), speed_rpm=list(pb.param_speeds),
        transform=["log" if lg else "offset" for lg in pb.is_log],
        prior=np.asarray(pb.prior_values, float).tolist(),
        theta=np.asarray(res.fit.theta, float).tolist(), matrix=matrix.tolist(),
        note="covariance of theta, the fitted coordinates: theta = log(value / prior) for "
             "'log' parameters, value - prior (file units) for 'offset' ones; linearised at "
             "the estimate, with the priors where given; null where the data and priors "
             "leave a direction undetermined")


def report_dict(res: IdentificationResult) -> dict:
    pb, fr, u = res.problem, res.fit, res.uncertainty
    sv = u.singular_values
    directions = [dict(singular_value=float(sv[i] / sv[0]), std=float(u.direction_std[i]),
                       combination=u.combination_text(i),
                       identified=bool(u.direction_std[i] < IDENTIFIABLE_STD))
                  for i in range(len(sv))]
    grad = fr.jacobian.T @ fr.residual
    synthetic = any(str((d.meta if is_frf(d) else d.record.meta).get("synthetic", "")).lower()
                    == "true" for d in res.data)
    priors = (None if pb.priors is None else
              dict(kind="Gaussian on the scaled parameter (log-normal for positive values), "
                        "centred on the prior parameter set", sigma=pb.priors,
                   determined_rule=f"the records alone (no prior) give a std <= "
                                   f"{DETERMINED_RATIO:g} x prior std and < "
                                   f"{IDENTIFIABLE_STD:g}"))
    return dict(
        synthetic_data=synthetic,
        parameters=parameter_rows(res),
        priors=priors,
        records=_record_rows(res),
        correlation=dict(names=list(pb.names), matrix=u.correlation.tolist()),
        covariance=covariance_block(res),
        identifiability=dict(
            scaled_singular_values=(sv / sv[0]).tolist(), threshold_std=IDENTIFIABLE_STD,
            note="data only (no prior); scaled parameters: log-values (relative) and offsets "
                 f"in um; a combination is identified when its standard error is below "
                 f"{IDENTIFIABLE_STD}",
            directions=directions),
        series_compliance=u.compliance,
        noise=u.noise,
        linearity=(None if res.linearity is None else dict(
            note="rise of 2 x cost at -1.96 / +1.96 standard errors along each parameter's "
                 "conditional path, / 3.84 (1 = quadratic); profile intervals replace the "
                 "linearised ones where a side is off by more than 10 %",
            table={n: res.linearity[i].tolist() for i, n in enumerate(pb.names)})),
        fit=dict(
            converged=fr.converged, convergence=fr.convergence_text,
            optimizer_converged=fr.optimizer_converged, remaining_step_sigma=fr.remaining_step,
            iterations=fr.steps, cost=fr.cost, gradient_max=float(np.max(np.abs(grad))),
            starts=[{k: v for k, v in s.items() if k != "theta"} for s in fr.starts],
            starts_reached_best=fr.starts_agreeing,
            staged=fr.stage1,
            seconds=res.seconds, fit_seconds=fr.seconds,
            method="optimistix dogleg (Gauss-Newton point by SVD truncated at the "
                   "information floor; steps capped at 2) on log-parameters (offsets in um), "
                   "every start one lane of one compiled solve, "
                   + ("maximum a posteriori with the stated priors" if pb.priors is not None
                      else "maximum likelihood (no priors)")
                   + "; forward-mode Jacobians; multi-start",
            measurement_model="sine records: Fourier coefficients of force and worktable "
                              "acceleration; per record the linearised FRF, its first-order "
                              "harmonic-balance correction or the periodic orbit (harmonic "
                              "balance, from the record's measured state or its sweep), "
                              f"the simplest whose predicted error is below {MODEL_ERROR:g} "
                              "standard errors; chirp/random/hammer: FRF lines vs the "
                              "linearised FRF, a chirp's lines whose predicted error exceeds "
                              f"{line_bound(MODEL_ERROR):g} standard errors left out",
            model_choice=fr.model_choice, orbit_harmonics=pb.structure.orbit_harmonics,
            model_issues=[dict(kind=k, text=t) for k, t in zip(fr.model_issue_kinds,
                                                                fr.model_issues)]),
        summary=summary_text(res),
    )


def _flag_lines(text: str, flags: dict) -> str:
    """Insert a comment line above each `section.key` line named in `flags`."""
    out, section = [], None
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("[") and s.endswith("]"):
            section = s[1:-1]
        elif section and "=" in s and not s.startswith("#"):
            key = f"{section}.{s.split('=')[0].strip()}"
            if key in flags:
                out.append(f"# {flags[key]}")
        out.append(line)
    return "\n".join(out) + "\n"


def write_identified(res: IdentificationResult, out_dir) -> list[Path]:
    """identified.toml (first speed) and, for per-speed offsets, one file per extra speed.

    Each fitted value that the data do not determine carries a comment line just above it:
    "NOT DETERMINED by the data", with what it rests on.
    """
    from bsfs_jax import params_to_toml
    from bsfs_jax.files import write_text_atomic

    out_dir = Path(out_dir)
    pb, u = res.problem, res.uncertainty
    per_speed = any(s is not None for s in pb.param_speeds)
    paths = []
    for j, speed in enumerate(pb.speeds):
        if j and not per_speed:
            break
        flags = {}
        for i, key in enumerate(pb.keys):
            if pb.param_speeds[i] not in (None, speed) or u.determined[i]:
                continue
            why = ("prior-dominated: the value is essentially the prior's" if pb.priors
                   is not None else "no information in the records")
            flags[key] = f"NOT DETERMINED by the data ({pb.names[i]}: {why}; see report.json)"
        name = "identified.toml" if j == 0 else f"identified_{speed:g}rpm.toml"
        header = ("Identified by `bsfs identify` from "
                  + ", ".join(Path(d.source if is_frf(d) else d.record.source).name
                              for d in res.data)
                  + f"\nfitted: {', '.join(pb.names)}; speed {speed:g} r/min"
                  + ("" if res.fit.converged else "\nWARNING: the fit did NOT converge")
                  + "\nsee report.json for standard errors and identifiability")
        text = _flag_lines(params_to_toml(res.params(speed), header=header), flags)
        write_text_atomic(out_dir / name, text)
        paths.append(out_dir / name)
    return paths
