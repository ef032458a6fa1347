"""Orbit metrics on the engine: the BSFS orbit at an operating point, and the FRC peak.

No solver lives here: orbits come from `solvers.periodic_orbit` and `continue_orbits`,
differentiated in reverse mode by the implicit function theorem (`ImplicitReverse`).

**The FRC peak.** The peak is the largest amplitude A along the continued branch of
periodic orbits near the first resonance, folded or not: the point where the residual
R(v; theta) = 0 (v = orbit unknowns and frequency) holds and dA/ds = 0 along the branch.
It is located on the host by continuation (harmonic balance by default) and regula falsi
on dA/ds (`Branch.peak`). Its derivative with respect to the parameters theta follows
from the implicit function theorem through the augmented system
{R = 0, dA/ds = 0}; because dA/ds = 0 at the solution, the term that moves the point
along the branch drops out (envelope theorem), and what remains is the derivative of A
at the point of the branch that stays on the hyperplane t* . (v - v*) = 0 normal to the
branch there:

    G(v; theta) = [R(v; theta), t* . (v - v*)] = 0,     dA*/dtheta = dA(v(theta), theta)/dtheta,

one bordered Newton matrix (regular at folds) and one reverse pass. This needs no second
derivatives of R and is exact at the located peak.
"""

import dataclasses
import functools

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..machine import BSFSFamily, bsfs_family, linear_frf, linear_liftoff_force, modes
from ..model import Sinusoid, build_system, vector_field
from ..solvers import (
    HarmonicBalance,
    ImplicitForward,
    ImplicitReverse,
    Shooting,
    SolverError,
    continue_orbits,
    family_amplitudes,
    family_residual,
    integrate,
    periodic_orbit,
)


@dataclasses.dataclass(frozen=True)
class OrbitSettings:
    """Numerical settings of the orbit metrics (static: a change recompiles).

    - `transient_periods`: periods integrated from the linear-FRF guess before Newton
      (point metrics `amplitude` and `floquet`).
    - `method`: the point metrics' orbit method, "shooting" (default: right at any force)
      or "hb" (harmonic balance with `harmonics` harmonics, fixed inside the jitted
      metric; where its error estimate exceeds 1e-4 the metric is NaN and refused).
    - `frc_band`: the FRC-peak search interval, in multiples of the first natural
      frequency f1; `frc_method`: "hb" (harmonic balance, the harmonic count doubled from
      `frc_harmonics` up to `frc_max_harmonics` until its error estimate is below
      `frc_tol`), "shooting", or "auto" (default: harmonic balance where its estimate
      passes along the whole branch, else shooting); `frc_ds`: initial step. The tight
      default tolerance matters for the gradient: where the joints lose contact, the AFT
      truncation error varies non-smoothly with the parameters (the force's kink moves
      across the time grid), and at an estimate of 4e-5 (32 harmonics, 100 N) the peak's
      gradient was 0.7 % off; shooting and 128 harmonics agree to 3e-6.
    """

    transient_periods: int = 10
    method: str = "shooting"
    harmonics: int = 16
    frc_band: tuple = (0.8, 1.2)
    frc_method: str = "auto"
    frc_harmonics: int = 8
    frc_max_harmonics: int = 64
    frc_tol: float = 1e-6
    frc_ds: float = 0.1

    def point_orbit_method(self):
        if self.method == "shooting":
            return Shooting()
        if self.method == "hb":
            return HarmonicBalance(harmonics=self.harmonics, max_harmonics=self.harmonics,
                                   second_order=True)
        raise ValueError(f"method must be 'hb' or 'shooting', got {self.method!r}")

    def frc_orbit_method(self):
        if self.frc_method in ("hb", "auto"):
            return HarmonicBalance(harmonics=self.frc_harmonics,
                                   max_harmonics=max(self.frc_harmonics,
                                                     self.frc_max_harmonics),
                                   error_tol=self.frc_tol, second_order=True)
        if self.frc_method == "shooting":
            return Shooting()
        raise ValueError(f"frc_method must be 'hb' or 'shooting', got {self.frc_method!r}")


