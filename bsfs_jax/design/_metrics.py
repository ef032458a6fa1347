"""Response metrics of a design as differentiable functions of `BallScrewParams`.

Every metric is `fn(params, operating_point, settings) -> scalar` in SI units, pure JAX
and differentiable in reverse mode with respect to every parameter:

- static metrics (first natural frequency, static axial stiffness, linear FRF peak,
  thermal positioning error) differentiate through `build_system`, the Newton static
  equilibrium (optimistix, implicit adjoint) and `eigh`;
- orbit metrics (amplitude at an operating point, FRC peak amplitude, largest Floquet
  multiplier) differentiate through the T-periodic orbit by the implicit function
  theorem (`_orbit.py`), never through a long transient.
"""

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from ..model import Sinusoid, accelerations, build_system
from ..solvers import linear_frf, modes
from ._orbit import OrbitSettings, flow_and_monodromy, orbit_samples, periodic_orbit


class OperatingPoint(eqx.Module):
    """Excitation P sin(2 pi f t) on the nut: `frequency_hz` [Hz] and `force_n` [N]."""

    frequency_hz: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))
    force_n: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))

    @property
    def forcing(self) -> Sinusoid:
        return Sinusoid(self.force_n, self.frequency_hz)


@dataclasses.dataclass(frozen=True)
class Metric:
    """A named response metric.

    - `name`: CLI / API name; `label`: plot label; `unit`: the reporting unit, and
      `scale`: SI value * scale = value in `unit`.
    - `direction`: "min" or "max", the sensible design direction (used by `optimize`).
    - `needs_orbit`: True when it solves periodic orbits (needs frequency and force).
    - `fn(params, op, settings)`: the SI value.
    """

    name: str
    label: str
    unit: str
    scale: float
    direction: str
    needs_orbit: bool
    uses_operating_point: bool
    description: str
    fn: Callable = dataclasses.field(repr=False, compare=False)


# -- static metrics ---------------------------------------------------------------------
def natural_frequency(params, op=None, settings=None):
    """First undamped natural frequency [Hz] about the static equilibrium."""
    return modes(build_system(params)).frequencies_hz[0]


def static_stiffness(params, op=None, settings=None):
    """Axial stiffness at the nut P / x_n [N/m] about the equilibrium (series chain)."""
    return modes(build_system(params)).static_stiffness


def thermal_error(params, op=None, settings=None):
    """Thermal positioning error: screw elongation delta_s to the nut [m] (Eq. 30)."""
    return build_system(params).thermal.elongation


def _receptance_modulus(system, frequency_hz):
    return jnp.abs(linear_frf(system, frequency_hz)[0, 2])


def _parabola_vertex(f, a, k):
    """Abscissa of the parabola through (f[k-1..k+1], a[k-1..k+1]) (k clipped inside)."""
    k = jnp.clip(k, 1, f.shape[0] - 2)
    f0, f1, f2 = f[k - 1], f[k], f[k + 1]
    a0, a1, a2 = a[k - 1], a[k], a[k + 1]
    denom = a0 - 2.0 * a1 + a2
    h = f1 - f0
    ok = (denom < 0) & jnp.isfinite(denom)  # a proper maximum, all three points valid
    safe = jnp.where(ok, denom, -1.0)
    shift = jnp.where(ok, 0.5 * h * (jnp.where(ok, a0 - a2, 0.0)) / safe, 0.0)
    return f1 + jnp.clip(shift, -h, h)


def frf_peak_frequency(params):
    """Frequency [Hz] of the linearised nut receptance peak near the first mode (no
    gradient): |H| on 201 points over 0.8-1.2 f1, then twice on 41 points over +-2 grid
    steps around the best one (each 10x finer), refined by a three-point parabola in ln|H|."""
    sys_ng = jax.lax.stop_gradient(build_system(params))
    f1 = modes(sys_ng).frequencies_hz[0]
    coarse = f1 * jnp.linspace(0.8, 1.2, 201)
    log_h = jnp.log(jnp.abs(linear_frf(sys_ng, coarse)[:, 2]))
    f_c = _parabola_vertex(coarse, log_h, jnp.argmax(log_h))
    step = coarse[1] - coarse[0]
    for _ in range(2):
        fine = f_c + step * jnp.linspace(-2.0, 2.0, 41)
        log_h = jnp.log(jnp.abs(linear_frf(sys_ng, fine)[:, 2]))
        f_c = _parabola_vertex(fine, log_h, jnp.argmax(log_h))
        step = step / 10.0
    return jax.lax.stop_gradient(f_c)


