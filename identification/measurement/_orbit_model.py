"""The periodic-orbit measurement model, and which branch a record is on.

**Model.** Where a sine record is not explained by the linear or first-order model, its
acceleration harmonics come from the periodic orbit of the full Eq. 31 under the measured
force harmonics: the package's orbit engine (`bsfs_jax.solvers.periodic_orbit`) with
harmonic balance at `ORBIT_HARMONICS` harmonics (AFT on 64 samples per period), solved by
the engine's Newton and differentiated by the implicit function theorem (`ImplicitForward`,
as the fit's forward-mode Jacobian needs). The acceleration harmonics are those of the
velocity series, i k w V_k (what the balance enforces).

Harmonic balance rather than shooting (the earlier model), measured on the bundled
through-resonance records at the truth (`scripts/orbit_model_check.py`):
- at 16 harmonics it agrees with a shooting orbit sampled at 512 points to within 0.003
  standard errors of every harmonic, also at 3000 N where a joint loses contact (its force
  is only C^1 and harmonic balance converges algebraically);
- the shooting model sampled its orbit at 64 points, and the contact-loss harmonics aliased
  into the fitted ones: 0.29 standard errors at 3000 N / 150 Hz;
- no ODE solve in the program: one evaluation costs 3-10x less, and the program compiles
  in a fraction of the time.
The remaining truncation error is checked per record at the estimate (`branches`: 16
against 32 harmonics, in standard errors; above `_report.TRUNCATION_GATE` the fit is not
converged). So the engine's own bound on the HB defect (`ORBIT_ERROR_TOL`) is only a guard
against a gross failure: at 1e-3 it rejected 16-harmonic orbits at 3000 N on worn drives
(bearing preload near half its nominal) whose harmonics agree with 64 harmonics to 0.01
m/s^2, 1/80 of the records' noise; the fit then had no model for those records.

**Start, and the branch the record is on.** Near a fold the model has two stable orbits at
one frequency and force. Newton is started from the record's own measured state: the
linear response whose fundamental is rescaled so that the nut's displacement matches the
measured one (`measured_start`). Where two stable orbits exist it converges to the one
nearer the measurement, so each record is fitted to the orbit it is on.

`branches` says which one that is, at the estimate: the orbits that a stepped sine reaches
sweeping up to the record's frequency and sweeping down to it (natural continuation in
frequency over `SWEEP_SPAN` on each side, steps of at most 1/`SWEEP_STEPS` of it, halved
where Newton from the previous step's orbit fails: like a quasi-static test it follows a
branch until its fold and then jumps, restarting from the scaled linear response,
`JUMP_SCALES`).
Where they differ the record's orbit is "upper" (the larger fundamental amplitude of the
two) or "lower"; where they coincide it is the only one ("single").

A record whose header gives a stepped sine's direction (`sweep = up` or `down`) is fitted
on the orbit that sweep reaches, not on the one nearest its measurement: Newton starts from
its anchor (`start=`), the sweep's orbit at a nearby parameter set, and the fit checks at
its result that this is still the orbit the sweep reaches (`_anchors.py`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax
from bsfs_jax.machine import BSFS_SCALE, Horizon, simulate_core
from bsfs_jax.solvers import HarmonicBalance, ImplicitForward, periodic_orbit

from ._linear import receptance

ORBIT_HARMONICS = 16
#: The engine's own acceptance bound on the HB error estimate (a relative state error): a
#: guard against gross failure only. The model's accuracy where it matters, in standard
#: errors of the record's harmonics, is checked at the estimate (`branches`).
ORBIT_ERROR_TOL = 1e-2
ORBIT_NEWTON_TOL = 1e-10
SWEEP_SPAN = 0.1  # relative frequency span of the up- and down-sweep
SWEEP_STEPS = 24  # the longest step: SWEEP_SPAN / SWEEP_STEPS of the frequency
SWEEP_HALVINGS = 4  # a failed step is halved this often before a fold is declared
SWEEP_MAX_SOLVES = 160  # orbit solves per sweep, at most (24 steps and their retries)
# Newton iterations per sweep step: from the previous step's orbit it converges in 3-9
# (measured through a 100 N resonance peak); a step that needs more is past a fold, and
# each failed attempt at the 30 of `orbit_of` cost 30 iterations (1.1 s for one sweep).
SWEEP_NEWTON_STEPS = 15
_SCALE = np.asarray(BSFS_SCALE)


def _method(harmonics: int = ORBIT_HARMONICS) -> HarmonicBalance:
    return HarmonicBalance(harmonics=harmonics, error_tol=ORBIT_ERROR_TOL)


def _forcing(frequency_hz, force_coeffs):
    return bsfs_jax.HarmonicForcing(frequency_hz, jnp.real(force_coeffs),
                                    -jnp.imag(force_coeffs))


def _unknowns(x, frequency_hz, harmonics):
    """HB unknowns (scaled, offset zero) of the displacement harmonics x (Hf, 3)."""
    hf = x.shape[0]
    k = jnp.arange(1, hf + 1)[:, None]
    v = 1j * k * (2.0 * jnp.pi * frequency_hz) * x
    y = jnp.concatenate([x, v], axis=1) / jnp.asarray(_SCALE)[None, :]
    a = jnp.zeros((harmonics, 6)).at[:hf].set(jnp.real(y))
    b = jnp.zeros((harmonics, 6)).at[:hf].set(-jnp.imag(y))
    return jnp.concatenate([jnp.zeros(6), a.reshape(-1), b.reshape(-1)])


def linear_harmonics(system, frequency_hz, force_coeffs):
    """Displacement harmonics (Hf, 3) of the linear steady state."""
    k = jnp.arange(1, force_coeffs.shape[-1] + 1)
    return receptance(system, frequency_hz * k) * force_coeffs[:, None]


def measured_start(system, frequency_hz, force_coeffs, measured_acc,
                   harmonics: int = ORBIT_HARMONICS):
    """HB unknowns of the linear steady state with its fundamental rescaled (every mass by
    the same complex factor, clipped to 0.1-10 in modulus) so that the nut's displacement
    equals the measured one, -A_1 / w^2."""
    x = linear_harmonics(system, frequency_hz, force_coeffs)
    w = 2.0 * jnp.pi * frequency_hz
    ratio = (-measured_acc[0] / w**2) / x[0, 2]
    size = jnp.abs(ratio)
    ok = jnp.isfinite(ratio) & (size > 0)
    ratio = jnp.where(ok, ratio * jnp.clip(size, 0.1, 10.0) / jnp.where(ok, size, 1.0), 1.0)
    return _unknowns(x.at[0].multiply(ratio), frequency_hz, harmonics)


def orbit_of(system, frequency_hz, force_coeffs, unknowns, harmonics: int = ORBIT_HARMONICS,
             max_steps: int = 30, stability: bool = False):
    """The periodic orbit (`PeriodicOrbit`, harmonic balance) from HB unknowns (at most
    `max_steps` Newton iterations). `stability`: compute its Floquet multipliers (only
    the branch check needs them; without, `orbit.stable` is False)."""
    forcing = _forcing(frequency_hz, force_coeffs)
    return periodic_orbit(bsfs_jax.vector_field, jnp.zeros(6), (system, forcing),
                          forcing.period, method=_method(harmonics),
                          scale=jnp.asarray(_SCALE), unknowns=unknowns,
                          tol=ORBIT_NEWTON_TOL, max_steps=max_steps, adjoint=ImplicitForward(),
                          throw=False, stability=stability)


def acceleration_of(orbit, frequency_hz, n_harmonics: int):
    """The nut's acceleration harmonics (n_harmonics,) of an HB orbit: i k w V_k."""
    return _acceleration_of_unknowns(orbit.unknowns, frequency_hz, n_harmonics,
                                     orbit.method.harmonics)


