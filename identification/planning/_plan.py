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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..fitting import DEFAULT_FIT, Problem
from ..intervals import IDENTIFIABLE_STD
from ..measurement import HarmonicData, predict, require_x64, traced_residual_and_jacobian
from ..records import Record


@dataclasses.dataclass(frozen=True)
class PlannedRecord:
    """A planned record: a sine at `frequency_hz`, or (`excitation="chirp"`) a linear burst
    chirp from `start_hz` to `stop_hz` at amplitude `force_n`, fitted as its FRF."""

    frequency_hz: float
    force_n: float
    speed_rpm: float
    duration_s: float = 2.0
    excitation: str = "sine"
    start_hz: float | None = None
    stop_hz: float | None = None


@dataclasses.dataclass(frozen=True)
class TestPlan:
    name: str
    records: tuple

    @property
    def test_time_s(self) -> float:
        return float(sum(r.duration_s for r in self.records))


PLAN_RATIO = 0.3
STEPPED = (100, 150, 250, 400, 600, 800, 950, 1050, 1150, 1300, 1700, 2500)


# Sines of a through-resonance plan, as fractions of the first natural frequency: two of
# them within +-10 % of it, where the joints' nonlinearity and the damping show.
RESONANCE_RATIOS = (0.62, 0.84, 0.95, 1.03, 1.24)


def resonance_plan(resonance_hz: float, speed_rpm: float = 2000.0) -> TestPlan:
    """100 N stepped sines (0.5 s each, swept up) around the first resonance at
    `resonance_hz` (`RESONANCE_RATIOS`), and a 5 N chirp 50-2500 Hz that locates it."""
    sines = tuple(PlannedRecord(round(r * resonance_hz, 1), 100.0, speed_rpm, 0.5)
                  for r in RESONANCE_RATIOS)
    chirp = PlannedRecord(float("nan"), 5.0, speed_rpm, 1.0, "chirp", 50.0, 2500.0)
    return TestPlan(f"through the resonance: 5 sines 0.62-1.24 x {resonance_hz:.0f} Hz, "
                    "100 N + chirp", sines + (chirp,))


def candidate_plans(include_nonlinear: bool = False,
                    resonance_hz: float | None = None) -> list[TestPlan]:
    """The default candidates: the paper's test and richer ones (see `bsfs plan-test`).

    `include_nonlinear` adds a plan with 3000 N records, whose Fisher information needs the
    periodic-orbit model (a minute of compilation); it is never needed to determine the
    default or the preload parameters, which the 100 N stepped sine determines.
    `resonance_hz` (the prior's first natural frequency) adds `resonance_plan`: sines near
    the resonance, whose Fisher information also comes from the periodic-orbit model. The
    sines are placed relative to the prior's resonance; in the test, place them relative to
    the one the chirp measures (`bsfs identify` reports it as the first estimate).
    """
    paper = tuple(PlannedRecord(f, 100.0, 2000.0, 2.0) for f in (100.0, 120.0, 150.0))
    speeds = tuple(PlannedRecord(f, 100.0, s, 2.0) for s in (1000.0, 2000.0, 3000.0)
                   for f in (100.0, 120.0, 150.0))
    stepped = tuple(PlannedRecord(float(f), 100.0, 2000.0, 0.5) for f in STEPPED)
    rich = stepped + tuple(PlannedRecord(f, 3000.0, 2000.0, 0.5) for f in (150.0, 300.0)) + \
        tuple(PlannedRecord(f, 100.0, s, 0.5) for s in (1000.0, 3000.0) for f in (150.0, 950.0))
    chirp = PlannedRecord(float("nan"), 5.0, 2000.0, 1.0, "chirp", 50.0, 2500.0)
    few = tuple(PlannedRecord(f, 100.0, 2000.0, 0.5) for f in (150.0, 400.0, 700.0, 1700.0,
                                                             2500.0))
    plans = [TestPlan("paper: 100/120/150 Hz, 100 N, 1 speed", paper),
             TestPlan("paper at 3 speeds", speeds),
             TestPlan("stepped sine 100-2500 Hz, 100 N", stepped),
             TestPlan("chirp 50-2500 Hz, 5 N, 1 s", (chirp,)),
             TestPlan("5 sines off resonance + chirp 50-2500 Hz", few + (chirp,))]
    if resonance_hz is not None:
        plans.append(resonance_plan(resonance_hz))
    if include_nonlinear:
        plans.append(TestPlan("stepped sine + 3000 N + 3 speeds", rich))
    return plans


