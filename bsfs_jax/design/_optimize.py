"""Gradient-based design optimisation within bounds, with a minimum-stiffness constraint.

Formulation (stated so a designer can judge it):

- variables: named parameters theta_i in file units, kept inside [lo_i, hi_i] by the
  smooth transform theta = lo + (hi - lo) sigmoid(z), z unconstrained;
- objective: J(z) = s m(theta) / |m(theta_0)|, s = +1 to minimise, -1 to maximise (each
  metric has a sensible direction, e.g. maximise the natural frequency and the static
  stiffness, minimise amplitudes, the Floquet modulus and the thermal error);
- constraint k_static(theta) >= k_min by an exterior quadratic penalty
  rho max(0, 1 - k_static / k_min)^2, solved for rho = 1e2, 1e4, 1e6 in turn (each solve
  warm-started from the last) until the violation is below 1e-3 relative;
- solver: optimistix BFGS on z with exact reverse-mode gradients (implicit
  differentiation through orbits and equilibria).
"""

import dataclasses
import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..params import BallScrewParams, lookup_key, validate
from ._metrics import Metric, OperatingPoint, get_metric, static_stiffness
from ._orbit import OrbitSettings
from ._sensitivity import (
    _check_finite,
    check_design_inputs,
    compiled,
    operating_point,
    parameter_values,
    with_values,
)

PENALTIES = (1e2, 1e4, 1e6)
CONSTRAINT_TOL = 1e-3


def default_bounds(params: BallScrewParams, names, spread: float = 0.3) -> dict:
    """+-`spread` (relative) about the current values, clipped to the vocabulary ranges."""
    out = {}
    for name, value in zip(names, parameter_values(params, names), strict=True):
        key = lookup_key(name)
        lo, hi = value * (1 - spread), value * (1 + spread)
        lo, hi = min(lo, hi), max(lo, hi)
        if key.low is not None:
            lo = max(lo, key.low + (1e-9 if key.low_open else 0.0))
        if key.high is not None:
            hi = min(hi, key.high - (1e-9 if key.high_open else 0.0))
        out[name] = (lo, hi)
    return out


@dataclasses.dataclass(frozen=True)
class OptimizationResult:
    """Outcome of `optimize` (values in file units and the metric's unit)."""

    metric: str
    unit: str
    direction: str
    names: tuple
    bounds: dict
    start: np.ndarray
    optimum: np.ndarray
    start_value: float
    optimum_value: float
    improvement_percent: float  # in the sensible direction (positive = better)
    min_stiffness_n_per_um: float | None
    start_stiffness_n_per_um: float
    optimum_stiffness_n_per_um: float
    constraint_satisfied: bool
    at_bound: tuple  # names that ended within 0.1 % of a bound
    steps: int
    converged: bool
    params: BallScrewParams = dataclasses.field(repr=False)

    def to_dict(self) -> dict:
        return {
            "metric": self.metric, "unit": self.unit, "direction": self.direction,
            "start_value": self.start_value, "optimum_value": self.optimum_value,
            "improvement_percent": self.improvement_percent,
            "constraint": {
                "min_static_stiffness_n_per_um": self.min_stiffness_n_per_um,
                "start_static_stiffness_n_per_um": self.start_stiffness_n_per_um,
                "optimum_static_stiffness_n_per_um": self.optimum_stiffness_n_per_um,
                "satisfied": self.constraint_satisfied,
                "method": "exterior quadratic penalty, rho = 1e2, 1e4, 1e6",
            },
            "variables": [
                {"name": n, "start": float(s), "optimum": float(o), "lower": self.bounds[n][0],
                 "upper": self.bounds[n][1], "at_bound": n in self.at_bound}
                for n, s, o in zip(self.names, self.start, self.optimum, strict=True)
            ],
            "bfgs_steps": self.steps, "converged": self.converged,
        }


#: The static-stiffness constraint's value on the host (start, after each penalty round,
#: optimum) as one program: called eagerly, its modal analysis ran op by op (95 small
#: compiled programs in a cold `bsfs optimize`).
_static_stiffness = eqx.filter_jit(static_stiffness)


