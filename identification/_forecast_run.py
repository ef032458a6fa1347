"""The forecast's quantities (`forecast`): modal, FRC peak and folds, lift-off, preloads,
and the health verdict per joint. See `_forecast.py` for the intervals."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._forecast import (
    ForecastError,
    Identified,
    Quantity,
    delta_interval,
    from_hessian,
    from_probes,
    probe_steps,
)

# A force beyond this many times the larger preload drives the joints far out of contact,
# beyond what the model's Hertz joints were validated for (physics.md): refused.
MAX_FORCE_PRELOADS = 10.0
# A joint keeping at least this fraction of its nominal preload (the interval's lower end)
# is called healthy.
HEALTHY_FRACTION = 0.8
GRID = 2001
MARGIN_HALF_WIDTHS = 4.0
PROBES = 3  # least determined directions probed for the FRC quantities' second order


def _value_jac_hess(fn, x):
    """fn(x), its Jacobian and its Hessian from one forward-over-forward pass."""
    import jax

    def twice(f):  # f's output, also as its aux (jacfwd returns aux undifferentiated)
        return lambda z: (lambda y: (y, y))(f(z))

    jac_and_value = jax.jacfwd(twice(fn), has_aux=True)
    hess, (jac, value) = jax.jacfwd(lambda z: (lambda jy: (jy[0], jy))(jac_and_value(z)),
                                    has_aux=True)(x)
    return np.asarray(value), np.asarray(jac), np.asarray(hess)


def _modal(ident: Identified):
    """natural_frequency_1_hz, damping_ratio_1, static_stiffness_n_per_um: exact gradients
    and Hessians (`from_hessian`)."""
    import jax.numpy as jnp

    from bsfs_jax import build_system, modes

    def fn(theta):
        m = modes(build_system(ident.params_at(theta)))
        return jnp.stack([m.frequencies_hz[0], m.damping_ratios[0], m.static_stiffness])

    value, jac, hess = _value_jac_hess(fn, jnp.asarray(ident.theta))
    out = []
    for k, (name, unit, scale) in enumerate((("natural_frequency_1_hz", "Hz", 1.0),
                                             ("damping_ratio_1", "-", 1.0),
                                             ("static_stiffness_n_per_um", "N/um", 1e-6))):
        out.append(from_hessian(name, unit, value[k], jac[k], hess[k], ident,
                                scale=scale))
    return out, float(value[0])


def _frc(params, force, start, stop, settings):
    """(hint, branch) of the FRC; a band without an interior peak is refused."""
    from bsfs_jax.design import locate_frc_peak
    from bsfs_jax.solvers import SolverError

    try:
        return locate_frc_peak(params, force, settings, start_hz=start, stop_hz=stop)
    except SolverError as exc:
        raise ForecastError(f"no resonance peak between {start:g} and {stop:g} Hz at "
                            f"{force:g} N ({str(exc).split(':')[0]}); choose a band around the "
                            "first natural frequency (--start/--stop)") from None


def _folds(branch):
    """(fold_up, fold_down): the fold where an up-sweep jumps (the first in branch order,
    from the low end) and where a down-sweep jumps (the last); None where there is none."""
    folds = [b for b in branch.bifurcations if b.kind == "fold" and b.point is not None]
    if len(folds) < 2:
        return None, None
    return folds[0], folds[-1]


def _frc_quantities(ident, force, start, stop, settings, damping_ratio):
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design import (
        fold_frequency_value,
        frc_peak_frequency_value,
        frc_peak_value,
        point_hint,
    )

    theta = jnp.asarray(ident.theta)
    hint, branch = _frc(ident.params_at(ident.theta), force, start, stop, settings)
    shooting = type(branch.method).__name__ == "Shooting"
    # The probes are continued by the method that served the estimate (no failed
    # harmonic-balance attempt first where it fell back to shooting).
    settings = dataclasses.replace(settings, frc_method="shooting") if shooting else (
        dataclasses.replace(settings, frc_method="hb", frc_harmonics=branch.method.harmonics))
    # (name, unit, scale, q(theta, hint), its derivative, hint); the value is the located
    # point's (the implicit functions return it unchanged and attach only derivatives).
    specs = [("peak_frequency_hz", "Hz", 1.0, lambda th, h: frc_peak_frequency_value(
        ident.params_at(th), force, h), jax.jacfwd, hint),
        ("peak_amplitude_um", "um", 1e6, lambda th, h: frc_peak_value(
            ident.params_at(th), force, h), jax.grad, hint)]
    up, down = _folds(branch)
    for name, fold in (("fold_up_hz", up), ("fold_down_hz", down)):
        if fold is not None:
            specs.append((name, "Hz", 1.0, lambda th, h: fold_frequency_value(
                ident.params_at(th), force, h), jax.grad, point_hint(fold.point, branch)))
    # The probes need the peak and folds only: their branches are continued over the
    # features +- `MARGIN_HALF_WIDTHS` half-power widths (single-valued there, so the
    # linear start lies on the one branch), not the whole band.
    marks = [float(h.frequency_hz) for *_, h in specs]
    width = MARGIN_HALF_WIDTHS * max(marks) * damping_ratio
    sub = (max(start, min(marks) - width), min(stop, max(marks) + width))
    steps = probe_steps(ident, min(PROBES, len(ident.names)))
    curves, read = {"estimate": branch}, {}
    for i, step in enumerate(steps):
        for sgn in (1.0, -1.0):
            try:
                _, br = _frc(ident.params_at(ident.theta + sgn * step), force, *sub, settings)
            except ForecastError:
                br = None  # no peak inside the sub-band there: every FRC quantity vanishes
            curves[f"probe{i}{'+' if sgn > 0 else '-'}"] = br
            read[(i, sgn)] = {name: None if br is None else _read(name, br)
                              for name, *_ in specs}
    out = []
    for name, unit, scale, fn, diff, h in specs:
        value = _read(name, branch)
        grad = np.asarray(diff(fn)(theta, h))
        q = from_probes(name, unit, value, grad, ident, steps,
                        [read[(i, 1.0)][name] for i in range(len(steps))],
                        [read[(i, -1.0)][name] for i in range(len(steps))], scale=scale)
        fold = {"fold_up_hz": up, "fold_down_hz": down}.get(name)
        if fold is not None:
            q.extra["amplitude_um"] = fold.amplitude * 1e6  # where the figure marks it
        if name == "peak_frequency_hz" and shooting:
            q.extra["note"] = ("the joints lose contact at the peak (the curve is continued "
                               "by shooting): the peak frequency's second derivatives are "
                               "approximate there, its gradient to about 2 %")
        out.append(q)
    curves = {k: v for k, v in curves.items() if v is not None}
    for name, fold in (("fold_up_hz", up), ("fold_down_hz", down)):
        if fold is None:
            out.append(Quantity(name, "Hz", None, None, "none", None, reason=(
                f"the FRC at {force:g} N has no fold between {start:g} and {stop:g} Hz: the "
                "response is single-valued, an up- or down-sweep does not jump")))
    return out, curves


def _read(name, branch):
    if name == "peak_frequency_hz":
        return branch.peak.p if branch.peak else None
    if name == "peak_amplitude_um":
        return branch.peak.amplitude if branch.peak else None
    up, down = _folds(branch)
    fold = up if name == "fold_up_hz" else down
    return None if fold is None else fold.p


def joint_windows(system, x_eq):
    """{joint: margin [m]}: how far each joint's relative displacement may move from
    equilibrium (either way) before a side's contact deformation reaches zero
    (`physics.contact_deformations`), from the pair's geometry."""
    import jax.numpy as jnp

    out = {}
    for joint, pair, u_eq in (("bearing", system.bearing, x_eq[0]),
                              ("nut", system.nut, x_eq[2] - x_eq[1])):
        root = jnp.sqrt(pair.reach**2 - pair.radial_sq)
        u_hi = pair.cos_helix * (pair.axial - root)
        out[joint] = jnp.minimum(u_hi - u_eq, u_eq + u_hi)
    return out