def frf_peak(params, op=None, settings=None):
    """Peak of the linearised nut receptance |x_n / P| [m/N] near the first mode.

    The peak frequency is located without gradient (`frf_peak_frequency`); by the
    envelope theorem the derivative of the peak value is the partial derivative at that
    frequency, so this is exact at the located peak.
    """
    return _receptance_modulus(build_system(params), frf_peak_frequency(params))


# -- orbit metrics ----------------------------------------------------------------------
def _extreme(x, v, a, sign):
    """Refined extreme of a sampled signal: Taylor step x - v^2 / (2 a) at the best sample.

    `sign` = +1 for the maximum, -1 for the minimum. Between samples the true extreme is
    where v = 0; one Taylor step with the exact v and a at the sample is accurate to
    O(dt^3). Differentiable (the argmax is fixed, as for any max).
    """
    k = jnp.argmax(sign * x)
    xk, vk, ak = x[k], v[k], a[k]
    ok = sign * ak < 0.0
    safe_a = jnp.where(ok, ak, -sign * 1.0)
    return jnp.where(ok, xk - vk**2 / (2.0 * safe_a), xk)


def _orbit_and_samples(system, forcing, settings):
    y, res, _ = periodic_orbit(system, forcing, settings)
    bad = ~(res <= settings.newton_tol)
    _, ys = orbit_samples(system, forcing, y, settings)
    return y, ys, bad


def _nut_amplitude(system, forcing, ys):
    x, v = ys[:, :3], ys[:, 3:]
    force = jax.vmap(forcing)(forcing.period * jnp.arange(ys.shape[0]) / (ys.shape[0] - 1))
    a = accelerations(system, x, v, force)
    top = _extreme(x[:, 2], v[:, 2], a[:, 2], 1.0)
    bottom = _extreme(x[:, 2], v[:, 2], a[:, 2], -1.0)
    return 0.5 * (top - bottom)


def orbit_amplitude(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings()):
    """Steady (period-1 orbit) nut amplitude, half peak-to-peak of x_n [m]; NaN if the
    Newton solve did not converge."""
    system = build_system(params)
    forcing = op.forcing
    _, ys, bad = _orbit_and_samples(system, forcing, settings)
    return jnp.where(bad, jnp.nan, _nut_amplitude(system, forcing, ys))


def floquet_modulus(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings()):
    """Largest Floquet multiplier modulus |mu|_max of the orbit (< 1: stable)."""
    system = build_system(params)
    forcing = op.forcing
    y, res, _ = periodic_orbit(system, forcing, settings)
    _, mono = flow_and_monodromy(system, forcing, y, settings)
    mu = jnp.max(jnp.abs(jnp.linalg.eigvals(mono)))
    return jnp.where(res <= settings.newton_tol, mu, jnp.nan)


