"""The fit problem: which parameters, their priors, the data and the noise-weighted residual.

Parametrisation. Every unknown is a well-scaled, unconstrained number theta: positive
quantities (Hertz coefficients, preloads, screw stiffness, damping, thermal expansion) as
theta = ln(value / prior value), signed thermal offsets as theta = D - D_prior in
micrometres. So theta = 0 is the prior, a unit of theta is "a factor e" or "1 um", and a
standard error of theta is a relative error (or um), whatever the parameter's size.

Priors (optional; maximum a posteriori). Each parameter may carry a Gaussian prior on theta
with standard deviation `sigma` (so a log-normal prior on positive values). The prior enters
the residual as extra entries theta_i / sigma_i, which makes the cost the negative log
posterior and keeps directions that the data do not determine where the prior puts them;
without priors (`priors=None`) the fit is maximum likelihood.

Residual. The noise-weighted difference of measured and model worktable acceleration:
harmonics of every sine record (see `identification.measurement`) and lines of every FRF record
(chirp, random or hammer; accelerance times a unit force). Records at different spindle
speeds share stiffness, preload and damping; each speed gets its own thermal offsets
(`d_n`, `d_b`) or the thermal chain's expansion coefficient is fitted (`expansion`).
"""

from __future__ import annotations

import copy

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bsfs_jax.machine import as_system
from bsfs_jax.model import bearing_hertz_k, nut_hertz_k, screw_stiffness

from ..measurement import (
    MODEL_ERROR,
    anchored,
    build_data,
    force_gains,
    is_frf,
    keep_marginal,
    line_bound,
    padded_counts,
    predict,
    predictions,
    residual,
    residual_and_jacobian,
    same_choice,
    screen,
    used_rows,
)
from ._lm import NO_INFORMATION_STD
from ._parameters import DEFAULT_FIT, FIT_PARAMETERS, MAX_HARMONIC_FRACTION


@eqx.filter_jit
def _stiffnesses(prior):
    """The prior's nut and bearing Hertz constants and screw stiffness, as one program
    (each evaluated eagerly ran its Hertz contact formulas op by op)."""
    return nut_hertz_k(prior), bearing_hertz_k(prior), screw_stiffness(prior)