JOINTS = ("bearing", "nut")


def _linear_liftoff(ident, start, stop):
    """Per joint (`JOINTS` order) the smallest force amplitude at which its linearised
    relative displacement reaches its contact window anywhere in the band (the frequency
    of the largest joint receptance is located without gradient, the envelope theorem
    makes that exact for the linearised value), and the frequencies there."""
    import jax.numpy as jnp

    from bsfs_jax import build_system
    from bsfs_jax.machine import linear_frf, linearise

    def receptances(system, f):
        h = linear_frf(system, f)
        return {"bearing": jnp.abs(h[:, 0]), "nut": jnp.abs(h[:, 2] - h[:, 1])}

    system = build_system(ident.params_at(ident.theta))
    grid = np.linspace(start, stop, GRID)
    rec = {j: np.asarray(v) for j, v in receptances(system, jnp.asarray(grid)).items()}
    f_at = []
    for j in JOINTS:
        k = int(np.argmax(rec[j]))
        fine = np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, GRID - 1)], 401)
        f_at.append(float(fine[np.argmax(np.asarray(receptances(system, jnp.asarray(fine))[j]))]))

    def forces(theta):
        system = build_system(ident.params_at(theta))
        win = joint_windows(system, linearise(system)[3])
        return jnp.stack([win[j] / receptances(system, jnp.asarray(f_at[k:k + 1]))[j][0]
                          for k, j in enumerate(JOINTS)])

    values, jac, hess = _value_jac_hess(forces, jnp.asarray(ident.theta))
    per = [from_hessian(f"liftoff_force_{j}_n", "N", values[i], jac[i], hess[i], ident,
                        method="delta (linearised)") for i, j in enumerate(JOINTS)]
    for q, f in zip(per, f_at):
        q.extra.update(frequency_hz=f, note="the force amplitude at which the linearised "
                       "joint displacement reaches the end of its contact window at the "
                       "joint's resonance")
    return per


