"""Pseudo-arclength continuation of periodic orbits on the orbit engine.

A family of T(p)-periodic systems is given by `family(p) -> (args, period)`, so a
frequency continuation changes both the forcing in `args` and the period. The unknowns
are u = (z, q): z the method's scaled unknowns (shooting: states; harmonic balance:
Fourier coefficients) and q = p / p_scale. Each step predicts along the unit tangent,
u_pred = u + ds t, and corrects with the engine's Newton on

    R(z; p(q)) = 0,      t . (u - u_pred) = 0       (Keller's pseudo-arclength condition),

so the branch is followed through folds. The corrector, the new tangent, the Floquet
multipliers, the amplitudes and the amplitude's slope along the branch are one jitted
function, traced once per (family structure, vector field, method) and reused.

Events, from test functions whose sign changes between two points (`_events.py` locates
them by regula falsi on the step length): fold (dp/ds), branch point (prod(mu - 1) without
a fold), period doubling (prod(mu + 1)), Neimark-Sacker (prod_{i<j}(mu_i mu_j - 1) with a
complex pair on the circle) and amplitude peaks (dA/ds from + to -).

With harmonic balance the time-domain error estimate is checked at every point; where it
exceeds the method's `error_tol`, the harmonic count is doubled and the step redone, so
every point of the branch carries an error below tolerance (or the run says why not).
Where a point's estimate falls below a hundredth of the tolerance (past a resonance peak),
the same point is solved again with half the harmonics (never fewer than the first
point's) and the branch goes on with them if that estimate is below half the tolerance:
on the 100 N BSFS resonance the stretch after the peak no longer runs on 64 harmonics.
Events are located, and the branch reported, with the largest count used.
"""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from ._branch import Branch, HostPoint, as_host, test_values
from ._events import EVENT_KINDS, locate_event, locate_peak, points_to_branch
from ._harmonic import HarmonicBalance
from ._integrate import SolverError
from ._kernel import TRACE_COUNTS, Kernel, prepare_outside
from ._orbit import BRANCH_POINT, _init_jit, periodic_orbit
from ._shooting import Shooting, default_scale, float_leaves_to_arrays


