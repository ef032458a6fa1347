"""The computations behind `bsfs reproduce`: one function per group of the paper's figures.

Compile sharing (the machine is small): every single steady-state run goes through
`bsfs_jax.simulate` with a `System` built beforehand, so thermal on/off, speeds, preloads and
ball diameters all reuse one compiled function (they only change array values); every
frequency sweep of Figs. 24-27 uses one `SweepConfig` and one number of points, so the
continued-sweep kernel is compiled once.

Motion labels come in two kinds. The *fixed-transient* (candidate) label reads the samples
after a fixed number of forcing periods, as the paper's fixed-length Runge-Kutta runs do
(`classify_motion`, `SweepResult.motions`). The *verified* label (`verify_points`,
`verify_sweep`) needs evidence: a converged, stable orbit for period-n, a Lyapunov
exponent whose 95 % interval excludes zero plus a broadband spectrum for chaos, and so on;
otherwise the point is "unresolved". The claims of Figs. 18-21 and 24-25 are judged on the
verified labels only.
"""

import dataclasses
import time
from pathlib import Path

import equinox as eqx
import numpy as np

from .._numerics import half_range
from ..analysis import (
    ClassifierSettings,
    VerifySettings,
    amplitude_spectrum,
    bsfs_problem,
    classify_motion,
    largest_lyapunov,
    slowest_decay_rate,
    verify_points,
)
from ..machine import modes, simulate
from ..model import Sinusoid, build_system, vector_field
from ..params import preset as load_preset
from ..solvers import SolverSettings, result_codes, result_from_codes, result_text
from ._judge import point_class, subharmonic_fraction

SPEEDS_RPM = (1000.0, 2000.0, 3000.0)
PRELOADS_N = (1000.0, 1500.0, 2000.0)
#: (figure, frequency [Hz], paper's motion label, paper's amplitude [m])
MOTION_CASES = (
    ("fig18", 500.0, "period-1", 250e-6),
    ("fig19", 1082.0, "period-7", 85.12e-6),
    ("fig20", 382.0, "quasi-periodic", 226e-6),
    ("fig21", 636.6, "chaotic", 544.5e-6),
)
#: (figure, parameter, values, label, unit)
SWEEP_VARIANTS = (
    ("fig24", "bearing.balls", (13.0, 16.0, 20.0), "bearing balls per row", ""),
    ("fig25", "nut.balls", (40.0, 50.0, 60.0), "nut balls per half", ""),
    ("fig26", "bearing.contact_angle_deg", (30.0, 40.0, 50.0), "bearing contact angle", " deg"),
    ("fig27", "nut.contact_angle_deg", (30.0, 40.0, 50.0), "nut contact angle", " deg"),
)
DIAMETERS_MM = {
    "bearing.ball_diameter_mm": (6.35, 9.525),  # 1/4" .. 3/8"
    "nut.ball_diameter_mm": (2.381, 3.969),  # 3/32" .. 5/32"
}