def linear_guess(system, forcing: Sinusoid):
    """Steady state of the linearised system at t = 0 for P sin(omega t + phase)."""
    h = linear_frf(system, forcing.frequency)[0]  # (3,) complex receptance [m/N]
    omega = 2.0 * jnp.pi * forcing.frequency
    x0 = forcing.amplitude * jnp.imag(h * jnp.exp(1j * forcing.phase))
    v0 = forcing.amplitude * omega * jnp.real(h * jnp.exp(1j * forcing.phase))
    return jnp.concatenate([x0, v0])


def operating_orbit(params, frequency_hz, force_n, settings: OrbitSettings):
    """(orbit, args) of the T-periodic BSFS orbit at the operating point (traceable).

    The guess is the linear steady state flowed for `transient_periods` (no gradient);
    the orbit is differentiable in reverse mode (implicit function theorem)."""
    family = BSFSFamily(params, frequency_hz, force_n)
    args, period = family(frequency_hz)
    stop = jax.lax.stop_gradient
    y = stop(linear_guess(args[0], args[1]))
    if settings.transient_periods > 0:
        t_end = stop(settings.transient_periods * period)
        y_t = integrate(vector_field, y, stop(args), 0.0, t_end, t_end[None]).ys[0]
        y = jnp.where(jnp.all(jnp.isfinite(y_t)), y_t, y)
    orbit = periodic_orbit(vector_field, y, args, period, method=settings.point_orbit_method(),
                           scale=family.scale, adjoint=ImplicitReverse(), throw=False)
    return orbit, args


@eqx.filter_jit
def _first_frequency(params):
    """The first natural frequency [Hz] (one small program, not op by op)."""
    return modes(build_system(params)).frequencies_hz[0]


#: A working force above this fraction of the smallest linearised lift-off force opens a
#: joint near the FRC peak (the orbits open a few per cent below the linearised value).
OPENS_FRACTION = 0.9


@eqx.filter_jit
def _liftoff_on_grid(params, lo, hi):
    return linear_liftoff_force(build_system(params), jnp.linspace(lo, hi, 257))


def opens_joint(params, force_n, lo, hi) -> bool:
    """Whether the force amplitude `force_n` is at least `OPENS_FRACTION` of the smallest
    linearised lift-off force over [lo, hi] Hz (`machine.linear_liftoff_force`, on a
    257-point grid: a slightly high lift-off force, so the answer errs towards "no")."""
    liftoff = np.asarray(_liftoff_on_grid(params, float(lo), float(hi)))
    return bool(float(force_n) >= OPENS_FRACTION * float(np.min(liftoff)))


@eqx.filter_jit
def _linear_start(family, p):
    """The linear steady state at t = 0 of the family's member at p (one program)."""
    args, _ = family(p)
    return linear_guess(args[0], args[1])


class PeakHint(eqx.Module):
    """A located FRC peak: what the differentiable evaluation needs (host-side result)."""

    v: jax.Array
    tangent: jax.Array
    jacobian: jax.Array
    scale: jax.Array
    p_scale: jax.Array
    frequency_hz: jax.Array
    method: object = eqx.field(static=True)


def _frc_band(params, settings: OrbitSettings, start_hz=None, stop_hz=None):
    """(lo, hi) [Hz] of the FRC-peak search: `settings.frc_band` x f1, or start/stop."""
    if start_hz is not None and stop_hz is not None:
        return float(start_hz), float(stop_hz)
    f1 = float(_first_frequency(params))
    return (settings.frc_band[0] * f1 if start_hz is None else float(start_hz),
            settings.frc_band[1] * f1 if stop_hz is None else float(stop_hz))


def _frc_settings(params, force_n, settings: OrbitSettings, lo, hi) -> OrbitSettings:
    """`settings` with "auto" resolved to "shooting" where the force opens a joint in
    [lo, hi]: the contact force is only C^1 there and harmonic balance converges
    algebraically; "auto" would climb to frc_max_harmonics, fail its tolerance and continue
    by shooting anyway (on the default drive at 100 N: four harmonic counts compiled and
    run, about 12 s)."""
    if settings.frc_method == "auto" and opens_joint(params, force_n, lo, hi):
        return dataclasses.replace(settings, frc_method="shooting")
    return settings