# The lift-off search on the nonlinear orbits: harmonic balance at this tolerance (the
# contact law's kink appears just past lift-off), secant steps, stop at this fraction of
# the first two deformations.
LIFTOFF_SETTINGS_TOL = 1e-4
LIFTOFF_STEPS = 8
LIFTOFF_RTOL = 1e-4


def joint_min_deformation(params, force, hint, joint):
    """Smallest contact deformation [m] of a joint's two sides over the orbit at a located
    FRC peak (differentiable: `bsfs_jax.design.peak_orbit_samples`); <= 0: a side opens."""
    import jax.numpy as jnp

    from bsfs_jax.design import peak_orbit_samples
    from bsfs_jax.physics import contact_deformations

    ys, system = peak_orbit_samples(params, force, hint)
    u = ys[:, 0] if joint == "bearing" else ys[:, 2] - ys[:, 1]
    pair = system.bearing if joint == "bearing" else system.nut
    return jnp.min(jnp.stack(contact_deformations(u, pair)))


def _nonlinear_liftoff(ident, per_joint, start, stop):
    """`liftoff_force_n`, and `per_joint` with its first joint's entry on the nonlinear
    orbits: the force F* at which that joint's smallest contact deformation at the FRC
    peak reaches zero (secant from the linearised value), with dF*/dtheta = -m_theta / m_F
    (implicit, reverse mode). On the bundled worn drive the linearised bearing value was
    61.5 N (95 % interval 61.3-62.0 N) and the orbits open at 59.9 N: the linearised
    interval missed it. Where the search fails the linearised value is kept and says so.
    The other joint stays linearised (it opens after the first, on orbits that have
    already lost contact)."""
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design import OrbitSettings

    first = int(np.argmin([q.value for q in per_joint]))
    joint, lin = JOINTS[first], per_joint[first]
    settings = OrbitSettings(frc_method="hb", frc_tol=LIFTOFF_SETTINGS_TOL)
    params = ident.params_at(ident.theta)

    def m(force):
        hint, _ = _frc(params, force, start, stop, settings)
        return float(joint_min_deformation(params, force, hint, joint)), hint

    def total(q):
        return dataclasses.replace(q, name="liftoff_force_n", extra=dict(
            q.extra, joint=joint, per_joint={j: p.value for j, p in zip(JOINTS, per)}))

    per = list(per_joint)
    try:
        f0, f1 = 0.9 * lin.value, 0.95 * lin.value
        (m0, _), (m1, hint) = m(f0), m(f1)
        scale = abs(m0) + abs(m1)
        for _ in range(LIFTOFF_STEPS):
            f2 = f1 - m1 * (f1 - f0) / (m1 - m0)
            m2, hint2 = m(f2)
            f0, m0, f1, m1, hint = f1, m1, f2, m2, hint2
            if abs(m1) < LIFTOFF_RTOL * scale:
                break
        else:
            raise ForecastError("no convergence")
    except (ForecastError, ZeroDivisionError):
        lin.extra["nonlinear"] = "the search on the nonlinear orbits failed: linearised value"
        return total(lin), per
    g_theta, g_f = jax.grad(lambda th, f: joint_min_deformation(
        ident.params_at(th), f, hint, joint), argnums=(0, 1))(jnp.asarray(ident.theta),
                                                              jnp.asarray(f1))
    per[first] = delta_interval(
        lin.name, "N", f1, -np.asarray(g_theta) / float(g_f), ident,
        "delta (nonlinear orbit at the FRC peak)", dict(
            frequency_hz=float(hint.frequency_hz), linearised_n=lin.value,
            note="the force at which the first joint to open loses contact on the periodic "
                 "orbit at the FRC peak (harmonic balance); its interval is the delta "
                 "method's, not checked at second order"))
    for i, q in enumerate(per):
        if i != first:
            q.extra["note"] = (f"linearised: the {joint} opens first, at {f1:.1f} N; beyond it "
                               "the orbits have lost contact")
    return total(per[first]), per


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


