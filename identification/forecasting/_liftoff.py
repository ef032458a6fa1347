"""The forecast's lift-off force (`liftoff_force_n`): per joint on the linearised model,
then for each joint on the nonlinear orbits at the FRC peak."""

from __future__ import annotations

import dataclasses

import numpy as np

import bsfs_jax
from bsfs_jax.machine import JOINTS

from ._intervals import ForecastError, from_hessian, locate_peak, value_jac_hess
from ._liftoff_draws import (
    LIFTOFF_FTOL,
    LIFTOFF_RTOL,
    LIFTOFF_STEPS,
    joint_deformations,
    liftoff_at_draws,
    prefetch_liftoff,
)

GRID = 2001  # frequencies over the band where each joint's receptance peak is sought


@bsfs_jax.cached_jit
def _receptance_program(coords, theta, freq):
    """(bearing, nut) linearised joint receptances |u / F| [m/N] at `freq`."""
    import jax.numpy as jnp

    from bsfs_jax.machine import linear_frf

    h = linear_frf(bsfs_jax.build_system(coords.at(theta)), freq)
    return jnp.abs(h[:, 0]), jnp.abs(h[:, 2] - h[:, 1])


@bsfs_jax.cached_jit
def _linear_liftoff_program(coords, theta, f_at):
    """(value, Jacobian, Hessian) of the per-joint (`JOINTS`) linearised lift-off forces,
    each at its own frequency `f_at[k]`."""
    import jax.numpy as jnp

    from bsfs_jax.machine import joint_windows, linear_frf, linearise

    def fn(th):
        system = bsfs_jax.build_system(coords.at(th))
        win = joint_windows(system, linearise(system)[3])
        h = linear_frf(system, f_at)
        rec = {"bearing": jnp.abs(h[0, 0]), "nut": jnp.abs(h[1, 2] - h[1, 1])}
        return jnp.stack([win[j] / rec[j] for j in JOINTS])

    return value_jac_hess(fn, theta)


@bsfs_jax.cached_jit
def _min_deformation_program(coords, theta, force, hint, joint):
    """`joint_min_deformation` at theta and force, with its gradients in both; `joint` a
    traced index into `JOINTS` (one program for both joints)."""
    import jax

    return jax.value_and_grad(lambda th, f: joint_min_deformation(
        coords.at(th), f, hint, joint), argnums=(0, 1))(theta, force)


def min_deformation(coords, theta, force, hint, joint: str):
    """(value, (d/dtheta, d/dforce)) of `joint_min_deformation` (compiled once)."""
    import jax.numpy as jnp

    return _min_deformation_program(coords, jnp.asarray(theta, float),
                                    jnp.asarray(force, float), hint,
                                    jnp.asarray(JOINTS.index(joint)))


def linear_liftoff(ident, start, stop):
    """Per joint (`JOINTS` order) the smallest force amplitude at which its linearised
    relative displacement reaches its contact window anywhere in the band (the frequency
    of the largest joint receptance is located without gradient, the envelope theorem
    makes that exact for the linearised value), and the frequencies there; with them
    their (values, Jacobians, Hessians) in theta, for the nonlinear value's second-order
    check."""
    import jax.numpy as jnp

    coords, theta = ident.coordinates, jnp.asarray(ident.theta, float)

    def receptances(f):
        return dict(zip(JOINTS, (np.asarray(r) for r in _receptance_program(
            coords, theta, jnp.asarray(f, float)))))

    grid = np.linspace(start, stop, GRID)
    rec = receptances(grid)
    f_at = []
    for j in JOINTS:
        k = int(np.argmax(rec[j]))
        # the same length as the grid: one receptance program for both
        fine = np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, GRID - 1)], GRID)
        f_at.append(float(fine[np.argmax(receptances(fine)[j])]))
    values, jac, hess = (np.asarray(a) for a in _linear_liftoff_program(
        coords, theta, jnp.asarray(f_at, float)))
    per = [from_hessian(f"liftoff_force_{j}_n", "N", values[i], jac[i], hess[i], ident,
                        method="delta (linearised)") for i, j in enumerate(JOINTS)]
    for q, f in zip(per, f_at):
        q.extra.update(frequency_hz=f, note="the force amplitude at which the linearised "
                       "joint displacement reaches the end of its contact window at the "
                       "joint's resonance")
    return per, (values, jac, hess)