def _acceleration_of_unknowns(z, frequency_hz, n_harmonics: int,
                              h: int = ORBIT_HARMONICS):
    a = z[6:6 + 6 * h].reshape(h, 6)[:n_harmonics, 5]
    b = z[6 + 6 * h:].reshape(h, 6)[:n_harmonics, 5]
    k = jnp.arange(1, n_harmonics + 1)
    return 1j * k * (2.0 * jnp.pi * frequency_hz) * (a - 1j * b) * _SCALE[5]


def nonlinear_acceleration(system, frequency_hz, force_coeffs, measured_acc=None,
                           harmonics: int = ORBIT_HARMONICS, start=None):
    """(acceleration harmonics (H,), ok flag) of the periodic steady state under the force
    harmonics, started from the measured state (`measured_start`; from the linear steady
    state without `measured_acc`). `start` (traced HB unknowns, `harmonics`): where
    given and not all zero, Newton starts there instead (a swept record's anchor: the orbit
    its sweep reaches, `swept_unknowns`, computed at a nearby parameter set)."""
    h_f = force_coeffs.shape[-1]
    if measured_acc is None:
        z0 = _unknowns(linear_harmonics(system, frequency_hz, force_coeffs), frequency_hz,
                       harmonics)
    else:
        z0 = measured_start(system, frequency_hz, force_coeffs, measured_acc, harmonics)
    if start is not None:
        z0 = jnp.where(jnp.any(start != 0), start, z0)  # an anchor of `harmonics` harmonics
    z0 = jax.lax.stop_gradient(z0)
    orbit = orbit_of(system, frequency_hz, force_coeffs, z0, harmonics)
    return acceleration_of(orbit, frequency_hz, h_f), orbit.converged


