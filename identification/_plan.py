"""Experiment design: compare candidate exciter tests by their Fisher information.

For a planned record (frequency, force, speed, duration, sample rate, SNR) the prior model
predicts the force and acceleration harmonics; the accelerometer and force-sensor noise
at the stated SNR give each coefficient's standard error (2 sigma^2 / N per component).
The Jacobian of the same noise-weighted residual the fit uses (JAX forward mode, at the
prior) gives the Fisher information J^T J of the scaled parameters; its inverse is the
expected covariance of a fit on that test.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ._measurement import HarmonicData
from ._problem import DEFAULT_FIT, Problem
from ._records import Record
from ._uncertainty import IDENTIFIABLE_STD


@dataclasses.dataclass(frozen=True)
class PlannedRecord:
    frequency_hz: float
    force_n: float
    speed_rpm: float
    duration_s: float = 2.0


@dataclasses.dataclass(frozen=True)
class TestPlan:
    name: str
    records: tuple

    @property
    def test_time_s(self) -> float:
        return float(sum(r.duration_s for r in self.records))


STEPPED = (100, 150, 250, 400, 600, 800, 950, 1050, 1150, 1300, 1700, 2500)


def candidate_plans() -> list[TestPlan]:
    """The default candidates: the paper's test and richer ones (see `bsfs plan-test`)."""
    paper = tuple(PlannedRecord(f, 100.0, 2000.0, 2.0) for f in (100.0, 120.0, 150.0))
    speeds = tuple(PlannedRecord(f, 100.0, s, 2.0) for s in (1000.0, 2000.0, 3000.0)
                   for f in (100.0, 120.0, 150.0))
    stepped = tuple(PlannedRecord(float(f), 100.0, 2000.0, 0.5) for f in STEPPED)
    rich = stepped + tuple(PlannedRecord(f, 3000.0, 2000.0, 0.5) for f in (150.0, 300.0)) + \
        tuple(PlannedRecord(f, 100.0, s, 0.5) for s in (1000.0, 3000.0) for f in (150.0, 950.0))
    return [TestPlan("paper: 100/120/150 Hz, 100 N, 1 speed", paper),
            TestPlan("paper at 3 speeds", speeds),
            TestPlan("stepped sine 100-2500 Hz, 100 N", stepped),
            TestPlan("stepped sine + 3000 N + 3 speeds", rich)]


def plan_from_records(name, records) -> TestPlan:
    """The design of existing records (to compare predicted with achieved errors)."""
    return TestPlan(name, tuple(PlannedRecord(r.frequency_hz, r.force_amplitude_n, r.speed_rpm,
                                              r.duration) for r in records))


def _planned_data(plan: TestPlan, prior, sample_rate_hz, distortion):
    out = []
    for j, pr in enumerate(plan.records):
        meta = dict(frequency_hz=pr.frequency_hz, force_amplitude_n=pr.force_n,
                    sample_rate_hz=sample_rate_hz, speed_rpm=pr.speed_rpm, ambient_c=20.0)
        rec = Record(np.zeros(0), np.zeros(0), np.zeros(0), pr.frequency_hz, pr.force_n,
                     sample_rate_hz, pr.speed_rpm, 20.0, meta, f"plan_{j}")
        force = pr.force_n * np.asarray([1.0] + list(distortion), complex)
        h = force.size
        out.append(HarmonicData(pr.frequency_hz, np.arange(1, h + 1), force,
                                np.zeros(h, complex), np.zeros((h, 2)), np.zeros((h, 2)),
                                0.0, 0.0, 0.0, 0.0, int(pr.duration_s * sample_rate_hz), rec))
    return out


def fisher_std(plan: TestPlan, prior, fit_names=DEFAULT_FIT, *, accel_snr_db=35.0,
               force_snr_db=40.0, sample_rate_hz=10240.0, distortion=(0.04, 0.02)):
    """(names, expected std of the scaled parameters, scaled singular values, problem)."""
    data = _planned_data(plan, prior, sample_rate_hz, distortion)
    first = Problem(data, prior, fit_names, priors=None)
    acc = first.model_harmonics(np.zeros(first.n_params))
    noisy = []
    for d, a in zip(data, acc):
        n = d.n_samples
        var_a = 2 * (np.sum(np.abs(a) ** 2) / 2) * 10 ** (-accel_snr_db / 10) / n
        var_f = 2 * (np.sum(np.abs(d.force) ** 2) / 2) * 10 ** (-force_snr_db / 10) / n
        noisy.append(dataclasses.replace(d, acceleration=np.asarray(a),
                                         acceleration_var=np.full((a.size, 2), var_a),
                                         force_var=np.full((a.size, 2), var_f)))
    problem = Problem(noisy, prior, fit_names, priors=None)
    jac = np.asarray(problem._jac_jit(jnp.zeros(problem.n_params), problem.groups))[
        problem.used_mask()]
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    inv = np.where(sv > sv[0] * 1e-14, 1.0 / np.maximum(sv, 1e-300) ** 2, np.inf)
    with np.errstate(invalid="ignore"):
        var = np.where(np.any((np.abs(vt) > 1e-3) & ~np.isfinite(inv)[:, None], axis=0),
                       np.inf, (vt.T**2 * np.where(np.isfinite(inv), inv, 0.0)[None, :]).sum(1))
    return problem.names, np.sqrt(var), sv / sv[0], problem


def plan_test(prior, fit_names=DEFAULT_FIT, plans=None, *, accel_snr_db=35.0,
              force_snr_db=40.0, threshold=IDENTIFIABLE_STD) -> dict:
    """Compare plans; recommend the shortest one that identifies every chosen parameter."""
    plans = candidate_plans() if plans is None else plans
    rows = []
    for plan in plans:
        names, std, sv, _ = fisher_std(plan, prior, fit_names, accel_snr_db=accel_snr_db,
                                       force_snr_db=force_snr_db)
        ok = std < threshold
        rows.append(dict(name=plan.name, records=len(plan.records), test_time_s=plan.test_time_s,
                         expected_std=dict(zip(names, std.tolist())),
                         scaled_singular_values=sv.tolist(), identified=int(ok.sum()),
                         all_identified=bool(ok.all()),
                         design=[dataclasses.asdict(r) for r in plan.records]))
    good = [r for r in rows if r["all_identified"]]
    best = (min(good, key=lambda r: (r["test_time_s"], r["records"])) if good
            else max(rows, key=lambda r: r["identified"]))
    return dict(plans=rows, recommended=best["name"], all_identified=bool(good),
                noise=dict(accel_snr_db=accel_snr_db, force_snr_db=force_snr_db),
                threshold=threshold, parameters=list(rows[0]["expected_std"]))