def plan_from_records(name, records) -> TestPlan:
    """The design of existing records (to compare predicted with achieved errors)."""
    return TestPlan(name, tuple(PlannedRecord(r.frequency_hz, r.force_amplitude_n, r.speed_rpm,
                                              r.duration) for r in records))


def _chirp_force_spectrum(pr: PlannedRecord, sample_rate_hz):
    """Line frequencies and |DFT|^2 of the planned chirp's force (numpy, rectangular)."""
    n = int(round(pr.duration_s * sample_rate_hz))
    t = np.arange(n) / sample_rate_hz
    rate = (pr.stop_hz - pr.start_hz) / pr.duration_s
    taper = 0.02 * pr.duration_s
    ramp = np.clip(np.minimum(t, pr.duration_s - t) / taper, 0.0, 1.0)
    force = pr.force_n * np.sin(0.5 * np.pi * ramp) ** 2 * np.sin(
        2 * np.pi * (pr.start_hz * t + 0.5 * rate * t**2))
    spec = np.fft.rfft(force)
    f = np.fft.rfftfreq(n, 1.0 / sample_rate_hz)
    keep = (f >= pr.start_hz) & (f <= min(pr.stop_hz, 0.4 * sample_rate_hz))
    return f[keep], np.abs(spec[keep]) ** 2, n


@eqx.filter_jit
def _chirp_accelerance(prior, speed_rpm, f):
    """The linear model's accelerance [m/s^2 per N] at the lines `f` [Hz] and the speed,
    as one program (called eagerly it ran op by op: 95 small compiled programs in a cold
    `bsfs plan-test`)."""
    import bsfs_jax

    from ..measurement import linear_acceleration

    system = bsfs_jax.build_system(prior.replace("thermal.speed_rpm", speed_rpm))
    return linear_acceleration(system, f, jnp.ones(f.shape, complex))


def _planned_frf(pr: PlannedRecord, j, prior, sample_rate_hz, accel_snr_db, force_snr_db):
    """The FRF lines a planned chirp gives, with variances from the sensors' SNR.

    A white sensor noise sigma^2 per sample puts N sigma^2 / 2 into each of Re and Im of
    a DFT line, so a line's accelerance A_k / F_k carries (N / (2 |F_k|^2)) (sigma_a^2 +
    |H_k|^2 sigma_f^2), with sigma set by the SNR relative to each channel's RMS.
    """
    from ..records import FrfRecord

    f, f2, n = _chirp_force_spectrum(pr, sample_rate_hz)
    h = np.asarray(_chirp_accelerance(prior, jnp.asarray(pr.speed_rpm, float), jnp.asarray(f)))
    rms_f = np.sqrt(2.0 * np.sum(f2)) / n
    rms_a = np.sqrt(2.0 * np.sum(np.abs(h) ** 2 * f2)) / n
    sa2 = (rms_a * 10 ** (-accel_snr_db / 20)) ** 2
    sf2 = (rms_f * 10 ** (-force_snr_db / 20)) ** 2
    var = n / (2.0 * f2) * (sa2 + np.abs(h) ** 2 * sf2)
    return FrfRecord(f, h, np.stack([var, var], 1), None, 1, pr.speed_rpm, 20.0,
                     dict(variance_dof=100.0), f"plan_{j}", "chirp", pr.force_n)


def _planned_data(plan: TestPlan, prior, sample_rate_hz, distortion, accel_snr_db=35.0,
                  force_snr_db=40.0):
    out = []
    for j, pr in enumerate(plan.records):
        if pr.excitation == "chirp":
            out.append(_planned_frf(pr, j, prior, sample_rate_hz, accel_snr_db, force_snr_db))
            continue
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


def fisher_std(plan: TestPlan, prior, fit_names=DEFAULT_FIT, **kw):
    """(names, expected std of the scaled parameters, scaled singular values, problem) of
    one plan (see `fisher_stds`)."""
    return fisher_stds([plan], prior, fit_names, **kw)[0]


def _batched(fn, problems, *args):
    """`fn(*args, fit_data, structure)` for every problem of one layout, in one program."""
    stacked = jax.tree_util.tree_map(lambda *xs: np.stack(xs),
                                     *[pb.fit_data for pb in problems])
    return fn(*args, stacked, problems[0].structure)


@eqx.filter_jit
def _predictions(theta, data, structure):
    return jax.vmap(lambda d: predict(theta, d, structure))(data)


@eqx.filter_jit
def _jacobians(theta, data, structure):
    return jax.vmap(lambda d: traced_residual_and_jacobian(theta, d, structure)[1])(data)