def nonlinear_acceleration_transient(system, frequency_hz, force_coeffs, *,
                                     transient_periods: int = 200, samples: int = 64,
                                     settings=bsfs_jax.SolverSettings(rtol=1e-10, atol=1e-14)):
    """Reference for `nonlinear_acceleration`: simulate and discard a long transient
    (tests and checks only, not the fit)."""
    n_harm = force_coeffs.shape[-1]
    forcing = _forcing(frequency_hz, force_coeffs)
    x = linear_harmonics(system, frequency_hz, force_coeffs)
    k = jnp.arange(1, n_harm + 1)[:, None]
    y0 = jnp.concatenate([jnp.sum(jnp.real(x), axis=0),
                          jnp.sum(jnp.real(1j * k * 2.0 * jnp.pi * frequency_hz * x), axis=0)])
    traj = simulate_core(system, forcing, y0, Horizon(1, transient_periods, samples), settings)
    a = traj.acceleration[:-1, 2]
    n = jnp.arange(samples)
    basis = jnp.exp(-2j * jnp.pi * k * n[None, :] / samples)
    return (2.0 / samples) * (basis @ a), traj.ok


# ------------------------------------------------------------------- branches at the estimate


# Starts tried, in order, where continuation from the previous step fails: the linear
# response scaled by these factors (Newton from the linear response alone missed the upper
# orbit just past a softening fold, 1106 Hz on the bundled resonance drive; 1.5x found it).
# Just past a hardening fold at the linear resonance the orbit left is near a quarter of
# the linear response (drive 262 of the preload robustness study, 1090 Hz: 810 against
# 2986 m/s^2; only 0.2-0.3x converged there).
JUMP_SCALES = (1.0, 1.5, 0.7, 2.0, 1.25, 3.0, 0.5, 0.3)


