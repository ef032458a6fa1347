"""The forecast's quantities (`forecast`): modal, FRC peak and folds, lift-off, preloads,
and the health verdict per joint. See `_forecast.py` for the intervals."""

from __future__ import annotations

import dataclasses
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import bsfs_jax
from bsfs_jax.design.building import OPENS_FRACTION

from ..measurement import require_x64
from ._batches import on_threads
from ._frc_checks import from_draws, from_probes, probe_steps
from ._frc_draws import frc_points
from ._intervals import ForecastError, Identified, Quantity, locate_peak
from ._liftoff import linear_liftoff, nonlinear_liftoff
from ._modal import _modal
from ._result import Forecast

# A force beyond this many times the larger preload drives the joints far out of contact,
# beyond what the model's Hertz joints were validated for (physics.md): refused.
MAX_FORCE_PRELOADS = 10.0
# A joint keeping at least this fraction of its nominal preload (the interval's lower end)
# is called healthy.
HEALTHY_FRACTION = 0.8
MARGIN_HALF_WIDTHS = 4.0
PROBES = 3  # least determined directions probed for the FRC quantities' second order


def _folds(branch):
    """(fold_up, fold_down): the fold where an up-sweep jumps (the first in branch order,
    from the low end) and where a down-sweep jumps (the last); None where there is none."""
    folds = [b for b in branch.bifurcations if b.kind == "fold" and b.point is not None]
    if len(folds) < 2:
        return None, None
    return folds[0], folds[-1]


def _frc_quantities(ident, force, start, stop, settings, damping_ratio):
    from bsfs_jax.design.building import point_hint

    params = ident.params_at(ident.theta)
    hint, branch = locate_peak(params, force, start, stop, settings)
    shooting = type(branch.method).__name__ == "Shooting"
    # The probes are continued by the method that served the estimate (no failed
    # harmonic-balance attempt first where it fell back to shooting).
    settings = dataclasses.replace(settings, frc_method="shooting") if shooting else (
        dataclasses.replace(settings, frc_method="hb", frc_harmonics=branch.method.harmonics))
    # (name, unit, scale, hint); the value is the located point's (the implicit functions
    # return it unchanged and attach only derivatives: `frc_points`).
    specs = [("peak_frequency_hz", "Hz", 1.0, hint), ("peak_amplitude_um", "um", 1e6, hint)]
    up, down = _folds(branch)
    for name, fold in (("fold_up_hz", up), ("fold_down_hz", down)):
        if fold is not None:
            specs.append((name, "Hz", 1.0, point_hint(fold.point, branch)))
    # The probes need the peak and folds only: their branches are continued over the
    # features +- `MARGIN_HALF_WIDTHS` half-power widths (single-valued there, so the
    # linear start lies on the one branch), not the whole band.
    marks = [float(h.frequency_hz) for *_, h in specs]
    width = MARGIN_HALF_WIDTHS * max(marks) * damping_ratio
    sub = (max(start, min(marks) - width), min(stop, max(marks) + width))
    # With draws (refits, posterior) each point is followed to every draw, and the model
    # itself there decides (`from_draws`); where it could not be followed at some draw,
    # the probes decide and the quantity says at how many draws the model failed. The
    # probes' FRCs are also the figure's band.
    exact, gradients = frc_points(ident, force, specs, central=shooting)
    steps = probe_steps(ident, min(PROBES, len(ident.names)))
    curves, read = {"estimate": branch}, {}
    jobs = [(i, sgn) for i in range(len(steps)) for sgn in (1.0, -1.0)]
    for (i, sgn), br in zip(jobs, _probe_branches(ident, steps, jobs, force, sub, settings)):
        curves[f"probe{i}{'+' if sgn > 0 else '-'}"] = br
        read[(i, sgn)] = {name: None if br is None else _read(name, br)
                          for name, *_ in specs}
    out = []
    grads, central = gradients()
    for name, unit, scale, h in specs:
        value = _read(name, branch)
        grad = grads[name]
        at = exact[name]() if name in exact else None
        if at is not None and np.all(np.isfinite(at)):
            q = from_draws(name, unit, value, grad, ident, at, scale=scale)
        else:
            q = from_probes(name, unit, value, grad, ident, steps,
                            [read[(i, 1.0)][name] for i in range(len(steps))],
                            [read[(i, -1.0)][name] for i in range(len(steps))], scale=scale,
                            exact=exact.get(name))
        fold = {"fold_up_hz": up, "fold_down_hz": down}.get(name)
        if fold is not None:
            q.extra["amplitude_um"] = fold.amplitude * 1e6  # where the figure marks it
        if name == "peak_frequency_hz" and shooting:
            q.extra["note"] = ("the joints lose contact at the peak (the curve is continued "
                               "by shooting): " + (
                                   "the peak frequency's gradient is by central differences "
                                   "of the peak followed to +-0.5 standard deviations of "
                                   "each fitted parameter" if central else
                                   "the peak could not be followed to every central-"
                                   "difference step, so the peak frequency's gradient is "
                                   "the implicit one, whose second derivatives are "
                                   "approximate there (1.6-2.8 % off central differences "
                                   "on the bundled worn drive)"))
        out.append(q)
    curves = {k: v for k, v in curves.items() if v is not None}
    for name, fold in (("fold_up_hz", up), ("fold_down_hz", down)):
        if fold is None:
            out.append(Quantity(name, "Hz", None, None, "none", None, reason=(
                f"the FRC at {force:g} N has no fold between {start:g} and {stop:g} Hz: the "
                "response is single-valued, an up- or down-sweep does not jump")))
    return out, curves