@dataclasses.dataclass(frozen=True)
class ReproduceSettings:
    """What a reproduction run computes (static: changing a horizon recompiles).

    - `preset`: parameter preset (default "paper-tuned", see REPRODUCTION.md).
    - `force_n`: the paper's excitation amplitude for Figs. 18-27 [N].
    - `thermal_frequency_hz`, `thermal_force_n`: excitation of Figs. 13-17 (the paper does
      not state it; see the report).
    - `transient_periods`, `periods`, `samples_per_period`: horizon of single runs.
    - `lyapunov_periods`: periods averaged for the largest Lyapunov exponent (Figs. 18-21).
    - `n_diameters`: ball diameters in each waterfall (Figs. 22-23), at
      `waterfall_frequency_hz`.
    - `sweep_start_hz`, `sweep_stop_hz`, `sweep_points`: the frequency grid of Figs. 24-27,
      swept up and down (continued); `sweep_transient`, `sweep_continued_transient`,
      `sweep_periods`, `sweep_samples_per_period`: its horizon.
    - `rtol`, `atol`, `solver`: integration settings.
    - `verify_block_periods`, `verify_max_blocks`, `verify_min_blocks`: the verifier's
      continuation blocks for points whose samples lead to no orbit (`VerifySettings`;
      the other verifier settings are its defaults).
    """

    preset: str = "paper-tuned"
    force_n: float = 5000.0
    thermal_frequency_hz: float = 500.0
    thermal_force_n: float = 5000.0
    transient_periods: int = 400
    periods: int = 64
    samples_per_period: int = 64
    lyapunov_periods: int = 200
    n_diameters: int = 9
    waterfall_frequency_hz: float = 500.0
    sweep_start_hz: float = 100.0
    sweep_stop_hz: float = 3500.0
    sweep_points: int = 86
    sweep_transient: int = 300
    sweep_continued_transient: int = 100
    sweep_periods: int = 48
    sweep_samples_per_period: int = 32
    exciter_periods: int = 20
    exciter_transient: int = 60
    rtol: float = 1e-8
    atol: float = 1e-12
    solver: str = "dopri5-fused"
    verify_block_periods: int = 256
    verify_max_blocks: int = 8
    verify_min_blocks: int = 3
    quick: bool = False

    @classmethod
    def quick_settings(cls, **overrides) -> "ReproduceSettings":
        """Coarse grids and short horizons (about a minute on 2 CPU cores): a smoke run."""
        base = dict(transient_periods=200, periods=24, samples_per_period=32,
                    lyapunov_periods=24, n_diameters=4, sweep_points=6, sweep_start_hz=200.0,
                    sweep_stop_hz=2400.0, sweep_transient=60, sweep_continued_transient=12,
                    sweep_periods=12, sweep_samples_per_period=16, exciter_periods=6,
                    exciter_transient=20, rtol=1e-7, atol=1e-11, verify_block_periods=64,
                    verify_max_blocks=2, verify_min_blocks=1, quick=True)
        base.update(overrides)
        return cls(**base)

    def solver_settings(self) -> SolverSettings:
        return SolverSettings(rtol=float(self.rtol), atol=float(self.atol), solver=self.solver)

    def verify_settings(self) -> VerifySettings:
        """The verifier's settings (its defaults, with this run's block budget)."""
        return VerifySettings(block_periods=int(self.verify_block_periods),
                              max_blocks=int(self.verify_max_blocks),
                              min_blocks=int(self.verify_min_blocks),
                              align_periods=min(16, int(self.verify_block_periods) // 8))


@dataclasses.dataclass
class Reproduction:
    """What `reproduce` produced: the claims table rows, numbers, figure paths, timings."""

    out_dir: Path
    rows: list
    numbers: dict
    figures: dict
    timings: dict
    settings: ReproduceSettings

    @property
    def report_path(self) -> Path:
        return self.out_dir / "REPRODUCTION.md"


def _steady(system, frequency_hz, force_n, s: ReproduceSettings, *, periods=None,
            transient=None):
    traj = simulate(system, frequency_hz=float(frequency_hz), force_n=float(force_n),
                    periods=periods or s.periods,
                    transient_periods=s.transient_periods if transient is None else transient,
                    samples_per_period=s.samples_per_period, rtol=s.rtol, atol=s.atol,
                    solver=s.solver, throw=False)
    return traj


def _traj_numbers(traj, dof=2) -> dict:
    x = np.asarray(traj.displacement)[:, dof]
    return {
        "status": int(result_codes(traj.result)),
        "status_message": str(result_text(traj.result)),
        "amplitude_m": float(half_range(x)),
        "max_abs_m": float(np.abs(x).max()),
        "mean_m": float(x.mean()),
    }


def _thermal_numbers(system) -> dict:
    th = system.thermal
    rise = np.asarray(th.temperature_rise_k)
    return {
        "rise_k": {"bearing": float(rise[0]), "screw": float(rise[1]), "nut": float(rise[2])},
        "nut_offset_m": float(th.nut_offset),
        "bearing_offset_m": float(th.bearing_offset),
        "nut_preload_deformation_m": float(system.nut.a - system.nut.a0),
        "bearing_preload_deformation_m": float(system.bearing.a - system.bearing.a0),
    }


@eqx.filter_jit
def _system_and_modes(params):
    system = build_system(params)
    return system, modes(system).frequencies_hz


def thermal_experiments(params, s: ReproduceSettings) -> dict:
    """Figs. 13-17: thermal deformation on/off, speeds, preloads (one compiled simulate)."""
    f, force = s.thermal_frequency_hz, s.thermal_force_n
    out = {"frequency_hz": f, "force_n": force, "runs": {}}
    cases = {"thermal": params, "no_thermal": params.replace("thermal.enabled", False)}
    for n in SPEEDS_RPM:
        cases[f"speed_{n:.0f}"] = params.replace("thermal.speed_rpm", n)
    for fp in PRELOADS_N:
        cases[f"preload_{fp:.0f}"] = params.replace("nut.preload_n", fp)
    trajs = {}
    for name, p in cases.items():
        system, mode_hz = _system_and_modes(p)
        traj = _steady(system, f, force, s)
        trajs[name] = traj
        row = _traj_numbers(traj)
        row.update(_thermal_numbers(system))
        row["first_mode_hz"] = float(np.asarray(mode_hz)[0])
        out["runs"][name] = row
    return out, trajs


def motion_experiments(params, s: ReproduceSettings, *, cases=MOTION_CASES,
                       transient_periods: int | None = None) -> tuple[dict, dict]:
    """Figs. 18-21: steady response, motion class and largest Lyapunov exponent.

    Each point gets two labels: the fixed-transient one (`motion`, `reading`: the samples
    after `transient_periods` forcing periods, default `s.transient_periods`) and the
    verified one (`verified_motion` with its evidence, from `verify_points` continuing the
    same run). `free_vibration_left` is exp(-sigma t) at the start of the record: the part
    of the slowest linear mode's free vibration (decay rate sigma) the transient leaves.
    """
    system, _ = _system_and_modes(params)
    n_tr = s.transient_periods if transient_periods is None else int(transient_periods)
    out, trajs = {}, {}
    for key, f, paper_label, paper_amp in cases:
        traj = _steady(system, f, s.force_n, s, transient=n_tr)
        row = _traj_numbers(traj)
        period = 1.0 / f
        lyap = largest_lyapunov(vector_field, traj.final_state, (system, Sinusoid(s.force_n, f)),
                                interval=period, n_intervals=s.lyapunov_periods,
                                settings=s.solver_settings())
        # Drop the first quarter of the intervals: the tangent vector starts in an arbitrary
        # direction, and its alignment transient would bias a short average upwards.
        logs = np.asarray(lyap.log_growth)
        lam = float(np.mean(logs[len(logs) // 4:]) / period) if bool(lyap.ok) \
            else float("nan")
        strobe = np.asarray(traj.stroboscopic())
        state = np.asarray(traj.state)
        x = state[:, 2]
        motion = classify_motion(strobe, signal=x[:-1], lyapunov_per_period=lam * period,
                                 scale=half_range(state, axis=0), result=traj.result,
                                 settings=ClassifierSettings(tol=2e-3))
        freqs, amp = amplitude_spectrum(x[:-1], period / s.samples_per_period, window="rect")
        sub = subharmonic_fraction(amp, freqs * period, guard=0)
        row.update(frequency_hz=f, lyapunov_per_s=lam, lyapunov_per_period=lam * period,
                   motion=motion.label, motion_kind=motion.kind,
                   reading=point_class(motion, sub), subharmonic_fraction=sub,
                   spectral_line_fraction=motion.line_fraction, paper_motion=paper_label,
                   paper_amplitude_m=paper_amp, transient_periods=n_tr,
                   record_periods=s.periods)
        out[key] = row
        trajs[key] = traj
    _verify_motion(params, s, out, trajs)
    return out, trajs


def _verify_motion(params, s: ReproduceSettings, rows: dict, trajs: dict) -> None:
    """Add the verified label and its evidence to each row of `motion_experiments`."""
    keys = list(rows)
    freqs = np.array([rows[k]["frequency_hz"] for k in keys], dtype=float)
    problem = bsfs_problem(params, force_n=s.force_n)
    strobes = np.array([np.asarray(trajs[k].stroboscopic()) for k in keys])
    amps = np.array([half_range(np.asarray(trajs[k].state), axis=0) for k in keys])
    n_tr = np.array([rows[k]["transient_periods"] for k in keys], dtype=float)
    n_rec = np.array([rows[k]["record_periods"] for k in keys], dtype=float)
    ok = np.array([rows[k]["status"] == 0 for k in keys])
    verdicts = {}
    if ok.any():
        got = verify_points(problem, freqs[ok], strobes[ok], amps[ok], 1.0 / freqs[ok],
                            (n_tr[ok] + n_rec[ok]) / freqs[ok], settings=s.verify_settings())
        for j, k in enumerate(np.array(keys)[ok]):
            verdicts[str(k)] = {name: got[name][j] for name in got}
    sigma = slowest_decay_rate(problem, freqs)
    for j, k in enumerate(keys):
        v = verdicts.get(k)
        row = rows[k]
        left = float(np.exp(-sigma[j] * n_tr[j] / freqs[j]))
        row.update(decay_rate_per_s=float(sigma[j]), free_vibration_left=left)
        if v is None:
            row.update(verified_motion="failed", verified=False, verify_reason=(
                f"the fixed-transient run failed: {row['status_message']}"))
            continue
        row.update(
            verified_motion=str(v["motion"]), verified=bool(v["verified"]),
            verified_period_n=int(v["period_n"]),
            verified_amplitude_m=float(v["amplitude"]),
            orbit_residual=float(v["orbit_residual"]),
            max_multiplier=float(v["max_multiplier"]),
            verified_lyapunov_per_period=float(v["lyapunov_per_period"]),
            lyapunov_low=float(v["lyapunov_low"]), lyapunov_high=float(v["lyapunov_high"]),
            rotation_number=float(v["rotation_number"]),
            curve_error=float(v["curve_error"]),
            verified_line_fraction=float(v["line_fraction"]),
            verify_transient_s=float(v["transient"]), verify_reason=str(v["reason"]))


def diameter_experiments(params, s: ReproduceSettings) -> dict:
    """Figs. 22-23: spectra of the nut response against ball diameter (fixed excitation)."""
    out = {}
    f = s.waterfall_frequency_hz
    for name, (lo, hi) in DIAMETERS_MM.items():
        values = np.linspace(lo, hi, s.n_diameters)
        spectra, amps, harmonics, status = [], [], [], []
        freqs = None
        for d in values:
            system, _ = _system_and_modes(params.replace(name, float(d)))
            traj = _steady(system, f, s.force_n, s)
            x = np.asarray(traj.displacement)[:-1, 2]
            dt = float(traj.period) / s.samples_per_period
            freqs, amp = amplitude_spectrum(x, dt, window="rect")
            spectra.append(amp)
            amps.append(half_range(x))
            # Amplitudes at the forcing frequency and its 2nd..4th multiples.
            idx = [int(np.argmin(np.abs(freqs - k * f))) for k in (1, 2, 3, 4)]
            harmonics.append([float(amp[i]) for i in idx])
            status.append(int(result_codes(traj.result)))
        out[name] = {"values_mm": values, "freqs_hz": freqs, "spectra_m": np.array(spectra),
                     "amplitude_m": np.array(amps), "harmonics_m": np.array(harmonics),
                     "status": np.array(status), "frequency_hz": f,
                     "status_messages": [str(result_text(result_from_codes(c))) for c in status]}
    return out


def exciter_experiments(params, s: ReproduceSettings) -> tuple[dict, dict]:
    """Figs. 10-12: 100 N at 100/120/150 Hz (the model side only; no measurements here)."""
    system, _ = _system_and_modes(params)
    out, trajs = {}, {}
    for f in (100.0, 120.0, 150.0):
        traj = _steady(system, f, 100.0, s, periods=s.exciter_periods,
                       transient=s.exciter_transient)
        a = np.asarray(traj.acceleration)[:, 2]
        out[f"{f:.0f}"] = {"frequency_hz": f, "status": int(result_codes(traj.result)),
                           "status_message": str(result_text(traj.result)),
                           "acceleration_amplitude_m_s2": float(half_range(a)),
                           "displacement_amplitude_m": float(half_range(
                               np.asarray(traj.displacement)[:, 2]))}
        trajs[f] = traj
    return out, trajs


def load_params_for(s: ReproduceSettings):
    return load_preset(s.preset)


class Timer:
    """Wall-clock time of each stage (reported in REPRODUCTION.md)."""

    def __init__(self):
        self.stages = {}
        self._t = time.perf_counter()

    def lap(self, name):
        now = time.perf_counter()
        self.stages[name] = now - self._t
        self._t = now
