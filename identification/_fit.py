"""Joint Levenberg-Marquardt fit of model parameters to several exciter records.

The unknowns are transformed so that the optimiser works on well-scaled, unconstrained
numbers: positive parameters (Hertz coefficients, screw stiffness, damping, thermal
expansion) as theta = log(value / prior), signed thermal offsets as theta = (D - D_prior)
in micrometres. The residual is the noise-weighted difference of measured and model
acceleration harmonics of every record (see `_measurement.py`), so the least-squares cost is
a log-likelihood and the Gauss-Newton covariance is meaningful. Records at different
spindle speeds share stiffness and damping; each speed gets its own offsets (`d_n`, `d_b`)
or the thermal chain's expansion coefficient is fitted (`expansion`).
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import bsfs_jax
from bsfs_jax.model import bearing_hertz_k, nut_hertz_k, screw_stiffness

from ._measurement import HarmonicData, linear_acceleration, nonlinear_acceleration, receptance


@dataclasses.dataclass(frozen=True)
class FitParameter:
    key: str  # vocabulary key written to identified.toml
    transform: str  # "log" (positive) or "offset" (signed, micrometres)
    unit: str
    doc: str
    per_speed: bool = False


FIT_PARAMETERS = {
    "nut_k": FitParameter("nut.hertz_k_m_per_n23", "log", "m/N^(2/3)",
                          "Hertz coefficient K_n of the screw-nut joint (larger = softer)"),
    "bearing_k": FitParameter("bearing.hertz_k_m_per_n23", "log", "m/N^(2/3)",
                              "Hertz coefficient K_b of the bearing joint (larger = softer)"),
    "screw_k": FitParameter("screw.stiffness_n_per_um", "log", "N/um", "screw stiffness k_s"),
    "c_b": FitParameter("damping.bearing_n_s_per_m", "log", "N s/m", "bearing damping c_b"),
    "c_s": FitParameter("damping.screw_n_s_per_m", "log", "N s/m", "screw damping c_s"),
    "c_n": FitParameter("damping.nut_n_s_per_m", "log", "N s/m", "nut-joint damping c_n"),
    "expansion": FitParameter("thermal.expansion_per_k", "log", "1/K",
                              "thermal expansion coefficient (scales D_n and D_b at all speeds)"),
    "d_n": FitParameter("thermal.nut_offset_um", "offset", "um",
                        "thermal offset D_n of the nut joint, one per spindle speed", True),
    "d_b": FitParameter("thermal.bearing_offset_um", "offset", "um",
                        "thermal offset D_b of the bearing joint, one per spindle speed", True),
}
DEFAULT_FIT = ("nut_k", "bearing_k", "screw_k", "c_b", "c_s", "c_n", "expansion")
LOG_BOUND_FACTOR = 20.0  # log-parameters stay within prior / 20 .. prior * 20
OFFSET_BOUND_UM = 2.0  # offsets within +-2 um of the prior (contact must stay preloaded)
# Above this joint amplitude / preload deformation the nonlinear (shooting) model is used.
NONLINEAR_RATIO = 0.1
# Harmonics above this fraction of the sample rate are not used (anti-alias filter phase).
MAX_HARMONIC_FRACTION = 0.25


def parse_fit(text: str | None) -> tuple[str, ...]:
    """'nut_k,c_n' -> ('nut_k', 'c_n'); validates names (ValueError naming the bad one)."""
    if not text:
        return DEFAULT_FIT
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    for n in names:
        if n not in FIT_PARAMETERS:
            raise ValueError(f"--fit: unknown parameter '{n}'. Choose from "
                             f"{', '.join(FIT_PARAMETERS)}.")
    if len(set(names)) != len(names):
        raise ValueError(f"--fit: a name appears twice in '{text}'")
    if "expansion" in names and ({"d_n", "d_b"} & set(names)):
        raise ValueError("--fit: choose either 'expansion' (thermal model) or per-speed "
                         "offsets 'd_n'/'d_b', not both")
    return names


class _Group(eqx.Module):
    """Arrays of the records at one speed (jnp, traced data of the residual)."""

    lin_freq: jax.Array  # (R, H) harmonic frequencies
    lin_force: jax.Array  # (R, H) complex
    lin_acc: jax.Array  # (R, H) complex measured
    lin_scale: jax.Array  # (R, H, 2) std of (re, im)
    nl_freq: jax.Array  # (S,)
    nl_force: jax.Array  # (S, H)
    nl_acc: jax.Array
    nl_scale: jax.Array


_build = eqx.filter_jit(bsfs_jax.build_system)
_linear_jit = eqx.filter_jit(linear_acceleration)
_receptance_jit = eqx.filter_jit(receptance)


def joint_amplitude_ratio(system, data: HarmonicData) -> float:
    """Largest joint deformation amplitude / preload deformation, linear prediction (numpy).

    The nonlinearity error of the linear model grows about as this ratio squared; at the
    paper's 100 N and 100-150 Hz it is 0.04-0.05 (error ~1e-5, far below the noise).
    """
    freq = jnp.asarray(data.frequency_hz * data.harmonics)
    h = np.asarray(_receptance_jit(system, freq))  # (H, 3)
    x = h * data.force[:, None]
    u_bearing = np.sum(np.abs(x[:, 0]))
    u_nut = np.sum(np.abs(x[:, 2] - x[:, 1]))
    d_nut = float(system.nut.a - system.nut.a0 - system.nut.offset)
    d_bearing = float(system.bearing.a - system.bearing.a0 - system.bearing.offset)
    return float(max(u_nut / d_nut, u_bearing / d_bearing))


class Problem:
    """A fit problem: harmonic data of the records, the prior, the parameters to fit.

    `model`: "auto" (per record: the linearised FRF where the predicted joint amplitude is
    below `NONLINEAR_RATIO` of the preload deformation, else the nonlinear periodic orbit
    by shooting), "linear" or "nonlinear".
    """

    def __init__(self, data: list[HarmonicData], prior, fit=DEFAULT_FIT, model: str = "auto",
                 max_harmonic_fraction: float = MAX_HARMONIC_FRACTION):
        if not data:
            raise ValueError("no records")
        if model not in ("auto", "linear", "nonlinear"):
            raise ValueError(f"model must be auto, linear or nonlinear, got '{model}'")
        self.data = list(data)
        self.fit = tuple(fit)
        self.max_harmonic_hz = max_harmonic_fraction * min(d.record.sample_rate_hz
                                                          for d in data)
        self.speeds = sorted({d.speed_rpm for d in data})
        th = prior.thermal
        if ({"d_n", "d_b", "expansion"} & set(self.fit)) and not th.enabled:
            raise ValueError("fitting thermal offsets needs thermal.enabled = true in the prior")
        if "expansion" in self.fit and (th.nut_offset is not None or
                                        th.bearing_offset is not None):
            raise ValueError("the prior gives explicit thermal offsets, so the expansion "
                             "coefficient has no effect; fit 'd_n,d_b' instead")
        # Make the fitted stiffness keys explicit so that `replace` can scale them.
        base = prior
        if "nut_k" in self.fit:
            base = base.replace("nut.hertz_k_m_per_n23", nut_hertz_k(prior))
        if "bearing_k" in self.fit:
            base = base.replace("bearing.hertz_k_m_per_n23", bearing_hertz_k(prior))
        if "screw_k" in self.fit:
            base = base.replace("screw.stiffness_n_per_um", screw_stiffness(prior) / 1e6)
        self.prior = prior
        self.base = base
        # Expand per-speed parameters.
        names, keys, priors, speeds = [], [], [], []
        for n in self.fit:
            spec = FIT_PARAMETERS[n]
            if spec.per_speed:
                for s in self.speeds:
                    system = _build(base.replace("thermal.speed_rpm", s))
                    v = (system.thermal.nut_offset if n == "d_n"
                         else system.thermal.bearing_offset)
                    names.append(f"{n}@{s:g}rpm")
                    keys.append(spec.key)
                    priors.append(float(v) * 1e6)
                    speeds.append(s)
            else:
                names.append(n)
                keys.append(spec.key)
                priors.append(float(np.asarray(base.get(spec.key))))
                speeds.append(None)
        self.names = tuple(names)
        self.keys = tuple(keys)
        self.prior_values = np.asarray(priors)
        self.param_speeds = tuple(speeds)
        self.transforms = tuple(FIT_PARAMETERS[n.split("@")[0]].transform for n in names)
        self.units = tuple(FIT_PARAMETERS[n.split("@")[0]].unit for n in names)
        systems = {s: _build(base.replace("thermal.speed_rpm", s)) for s in self.speeds}
        self.amplitude_ratios = [joint_amplitude_ratio(systems[d.speed_rpm], d) for d in data]
        self.models = [model if model != "auto" else
                       ("nonlinear" if r > NONLINEAR_RATIO else "linear")
                       for r in self.amplitude_ratios]
        self.groups, self.order = self._build_groups()
        self._residual_jit = eqx.filter_jit(self.residual)
        self._jac_jit = eqx.filter_jit(jax.jacfwd(self.residual))

    # -- parameters ------------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        return len(self.names)

    def values(self, theta):
        """File-unit values of the fitted parameters for a theta vector (jnp or numpy).

        Bounded transforms: log-parameters stay within a factor `LOG_BOUND_FACTOR` of the
        prior (value = prior exp(B tanh(theta / B)), B = ln factor), offsets within
        +-`OFFSET_BOUND_UM` of the prior. Near the prior theta is the plain log-ratio (or
        the offset change in um), which is what the scaled Jacobian uses.
        """
        xp = jnp if isinstance(theta, jax.Array) else np
        log = xp.asarray([t == "log" for t in self.transforms])
        v0 = xp.asarray(self.prior_values)
        b = xp.where(log, np.log(LOG_BOUND_FACTOR), OFFSET_BOUND_UM)
        squashed = b * xp.tanh(theta / b)
        return xp.where(log, v0 * xp.exp(xp.where(log, squashed, 0.0)), v0 + squashed)

    def theta_of(self, values):
        """Inverse of `values` (numpy); values outside the bounds raise ValueError."""
        v = np.asarray(values, float)
        log = np.asarray([t == "log" for t in self.transforms])
        b = np.where(log, np.log(LOG_BOUND_FACTOR), OFFSET_BOUND_UM)
        squashed = np.where(log, np.log(np.where(log, v / self.prior_values, 1.0)),
                            v - self.prior_values)
        if np.any(np.abs(squashed) >= b):
            raise ValueError(f"values {v} outside the fit bounds around the prior")
        return b * np.arctanh(squashed / b)

    def params_at(self, theta, speed):
        """Full `BallScrewParams` at `speed` for the fitted theta (traceable)."""
        values = self.values(theta)
        p = self.base.replace("thermal.speed_rpm", speed)
        for i, (key, s) in enumerate(zip(self.keys, self.param_speeds)):
            if s is None or s == speed:
                p = p.replace(key, values[i])
        return p

    # -- data ------------------------------------------------------------------------------
    def _build_groups(self):
        prior_sys = {s: _build(self.base.replace("thermal.speed_rpm", s))
                     for s in self.speeds}
        groups, order = [], []
        for s in self.speeds:
            lin = [i for i, d in enumerate(self.data) if d.speed_rpm == s
                   and self.models[i] == "linear"]
            nl = [i for i, d in enumerate(self.data) if d.speed_rpm == s
                  and self.models[i] == "nonlinear"]
            order += lin + nl
            arrays = []
            for idx in (lin, nl):
                h = self.data[0].harmonics.size
                if not idx:
                    arrays += [np.zeros((0, h)), np.zeros((0, h), complex),
                               np.zeros((0, h), complex), np.zeros((0, h, 2))]
                    continue
                freq = np.stack([self.data[i].frequency_hz * self.data[i].harmonics
                                 for i in idx])
                force = np.stack([self.data[i].force for i in idx])
                acc = np.stack([self.data[i].acceleration for i in idx])
                # Errors in both channels: var(A - G F) = var(A) + |G|^2 var(F), with G the
                # prior model's transfer (a weight only; not differentiated).
                g = np.asarray(_linear_jit(prior_sys[s], jnp.asarray(freq),
                                                   jnp.ones(freq.shape, complex)))
                var = (np.stack([self.data[i].acceleration_var for i in idx])
                       + np.abs(g)[..., None] ** 2
                       * np.stack([self.data[i].force_var for i in idx]))
                # Harmonics near the anti-alias filter are left out (their phase is the
                # filter's, not the structure's): infinite std -> zero residual.
                std = np.where((freq <= self.max_harmonic_hz)[..., None], np.sqrt(var), np.inf)
                arrays += [freq, force, acc, std]
            lf, lF, lA, lS, nf, nF, nA, nS = arrays
            groups.append(_Group(jnp.asarray(lf), jnp.asarray(lF), jnp.asarray(lA),
                                 jnp.asarray(lS), jnp.asarray(nf[:, 0] if nf.size else
                                                              np.zeros(0)),
                                 jnp.asarray(nF), jnp.asarray(nA), jnp.asarray(nS)))
        return groups, order

    # -- model and residual ----------------------------------------------------------------
    def predict(self, theta, groups=None):
        """Model acceleration harmonics per group: list of (linear (R,H), nonlinear (S,H))."""
        groups = self.groups if groups is None else groups
        out = []
        for s, g in zip(self.speeds, groups):
            system = bsfs_jax.build_system(self.params_at(theta, s))
            lin = (linear_acceleration(system, g.lin_freq, g.lin_force)
                   if g.lin_freq.shape[0] else jnp.zeros((0, g.lin_freq.shape[1]), complex))
            if g.nl_freq.shape[0]:
                fn = lambda f, fc: nonlinear_acceleration(system, f, fc)
                nl, ok = jax.vmap(fn)(g.nl_freq, g.nl_force)
                nl = jnp.where(ok[:, None], nl, jnp.inf)
            else:
                nl = jnp.zeros((0, g.nl_force.shape[1]), complex)
            out.append((lin, nl))
        return out

    def residual(self, theta, groups=None):
        """Noise-weighted residual vector (dimensionless; about N(0, 1) at the truth)."""
        groups = self.groups if groups is None else groups
        parts = []
        for (lin, nl), g in zip(self.predict(theta, groups), groups):
            for model, meas, scale in ((lin, g.lin_acc, g.lin_scale), (nl, g.nl_acc, g.nl_scale)):
                d = meas - model
                # A trial point without preload gives inf/NaN: make it a huge, finite cost.
                d = jnp.where(jnp.isfinite(d), d, 1e6)
                parts.append((jnp.real(d) / scale[..., 0]).reshape(-1))
                parts.append((jnp.imag(d) / scale[..., 1]).reshape(-1))
        return jnp.concatenate(parts)

    def used_mask(self):
        """Residual entries that carry data (False: harmonics left out)."""
        parts = []
        for g in self.groups:
            for scale in (g.lin_scale, g.nl_scale):
                parts.append(np.isfinite(np.asarray(scale[..., 0])).reshape(-1))
                parts.append(np.isfinite(np.asarray(scale[..., 1])).reshape(-1))
        return np.concatenate(parts)

    def record_slices(self):
        """For each record (in data order) the indices of its entries in the residual."""
        h = self.data[0].harmonics.size
        idx = {}
        pos = 0
        for s, g in zip(self.speeds, self.groups):
            for count, kind in ((g.lin_freq.shape[0], "linear"), (g.nl_freq.shape[0],
                                                                   "nonlinear")):
                members = [i for i in self.order if self.data[i].speed_rpm == s
                           and self.models[i] == kind]
                for j, i in enumerate(members):
                    idx[i] = np.concatenate([pos + j * h + np.arange(h),
                                             pos + count * h + j * h + np.arange(h)])
                pos += 2 * count * h
        return [idx[i] for i in range(len(self.data))]

    def model_harmonics(self, theta):
        """Model acceleration coefficients (H,) per record, in data order (numpy)."""
        preds = self.predict(jnp.asarray(theta))
        out = {}
        for s, (lin, nl) in zip(self.speeds, preds):
            for arr, kind in ((lin, "linear"), (nl, "nonlinear")):
                members = [i for i in self.order if self.data[i].speed_rpm == s
                           and self.models[i] == kind]
                for j, i in enumerate(members):
                    out[i] = np.asarray(arr[j])
        return [out[i] for i in range(len(self.data))]


@dataclasses.dataclass
class FitResult:
    problem: Problem
    theta: np.ndarray
    values: np.ndarray
    cost: float
    residual: np.ndarray
    jacobian: np.ndarray
    starts: list  # dicts: start, cost, steps, converged
    converged: bool
    steps: int
    seconds: float


def _solve_fn(problem: Problem, rtol, atol, max_steps):
    key = (rtol, atol, max_steps)
    cache = problem.__dict__.setdefault("_solvers", {})
    if key not in cache:
        cache[key] = _make_solve(problem, rtol, atol, max_steps)
    return cache[key]


def _make_solve(problem: Problem, rtol, atol, max_steps):
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    @eqx.filter_jit
    def solve(theta0, groups):
        sol = optx.least_squares(lambda th, g: problem.residual(th, g), solver, theta0,
                                 args=groups, max_steps=max_steps, throw=False)
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return solve


def fit(problem: Problem, *, starts: int = 4, spread: float = 0.3, seed: int = 0,
        rtol: float = 1e-8, atol: float = 1e-8, max_steps: int = 100) -> FitResult:
    """Multi-start Levenberg-Marquardt (optimistix, forward-mode Jacobians).

    Start 0 is the prior; the others are drawn around it: log-parameters with a relative
    spread `spread` (0.3 = about 30 %), offsets with 0.3 um. The best final cost wins;
    every start's outcome is reported.
    """
    t0 = time.perf_counter()
    solve = _solve_fn(problem, rtol, atol, max_steps)
    rng = np.random.default_rng(seed)
    runs = []
    for k in range(max(1, starts)):
        th0 = np.zeros(problem.n_params)
        if k:
            th0 = rng.normal(0.0, spread, problem.n_params)
            th0 = np.where([t == "offset" for t in problem.transforms],
                           rng.normal(0.0, 0.3, problem.n_params), th0)
        theta, ok, steps = solve(jnp.asarray(th0), problem.groups)
        r = np.asarray(problem._residual_jit(theta, problem.groups))
        cost = float(0.5 * r @ r) if np.all(np.isfinite(r)) else float("inf")
        runs.append(dict(start=problem.values(th0).tolist(), theta=np.asarray(theta),
                         cost=cost, steps=int(steps), converged=bool(ok)))
    best = min(runs, key=lambda d: d["cost"])
    theta = best["theta"]
    for run in runs:
        run["same_minimum"] = bool(abs(run["cost"] - best["cost"]) <= 1e-6 * max(1.0,
                                                                                best["cost"]))
        run["theta"] = run["theta"].tolist()
    r = np.asarray(problem._residual_jit(jnp.asarray(theta), problem.groups))
    jac = np.asarray(problem._jac_jit(jnp.asarray(theta), problem.groups))
    return FitResult(problem, np.asarray(theta), np.asarray(problem.values(theta)),
                     float(0.5 * r @ r), r, jac, runs, best["converged"], best["steps"],
                     time.perf_counter() - t0)