def _probe_branches(ident, steps, jobs, force, sub, settings):
    """The FRC branch at each probe theta_hat + sgn steps[i] (None where the sub-band has
    no peak there: every FRC quantity vanishes), continued in threads: the corrector's
    program is compiled by then (the estimate's branch used it), and XLA runs it without
    Python's lock, so the probes share the cores (on the 2-core machine 26 s of probes
    took about 12 s)."""
    import os

    def one(job):
        i, sgn = job
        try:
            return locate_peak(ident.params_at(ident.theta + sgn * steps[i]), force, *sub,
                               settings)[1]
        except ForecastError:
            return None

    return on_threads(one, jobs, os.cpu_count() or 1)


def _read(name, branch):
    if name == "peak_frequency_hz":
        return branch.peak.p if branch.peak else None
    if name == "peak_amplitude_um":
        return branch.peak.amplitude if branch.peak else None
    up, down = _folds(branch)
    fold = up if name == "fold_up_hz" else down
    return None if fold is None else fold.p


def _preloads(ident: Identified, nominal):
    rows = {r: ident.report["parameters"].get(r) for r in ("nut_preload", "bearing_preload")}
    out = []
    for name, row in rows.items():
        key = f"{name.split('_')[0]}.preload_n"
        nom = float(nominal.get(key))
        if row is None:
            value = float(ident.params.get(key))
            out.append(Quantity(f"{name}_n", "N", value, None, "fixed (not fitted)", None,
                                reason="not in the identification's fit set: the value is "
                                       "the prior's, so preload health is not assessed",
                                extra=dict(nominal_n=nom)))
            continue
        lo, hi = row["ci95"] if row.get("ci95") else (None, None)
        q = Quantity(f"{name}_n", "N", row["value"], None if lo is None else [lo, hi],
                     f"identification ({row.get('ci_method', 'linearised')})", name)
        q.extra.update(
            nominal_n=nom, retained_percent=100.0 * row["value"] / nom,
            retained_ci95_percent=None if lo is None else [100 * lo / nom, 100 * hi / nom],
            loss_n=nom - row["value"],
            loss_significant=bool(hi is not None and hi < nom))
        out.append(q)
    return out