# The lift-off search on the nonlinear orbits: harmonic balance at this tolerance (the
# contact law's kink appears just past lift-off), secant steps, stop at this fraction of
# the first two deformations.
LIFTOFF_SETTINGS_TOL = 1e-4
# Its first harmonic count: on the worn drive the second joint's search needs 32 (the
# first's 16), so both start there, and the two searches share one corrector program and
# one deformation program (from 8, the count climbed through 8, 16 and 32: three of each).
LIFTOFF_HARMONICS = 32
# The secant's steps and stopping tests (LIFTOFF_STEPS, LIFTOFF_RTOL, LIFTOFF_FTOL) are
# `_liftoff_draws`' too, where the search runs at each draw.


def joint_min_deformation(params, force, hint, joint):
    """Smallest contact deformation [m] of a joint's two sides over the orbit at a located
    FRC peak (differentiable: `bsfs_jax.design.peak_orbit_samples`); <= 0: a side opens.
    `joint`: a name in `JOINTS` or its (traced) index."""
    import jax
    import jax.numpy as jnp

    from bsfs_jax.design.building import peak_orbit_samples

    deformations = joint_deformations(*peak_orbit_samples(params, force, hint), joint)
    # The smallest sample, chosen without gradient, then differentiated (the minimum over
    # the orbit is stationary in time, so this is its exact derivative). Not `jnp.min`:
    # the orbit's half-period symmetry makes one side's smallest sample bit-equal to the
    # other's, and at that tie jnp.min's gradient came out exactly 0 inside the compiled
    # program (5 of 67 coverage replicates; eager and theta + 1e-14 gave the right one).
    return deformations[jnp.argmin(jax.lax.stop_gradient(deformations))]


def carried_hessian(value, grad, lin_value, lin_grad, lin_hess):
    """The nonlinear lift-off force's Hessian in theta, from the linearised one's.

    Write F*(theta) = r(theta) F_lin(theta): the orbits open a few per cent below the
    linearised joints (r about 0.97 on the worn drive), and r varies far more slowly than
    F_lin, which carries the damping and the preloads. With r = F* / F_lin and its exact
    gradient g_r = (g* - r g_lin) / F_lin, the product rule gives
    H* = r H_lin + g_r g_lin^T + g_lin g_r^T + F_lin H_r; the last term, r's own curvature,
    is the one left out.
    """
    r = value / lin_value
    g_r = (np.asarray(grad, float) - r * np.asarray(lin_grad, float)) / lin_value
    g_lin = np.asarray(lin_grad, float)
    return r * np.asarray(lin_hess, float) + np.outer(g_r, g_lin) + np.outer(g_lin, g_r)