class Problem:
    """A fit problem: data of the records, the prior parameter set, the parameters to fit.

    `data`: `HarmonicData` (sine records) and FRF records (`FrfRecord`), any mix.
    `model`: "auto" (per sine record, decided at the prior or at `model_theta`: the
    linearised FRF where its predicted error, `linearisation_z[i][0]`, is below `model_error`
    standard errors in every harmonic; else the first-order harmonic-balance correction
    where its own predicted error `linearisation_z[i][1]` is; else the periodic orbit by
    harmonic balance; see `measurement._choice`), "linear", "first-order" or "nonlinear". FRF
    records use
    the linearised model (the small-signal FRF); in "auto" the lines of a chirp whose
    predicted error exceeds `line_bound(model_error)` (a tenth of it) are left out
    (`frf_left_out`).
    `nonlinear_ratio`: instead of the error rule, choose by the joint amplitude / preload
    deformation (planning, where the noise is not known yet).
    `priors`: {name: sigma of theta}, "default" (each parameter's `prior_sigma`) or None
    (maximum likelihood).
    """

    def __init__(self, data, prior, fit=DEFAULT_FIT, model: str = "auto",
                 max_harmonic_fraction: float = MAX_HARMONIC_FRACTION, priors="default",
                 nonlinear_ratio: float | None = None, model_error: float = MODEL_ERROR,
                 frf_left_out: dict | None = None, model_theta=None, previous=None):
        if not data:
            raise ValueError("no records")
        if model not in ("auto", "linear", "first-order", "nonlinear"):
            raise ValueError(f"model must be auto, linear, first-order or nonlinear, got "
                             f"'{model}'")
        self.data = list(data)
        self.fit = tuple(fit)
        self._options = dict(max_harmonic_fraction=max_harmonic_fraction)
        self._choice = dict(model=model, nonlinear_ratio=nonlinear_ratio,
                            model_error=model_error)
        sines = [d for d in self.data if not is_frf(d)]
        self.max_harmonic_hz = (max_harmonic_fraction * min(d.record.sample_rate_hz
                                                            for d in sines)
                                if sines else np.inf)
        for d in sines:
            if d.frequency_hz > self.max_harmonic_hz:
                raise ValueError(
                    f"record '{d.record.source}': its excitation ({d.frequency_hz:.4g} Hz) is "
                    f"above the usable band ({self.max_harmonic_hz:.4g} Hz = "
                    f"{max_harmonic_fraction:g} x the lowest sample rate, where the "
                    "anti-alias filter's phase is not the structure's); record it at a "
                    f"sample rate above {d.frequency_hz / max_harmonic_fraction:.0f} Hz or "
                    "leave it out")
        self.speeds = sorted({d.speed_rpm for d in self.data})
        # A layout shared with other problems (`padded`), so that they batch in one program.
        self.pad = None
        th = prior.thermal
        if ({"d_n", "d_b", "expansion"} & set(self.fit)) and not th.enabled:
            raise ValueError("fitting thermal offsets needs thermal.enabled = true in the prior")
        if "expansion" in self.fit and (th.nut_offset is not None or
                                        th.bearing_offset is not None):
            raise ValueError("the prior gives explicit thermal offsets, so the expansion "
                             "coefficient has no effect; fit 'd_n,d_b' instead")
        # Make the fitted stiffness keys explicit so that `replace` can scale them.
        base = prior
        if {"nut_k", "bearing_k", "screw_k"} & set(self.fit):
            k_nut, k_bearing, k_screw = _stiffnesses(prior)
        if "nut_k" in self.fit:
            base = base.replace("nut.hertz_k_m_per_n23", k_nut)
        if "bearing_k" in self.fit:
            base = base.replace("bearing.hertz_k_m_per_n23", k_bearing)
        if "screw_k" in self.fit:
            base = base.replace("screw.stiffness_n_per_um", k_screw / 1e6)
        self.prior = prior
        self.base = base
        self._expand_parameters()
        if priors == "default":
            priors = {n: FIT_PARAMETERS[n].prior_sigma for n in self.fit}
        self.priors = None if priors is None else dict(priors)
        self.prior_sigma = (None if priors is None else
                            np.asarray([self.priors[n.split("@")[0]] for n in self.names]))
        # Models, left-out lines and the weights' transfer functions are decided at the prior,
        # or at `model_theta` (an estimate: see `rechosen`).
        self.model_theta = None if model_theta is None else np.asarray(model_theta, float)
        systems = {s: as_system(base.replace("thermal.speed_rpm", s) if model_theta is None
                             else self.params_at(self.model_theta, s)) for s in self.speeds}
        # The chirp-line check needs no orbit model: the planner (nonlinear_ratio) gets it too.
        self.amplitude_ratios, self.linearisation_z, self.transfer = screen(
            self.data, self.speeds, systems, self.max_harmonic_hz,
            model == "auto" and nonlinear_ratio is None, model == "auto")
        self.models = [
            "frf" if is_frf(d) else model if model != "auto" else
            (("nonlinear" if r > nonlinear_ratio else "linear") if nonlinear_ratio is not None
             else "linear" if z[0] <= model_error else
             "first-order" if z[1] <= model_error else "nonlinear")
            for d, r, z in zip(self.data, self.amplitude_ratios, self.linearisation_z)]
        # Chirp lines the linear FRF cannot model within their bound: left out.
        bound = line_bound(model_error)
        self.frf_left_out = {i: np.asarray(z) > bound
                             for i, (d, z) in enumerate(zip(self.data, self.linearisation_z))
                             if is_frf(d) and z is not None and np.any(np.asarray(z) > bound)}
        if frf_left_out is not None:
            self.frf_left_out = dict(frf_left_out)
        if previous is not None:
            self.models, self.frf_left_out = keep_marginal(self, previous, model_error)
        self.info_floor = 1.0 / NO_INFORMATION_STD if self.prior_sigma is None else 0.0
        self.force_gain = {}
        self.fit_data, self.structure, self.layout = build_data(self, is_frf)
        if nonlinear_ratio is None:  # not a plan: the orbit records' weights from the orbit
            theta = np.zeros(self.n_params) if model_theta is None else self.model_theta
            self.force_gain = force_gains(self, theta)
            if self.force_gain:
                self.fit_data, self.structure, self.layout = build_data(self, is_frf)

    def without_orbit_records(self) -> Problem | None:
        """The records the linearised and first-order models explain (those not on the
        periodic-orbit model), as a problem with the same parameters (the records a staged
        fit's first stage keeps; the fit itself masks the others in place,
        `measurement.masked_orbit_records`). Their models are chosen where this problem's were
        (the prior or `model_theta`). None where no record is left or the parameters would differ (a
        speed only the orbit records have)."""
        idx = [i for i, m in enumerate(self.models) if m != "nonlinear"]
        if not idx or len(idx) == len(self.data):
            return None
        left_out = {k: self.frf_left_out[i] for k, i in enumerate(idx)
                    if i in self.frf_left_out}
        pb = Problem([self.data[i] for i in idx], self.prior, self.fit, priors=self.priors,
                     frf_left_out=left_out, model_theta=self.model_theta, **self._choice,
                     **self._options)
        return pb if pb.names == self.names else None

    @property
    def may_use_first_order(self) -> bool:
        """Whether any record can be on the first-order model, now or after a re-choice."""
        return self.chooses_models or self._choice["model"] == "first-order"

    @property
    def chooses_models(self) -> bool:
        """Whether the models per record follow the predicted-error rule (model "auto"
        without a planning ratio), so that `fit` may re-choose them at the estimate."""
        return self._choice["model"] == "auto" and self._choice["nonlinear_ratio"] is None

    def rechosen(self, theta) -> Problem:
        """The same problem with its models and left-out lines decided at `theta` instead of
        the prior (`fit` checks its choice at the estimate this way). A decision changes
        only where its predicted error is clearly on the other side of the bound (outside
        a factor 2 of it); marginal ones keep this problem's (hysteresis: a line whose
        error sits at the bound would otherwise flip with every small move)."""
        return Problem(self.data, self.prior, self.fit, priors=self.priors, model_theta=theta,
                       previous=self, **self._choice, **self._options)

    def same_choice(self, other: Problem) -> bool:
        """Whether `other` uses the same model per record and leaves out the same lines."""
        return same_choice(self, other)

    def with_fit_data(self, fit_data) -> Problem:
        """The same problem with other traced data of the same layout (a fit's anchors)."""
        out = copy.copy(self)
        out.fit_data = fit_data
        return out

    def anchored(self, theta) -> Problem:
        """The same problem with its swept records' anchors computed at theta
        (`measurement.anchored`; itself where no record carries a sweep direction)."""
        return (self.with_fit_data(anchored(self.fit_data, theta, self.structure))
                if self.structure.sweeps else self)

    def rj(self, theta, fit_data=None):
        """(residual, Jacobian) as numpy arrays (`residual`'s rows): one compiled program per
        structure and layout, shared by every problem of that layout."""
        r, j = residual_and_jacobian(jnp.asarray(theta, float),
                                     self.fit_data if fit_data is None else fit_data,
                                     self.structure)
        keep = self._residual_rows(r.shape[0])
        return np.asarray(r)[keep], np.asarray(j)[keep]

    def _residual_rows(self, n):
        """Rows of the model's residual that `residual` returns (no prior rows without
        priors)."""
        return slice(None) if self.prior_sigma is not None else slice(0, n - self.n_params)

    def _expand_parameters(self):
        names, keys, priors, speeds = [], [], [], []
        for n in self.fit:
            spec = FIT_PARAMETERS[n]
            if spec.per_speed:
                for s in self.speeds:
                    system = as_system(self.base.replace("thermal.speed_rpm", s))
                    v = (system.thermal.nut_offset if n == "d_n"
                         else system.thermal.bearing_offset)
                    names.append(f"{n}@{s:g}rpm")
                    keys.append(spec.key)
                    priors.append(float(v) * 1e6)
                    speeds.append(s)
            else:
                names.append(n)
                keys.append(spec.key)
                priors.append(float(np.asarray(self.base.get(spec.key))))
                speeds.append(None)
        self.names = tuple(names)
        self.keys = tuple(keys)
        self.prior_values = np.asarray(priors)
        self.param_speeds = tuple(speeds)
        self.transforms = tuple(FIT_PARAMETERS[n.split("@")[0]].transform for n in names)
        self.units = tuple(FIT_PARAMETERS[n.split("@")[0]].unit for n in names)

    # -- parameters ------------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def is_log(self) -> np.ndarray:
        return np.asarray([t == "log" for t in self.transforms])

    def values(self, theta):
        """File-unit values for a theta vector: prior * exp(theta), or prior + theta [um]."""
        xp = jnp if isinstance(theta, jax.Array) else np
        log = xp.asarray(self.is_log)
        v0 = xp.asarray(self.prior_values)
        return xp.where(log, v0 * xp.exp(xp.where(log, theta, 0.0)), v0 + theta)

    def theta_of(self, values):
        """Inverse of `values` (numpy); a non-positive value of a log-parameter raises."""
        v = np.asarray(values, float)
        log = self.is_log
        if np.any(log & ~(v > 0)):
            raise ValueError(f"values {v} must be positive for the log-parameters")
        return np.where(log, np.log(np.where(log, v, 1.0) / np.where(log, self.prior_values,
                                                                      1.0)),
                        v - self.prior_values)

    def params_at(self, theta, speed):
        """Full `BallScrewParams` at `speed` for the fitted theta (traceable)."""
        values = self.values(theta)
        p = self.base.replace("thermal.speed_rpm", speed)
        for i, (key, s) in enumerate(zip(self.keys, self.param_speeds)):
            if s is None or s == speed:
                p = p.replace(key, values[i])
        return p

    def system_at(self, theta, speed):
        """The `System` at `speed` for the fitted theta (one compiled build)."""
        return as_system(self.params_at(np.asarray(theta, float), speed))

    # -- model and residual ----------------------------------------------------------------
    def predict(self, theta, fit_data=None):
        """Model per speed group: [(sine harmonics (R, H), FRF accelerance (L,), the sines'
        drift terms (R, H))] (`measurement.predict`)."""
        return predict(theta, self.fit_data if fit_data is None else fit_data, self.structure)

    def data_residual(self, theta, fit_data=None):
        """Noise-weighted data residual (dimensionless; about N(0, 1) at the truth)."""
        r = residual(theta, self.fit_data if fit_data is None else fit_data, self.structure)
        return r[:r.shape[0] - self.n_params]

    def residual(self, theta, fit_data=None):
        """Data residual followed by the prior's entries theta / sigma (when priors are on)."""
        r = residual(theta, self.fit_data if fit_data is None else fit_data, self.structure)
        return r[self._residual_rows(r.shape[0])]

    def padded(self, pad) -> Problem:
        """This problem in the common layout `pad` (`common_padding`): the same records,
        models and weights, more speeds, rows and lines (no new screening)."""
        out = copy.copy(self)
        out.pad = pad
        out.speeds = sorted(set(self.speeds) | set(pad["speeds"]))
        out.fit_data, out.structure, out.layout = build_data(out, is_frf)
        return out

    def common_padding(self, others) -> dict | None:
        """A layout that fits this problem and `others` (union of the speeds, the largest
        padded counts per speed), or None where the structures differ (per-speed
        parameters at different speeds)."""
        problems = [self, *others]
        if any(s is not None for pb in problems for s in pb.param_speeds):
            return None
        speeds = sorted({s for pb in problems for s in pb.speeds})
        counts = {s: (0, 0, 0) for s in speeds}
        for pb in problems:
            for s, c in padded_counts(pb, is_frf).items():
                counts[s] = tuple(max(a, b) for a, b in zip(counts[s], c))
        harmonics = max([d.harmonics.size for pb in problems for d in pb.data
                         if not is_frf(d)] or [1])
        return dict(speeds=speeds, counts=counts, harmonics=harmonics)

    @property
    def n_data(self) -> int:
        return int(self.used_mask().size)

    def used_mask(self):
        """Data-residual entries that carry data (False: padding, harmonics left out)."""
        return used_rows(self.fit_data)

    def record_slices(self):
        """For each record (in data order) the indices of its entries in the residual."""
        return [self.layout[i][2] for i in range(len(self.data))]

    def model_harmonics(self, theta, orbit_model: dict | None = None):
        """Model accelerations per record in data order (numpy): harmonics or FRF lines.
        `orbit_model` ({record index: harmonics}): the periodic-orbit records' model where
        the caller has it already (`_report.record_branches` at the estimate, without the
        drifting force's terms, which are added here); the program then solves no orbit."""
        preds = predictions(jnp.asarray(theta, float), self.fit_data, self.structure,
                            orbit_model is None)
        out = self.per_record(preds)
        for i, a in (orbit_model or {}).items():
            gi, _, _, row = self.layout[i]
            out[i] = np.asarray(a) + np.asarray(preds[gi][2])[row]
        return out

    def record_residuals(self, residual):
        """For each record (in data order) its used entries of a data residual (numpy)."""
        used = self.used_mask()
        r = np.asarray(residual)
        return [r[s][used[s]] for s in self.record_slices()]

    def per_record(self, preds):
        """A prediction per group ([(sine (R, H), FRF (L,), ...)], `measurement.predict`) -> the
        model
        values of each record in data order (numpy)."""
        out = []
        for i in range(len(self.data)):
            gi, kind, _, row = self.layout[i]
            out.append(np.asarray(preds[gi][kind])[row])
        return out