def health(quantities: dict, force: float) -> dict:
    """Per joint: preload retained (with its interval), the lift-off margin at the working
    force, and one verdict line that never says more than the intervals allow."""
    out = {}
    for joint in ("nut", "bearing"):
        pre = quantities[f"{joint}_preload_n"]
        lift = quantities[f"liftoff_force_{joint}_n"]
        lines = []
        if pre.ci95 is None:
            lines.append("preload not assessed (not fitted)")
            verdict = "not assessed"
        else:
            lo, hi = pre.extra["retained_ci95_percent"]
            if hi < 100.0:
                verdict = "preload loss significant"
            elif lo >= 100 * HEALTHY_FRACTION:
                verdict = "healthy"
            else:
                verdict = "undetermined"
            lines.append(f"preload {pre.extra['retained_percent']:.0f} % of nominal "
                         f"(95 % CI {lo:.0f}-{hi:.0f} %)")
        if lift.ci95 is None:
            contact = f"lift-off force not determined ({lift.reason})"
            out[joint] = dict(verdict=verdict, contact=contact,
                              line=f"{joint}: {verdict}; " + "; ".join(lines + [contact]),
                              margin_n=None, margin_ci95_n=None)
            continue
        l_lo, l_hi = lift.ci95
        if force >= l_hi:
            contact = f"contact loss expected above {l_hi:.0f} N"
        elif force < l_lo:
            contact = f"contact kept at {force:g} N (lift-off from {l_lo:.0f} N)"
        else:
            contact = f"contact loss possible at {force:g} N (lift-off {l_lo:.0f}-{l_hi:.0f} N)"
        out[joint] = dict(verdict=verdict, contact=contact,
                          line=f"{joint}: {verdict}; " + "; ".join(lines + [contact]),
                          margin_n=None if lift.value is None else lift.value - force,
                          margin_ci95_n=[l_lo - force, l_hi - force])
    return out


def _band(ident: Identified, settings, start_hz, stop_hz):
    """(modal quantities, f1, start, stop): the band around the identified resonance
    (`settings.frc_band` times f1 where not given), refused where it holds no resonance."""
    modal, f1 = _modal(ident)
    start = settings.frc_band[0] * f1 if start_hz is None else float(start_hz)
    stop = settings.frc_band[1] * f1 if stop_hz is None else float(stop_hz)
    if not (0 < start < f1 < stop):
        raise ForecastError(f"the band {start:g}-{stop:g} Hz holds no resonance: the "
                            f"identified first natural frequency is {f1:.1f} Hz; choose "
                            "--start and --stop around it")
    return modal, f1, start, stop


def forecast_liftoff(ident: Identified, *, start_hz=None, stop_hz=None,
                     settings=None, second_joint: bool = True) -> dict:
    """The lift-off part of `forecast` alone (the same computation, on the same band):
    {"quantities": [liftoff_force_n], "per_joint_liftoff": [...]}. For studies of the
    lift-off's interval that need not continue the FRC. `second_joint=False`: the joint
    that opens second is left linearised (its search on the orbits skipped)."""
    require_x64("identification.forecast_liftoff")
    from bsfs_jax.design import OrbitSettings

    settings = OrbitSettings() if settings is None else settings
    _, _, start, stop = _band(ident, settings, start_hz, stop_hz)
    lift, per_joint = nonlinear_liftoff(ident, *linear_liftoff(ident, start, stop), start,
                                         stop, second=second_joint)
    return dict(quantities=[lift], per_joint_liftoff=per_joint)


def frc_settings(settings, force: float, linear_liftoff_n):
    """The FRC's continuation method: where the working force opens a joint near the
    peak (above `OPENS_FRACTION` of the smallest linearised lift-off force) and the
    settings leave the choice to "auto", shooting from the start. There the contact force
    is only C^1 and harmonic balance converges algebraically: on the bundled worn drive at
    100 N (lift-off 60 N) "auto" raised it from 8 to 64 harmonics, failed at 1.7e-6
    against its 1e-6 tolerance and then continued by shooting anyway, 26 s of a 178 s
    forecast (20 s of it compiling the four harmonic counts' programs)."""
    opens = force >= OPENS_FRACTION * float(np.min(linear_liftoff_n))
    if opens and settings.frc_method == "auto":
        return dataclasses.replace(settings, frc_method="shooting")
    return settings


