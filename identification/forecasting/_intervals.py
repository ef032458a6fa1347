"""From fit to forecast: what the identified drive will do, with intervals (`bsfs predict`).

An identification's output folder (`identified.toml`, `report.json` with its `covariance`)
gives the estimate theta_hat of the fitted coordinates and their posterior covariance C.
Each forecast quantity q(theta) is a differentiable function of theta through the model
(`identified.toml` with the fitted keys replaced), and its interval comes from:

- **delta**: q_hat +- 1.96 sqrt(g^T C g), g = dq/dtheta by exact (implicit) derivatives:
  the modal quantities through the equilibrium and `eigh`; the FRC peak and folds on the
  continued branch (`bsfs_jax.design`: the peak amplitude and the folds through the
  hyperplane normal to the branch, the peak frequency through the augmented system);
- **checked at second order**: a cheap quantity (modal, lift-off) by its exact Hessian, a
  costly one (FRC peak, folds) by its second differences at probes theta_hat +- 1.96
  sqrt(lambda_i) u_i along the covariance's least determined directions (one continuation
  per probe serves every FRC quantity). Where the second-order term's std exceeds
  `SECOND_ORDER_TOL` of the linear one the interval comes from draws instead: of the model
  quadratic model (exact Hessian) for a cheap quantity, of the probed quadratic model for
  a costly one.
  Where a fold appears or disappears at a probe, that side of its interval is left open.
- **the model at each draw**: where the identification saved draws (bootstrap refits,
  posterior draws), the modal quantities are evaluated at each draw where their delta
  method is doubtful (`_forecast_modal.py`), and the FRC's peak and folds are followed to
  every draw (`_forecast_frc_draws.py`); for these the draws themselves measure the
  linear model's error and decide (`_forecast_frc_checks.from_draws`), the probes serving
  only where a point could not be followed at some draw. The lift-off force of the joint
  that opens first (`liftoff_force_n`) is searched at each draw where its quadratic model
  is doubtful (`_liftoff_draws.py`: the FRC peak followed, a secant in the force).

`dominated_by`: the fitted parameter whose own variance contributes most, g_i^2 C_ii.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import equinox as eqx
import numpy as np

Z95 = 1.959963984540054
SECOND_ORDER_TOL = 0.1  # second-order std / linear std beyond which the delta is doubtful
DRAW_BATCH = 256  # at most this many draws per call of a program over the draws
DRAWS = 4000
DRAW_SEED = 0


class ForecastError(ValueError):
    """Bad input to a forecast: one line naming the cause and what to do."""


@dataclasses.dataclass(frozen=True)
class Identified:
    """What a forecast needs from an identification folder."""

    folder: Path | None  # None: from a result in memory (`identified_from_result`)
    params: object  # BallScrewParams of identified.toml
    names: tuple
    keys: tuple
    log: np.ndarray
    prior: np.ndarray
    theta: np.ndarray
    covariance: np.ndarray
    report: dict
    # (n, p) draws of theta, used in place of Gaussian draws where the linearisation is
    # doubtful: posterior draws (`bsfs identify --posterior`, posterior.npz), else the
    # bootstrap refits (`bsfs identify --refits`, refits.npz); None: none usable,
    # `draws_note` says why. `draws_kind`: "posterior draws" or "bootstrap refits".
    draws: np.ndarray | None = None
    draws_note: str | None = None
    draws_kind: str | None = None
    # where the draws' batches run (`run_batches`): None, this process's threads; a
    # `bsfs_jax.cluster.Cluster`, its workers, a batch a chunk (`forecast(cluster=...)`)
    cluster: object = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def coordinates(self) -> Coordinates:
        """theta -> model, as a pytree that compiled programs take as an argument."""
        import jax.numpy as jnp

        return Coordinates(self.params, jnp.asarray(self.prior, float),
                           tuple(bool(x) for x in self.log), tuple(self.keys))

    def params_at(self, theta):
        """The model at theta (traceable): identified.toml with the fitted keys set."""
        return self.coordinates.at(theta)


class Coordinates(eqx.Module):
    """The identified model as a function of the fitted coordinates theta: the parameters
    of identified.toml with each fitted key set to prior * exp(theta) ('log') or
    prior + theta ('offset'). Its arrays are traced where a program takes it, its keys
    static, so one compiled program serves every identification with the same fit set."""

    params: object
    prior: object
    log: tuple = eqx.field(static=True)
    keys: tuple = eqx.field(static=True)

    def at(self, theta):
        import jax.numpy as jnp

        p = self.params
        for i, key in enumerate(self.keys):
            th = theta[i]
            value = self.prior[i] * jnp.exp(th) if self.log[i] else self.prior[i] + th
            p = p.replace(key, value)
        return p


def load_identified(folder, speed_rpm: float | None = None) -> Identified:
    """Read `folder` (a `bsfs identify --out` folder). Refuses a folder that is not one, a
    fit that did not converge and a report without the covariance, each in one line."""
    import bsfs_jax

    folder = Path(folder)
    report_path, toml_path = folder / "report.json", folder / "identified.toml"
    if not folder.is_dir() or not report_path.is_file() or not toml_path.is_file():
        raise ForecastError(f"{folder}: not an identification output folder (it needs "
                            "identified.toml and report.json); run `bsfs identify ... --out "
                            f"{folder}` first")
    try:
        report = json.loads(report_path.read_text(encoding="utf-8"))
        report["fit"]
    except (ValueError, KeyError, TypeError):
        raise ForecastError(f"{report_path}: not a report.json written by `bsfs identify` "
                            "(unreadable or without its 'fit' section); identify again") from None
    ident = _identified(folder, bsfs_jax.load_params(toml_path), report, speed_rpm,
                        report_path)
    draws, note, kind = _saved_draws(folder, ident)
    return dataclasses.replace(ident, draws=draws, draws_note=note, draws_kind=kind)


def _saved_draws(folder: Path, ident: Identified):
    """(draws of theta, note, kind): the NUTS draws `bsfs identify --posterior` saved, else
    the randomised-maximum-likelihood refits it saved (`_refits.py`), else none."""
    notes = []
    for name, section, kind, failed in (
            ("posterior.npz", "posterior", "posterior draws", "the sampler did not converge"),
            ("refits.npz", "refits", "bootstrap refits", "too few refits converged")):
        theta, note = _npz_draws(folder / name, ident, section, kind, failed)
        if theta is not None:
            return theta, note, kind
        notes.append(note)
    return None, "; ".join(notes) + " (bsfs identify --refits N or --posterior N writes them)", None


def _npz_draws(path: Path, ident: Identified, section: str, what: str, failed: str):
    if not path.is_file():
        return None, f"no {what} ({path.name})"
    info = ident.report.get(section) or {}
    if not (info.get("converged") is True if section == "posterior" else info.get("usable")):
        return None, (f"{path.name}: {failed} (report.json's '{section}'); its draws are "
                      "not used")
    try:
        with np.load(path) as z:
            names = [str(n) for n in z["names"]]
            samples = np.asarray(z["samples"], float).reshape(-1, len(names))
            estimate = np.asarray(z["estimate"], float) if "estimate" in z else None
    except (OSError, ValueError, KeyError):
        return None, f"{path.name}: unreadable; its draws are not used"
    if not set(ident.names) <= set(names) or not np.all(np.isfinite(samples)):
        return None, f"{path.name}: does not match report.json; its draws are not used"
    cols = [names.index(n) for n in ident.names]
    values = samples[:, cols]
    with np.errstate(invalid="ignore", divide="ignore"):
        theta = np.where(ident.log, np.log(values / ident.prior), values - ident.prior)
        if estimate is not None:  # written for this report's estimate (not a stale file)
            est = np.where(ident.log, np.log(estimate[cols] / ident.prior),
                           estimate[cols] - ident.prior)
            if not np.allclose(est, ident.theta, rtol=0.0, atol=1e-9):
                return None, (f"{path.name}: written for another estimate than report.json's; "
                              "its draws are not used")
    if not np.all(np.isfinite(theta)):
        return None, f"{path.name}: a draw outside the parameters' range; not used"
    return theta, f"{len(theta)} {what} ({path.name})"


def identified_from_result(result, speed_rpm: float | None = None,
                           refits=None) -> Identified:
    """The same as `load_identified` on the folder `bsfs identify` would write for
    `result` (an `IdentificationResult`), without the files; `refits` (`refit(result)`,
    optional) as its refits.npz."""
    from ..report import report_dict

    ident = _identified(None, result.params(), report_dict(result), speed_rpm,
                        "the identification")
    if refits is None:
        return dataclasses.replace(ident, draws_note="no bootstrap refits given")
    if not refits.usable:
        return dataclasses.replace(ident, draws_note=(
            f"too few refits converged ({refits.converged} of {refits.requested}); not used"))
    cols = [list(refits.names).index(n) for n in ident.names]
    return dataclasses.replace(ident, draws=np.asarray(refits.theta)[:, cols],
                               draws_kind="bootstrap refits",
                               draws_note=f"{refits.converged} bootstrap refits")


def _identified(folder, params, report, speed_rpm, where) -> Identified:
    fit, cov = report["fit"], report.get("covariance")
    if not fit.get("converged"):
        raise ForecastError(
            f"{folder or where}: the identification did not converge "
            f"({fit.get('convergence', '?')}); a forecast from it would not be trustworthy. "
            "Identify again with records through the resonance (`bsfs plan-test` recommends "
            "them), or fit fewer parameters (--fit)")
    if cov is None:
        raise ForecastError(f"{where}: no 'covariance' section (written by an older "
                            "bsfs); run `bsfs identify` again to refresh the folder")
    if speed_rpm is not None:
        params = params.replace("thermal.speed_rpm", float(speed_rpm))
    speed = float(params.get("thermal.speed_rpm"))
    matrix = np.array([[np.nan if x is None else x for x in row] for row in cov["matrix"]],
                      float)
    keep = [i for i, s in enumerate(cov["speed_rpm"]) if s is None or abs(s - speed) < 1e-9]
    keep = [i for i in keep if np.isfinite(matrix[i, i])]
    if not keep:
        raise ForecastError(f"{where}: no fitted parameter has a finite variance at "
                            f"{speed:g} r/min; nothing to carry into a forecast")
    idx = np.asarray(keep)
    return Identified(folder, params, tuple(cov["names"][i] for i in keep),
                      tuple(cov["keys"][i] for i in keep),
                      np.asarray([cov["transform"][i] == "log" for i in keep]),
                      np.asarray([cov["prior"][i] for i in keep], float),
                      np.asarray([cov["theta"][i] for i in keep], float),
                      matrix[np.ix_(idx, idx)], report)


@dataclasses.dataclass
class Quantity:
    """One forecast quantity (`prediction.json`'s `quantities`)."""

    name: str
    unit: str
    value: float | None
    ci95: list | None
    method: str
    dominated_by: str | None
    reason: str | None = None
    extra: dict = dataclasses.field(default_factory=dict)

    def as_dict(self) -> dict:
        out = dict(name=self.name, unit=self.unit, value=self.value, ci95=self.ci95,
                   method=self.method, dominated_by=self.dominated_by)
        if self.reason:
            out["reason"] = self.reason
        out.update(self.extra)
        return out


def _dominant(g, ident):
    contrib = g**2 * np.diag(ident.covariance)
    return ident.names[int(np.argmax(contrib))] if np.any(contrib > 0) else None


def _std(g, ident) -> float:
    return float(np.sqrt(max(g @ ident.covariance @ g, 0.0)))


def _quantity(name, unit, v, ci, method, g, ident, scale, extra):
    extra = dict(std=_std(g, ident) * scale, **extra)
    ci = [None if c is None else float(c) * scale for c in ci]
    return Quantity(name, unit, float(v) * scale, ci, method, _dominant(g, ident), extra=extra)


def _checked(name, unit, value, g, h, ident, scale, method, quadratic, extra,
             approximate=False, exact=None):
    """The delta interval where the quadratic model's second-order std
    sqrt(tr((H C)^2) / 2) is at most `SECOND_ORDER_TOL` of the linear std; else the 2.5-97.5 %
    range of value + g.delta + delta.H.delta / 2 over `DRAWS` draws of delta from the
    covariance (numpy only), method `quadratic`; where the identification saved posterior
    draws (`Identified.draws`) delta runs over them instead (method "..., posterior
    draws").

    With the quadratic model the value is the draws' median, the model at the estimate is
    kept as `plug_in`: there the plug-in value is biased by about half the curvature term
    tr(H C) / 2. In the forecast's coverage study (docs/COVERAGE.md) the plug-in damping
    ratio, peak and fold frequencies sat 0.3-0.5 std from the truth on average, the
    median within the study's error of it.

    `approximate`: H is not the exact Hessian (the probed one spans three directions
    without cross terms; the lift-off's is carried from the linearised joints). Over
    skewed draws (refits, posterior) such a model can cancel spread it does not see: on
    the bundled drive the exact FRC peak over 100 refits spread 0.99 and 1.16 of the
    delta width (frequency, amplitude), the probed model over the same kind of refits
    0.95 and 1.07, and over replicates 200-299 the probed intervals were 9 % narrower
    than the delta's and covered 88-94 % (docs/COVERAGE.md). So each side of its
    interval is at least the delta method's half-width from the value (`extra["floor"]`
    says where that applied).

    `exact`: where the identification saved draws (posterior or refits), a callable that
    returns the model itself at each of them (one vmapped batch); used instead of the
    quadratic model (method "model at each draw, ..."), the quadratic model's range kept
    in `extra["quadratic_ci95"]` for comparison."""
    c = ident.covariance
    sd = _std(g, ident)
    hc = h @ c
    sd2 = float(np.sqrt(max(0.5 * np.trace(hc @ hc), 0.0)))
    ratio = sd2 / sd if sd > 0 else (0.0 if sd2 == 0 else np.inf)
    extra = dict(extra, second_order=ratio)
    if ratio <= SECOND_ORDER_TOL:
        return _quantity(name, unit, value, [value - Z95 * sd, value + Z95 * sd], method, g,
                         ident, scale, extra)
    if ident.draws is not None:
        delta = ident.draws - ident.theta
        quadratic += f", {ident.draws_kind or 'posterior draws'}"
    else:
        rng = np.random.default_rng(DRAW_SEED)
        delta = rng.multivariate_normal(np.zeros(len(g)), c, size=DRAWS, method="eigh")
    q = float(value) + delta @ g + 0.5 * np.einsum("ni,ij,nj->n", delta, h, delta)
    if exact is not None and ident.draws is not None:
        at = np.asarray(exact(), float)
        if at.shape == q.shape and np.all(np.isfinite(at)):
            extra["quadratic_ci95"] = [float(x) * scale for x in np.percentile(q, [2.5, 97.5])]
            quadratic = f"model at each draw, {ident.draws_kind or 'posterior draws'}"
            q = at
        else:
            failed = int(np.sum(~np.isfinite(at))) if at.shape == q.shape else len(q)
            extra["exact_failed"] = (f"the model failed at {failed} of {len(q)} draws: "
                                     "the quadratic model used")
    lo, median, hi = np.percentile(q, [2.5, 50.0, 97.5])
    extra.update(draws=len(delta), draws_std=float(np.std(q)) * scale,
                 plug_in=float(value) * scale)
    if approximate:
        lo, hi = floored(lo, median, hi, sd, extra)
    return _quantity(name, unit, median, [lo, hi], quadratic, g, ident, scale, extra)


def floored(lo, value, hi, sd, extra):
    """(lo, hi) with each side at least the delta half-width Z95 sd from `value`;
    `extra["floor"]` says on which sides that applied."""
    floor = (value - Z95 * sd, value + Z95 * sd)
    sides = [side for side, moved in (("low", floor[0] < lo), ("high", floor[1] > hi))
             if moved]
    extra["floor"] = ("delta half-width on the " + " and ".join(sides) + " side"
                      if sides else None)
    return min(lo, floor[0]), max(hi, floor[1])


def from_hessian(name, unit, value, grad, hess, ident: Identified, *, scale=1.0,
                 method="delta", quadratic="quadratic (exact Hessian)", extra=None,
                 approximate=False, exact=None) -> Quantity:
    """A cheap quantity (modal, linearised lift-off) with its exact gradient and Hessian,
    checked at second order (`_checked`, method "quadratic (exact Hessian)" where
    doubtful; draws of the model itself, tried first, twice left the process waiting
    forever inside XLA on the 2-core machine)."""
    return _checked(name, unit, value, np.asarray(grad, float), np.asarray(hess, float),
                    ident, scale, method, quadratic, dict(extra or {}), approximate, exact)


def value_jac_hess(fn, x):
    """fn(x), its Jacobian and its Hessian from one forward-over-forward pass (traced)."""
    import jax

    def twice(f):  # f's output, also as its aux (jacfwd returns aux undifferentiated)
        return lambda z: (lambda y: (y, y))(f(z))

    jac_and_value = jax.jacfwd(twice(fn), has_aux=True)
    hess, (jac, value) = jax.jacfwd(lambda z: (lambda jy: (jy[0], jy))(jac_and_value(z)),
                                    has_aux=True)(x)
    return value, jac, hess


def locate_peak(params, force, start, stop, settings, near=None):
    """(hint, branch) of the FRC; a band without an interior peak is refused. `near`: the
    branch at a nearby force or parameters, whose peak's stretch is continued instead of
    the band (`design.locate_frc_peak_near`; the band where that stretch holds no peak)."""
    from bsfs_jax.design import locate_frc_peak
    from bsfs_jax.design.building import locate_frc_peak_near
    from bsfs_jax.solvers import SolverError

    try:
        if near is not None:
            return locate_frc_peak_near(params, force, settings, near, start_hz=start,
                                        stop_hz=stop)
        return locate_frc_peak(params, force, settings, start_hz=start, stop_hz=stop)
    except SolverError as exc:
        raise ForecastError(f"no resonance peak between {start:g} and {stop:g} Hz at "
                            f"{force:g} N ({str(exc).split(':')[0]}); choose a band around the "
                            "first natural frequency (--start/--stop)") from None