def nonlinear_liftoff(ident, per_joint, derivs, start, stop, *, second: bool = True):
    """`liftoff_force_n`, and `per_joint` with each joint's entry on the nonlinear orbits:
    the force F* at which that joint's smallest contact deformation at the FRC peak
    reaches zero (secant from the linearised value), with dF*/dtheta = -m_theta / m_F
    (implicit, reverse mode). On the bundled worn drive the linearised bearing value was
    61.5 N (95 % interval 61.3-62.0 N) and the orbits open at 59.9 N: the linearised
    interval missed it. The joint that opens second does so on orbits on which the first
    has already lost contact: there the linearised value was 97.0 N (95.8-98.2 N) for the
    nut and the orbits open at 101.6 N (shooting agreed with harmonic balance to 0.02 N),
    so it is searched on the orbits too. Each interval is checked at second order like
    the other quantities (`from_hessian`), with the Hessian carried over from the joint's
    linearised value's (`carried_hessian`; `derivs`: `linear_liftoff`'s values, Jacobians
    and Hessians). Where a search fails the quantity has no value and no interval, and says
    why (`undetermined`). The two searches run on two threads (their programs are the same;
    XLA runs them without Python's lock). `second=False`: the first joint's search alone,
    the other joint left linearised (for studies of `liftoff_force_n`)."""
    from concurrent.futures import ThreadPoolExecutor

    first = int(np.argmin([q.value for q in per_joint]))
    other = 1 - first
    per = list(per_joint)
    # The first joint's orbits open a few per cent below its linearised value (the pair
    # softens); the second joint's above it (the first has let go): secant starts either
    # side of where each was found on the worn drive.
    starts = ((first, (0.9, 0.95)), (other, (1.0, 1.05)))[:2 if second else 1]
    found = {}
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = [(k, pool.submit(_joint_on_orbits, ident, k, per_joint[k], derivs, start,
                                stop, f0 * per_joint[k].value, f1 * per_joint[k].value,
                                k == first))
                for k, (f0, f1) in starts]
        for k, job in jobs:
            per[k], found[k] = job.result()
    joint = JOINTS[first]
    if not second:
        per[other].extra["note"] = "linearised (the search on the orbits was not asked for)"
    elif found[first] is not None:
        note = (f"the {JOINTS[other]} loses contact on orbits on which the {joint} has "
                f"already lost contact (from {found[first]:.1f} N)")
        per[other].extra["note"] = (per[other].extra.get("note", "") + "; "
                                    + note).lstrip("; ")
    total = dataclasses.replace(per[first], name="liftoff_force_n", extra=dict(
        per[first].extra, joint=joint, per_joint={j: q.value for j, q in zip(JOINTS, per)}))
    return total, per


def search_on_orbits(ident, theta, joint: str, f0: float, f1: float, start: float,
                     stop: float, first_hint=None):
    """(F*, the FRC peak's hint at F*, m_F, m_theta there): the force at which `joint`
    loses contact on the orbit at the FRC peak of the model at `theta`, by a secant in the
    force from f0, f1, the peak located afresh by continuation at each force (each step's
    program returns the deformation's gradients with its value): at f0 over the band, at
    each later force by a short continuation around the previous force's peak
    (`locate_peak`'s `near`; over the band where that stretch holds no peak). On the bundled
    worn drive a later step's search took 0.3-3 s instead of 4-12 s, and the lift-off
    forces agreed with the whole-band searches' to 1e-10 relative. `first_hint(hint)`:
    called with the first located peak."""
    from bsfs_jax.design import OrbitSettings

    settings = OrbitSettings(frc_method="hb", frc_tol=LIFTOFF_SETTINGS_TOL,
                             frc_harmonics=LIFTOFF_HARMONICS)
    p = ident.params_at(theta)

    near = [None]  # the branch located at the previous force

    def m(force):
        hint, near[0] = locate_peak(p, force, start, stop, settings, near[0])
        (value, (g_theta, g_f)) = min_deformation(ident.coordinates, theta, force, hint,
                                                  joint)
        return float(value), np.asarray(g_theta), float(g_f), hint

    m0, *first = m(f0)
    if first_hint is not None:
        first_hint(first[-1])
    m1, *last = m(f1)
    scale = abs(m0) + abs(m1)
    for _ in range(LIFTOFF_STEPS):
        f2 = f1 - m1 * (f1 - f0) / (m1 - m0)
        m2, *step = m(f2)
        f0, m0, f1, m1, last = f1, m1, f2, m2, step
        if abs(m1) < LIFTOFF_RTOL * scale or abs(f1 - f0) < LIFTOFF_FTOL * abs(f1):
            return f1, *last[::-1]
    raise ForecastError("no convergence")