def forecast_modal(ident: Identified, nominal=None) -> dict:
    """The modal quantities and the preloads of `forecast` alone (the same computation):
    {"quantities": [...], "per_joint_liftoff": []}. For studies of those intervals that
    need not continue the FRC."""
    require_x64("identification.forecast_modal")
    modal, _ = _modal(ident)
    pre = _preloads(ident, bsfs_jax.preset() if nominal is None else nominal)
    return dict(quantities=modal + pre, per_joint_liftoff=[])


def forecast(ident: Identified, force_n: float, *, start_hz=None, stop_hz=None,
             nominal=None, settings=None, nominal_curve: bool = True,
             cluster=None) -> Forecast:
    """The forecast (`prediction.json`'s content less the file fields): quantities, health,
    the FRC branches (estimate, probes) and, with `nominal_curve`, the nominal drive's
    (for the figure only; the coverage study skips it). `cluster`: a
    `bsfs_jax.cluster.Cluster` whose workers follow the FRC's points and the lift-off
    search to the identification's draws, a batch of draws a chunk (the same values as
    here; `Identified.cluster`)."""
    require_x64("identification.forecast")
    if cluster is not None:
        ident = dataclasses.replace(ident, cluster=cluster)
    import bsfs_jax
    from bsfs_jax.design import OrbitSettings

    nominal = bsfs_jax.preset() if nominal is None else nominal
    force = float(force_n)
    top = MAX_FORCE_PRELOADS * max(float(ident.params.get("nut.preload_n")),
                                   float(ident.params.get("bearing.preload_n")))
    if not (np.isfinite(force) and 0.0 < force <= top):
        raise ForecastError(f"--force {force_n}: outside the model's plausible range (0, "
                            f"{top:g}] N ({MAX_FORCE_PRELOADS:g} x the larger preload); "
                            "choose a working force in that range")
    settings = OrbitSettings() if settings is None else settings
    modal, f1, start, stop = _band(ident, settings, start_hz, stop_hz)
    zeta = next(q.value for q in modal if q.name == "damping_ratio_1")
    linear = linear_liftoff(ident, start, stop)
    settings = frc_settings(settings, force, linear[1][0])

    def nominal_frc():
        try:
            return locate_peak(nominal.replace("thermal.speed_rpm",
                                               ident.params.get("thermal.speed_rpm")),
                               force, start, stop, settings)[1]
        except ForecastError:
            return None  # the nominal drive's peak may lie outside the band: plotted without

    # The lift-off search does not depend on the FRC's quantities: it runs beside them
    # (while they wait for their points' program, one core was idle). The nominal curve
    # (for the figure) runs on whichever thread finishes its part first: its program is
    # the estimate's, compiled by then, and XLA runs it without Python's lock. (After the
    # FRC's quantities always, it ended a forecast at 100 N 12 s after the rest.)
    claim = threading.Lock()
    nominal_branches = []  # the one thread's that claimed it

    def nominal_if_first():
        if nominal_curve and claim.acquire(blocking=False):
            nominal_branches.append(nominal_frc())

    def search_then_nominal():
        out = nonlinear_liftoff(ident, *linear, start, stop)
        nominal_if_first()
        return out

    with ThreadPoolExecutor(max_workers=1) as pool:
        search = pool.submit(search_then_nominal)
        frc, curves = _frc_quantities(ident, force, start, stop, settings, zeta)
        nominal_if_first()
        lift, per_joint = search.result()
    nominal_branch = nominal_branches[0] if nominal_branches else None
    pre = _preloads(ident, nominal)
    quantities = modal + frc + [lift] + pre
    by_name = {q.name: q for q in quantities + per_joint}
    return Forecast(force_n=force, band_hz=[start, stop], quantities=quantities,
                    per_joint_liftoff=per_joint, health=health(by_name, force),
                    curves=curves, nominal_branch=nominal_branch)