def peak_hint_layout(params, force_n, settings: OrbitSettings, *, start_hz=None,
                     stop_hz=None):
    """A `PeakHint` laid out as `locate_frc_peak(params, force_n, settings, start_hz=...,
    stop_hz=...)` will return it (the values mean nothing), where that is known before the
    search: the FRC is continued by shooting (`_frc_settings`, the same decision). None
    for harmonic balance, whose harmonic count the search finds. For compiling the peak's
    programs while the search runs (`design.prefetch_programs`, the forecast)."""
    lo, hi = _frc_band(params, settings, start_hz, stop_hz)
    if _frc_settings(params, force_n, settings, lo, hi).frc_method != "shooting":
        return None
    d = 6  # the drive's state: three displacements, three velocities
    n = d + 1  # single shooting's unknowns and the frequency
    # numpy arrays (no compiled program to fill them); the two scalars weakly typed, as
    # the located hint's, which come from Python floats
    return PeakHint(np.zeros(n), np.zeros(n), np.zeros((n, n)), np.ones(d),
                    jnp.asarray(1.0), jnp.asarray(1.0), Shooting())


def locate_frc_peak(params, force_n, settings: OrbitSettings, *, start_hz=None,
                    stop_hz=None, progress=False):
    """(PeakHint, Branch): the FRC peak over `settings.frc_band` x f1 (or start/stop).

    Raises `SolverError` when the amplitude has no maximum inside the interval."""
    lo, hi = _frc_band(params, settings, start_hz, stop_hz)
    family = bsfs_family(params, force_n)
    guess = _linear_start(family, jnp.asarray(lo, float))  # traced: a float would be static
    settings = _frc_settings(params, force_n, settings, lo, hi)

    def run(method):
        return continue_orbits(family, guess, lo, hi, method=method, ds=settings.frc_ds,
                               ds_max=10 * settings.frc_ds, max_points=2000,
                               amplitude_index=2, progress=progress)

    try:
        branch = run(settings.frc_orbit_method())
        done = branch.info["stop_reason"] == "left the parameter interval"
    except SolverError:
        if settings.frc_method != "auto":
            raise
        done = False
    if not done and settings.frc_method == "auto":
        branch = run(Shooting())
    pk = branch.peak
    if pk is None:
        raise SolverError(
            f"no FRC peak between {lo:.6g} and {hi:.6g} Hz at {float(force_n):g} N: the nut "
            f"amplitude is largest at an end of the interval ({branch.info['stop_reason']}). "
            "Widen the band (OrbitSettings.frc_band) or check the parameters.")
    return point_hint(pk.point, branch), branch


def locate_frc_peak_near(params, force_n, settings: OrbitSettings, near, *, back: int = 6,
                         ahead: int = 6, start_hz=None, stop_hz=None):
    """(PeakHint, Branch): the FRC peak of `params`, searched by a short continuation on
    the stretch of `near` (the FRC branch of nearby parameters, e.g. the nominal drive's)
    around its peak, instead of over the whole band; what a finite-difference quotient of
    the peak needs (`finite_difference_sensitivities`).

    The search starts on `params`' own orbit at the frequency of `near`'s point `back`
    points before its peak (Newton from that point's state), never before the last fold
    ahead of the peak (there the orbit is the only one of its branch), and ends `ahead`
    points past the peak, before the next fold. It is a search of its own: only its first
    guess comes from `near`. Falls back to `locate_frc_peak` over the whole band when the
    stretch holds no peak (the parameters moved it further than a few points): over
    `settings.frc_band` x f1, or `start_hz`-`stop_hz` where given."""
    def whole_band():
        return locate_frc_peak(params, force_n, settings, start_hz=start_hz, stop_hz=stop_hz)

    pk = near.peak
    if pk is None:
        return whole_band()
    folds = [b.index for b in near.bifurcations if b.kind == "fold"]
    i_a = max([pk.index - back, 0, *(i + 1 for i in folds if i < pk.index)])
    i_b = min([pk.index + 1 + ahead, len(near) - 1, *(i for i in folds if i > pk.index)])
    p_a, p_b = float(near.p[i_a]), float(near.p[i_b])
    if i_b <= i_a or p_a == p_b:
        return whole_band()
    # The settings' method (a caller that differences fixes it to `near`'s discretisation);
    # under "auto", the one `near` ended with.
    method = near.method if settings.frc_method == "auto" else settings.frc_orbit_method()
    family = bsfs_family(params, force_n)
    try:
        branch = continue_orbits(family, near.states[i_a], p_a, p_b, method=method,
                                 ds=settings.frc_ds, ds_max=10 * settings.frc_ds,
                                 max_points=4 * (i_b - i_a) + 20, amplitude_index=2,
                                 # `near`'s state scale, and a tighter corrector: a
                                 # difference quotient needs the peak to ~1e-10
                                 scale=near.scale, normalise=False, tol=1e-10,
                                 p_scale=near.info["p_scale"])
    except SolverError:
        return whole_band()
    if branch.peak is None or branch.info["stop_reason"] != "left the parameter interval":
        return whole_band()
    return point_hint(branch.peak.point, branch), branch