def swept_unknowns(system, frequency_hz, force_coeffs, direction,
                   harmonics: int = ORBIT_HARMONICS):
    """HB unknowns of the orbit a stepped sine reaches at `frequency_hz` sweeping up
    (direction +1, from (1 - SWEEP_SPAN) f) or down (-1): a quasi-static sweep, which
    follows its branch to the fold.

    Natural continuation with an adaptive step: each step starts from the previous step's
    orbit, at most `SWEEP_SPAN` f / `SWEEP_STEPS` long. A step whose Newton fails is halved
    (up to `SWEEP_HALVINGS` times) before the sweep is taken to be past a fold: a lightly
    damped drive's upper branch climbs steeply, and a fixed step lost it well before its
    fold (drive 267 of the preload robustness study, damping ratio 0.26 %: the fixed
    24-step sweep fell to the lower orbit, 558 m/s^2, at 1123 Hz, where the test's up-sweep
    stays on the upper one, 5.8 km/s^2). Past a fold the branch the sweep was on ends; a
    stepped sine then jumps to the orbit that remains, and so does the model: that step
    starts afresh from the linear response scaled by each of `JUMP_SCALES` in turn until
    one converges (none: the same again a full step further on, until one does or the sweep
    ends). One orbit solve per loop iteration, so vmapped lanes stay in step. The last step
    ends at `frequency_hz` itself, so the unknowns are the swept orbit's (where it
    converged).
    Not differentiated: the orbit's derivative comes from `orbit_of` started here."""
    system, frequency_hz, force_coeffs = jax.lax.stop_gradient(
        (system, frequency_hz, force_coeffs))
    f_end = jnp.asarray(frequency_hz, float)
    f_start = f_end * (1.0 - direction * SWEEP_SPAN)
    h_max = f_end * SWEEP_SPAN / SWEEP_STEPS
    h_min = h_max / 2**SWEEP_HALVINGS
    scales = jnp.asarray((0.0,) + JUMP_SCALES)
    n_scales = len(JUMP_SCALES)

    def fresh(f):
        return _unknowns(linear_harmonics(system, f, force_coeffs), f, harmonics)

    def remaining(f):
        return direction * (f_end - f)

    # state: frequency reached, its orbit, step, jump attempt (0: continuing), jump
    # frequency, iterations. It starts as a jump at f_start (the linear response there).
    def cond(c):
        f, _, _, k, _, n = c
        return ((k > 0) | (remaining(f) > 1e-9 * f_end)) & (n < SWEEP_MAX_SOLVES)

    def body(c):
        f, z, h, k, f_jump, n = c
        jumping = k > 0
        target = jnp.where(jumping, f_jump,
                           f + direction * jnp.minimum(h, jnp.maximum(remaining(f), 0.0)))
        z0 = jnp.where(jumping, scales[k] * fresh(target), z)
        orbit = orbit_of(system, target, force_coeffs, z0, harmonics,
                         max_steps=SWEEP_NEWTON_STEPS)
        ok = orbit.converged
        fold = ~jumping & ~ok & (h <= h_min * (1.0 + 1e-9))
        exhausted = jumping & ~ok & (k >= n_scales)
        # No orbit from any start here: jump again a full step further on (the branch's
        # own continuation failed already), until one converges or the sweep ends.
        again = exhausted & (remaining(target) > 1e-9 * f_end)
        moved = ok | exhausted  # the sweep is at `target` now (on the same orbit if none)
        f = jnp.where(moved, target, f)
        z = jnp.where(ok, orbit.unknowns, z)
        h = jnp.where(jumping, h_max, jnp.where(ok, jnp.minimum(1.5 * h, h_max), 0.5 * h))
        k = jnp.where(fold | again, 1, jnp.where(jumping & ~moved, k + 1, 0))
        f_jump = jnp.where(fold, target, jnp.where(
            again, target + direction * jnp.minimum(h_max, remaining(target)), f_jump))
        return f, z, h, k, f_jump, n + 1

    init = (f_start, fresh(f_start), h_max, jnp.asarray(1), f_start, jnp.asarray(0))
    return jax.lax.while_loop(cond, body, init)[1]


def swept_orbit(system, frequency_hz, force_coeffs, direction):
    """The orbit (`PeriodicOrbit`) a stepped sine reaches at `frequency_hz` sweeping up
    (direction +1) or down (-1): `orbit_of` from `swept_unknowns`."""
    z = swept_unknowns(system, frequency_hz, force_coeffs, direction)
    return orbit_of(system, frequency_hz, force_coeffs, z, stability=True)


@eqx.filter_jit
def swept_state(system, frequency_hz, force_coeffs, direction):
    """(state at t = 0, converged) of `swept_orbit` (synthetic stepped-sine records)."""
    orbit = swept_orbit(system, frequency_hz, force_coeffs, direction)
    return orbit.state, orbit.converged