def frc_peak_location(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings()):
    """(f*, A*): frequency [Hz] and nut amplitude [m] of the FRC peak near the first mode.

    Orbit amplitudes on a grid of `settings.frc_points` frequencies over
    `settings.frc_band` x f1 (force `op.force_n`; `op.frequency_hz` is not used) locate
    the peak; `settings.frc_refinements` rounds of three-point parabolic refinement
    of ln A (each 4x finer) find f* (no gradient), and A* is the orbit amplitude
    at f* (differentiable). By the envelope theorem (dA/df = 0 at f*) the derivative of
    A* is the partial derivative at fixed f*. Each grid point is an orbit reached from the
    linear guess; where the curve folds (strongly nonlinear: jumps between coexisting
    orbits) the peak is not a smooth maximum and A* is NaN (the user-facing functions
    then raise). Lower the force for a weakly nonlinear FRC.
    """
    system = build_system(params)
    sys_ng = jax.lax.stop_gradient(system)
    force = jax.lax.stop_gradient(op.force_n)
    f1 = modes(sys_ng).frequencies_hz[0]

    def amp(f):  # log amplitude: a resonance peak is closer to a parabola in ln A
        forcing = Sinusoid(force, f)
        _, ys, bad = _orbit_and_samples(sys_ng, forcing, settings)
        return jnp.where(bad, -jnp.inf, jnp.log(_nut_amplitude(sys_ng, forcing, ys)))

    grid = f1 * jnp.linspace(settings.frc_band[0], settings.frc_band[1], settings.frc_points)
    amps = jax.lax.map(amp, grid)
    best = jnp.max(amps)
    f_star = _parabola_vertex(grid, amps, jnp.argmax(amps))
    h = grid[1] - grid[0]
    smooth = jnp.asarray(True)
    for _ in range(settings.frc_refinements):
        h = h / 4.0
        pts = f_star + h * jnp.array([-1.0, 0.0, 1.0])
        a3 = jax.lax.map(amp, pts)
        best = jnp.maximum(best, jnp.max(a3))
        smooth = (a3[0] - 2.0 * a3[1] + a3[2]) < 0
        f_star = _parabola_vertex(pts, a3, jnp.asarray(1))
    f_star = jax.lax.stop_gradient(f_star)
    forcing = Sinusoid(op.force_n, f_star)
    _, ys, bad = _orbit_and_samples(system, forcing, settings)
    peak = _nut_amplitude(system, forcing, ys)
    # A smooth maximum: the last three points bend down and the refined peak is the
    # largest amplitude seen. Otherwise the curve jumps (a fold of a strongly nonlinear
    # FRC, where the envelope theorem does not hold): NaN rather than a wrong gradient.
    valid = ~bad & smooth & (jnp.log(jax.lax.stop_gradient(peak)) >= best - 1e-3)
    return f_star, jnp.where(valid, peak, jnp.nan)


def frc_peak(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings()):
    """Peak nut amplitude [m] of the frequency-response curve near the first resonance at
    force `op.force_n` (see `frc_peak_location`)."""
    return frc_peak_location(params, op, settings)[1]


METRICS: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric("frc_peak", "FRC peak amplitude", "um", 1e6, "min", True, True,
               "peak nut amplitude of the frequency-response curve near the first resonance "
               "at the given force (orbit amplitudes on a frequency grid, refined)",
               frc_peak),
        Metric("amplitude", "amplitude at the operating point", "um", 1e6, "min", True, True,
               "steady nut amplitude (half peak-to-peak of x_n) of the period-1 orbit at the "
               "given frequency and force", orbit_amplitude),
        Metric("natural_frequency", "first natural frequency", "Hz", 1.0, "max", False, False,
               "first undamped natural frequency about the static equilibrium",
               natural_frequency),
        Metric("static_stiffness", "static axial stiffness", "N/um", 1e-6, "max", False, False,
               "axial stiffness of the bearing-screw-nut chain at the nut", static_stiffness),
        Metric("floquet", "largest Floquet multiplier modulus", "-", 1.0, "min", True, True,
               "stability margin of the period-1 orbit at the given frequency and force "
               "(< 1 stable; smaller is more stable)", floquet_modulus),
        Metric("thermal_error", "thermal positioning error", "um", 1e6, "min", False, False,
               "screw thermal elongation to the nut at the steady temperature of the "
               "given speed (Eq. 30)", thermal_error),
        Metric("frf_peak", "linear FRF peak compliance", "um/N", 1e6, "min", False, False,
               "peak of the linearised nut receptance near the first mode", frf_peak),
    )
}


def get_metric(name: str) -> Metric:
    """The `Metric` called `name`, or a ValueError listing the choices."""
    try:
        return METRICS[name]
    except KeyError:
        import difflib

        close = difflib.get_close_matches(name, list(METRICS), n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        raise ValueError(f"unknown metric '{name}'.{hint} Choose one of: "
                         f"{', '.join(METRICS)}") from None