def _one_program(fn):
    """`fn(params, force_n, hint, ...)` as one compiled program (`eqx.filter_jit`), the
    force traced (a float would be static: a program per force). Called outside a jit (a
    test, a notebook, a user's `jax.grad`), the implicit function theorem's pieces would
    otherwise run op by op: about 900 small programs compiled for the two fold gradients
    and the peak's of tests/test_branch_points.py."""
    jitted = eqx.filter_jit(fn)

    @functools.wraps(fn)
    def value(params, force_n, hint, *args):
        return jitted(params, jnp.asarray(force_n, float), hint, *args)

    return value


def _on_hyperplane(params, force_n, hint: PeakHint, adjoint):
    """(v, family): the branch point's unknowns attached to (params, force_n) through the
    hyperplane system G(v; theta) = [R(v; theta), t* . (v - v*)] = 0 (module docstring).
    `hint.jacobian` is G's Newton matrix: the corrector stores [R_v; t*] at the point (the
    border row's sign, flipped where the branch was oriented, does not change the
    solution: G's last row does not depend on theta)."""
    family = BSFSFamily(params, hint.frequency_hz, force_n)
    v_star = jax.lax.stop_gradient(hint.v)
    t_star = jax.lax.stop_gradient(hint.tangent)
    res = _residual(hint, adjoint.ode_adjoint())

    def augmented(v, fam):
        return jnp.concatenate([res(v, fam), jnp.dot(t_star, v - v_star)[None]])

    return adjoint.attach(augmented, family, v_star, hint.jacobian), family


@_one_program
def frc_peak_value(params, force_n, hint: PeakHint, adjoint=ImplicitReverse()):
    """The FRC peak nut amplitude [m] at the located peak, differentiable in `params` and
    `force_n` by the implicit function theorem (module docstring). `adjoint`:
    `ImplicitReverse` (jax.grad) or `ImplicitForward` (jax.jacfwd)."""
    return frc_point_values(params, force_n, hint, adjoint)[0]


@_one_program
def frc_point_values(params, force_n, hint: PeakHint, adjoint=ImplicitReverse()):
    """(nut amplitude [m], frequency [Hz]) of a located branch point on the hyperplane
    normal to the branch there, differentiable in `params` and `force_n`: at the peak
    the amplitude's derivative is the peak amplitude's (`frc_peak_value`), at a fold the
    frequency's is the fold frequency's (`fold_frequency_value`). One program serves the
    peak and the folds (vmapped over stacked hints); the other entry of each pair is not
    a derivative of anything."""
    v, family = _on_hyperplane(params, force_n, hint, adjoint)
    amps = family_amplitudes(family, vector_field, hint.method, hint.scale, hint.p_scale, 1,
                             v, adjoint.ode_adjoint())
    return jnp.stack([amps[2], v[-1] * hint.p_scale])


def point_hint(point, branch) -> PeakHint:
    """`PeakHint` at a located point of `branch` (its peak's or a fold's `HostPoint`)."""
    # numpy (uncommitted), as `peak_hint_layout` lays them out: the prefetched programs
    # then serve the located hint (the corrector's matrices may be committed arrays)
    return PeakHint(np.asarray(point.u), np.asarray(point.tangent),
                    np.asarray(point.jacobian), np.asarray(branch.scale),
                    jnp.asarray(branch.info["p_scale"]),
                    jnp.asarray(point.p(branch.info["p_scale"])), branch.method)