@bsfs_jax.cached_jit(fast_compile=True)
def _branch_kernel(system, freq, force, measured, sweep, harmonics: int = ORBIT_HARMONICS):
    """Per record: the fitted, up-swept and down-swept orbits' (acceleration, stable,
    converged), and the fitted orbit's truncation error (2 x `harmonics` harmonics,
    started from the fitted orbit, minus the fitted acceleration)."""
    h = harmonics
    def one(f, fc, am, sw):
        h_f = fc.shape[-1]
        # One Newton in the program for the two sweeps, one for the three orbits (started
        # from the measured state and from each sweep's end), one at 32 harmonics: each
        # inlined Newton is a large part of the compilation.
        z_up, z_down = jax.vmap(lambda d: swept_unknowns(system, f, fc, d, h))(
            jnp.asarray([1.0, -1.0]))
        starts = jnp.stack([measured_start(system, f, fc, am, h), z_up, z_down])
        orbits = jax.vmap(lambda z: orbit_of(system, f, fc, z, h, stability=True))(starts)
        acc = jax.vmap(lambda z: _acceleration_of_unknowns(z, f, h_f, h))(orbits.unknowns)
        every = (acc, orbits.stable, orbits.converged, orbits.unknowns)
        # A record with a sweep direction is fitted on that sweep's orbit.
        pick = jnp.where(sw > 0, 1, jnp.where(sw < 0, 2, 0))
        fit = tuple(x[pick] for x in every)
        up, down = (tuple(x[i] for x in every[:3]) for i in (1, 2))
        wide = _method(2 * h)
        z32 = wide.from_coefficients(_method(h), fit[3], 6)
        o32 = orbit_of(system, f, fc, z32, 2 * h)
        # No 32-harmonic orbit: the truncation error is unknown (nan; the fit is gated).
        a32 = jnp.where(o32.converged, acceleration_of(o32, f, h_f), jnp.nan)
        return fit[:3], up, down, a32 - fit[0]

    return jax.vmap(one)(freq, force, measured, sweep)


def _branch_args(system, freq, force, measured, sweep, harmonics):
    return (system, jnp.asarray(freq, float), jnp.asarray(force), jnp.asarray(measured),
            jnp.zeros(len(freq)) if sweep is None else jnp.asarray(sweep, float), harmonics)


def prefetch_branches(system, freq, force, measured, sweep=None,
                      harmonics: int = ORBIT_HARMONICS) -> bool:
    """Start compiling the program of `branches(...)` with arguments of this layout in the
    background (`bsfs_jax.cached_jit`'s `prefetch`); the values do not matter."""
    return _branch_kernel.prefetch(*_branch_args(system, freq, force, measured, sweep,
                                                 harmonics))


def branches(system, freq, force, measured, sweep=None, rtol: float = 1e-4,
             harmonics: int = ORBIT_HARMONICS):
    """Per record (lists): the branch label of the orbit the record is fitted on ("single",
    "upper", "lower", or "unresolved" where the orbits could not be computed, the fitted
    one is unstable or it is neither of the swept ones); a dict of the evidence
    (fundamental amplitudes [m/s^2] of the fitted, up-swept and down-swept orbits, their
    stability); the fitted
    orbit's truncation error (R, H) (2 x `harmonics` harmonics against `harmonics`,
    the model's); and the fitted orbit's acceleration harmonics (R, H), nan where
    it did not converge. One compiled program for all of it."""
    (a_fit, s_fit, ok_fit), up, down, trunc = (
        jax.tree_util.tree_map(np.asarray, out) for out in _branch_kernel(
            *_branch_args(system, freq, force, measured, sweep, harmonics)))
    labels, evidence = [], []
    for i in range(len(freq)):
        amp = lambda a: float(np.abs(a[i, 0]))
        same = lambda a, b: bool(np.abs(a[i, 0] - b[i, 0]) <= rtol * max(np.abs(b[i, 0]),
                                                                          1e-300))
        ev = dict(fitted_amplitude_m_s2=amp(a_fit), up_sweep_amplitude_m_s2=amp(up[0]),
                  down_sweep_amplitude_m_s2=amp(down[0]), fitted_stable=bool(s_fit[i]),
                  up_sweep_stable=bool(up[1][i]), down_sweep_stable=bool(down[1][i]))
        if not (ok_fit[i] and up[2][i] and down[2][i] and s_fit[i]):
            # an orbit failed, or the fitted one is unstable (no record can stay on it)
            label = "unresolved"
        elif same(up[0], down[0]):
            label = "single" if same(a_fit, up[0]) else "unresolved"
        elif same(a_fit, up[0]) or same(a_fit, down[0]):
            other = down[0] if same(a_fit, up[0]) else up[0]
            label = "upper" if amp(a_fit) > float(np.abs(other[i, 0])) else "lower"
        else:
            label = "unresolved"
        ev["sweep_reaching_it"] = ("both" if label == "single" else
                                   "up" if same(a_fit, up[0]) else
                                   "down" if same(a_fit, down[0]) else "neither")
        labels.append(label)
        evidence.append(ev)
    fitted = np.where(ok_fit[:, None], a_fit, np.nan)
    return labels, evidence, trunc, fitted