def forecast(ident: Identified, force_n: float, *, start_hz=None, stop_hz=None,
             nominal=None, settings=None) -> dict:
    """The forecast (`prediction.json`'s content less the file fields): quantities, health,
    the FRC branches (estimate, probes) and the nominal drive's."""
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
    modal, f1 = _modal(ident)
    start = settings.frc_band[0] * f1 if start_hz is None else float(start_hz)
    stop = settings.frc_band[1] * f1 if stop_hz is None else float(stop_hz)
    if not (0 < start < f1 < stop):
        raise ForecastError(f"the band {start:g}-{stop:g} Hz holds no resonance: the "
                            f"identified first natural frequency is {f1:.1f} Hz; choose "
                            "--start and --stop around it")
    zeta = next(q.value for q in modal if q.name == "damping_ratio_1")
    frc, curves = _frc_quantities(ident, force, start, stop, settings, zeta)
    lift, per_joint = _nonlinear_liftoff(ident, _linear_liftoff(ident, start, stop), start,
                                         stop)
    pre = _preloads(ident, nominal)
    quantities = modal + frc + [lift] + pre
    by_name = {q.name: q for q in quantities + per_joint}
    nominal_branch = None
    try:
        nominal_branch = _frc(nominal.replace("thermal.speed_rpm",
                                              ident.params.get("thermal.speed_rpm")),
                              force, start, stop, settings)[1]
    except ForecastError:
        pass  # the nominal drive's peak may lie outside the band: plotted without it
    return dict(force_n=force, band_hz=[start, stop], quantities=quantities,
                per_joint_liftoff=per_joint, health=health(by_name, force),
                curves=curves, nominal_branch=nominal_branch)