def _residual(hint, ode_adj):
    return lambda v, fam: family_residual(fam, vector_field, hint.method, hint.scale,
                                          hint.p_scale, 1, v, ode_adj)


@_one_program
def fold_frequency_value(params, force_n, hint: PeakHint, adjoint=ImplicitReverse()):
    """The frequency [Hz] of a located fold of the FRC at `force_n`, differentiable in
    `params` and `force_n`.

    At a fold the frequency is extremal along the branch (dp/ds = 0), as the amplitude is at
    the peak, so the same argument holds (module docstring): the derivative of the fold's
    frequency is that of p at the branch point that stays on the hyperplane normal to the
    branch there (`_on_hyperplane`). This is the Moore-Spence result
    dp/dtheta = -psi^T R_theta / psi^T R_p without forming psi. `adjoint`:
    `ImplicitReverse` (jax.grad) or `ImplicitForward` (jax.jacfwd)."""
    return _on_hyperplane(params, force_n, hint, adjoint)[0][-1] * hint.p_scale


@_one_program
def frc_peak_frequency_value(params, force_n, hint: PeakHint):
    """The frequency [Hz] of the located FRC peak, differentiable (forward mode).

    At the peak the frequency is not extremal along the branch, so the hyperplane argument
    does not hold; the peak is the solution of the square system
    H(v; theta) = [R(v; theta), g(v; theta)] = 0 with g = grad_v A . t(v), the amplitude's
    rate along the branch's tangent t(v) (the null vector of R_v, normalised by t* . t = 1:
    one bordered solve). H's Jacobian and its derivative differentiate through R_v, so
    this costs second derivatives of R, taken in forward mode throughout (a shooting
    residual's ODE solve supports one mode only): differentiate with `jax.jacfwd`."""
    family = BSFSFamily(params, hint.frequency_hz, force_n)
    v_star = jax.lax.stop_gradient(hint.v)
    t_star = jax.lax.stop_gradient(hint.tangent)
    ode_adj = dfx.ForwardMode()
    res = _residual(hint, ode_adj)
    e_last = jnp.zeros(v_star.shape[0]).at[-1].set(1.0)

    def rate(v, fam):
        r_v = jax.jacfwd(res)(v, fam)
        t = jnp.linalg.solve(jnp.concatenate([r_v, t_star[None]]), e_last)
        grad_a = jax.jacfwd(lambda w: family_amplitudes(
            fam, vector_field, hint.method, hint.scale, hint.p_scale, 1, w, ode_adj)[2])(v)
        return jnp.dot(grad_a, t)

    def system(v, fam):
        return jnp.concatenate([res(v, fam), rate(v, fam)[None]])

    fam0 = jax.lax.stop_gradient(family)
    jac = jnp.concatenate([jax.lax.stop_gradient(hint.jacobian)[:-1],
                           jax.jacfwd(rate)(v_star, fam0)[None]])
    v = ImplicitForward().attach(system, family, v_star, jac)
    return v[-1] * hint.p_scale


def peak_orbit_samples(params, force_n, hint: PeakHint, adjoint=ImplicitReverse()):
    """(ys (K, 6) [SI], system): the orbit at a located branch point (the FRC peak) as the
    method's uniform samples over one period, differentiable in `params` and `force_n`
    through the hyperplane system (`_on_hyperplane`: first-order exact for any quantity
    of the orbit evaluated at the point; exact where that quantity is extremal along the
    branch)."""
    v, family = _on_hyperplane(params, force_n, hint, adjoint)
    return orbit_samples(family, hint, v, adjoint.ode_adjoint())


def orbit_samples(family, hint: PeakHint, v, ode_adjoint):
    """(ys (K, 6) [SI], system): the orbit of `family` with the hint's unknowns `v` (the
    scaled frequency last) as the hint's method's uniform samples over one period."""
    args, period = family(v[-1] * hint.p_scale)
    _, ys = hint.method.samples(vector_field, v[:-1], args, period, 1, hint.scale,
                                ode_adjoint)
    return ys, args[0]