def continue_orbits(family, y_guess, p_start, p_stop, *, method=None, ds: float = 0.02,
                    vector_field=None, ds_min: float | None = None,
                    ds_max: float | None = None, max_points: int = 400,
                    n_periods: int = 1, scale=None, p_scale: float | None = None,
                    tol: float = 1e-8, max_newton: int = 8, max_angle: float = 0.3,
                    amplitude_index: int = 0, locate: bool = True, locate_iters: int = 14,
                    find_peaks: bool = True, normalise: bool = True, trim: bool = True,
                    amplitudes: bool | str = True, brief: bool = False,
                    angle_target: float | None = None, progress=False) -> Branch:
    """Follow a branch of n T-periodic orbits from p_start towards p_stop.

    **Main arguments:**
    - `family`: p -> (args, period) (a function or an `eqx.Module`, whose arrays are
      traced, so new values do not recompile); may carry `vector_field` and `scale`, and
      `prepare()`, returning the same family with the work that does not depend on p done
      once (called once, before the corrector; `_kernel.prepare_outside`).
    - `y_guess`: a state near the orbit at p_start, t = 0 (the end of a transient); or
      states (N, d) at N equally spaced times over [0, n T) (the last period of a
      transient), from which harmonic balance takes its start's coefficients without
      integrating (`init_from_samples`).
    - `p_start`, `p_stop`: the run stops once p leaves the interval between them (it may
      fold back and forth inside); with `trim` the last point is moved onto the bound.
    - `method`: `Shooting()` (default) or `HarmonicBalance(harmonics=H)`; the first orbit
      is found by `periodic_orbit` (which, for harmonic balance, also picks H by the error
      estimate).
    - `ds`: initial step in the scaled space, adapted in [`ds_min`, `ds_max`] (default
      ds / 1000 and 10 ds).

    **Other arguments:**
    - `scale`: state scale (default `family.scale`, else from `y_guess`); with `normalise`
      it is multiplied by the rms of the first orbit's scaled state (so ds weighs relative
      changes of the orbit); `p_scale`: default |p_stop - p_start|.
    - `tol`, `max_newton`: corrector tolerance and iterations; a step whose corrector fails
      or turns the tangent by more than `max_angle` [rad] is halved.
    - `angle_target`: None (default) grows the step 1.5x after every corrector call of at
      most 4 Newton steps (and shrinks it 0.7x after one of `max_newton` + 2 or more);
      an angle [rad] below `max_angle` instead scales the step by angle_target / (the
      angle the tangent turned), kept in [0.5, 1.5], so the steps follow the branch's
      curvature: long where it is straight, short (and seldom rejected) where it turns;
      it still never grows after more than 4 Newton steps. On `bsfs map`'s rows
      (angle_target 0.25, max_angle 0.4, ds_max 1000 ds) each row took 70-144 corrector
      calls instead of 190-224 (57-130 with the events' noise floor, `_events`), the same
      folds to 1e-6 Hz.
    - `amplitude_index`: the coordinate whose half peak-to-peak is `Branch.amplitude`.
    - `locate`: locate events by regula falsi (`locate_iters` corrector calls each).
    - `find_peaks`: also find the amplitude's maxima along the branch (`Branch.peaks`; False
      skips their location, e.g. where only the bifurcations are wanted, and
      `info["peaks_searched"]` says so: `Branch.peak` is then None without meaning that
      the amplitude has no interior maximum).
    - `amplitudes`: False leaves the orbits' amplitudes out (NaN; needs
      `find_peaks=False`): a smaller corrector program, where only the bifurcations
      are wanted (`bsfs continue`'s cross-check of the folds by the other method).
      "events": the same corrector, with the amplitudes of each located bifurcation
      computed afterwards by a small program of their own (`bsfs map`'s row
      continuations: each corrector call about 35 % cheaper).
    - `brief`: a continuation of a few dozen corrector calls (a local search, `bsfs
      continue`'s cross-check of the folds): its corrector compiled as quickly as XLA
      can, even for a method whose calls run long (`runs_long`: shooting), whose
      corrector otherwise gets the slower-compiling, faster code. On the 100 N FRC the
      cross-check's shooting compiles about 4 s sooner and `bsfs continue` ends about
      2 s sooner from an empty cache.
    - `progress`: True for a tqdm bar, or a callable(n_points, p).

    **Returns:** a `Branch`; raises `SolverError` if the first orbit cannot be found.
    """
    if vector_field is None:
        vector_field = getattr(family, "vector_field", None)
        if vector_field is None:
            raise ValueError("give vector_field=f(t, y, args): the family has no "
                             "`vector_field` attribute")
    method = Shooting() if method is None else method
    p_start, p_stop, ds = float(p_start), float(p_stop), float(ds)
    if not (math.isfinite(p_start) and math.isfinite(p_stop)) or p_stop == p_start:
        raise ValueError(f"p_start and p_stop must be finite and differ, got {p_start} and "
                         f"{p_stop}")
    if not ds > 0:
        raise ValueError(f"ds must be positive, got {ds}")
    if angle_target is not None and not 0 < angle_target < max_angle:
        raise ValueError(f"angle_target must lie in (0, max_angle = {max_angle:g}) rad, got "
                         f"{angle_target}")
    if amplitudes not in (True, False, "events"):
        raise ValueError(f"amplitudes must be True, False or 'events', got {amplitudes!r}")
    if amplitudes is not True and find_peaks:
        raise ValueError("find_peaks needs the amplitudes: give find_peaks=False with "
                         f"amplitudes={amplitudes!r}")
    ds_min = ds / 1000 if ds_min is None else float(ds_min)
    ds_max = 10 * ds if ds_max is None else float(ds_max)
    family = prepare_outside(float_leaves_to_arrays(family))
    samples = np.asarray(y_guess, dtype=float)
    if not np.all(np.isfinite(samples)) or samples.ndim not in (1, 2) or (
            samples.ndim == 2 and samples.shape[0] < 2):
        raise ValueError(f"y_guess must be a finite state, or finite states at N >= 2 "
                         f"times over one orbit period, got {samples}")
    y_guess = jnp.asarray(samples[0] if samples.ndim == 2 else samples)
    samples = samples if samples.ndim == 2 else None
    if scale is None:
        scale = getattr(family, "scale", None)
    scale = default_scale(y_guess) if scale is None else jnp.broadcast_to(
        jnp.asarray(scale, dtype=float), y_guess.shape)
    p_scale = abs(p_stop - p_start) if p_scale is None else float(p_scale)
    direction = 1.0 if p_stop > p_start else -1.0
    lo, hi = min(p_start, p_stop), max(p_start, p_stop)

    kernel = Kernel(family, vector_field, method, scale, p_scale, n_periods, tol, max_newton,
                    amplitude_index if amplitudes is True else -1, bool(brief))
    traces_before = TRACE_COUNTS["corrector"]
    kernel, first = _first_point(kernel, y_guess, p_start, normalise, samples)
    first = first.oriented(direction)

    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_points, desc="continuation", unit="pt")
    callback = progress if callable(progress) else None

    points, arclength = [first], [0.0]
    steps_taken = rejected = upgrades = downgrades = 0
    h_min = getattr(kernel.method, "harmonics", None)
    kernel_max = kernel  # the largest harmonic count used: events and the branch's method
    down = _Downgrade()
    stop_reason = "max_points"
    events = []
    tests_prev = test_values(first)
    cos_max = math.cos(max_angle)
    try:
        while len(points) < max_points:
            prev = points[-1]
            steps_taken += 1
            cur = kernel.correct(prev.u + ds * prev.tangent, prev.tangent, ds_used=ds,
                                 chord=prev)
            if cur.converged and not cur.accurate and isinstance(kernel.method,
                                                                 HarmonicBalance):
                if 2 * kernel.method.harmonics <= kernel.method.max_harmonics:
                    upgrades += 1
                    kernel = kernel.with_method(
                        kernel.method.with_harmonics(2 * kernel.method.harmonics))
                    if kernel.method.harmonics > kernel_max.method.harmonics:
                        kernel_max = kernel
                    points[-1] = kernel.convert(points[-1])
                    down.reset()
                    continue
                # No more harmonics allowed: stop rather than continue with points whose
                # error exceeds the tolerance (the caller may switch to shooting).
                stop_reason = (f"harmonic balance: error estimate {cur.error:.2g} above "
                               f"error_tol {kernel.method.error_tol:g} with "
                               f"{kernel.method.harmonics} harmonics (max_harmonics) at p = "
                               f"{cur.p(p_scale):g}")
                break
            cos_turn = float(np.dot(cur.tangent, prev.tangent))
            ok = cur.converged and cos_turn >= cos_max
            if not ok:
                rejected += 1
                ds *= 0.5
                if ds < ds_min:
                    stop_reason = (f"step size fell below ds_min = {ds_min:g} at p = "
                                   f"{prev.p(p_scale):g} (corrector failed)")
                    break
                continue
            p_now = cur.p(p_scale)
            if trim and (p_now > hi or p_now < lo):
                bound = hi if p_now > hi else lo
                alpha = (bound / p_scale - prev.u[-1]) / (cur.u[-1] - prev.u[-1])
                u_b = prev.u + alpha * (cur.u - prev.u)
                u_b[-1] = bound / p_scale
                e_end = np.zeros_like(u_b)
                e_end[-1] = 1.0
                end = kernel.correct(u_b, e_end, ds_used=ds * alpha)
                if end.converged:
                    cur = end.oriented(1.0 if float(np.dot(end.tangent, prev.tangent)) >= 0
                                       else -1.0)
            points[-1] = prev.light()
            points.append(cur)
            arclength.append(arclength[-1] + float(np.linalg.norm(cur.u - prev.u)))
            tests = test_values(cur)
            for k, kind in enumerate(EVENT_KINDS):
                if np.sign(tests[k]) != np.sign(tests_prev[k]) and tests[k] != tests_prev[k]:
                    if kind == BRANCH_POINT and np.sign(tests[0]) != np.sign(tests_prev[0]):
                        continue  # the +1 crossing of a fold is the fold itself
                    if kind == "peak" and not tests_prev[k] > 0 > tests[k]:
                        continue  # a minimum of the amplitude
                    events.append((len(points) - 2, k, kind))
            tests_prev = tests
            # Step-size adaptation from the corrector's effort (chord + Newton iterations)
            # and, with an angle_target, from the turn of the tangent.
            ds = _next_step(ds, cur.steps, max_newton, angle_target, cos_turn, ds_min,
                            ds_max)
            # Past the strongly nonlinear stretch (a resonance peak) fewer harmonics
            # may meet the estimate again: try half as many at this point now and then.
            if h_min is not None and kernel.method.harmonics > h_min and down.due(
                    cur.error, kernel.accurate_tol):
                smaller = kernel.with_method(
                    kernel.method.with_harmonics(kernel.method.harmonics // 2))
                here = smaller.convert(cur)
                trial = smaller.correct(here.u, here.tangent, ds_used=cur.ds_used)
                if trial.converged and trial.error <= 0.5 * smaller.accurate_tol and abs(
                        trial.u[-1] - cur.u[-1]) <= 1e-6 * max(1.0, abs(cur.u[-1])):
                    kernel, points[-1] = smaller, trial.oriented(
                        1.0 if float(np.dot(trial.tangent, here.tangent)) >= 0 else -1.0)
                    tests_prev = test_values(points[-1])
                    downgrades += 1
                    down.reset()
                else:
                    down.back_off()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(p=f"{p_now:.6g}", ds=f"{ds:.2g}")
            if callback is not None:
                callback(len(points), p_now)
            if p_now > hi or p_now < lo:
                stop_reason = "left the parameter interval"
                break
    finally:
        if bar is not None:
            bar.close()

    kernel = kernel_max  # events are located with the most harmonics used
    if h_min is not None:  # every point in the unknowns of that harmonic count
        points = [kernel.convert(p) for p in points]
    bifurcations, peaks = [], []
    for index, k, kind in events:
        if kind == "peak":
            if not find_peaks:
                continue
            pk = locate_peak(kernel, points[index], points[index + 1], index,
                             locate_iters if locate else 0)
            if pk is not None:
                peaks.append(pk)
            continue
        bif = locate_event(kernel, points[index], points[index + 1], index, k, kind,
                           locate_iters if locate else 0)
        if bif is not None:
            if amplitudes == "events":
                amps = kernel.amplitudes(bif.point.u)
                bif = dataclasses.replace(
                    bif, amplitude=float(amps[amplitude_index]), amplitudes=amps,
                    point=dataclasses.replace(bif.point, amplitudes=amps))
            bifurcations.append(bif)
    info = {"steps": steps_taken, "rejected": rejected, "points": len(points),
            "stop_reason": stop_reason, "corrector_calls": kernel.calls,
            "corrector_traces": TRACE_COUNTS["corrector"] - traces_before,
            "p_scale": p_scale, "scale": np.asarray(kernel.scale).tolist(),
            "method": kernel.method.name, "harmonic_upgrades": upgrades,
            "harmonic_downgrades": downgrades, "peaks_searched": bool(find_peaks),
            **kernel.method.discretisation()}
    return points_to_branch(points, arclength, bifurcations, peaks, kernel, n_periods, info)


def _next_step(ds, steps, max_newton, angle_target, cos_turn, ds_min, ds_max):
    """The next step length after an accepted point (`continue_orbits`' `angle_target`):
    from the corrector's Newton steps alone, or also from the angle the tangent turned."""
    if angle_target is None:
        factor = 1.5 if steps <= 4 else 0.7 if steps >= max_newton + 2 else 1.0
    else:
        angle = math.acos(min(1.0, max(-1.0, cos_turn)))
        factor = min(1.5, max(0.5, angle_target / max(angle, 1e-12)))
        if steps >= max_newton + 2:
            factor = min(factor, 0.7)
        elif steps > 4:
            factor = min(factor, 1.0)
    return min(max(ds * factor, ds_min), ds_max)


class _Downgrade:
    """When to try half the harmonics: the point's error estimate at most a hundredth of
    the tolerance, and not within `wait` points of the last change or failed try (the wait
    doubles after each failed try)."""

    def __init__(self):
        self.wait, self.since = 4, 0

    def due(self, error, tol) -> bool:
        self.since += 1
        return tol is not None and self.since >= self.wait and error <= 1e-2 * tol

    def reset(self):
        self.wait, self.since = 4, 0

    def back_off(self):
        self.wait, self.since = min(2 * self.wait, 64), 0


def _first_point(kernel, y_guess, p_start, normalise, samples=None):
    """(kernel, point): the orbit at p_start, corrected by the continuation's own program.

    The method's start (`init`: for harmonic balance one period integrated from the
    guess; `init_from_samples` where the caller gave that period's states) is corrected
    at fixed p (tangent e_q); for harmonic balance the harmonic count is doubled while the
    error estimate is above tolerance. A first orbit by the same program as every later
    one spares compiling `periodic_orbit`'s (1.4 s for harmonic balance, 3.4 s for
    shooting with dopri8); only where the corrector's few Newton steps do not converge
    from the guess does `periodic_orbit` (more steps) find it first. With `normalise` the
    state scale is multiplied by the rms of the first orbit's scaled state
    (the scale is an argument of the program: no recompile)."""
    family, vector_field, method = kernel.family, kernel.vector_field, kernel.method
    p_scale, scale, n_periods = kernel.p_scale, kernel.scale, kernel.n_periods
    args0, period0 = family(p_start)

    def correct(k, z):
        e = np.zeros(z.size + 1)
        e[-1] = 1.0
        return k.correct(np.concatenate([z, [p_start / p_scale]]), e)

    # From the samples, or (single shooting) from the state itself: no program.
    z0 = method.init_from_samples(np.asarray(y_guess)[None] if samples is None else samples,
                                  np.asarray(scale))
    if z0 is None:
        z0 = np.asarray(_init_jit(method, vector_field, y_guess, args0, period0, n_periods,
                                  scale))
    pt = correct(kernel, z0) if np.all(np.isfinite(z0)) else None
    while pt is not None and pt.converged and not pt.accurate \
            and isinstance(kernel.method, HarmonicBalance) \
            and 2 * kernel.method.harmonics <= kernel.method.max_harmonics:
        kernel = kernel.with_method(kernel.method.with_harmonics(2 * kernel.method.harmonics))
        pt = correct(kernel, kernel.convert(pt).u[:-1])
    if pt is None or not (pt.converged and pt.accurate):
        try:
            orbit = periodic_orbit(vector_field, y_guess, args0, period0, method=method,
                                   n_periods=n_periods, scale=scale, tol=kernel.tol,
                                   throw=True)
        except SolverError as exc:
            raise SolverError(f"continuation: no periodic orbit at p = {p_start:g}: {exc}. "
                              "Start from the end of a transient simulation, or give "
                              "`scale` (typical state magnitudes).") from None
        if orbit.method != kernel.method:
            kernel = kernel.with_method(orbit.method)
        pt = correct(kernel, np.asarray(orbit.unknowns))
    if normalise:
        rms = float(np.sqrt(np.mean(np.square(np.asarray(pt.state) / np.asarray(scale)))))
        if np.isfinite(rms) and rms > 0:
            kernel = dataclasses.replace(kernel, scale=scale * rms, _no_chord=None)
            pt = correct(kernel, pt.u[:-1] / rms)
    if not pt.converged:
        raise SolverError(f"continuation: the corrector failed at p = {p_start:g} "
                          f"(residual {pt.residual:.3g}).")
    return kernel, pt


__all__ = ["continue_orbits", "Branch", "HostPoint", "as_host"]