@functools.lru_cache(maxsize=16)
def _objective(metric_name: str, names: tuple, settings: OrbitSettings):
    metric = get_metric(metric_name)
    sign = 1.0 if metric.direction == "min" else -1.0

    def theta_of(z, lo, hi):
        return lo + (hi - lo) * jax.nn.sigmoid(z)

    def objective(z, args):
        params, op, lo, hi, m0, k_min, rho = args
        p = with_values(params, names, theta_of(z, lo, hi))
        value = metric.fn(p, op, settings, None)
        violation = jnp.maximum(0.0, 1.0 - static_stiffness(p) / k_min)
        return sign * value / jnp.abs(m0) + rho * violation**2

    def solve(z0, args, max_steps):
        solver = optx.BFGS(rtol=1e-7, atol=1e-9)
        sol = optx.minimise(objective, solver, z0, args, max_steps=max_steps, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return theta_of, eqx.filter_jit(solve)


class OptimizationStart(NamedTuple):
    """The checked problem of `optimize`: bounds in file units and the (clipped) start."""

    metric: Metric
    names: tuple
    op: OperatingPoint
    bounds: dict
    lower: np.ndarray
    upper: np.ndarray
    theta: np.ndarray  # the start, clipped 0.1 % inside the bounds
    z: np.ndarray  # the same in the optimiser's unconstrained variables


def optimization_start(metric_name: str, params: BallScrewParams, vary,
                       bounds: dict | None = None, *, frequency_hz=None, force_n=None
                       ) -> OptimizationStart:
    """Every check of `optimize`'s inputs that needs no computing, and its start point.

    ValueError (ParameterError for an unknown name) naming the bad input: an unknown
    metric or parameter, bounds for a name not varied, non-finite or empty bounds, bounds
    outside the allowed range, a metric the optimiser cannot trace, a bad operating point.
    """
    metric, names, op = check_design_inputs(metric_name, params, vary,
                                            frequency_hz=frequency_hz, force_n=force_n)
    if metric.locate is not None:
        raise ValueError(
            f"metric '{metric.name}' needs a continuation run per evaluation (a host-side "
            "search), which the jitted optimiser cannot call; optimise 'frf_peak' (the "
            "linear resonance peak) or 'amplitude' at the resonance frequency instead, or "
            "scan candidates with `sensitivities`")
    full_bounds = default_bounds(params, names)
    for name, (lo, hi) in (bounds or {}).items():
        if name not in names:
            raise ValueError(f"bounds given for '{name}', which is not in --vary "
                             f"({', '.join(names)})")
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError(f"bounds for '{name}' must be finite numbers, got {lo} and {hi}")
        if not lo < hi:
            raise ValueError(f"bounds for '{name}': lower {lo} must be below upper {hi}")
        key = lookup_key(name)
        if (key.low is not None and lo < key.low) or (key.high is not None and hi > key.high):
            raise ValueError(f"bounds for '{name}' ({lo}, {hi}) leave the allowed range "
                             f"{key.range_text()}")
        full_bounds[name] = (float(lo), float(hi))
    lo = np.array([full_bounds[n][0] for n in names])
    hi = np.array([full_bounds[n][1] for n in names])
    theta0 = parameter_values(params, names)
    frac = np.clip((theta0 - lo) / (hi - lo), 1e-3, 1 - 1e-3)
    return OptimizationStart(metric, names, op, full_bounds, lo, hi, lo + (hi - lo) * frac,
                             np.log(frac / (1 - frac)))


def optimize(metric_name: str, params: BallScrewParams, vary, bounds: dict | None = None, *,
             min_stiffness_n_per_um: float | None = None, frequency_hz=None, force_n=None,
             max_steps: int = 60, settings: OrbitSettings = OrbitSettings()
             ) -> OptimizationResult:
    """Optimise `metric_name` over the parameters `vary` within `bounds`.

    - `vary`: vocabulary names; `bounds`: {name: (lo, hi)} in file units (missing names get
      `default_bounds`, +-30 %); the start value is clipped into the bounds.
    - `min_stiffness_n_per_um`: the drive's static axial stiffness must stay at or above
      this (exterior penalty, see the module docstring).
    - The metric's `direction` says whether it is minimised or maximised.
    """
    metric, names, op, full_bounds, lo, hi, theta_start, z0 = optimization_start(
        metric_name, params, vary, bounds, frequency_hz=frequency_hz, force_n=force_n)
    theta_of, solve = _objective(metric.name, names, settings)
    start_params = with_values(params, names, jnp.asarray(theta_start))
    value_fn = compiled(metric.name, names, settings)[0]
    m0 = float(value_fn(jnp.asarray(theta_start), params, op, None))
    _check_finite(m0, metric, op)
    k0 = float(_static_stiffness(start_params))
    k_min = (min_stiffness_n_per_um * 1e6) if min_stiffness_n_per_um else 1e-30
    z = jnp.asarray(z0)
    steps, converged = 0, False
    for rho in (PENALTIES if min_stiffness_n_per_um else (0.0,)):
        args = (params, op, jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(m0),
                jnp.asarray(k_min), jnp.asarray(rho))
        z, ok, n = solve(z, args, max_steps)
        steps += int(n)
        converged = bool(ok)
        theta = np.asarray(theta_of(z, jnp.asarray(lo), jnp.asarray(hi)))
        k_opt = float(_static_stiffness(with_values(params, names, jnp.asarray(theta))))
        if not min_stiffness_n_per_um or k_opt >= k_min * (1 - CONSTRAINT_TOL):
            break
    theta = np.asarray(theta_of(z, jnp.asarray(lo), jnp.asarray(hi)))
    opt_params = validate(with_values(params, names, jnp.asarray(theta)), source="optimum")
    m_opt = float(value_fn(jnp.asarray(theta), params, op, None))
    _check_finite(m_opt, metric, op)
    k_opt = float(_static_stiffness(opt_params))
    sign = 1.0 if metric.direction == "min" else -1.0
    improvement = 100.0 * sign * (m0 - m_opt) / abs(m0)
    tol = 1e-3 * (hi - lo)
    at_bound = tuple(n for n, t, a, b in zip(names, theta, lo, hi, strict=True)
                     if t - a < tol[names.index(n)] or b - t < tol[names.index(n)])
    satisfied = (not min_stiffness_n_per_um) or k_opt >= k_min * (1 - CONSTRAINT_TOL)
    return OptimizationResult(
        metric.name, metric.unit, metric.direction, names, full_bounds, theta_start, theta,
        m0 * metric.scale, m_opt * metric.scale, improvement, min_stiffness_n_per_um,
        k0 * 1e-6, k_opt * 1e-6, bool(satisfied), at_bound, steps, converged, opt_params)


def verify_by_simulation(metric_name: str, params: BallScrewParams, *, frequency_hz=None,
                         force_n=None, settings: OrbitSettings = OrbitSettings(),
                         transient_periods: int = 300, periods: int = 10) -> dict:
    """Check a metric value against a plain time simulation (`bsfs_jax.simulate`).

    - amplitude / floquet: steady nut amplitude simulated from rest at the operating point
      vs the orbit amplitude (a stable orbit is what the simulation settles on);
    - frc_peak: the same at the located peak frequency;
    - static_stiffness: P / amplitude of a quasi-static response (0.05 f1) vs k_static;
    - natural_frequency: frequency of a free vibration started in the first mode shape
      (zero crossings of x_n; damped, so about f1 sqrt(1 - zeta^2));
    - frf_peak: simulated amplitude per newton at the located peak, 1 N force;
    - thermal_error: not a dynamic quantity, nothing to simulate (returns `checked=False`).

    Returns {"quantity", "model", "simulated", "relative_difference", "checked", ...}.
    """
    from ..machine import modes, simulate
    from ._metrics import frc_peak_location, frf_peak_frequency, orbit_amplitude

    metric = get_metric(metric_name)
    op = operating_point(metric, frequency_hz, force_n)
    f_op, p_op = float(op.frequency_hz), float(op.force_n)
    sim = dict(transient_periods=transient_periods, periods=periods, rtol=1e-9, atol=1e-13)
    out = {"metric": metric.name}
    if metric.name in ("amplitude", "floquet", "frc_peak"):
        if metric.name == "frc_peak":
            f_op, model_amp = (float(v) for v in frc_peak_location(params, op, settings))
        else:
            model_amp = float(orbit_amplitude(params, op, settings))
        traj = simulate(params, frequency_hz=f_op, force_n=p_op, **sim)
        simulated = float(traj.amplitude())
        out.update(quantity=f"nut amplitude [um] at {f_op:.6g} Hz, {p_op:g} N",
                   model=model_amp * 1e6, simulated=simulated * 1e6)
    elif metric.name == "static_stiffness":
        m = modes(params)
        f_qs = 0.05 * float(m.frequencies_hz[0])
        traj = simulate(params, frequency_hz=f_qs, force_n=p_op, **sim)
        out.update(quantity=f"static stiffness [N/um] from a {f_qs:.4g} Hz, {p_op:g} N "
                   "quasi-static response", model=float(m.static_stiffness) * 1e-6,
                   simulated=p_op / float(traj.amplitude()) * 1e-6)
    elif metric.name == "natural_frequency":
        m = modes(params)
        f1 = float(m.frequencies_hz[0])
        shape = np.asarray(m.shapes[:, 0])
        y0 = np.concatenate([1e-8 * shape / np.max(np.abs(shape)), np.zeros(3)])
        traj = simulate(params, frequency_hz=f1, force_n=0.0, y0=y0, transient_periods=0,
                        periods=20, samples_per_period=64, rtol=1e-10, atol=1e-16)
        x, t = np.asarray(traj.displacement[:, 2]), np.asarray(traj.t)
        idx = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
        tc = t[idx] - x[idx] * (t[idx + 1] - t[idx]) / (x[idx + 1] - x[idx])
        f_sim = (len(tc) - 1) / (tc[-1] - tc[0])
        zeta = float(m.damping_ratios[0])
        out.update(quantity="first natural frequency [Hz] from a free vibration in mode 1 "
                   f"(damped; zeta = {zeta:.4f})", model=f1 * np.sqrt(1 - zeta**2),
                   simulated=f_sim, undamped_model=f1)
    elif metric.name == "frf_peak":
        f_pk = float(frf_peak_frequency(params))
        model = evaluate_si(metric, params, op, settings)
        traj = simulate(params, frequency_hz=f_pk, force_n=1.0, **sim)
        out.update(quantity=f"nut compliance [um/N] at {f_pk:.6g} Hz, 1 N",
                   model=model * 1e6, simulated=float(traj.amplitude()) * 1e6)
    else:
        out.update(quantity="thermal elongation (static thermal chain; no dynamic check)",
                   model=None, simulated=None, relative_difference=None, checked=False)
        return out
    out["relative_difference"] = abs(out["simulated"] - out["model"]) / abs(out["model"])
    out["checked"] = True
    return out


def evaluate_si(metric, params, op, settings):
    return float(metric.fn(params, op, settings))