def _joint_on_orbits(ident, k, lin, derivs, start, stop, f0, f1, at_draws):
    """(quantity, F* or None): joint `JOINTS[k]`'s lift-off force on the nonlinear orbits,
    or its linearised quantity `lin` with the reason where the search failed. `at_draws`:
    with saved draws, the search at each of them where the quadratic model is doubtful
    (`_liftoff_draws`). Only for the joint that opens first: the other opens on orbits on
    which the first joint has lost contact over part of the period, where the peak's
    extended system (its tangent rows) is not differentiable, and on the bundled worn
    drive its point could not be followed at 36 of the 200 refits (at 30 or at 100 chord
    steps alike), so it keeps the quadratic model (one-off check `liftoff_draws_check.py`, in git
    at 9d7344c)."""
    joint = JOINTS[k]

    def search(th, f0, f1, first_hint=None):
        return search_on_orbits(ident, th, joint, f0, f1, start, stop, first_hint)

    at_draws = at_draws and ident.draws is not None
    try:
        f_star, hint, g_f, g_theta = search(ident.theta, f0, f1, first_hint=(
            (lambda h: prefetch_liftoff(ident, h, k)) if at_draws else None))
    except (ForecastError, ZeroDivisionError) as exc:
        return undetermined(lin, f"the search on the nonlinear orbits failed ({exc})"), None
    how = "implicit"
    grad = -g_theta / g_f if g_f != 0 else np.full_like(g_theta, np.nan)
    if not np.all(np.isfinite(grad)):
        # A safeguard: should the implicit gradient be unusable (it was exactly 0 on 5 of
        # 67 coverage replicates, from jnp.min's tie rule, see `joint_min_deformation`),
        # central differences of the search itself, steps of a quarter standard deviation.
        how = "central differences of the search (the implicit gradient vanished)"
        grad = np.zeros_like(g_theta)
        for i in range(len(grad)):
            h = 0.25 * np.sqrt(max(ident.covariance[i, i], 0.0)) or 1e-6
            e = np.zeros_like(grad)
            e[i] = h
            try:
                grad[i] = (search(ident.theta + e, 0.99 * f_star, f_star)[0]
                           - search(ident.theta - e, 0.99 * f_star, f_star)[0]) / (2 * h)
            except (ForecastError, ZeroDivisionError):
                return undetermined(lin, "the lift-off force's gradient failed on the "
                                         "nonlinear orbits"), None
    values, jac, hess = derivs
    # With saved draws the model itself decides where the quadratic model is doubtful:
    # the search run at each draw in one vmapped program (`_liftoff_draws`).
    exact = (lambda: liftoff_at_draws(ident, hint, f_star, grad, k)) if at_draws else None
    q = from_hessian(
        lin.name, "N", f_star, grad, carried_hessian(f_star, grad, values[k], jac[k],
                                                     hess[k]), ident,
        method="delta (nonlinear orbit at the FRC peak)",
        quadratic="quadratic (nonlinear orbit; Hessian carried from the linearised joints)",
        approximate=True, exact=exact, extra=dict(
            frequency_hz=float(hint.frequency_hz), linearised_n=lin.value, gradient=how,
            note=f"the force at which the {joint} loses contact on the periodic orbit at the "
                 "FRC peak (harmonic balance); its second-order check uses the linearised "
                 "lift-off's exact Hessian carried to the orbits (F* = r F_lin, r's own "
                 "curvature left out)" + (", and where that says the linearisation is "
                 "doubtful and the identification saved draws, the search at each draw"
                 if exact is not None else "")))
    return q, f_star


def undetermined(lin, why: str):
    """The lift-off quantity where the search on the orbits failed: no value and no
    interval, with the reason and the linearised value for reference. Not the linearised
    interval: on the worn drive the orbits open outside it (4.8 N above it for the nut)."""
    return dataclasses.replace(
        lin, value=None, ci95=None, method="not determined", reason=(
            f"{why}; the linearised joint says {lin.value:.1f} N, which the orbits can miss "
            "by more than its interval"),
        extra=dict(lin.extra, linearised_n=lin.value))