def _problems(datas, prior, fit_names, **kw):
    """Problems of the plans, padded to one layout where their structures agree."""
    first = [Problem(d, prior, fit_names, priors=None, **kw) for d in datas]
    pad = first[0].common_padding(first[1:])
    if pad is None:
        return first, False
    return [pb.padded(pad) for pb in first], True


def fisher_stds(plans, prior, fit_names=DEFAULT_FIT, *, accel_snr_db=35.0,
                force_snr_db=40.0, sample_rate_hz=10240.0, distortion=(0.04, 0.02),
                nonlinear_ratio=PLAN_RATIO):
    """Per plan: (names, expected std of the scaled parameters, scaled singular values,
    problem).

    `nonlinear_ratio`: the joint amplitude / preload deformation above which the
    periodic-orbit model replaces the linearised one (`PLAN_RATIO`); None: the fit's own
    rule (predicted linearisation error against the planned noise), which reproduces a
    fit's models exactly but compiles the orbit model more often. Every plan is padded to
    one layout, so the predicted signals of all plans are one compiled program and their
    Jacobians another.
    """
    datas = [_planned_data(plan, prior, sample_rate_hz, distortion, accel_snr_db,
                           force_snr_db) for plan in plans]
    # The noise levels follow the predicted signal levels, from the same models as the
    # Jacobian below (the harmonics of a strongly nonlinear record are the orbit's).
    firsts, common = _problems(
        datas, prior, fit_names,
        nonlinear_ratio=PLAN_RATIO if nonlinear_ratio is None else nonlinear_ratio)
    zero = jnp.zeros(firsts[0].n_params)
    if common:
        preds = jax.tree_util.tree_map(np.asarray, _batched(_predictions, firsts, zero))
    noisy_sets = []
    for k, (data, first) in enumerate(zip(datas, firsts)):
        if common:
            acc = first.per_record([tuple(x[k] for x in group) for group in preds])
        else:
            acc = first.model_harmonics(np.zeros(first.n_params))
        noisy = []
        for d, a in zip(data, acc):
            if hasattr(d, "accelerance"):
                noisy.append(d)
                continue
            n = d.n_samples
            var_a = 2 * (np.sum(np.abs(a) ** 2) / 2) * 10 ** (-accel_snr_db / 10) / n
            var_f = 2 * (np.sum(np.abs(d.force) ** 2) / 2) * 10 ** (-force_snr_db / 10) / n
            noisy.append(dataclasses.replace(d, acceleration=np.asarray(a),
                                             acceleration_var=np.full((a.size, 2), var_a),
                                             force_var=np.full((a.size, 2), var_f)))
        noisy_sets.append(noisy)
    # Planning accepts the linearised model up to a joint amplitude of 30 % of the preload
    # deformation (the 100 N sine at resonance): it changes the predicted standard errors by
    # a few per cent, and saves compiling the periodic-orbit model for the whole table.
    problems, common = _problems(noisy_sets, prior, fit_names, nonlinear_ratio=nonlinear_ratio)
    if common:
        jacs = np.asarray(_batched(_jacobians, problems, zero))
    out = []
    for k, problem in enumerate(problems):
        jac = jacs[k] if common else problem.rj(np.zeros(problem.n_params))[1]
        jac = jac[:problem.used_mask().size][problem.used_mask()]
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)
        inv = np.where(sv > sv[0] * 1e-14, 1.0 / np.maximum(sv, 1e-300) ** 2, np.inf)
        with np.errstate(invalid="ignore"):
            var = np.where(np.any((np.abs(vt) > 1e-3) & ~np.isfinite(inv)[:, None], axis=0),
                           np.inf,
                           (vt.T**2 * np.where(np.isfinite(inv), inv, 0.0)[None, :]).sum(1))
        out.append((problem.names, np.sqrt(var), sv / sv[0], problem))
    return out


def plan_test(prior, fit_names=DEFAULT_FIT, plans=None, *, accel_snr_db=35.0,
              force_snr_db=40.0, threshold=IDENTIFIABLE_STD) -> dict:
    """Compare plans; recommend the shortest one that identifies every chosen parameter."""
    require_x64("identification.plan_test")
    plans = candidate_plans() if plans is None else plans
    rows = []
    for plan, (names, std, sv, _) in zip(plans, fisher_stds(
            plans, prior, fit_names, accel_snr_db=accel_snr_db, force_snr_db=force_snr_db)):
        ok = std < threshold
        rows.append(dict(name=plan.name, records=len(plan.records), test_time_s=plan.test_time_s,
                         max_force_n=max(r.force_n for r in plan.records),
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
