"""Response metrics of a design as differentiable functions of `BallScrewParams`.

Every metric is `fn(params, operating_point, settings) -> scalar` in SI units, pure JAX
and differentiable in reverse mode with respect to every parameter:

- static metrics (first natural frequency, static axial stiffness, linear FRF peak,
  thermal positioning error) differentiate through `build_system`, the Newton static
  equilibrium (optimistix, implicit adjoint) and `eigh`;
- orbit metrics (amplitude at an operating point, FRC peak amplitude, largest Floquet
  multiplier) differentiate through the periodic orbit of the engine
  (`solvers.periodic_orbit`, `continue_orbits`) by the implicit function theorem, never
  through a transient; the FRC peak through the augmented system of `_orbit.py`.
"""

import dataclasses
from collections.abc import Callable

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._numerics import float_array
from ..machine import linear_frf, modes
from ..model import Sinusoid, build_system, vector_field
from ..solvers import (
    SHOOTING_SETTINGS,
    ImplicitForward,
    ImplicitReverse,
    variational_monodromy,
)
from ._catalogue import METRIC_INFO, MetricInfo
from ._orbit import (
    OrbitSettings,
    frc_peak_value,
    locate_frc_peak,
    locate_frc_peak_near,
    operating_orbit,
    peak_hint_layout,
)


class OperatingPoint(eqx.Module):
    """Excitation P sin(2 pi f t) on the nut: `frequency_hz` [Hz] and `force_n` [N]."""

    frequency_hz: jax.Array = eqx.field(converter=float_array)
    force_n: jax.Array = eqx.field(converter=float_array)

    @property
    def forcing(self) -> Sinusoid:
        return Sinusoid(self.force_n, self.frequency_hz)


@dataclasses.dataclass(frozen=True)
class Metric(MetricInfo):
    """A named response metric: its description (`MetricInfo`) and its functions.

    - `fn(params, op, settings, hint=None)`: the SI value (traceable, differentiable);
    - `locate(params, op, settings) -> hint`: host-side search that `fn` needs (the FRC
      peak by continuation), None for metrics that need none;
    - `locate_near(params, op, settings, near=None) -> (hint, near)`: the same search,
      with what it found (`near`) to start the next one from, for nearby parameters
      (finite differences); None where `locate` has nothing to reuse;
    - `hint_layout(params, op, settings)`: a hint laid out as `locate` will return it
      (values meaningless) where that is known before the search, else None (for
      compiling `fn`'s programs while the search runs);
    - `forward_fn`: `fn` differentiable in forward mode (its implicit derivatives by
      `ImplicitForward`), where its gradient is cheaper to compile that way (the FRC
      peak: 6 s instead of 12 s for 16 parameters, the same numbers); None: reverse mode.
    """

    fn: Callable = dataclasses.field(repr=False, compare=False)
    locate: Callable | None = dataclasses.field(default=None, repr=False, compare=False)
    locate_near: Callable | None = dataclasses.field(default=None, repr=False, compare=False)
    hint_layout: Callable | None = dataclasses.field(default=None, repr=False, compare=False)
    forward_fn: Callable | None = dataclasses.field(default=None, repr=False, compare=False)


# -- static metrics ---------------------------------------------------------------------
def natural_frequency(params, op=None, settings=None, hint=None):
    """First undamped natural frequency [Hz] about the static equilibrium."""
    return modes(build_system(params)).frequencies_hz[0]


def static_stiffness(params, op=None, settings=None, hint=None):
    """Axial stiffness at the nut P / x_n [N/m] about the equilibrium (series chain)."""
    return modes(build_system(params)).static_stiffness


def thermal_error(params, op=None, settings=None, hint=None):
    """Thermal positioning error: screw elongation delta_s to the nut [m] (Eq. 30)."""
    return build_system(params).thermal.elongation


def _receptance_modulus(system, frequency_hz):
    return jnp.abs(linear_frf(system, frequency_hz)[0, 2])


def _parabola_vertex(f, a, k):
    """Abscissa of the parabola through (f[k-1..k+1], a[k-1..k+1]) (k clipped inside)."""
    k = jnp.clip(k, 1, f.shape[0] - 2)
    f0, f1 = f[k - 1], f[k]
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


def frf_peak(params, op=None, settings=None, hint=None):
    """Peak of the linearised nut receptance |x_n / P| [m/N] near the first mode.

    The peak frequency is located without gradient (`frf_peak_frequency`); by the
    envelope theorem the derivative of the peak value is the partial derivative at that
    frequency, so this is exact at the located peak.
    """
    return _receptance_modulus(build_system(params), frf_peak_frequency(params))


# -- orbit metrics ----------------------------------------------------------------------
def orbit_amplitude(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings(),
                    hint=None):
    """Steady (period-1 orbit) nut amplitude, half peak-to-peak of x_n [m]; NaN where the
    orbit was not found."""
    orbit, args = operating_orbit(params, op.frequency_hz, op.force_n, settings)
    amp = orbit.amplitudes(vector_field, args, adjoint=ImplicitReverse())[2]
    return jnp.where(orbit.converged, amp, jnp.nan)


def floquet_modulus(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings(),
                    hint=None):
    """Largest Floquet multiplier modulus |mu|_max of the orbit (< 1: stable).

    The monodromy matrix comes from the variational equations at the orbit (a plain ODE
    solve, so it is differentiable in reverse mode)."""
    orbit, args = operating_orbit(params, op.frequency_hz, op.force_n, settings)
    mono = variational_monodromy(vector_field, orbit.state, args, orbit.period, 1,
                                 SHOOTING_SETTINGS, ode_adjoint=dfx.RecursiveCheckpointAdjoint())
    mu = jnp.max(jnp.abs(jnp.linalg.eigvals(mono)))
    return jnp.where(orbit.converged, mu, jnp.nan)


def frc_peak_location(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings()):
    """(f*, A*): frequency [Hz] and nut amplitude [m] of the FRC peak near the first mode
    at force `op.force_n`: the maximum of the amplitude along the continued branch over
    `settings.frc_band` x f1, folded or not (`_orbit.locate_frc_peak`)."""
    hint, branch = locate_frc_peak(params, op.force_n, settings)
    return float(hint.frequency_hz), float(branch.peak.amplitude)


# The last whole-band FRC search, by its exact inputs: `sensitivities` and the
# finite-difference probe of its gradient that follows (`bsfs sensitivity`) search the
# same drive; the second reads the first's result instead of continuing again.
_LAST_SEARCH: dict = {}


def _search_key(params, force_n, settings):
    leaves, treedef = jax.tree_util.tree_flatten(params)
    return (str(treedef), tuple(np.asarray(x).tobytes() for x in leaves),
            float(force_n), repr(settings))


def _locate_frc(params, op, settings):
    return _locate_frc_near(params, op, settings)[0]


def _locate_frc_near(params, op, settings, near=None):
    """(hint, branch): the FRC peak over the whole band (`near` None), or on the stretch
    of the branch `near` around its peak (`_orbit.locate_frc_peak_near`)."""
    if near is not None:
        return locate_frc_peak_near(params, op.force_n, settings, near)
    key = _search_key(params, op.force_n, settings)
    found = _LAST_SEARCH.get(key)
    if found is None:
        found = locate_frc_peak(params, op.force_n, settings)
        _LAST_SEARCH.clear()
        _LAST_SEARCH[key] = found
    return found


def frc_peak(params, op: OperatingPoint, settings: OrbitSettings = OrbitSettings(),
             hint=None, adjoint=None):
    """Peak nut amplitude [m] of the frequency-response curve near the first resonance at
    force `op.force_n`. `hint` is the located peak (`Metric.locate`); the value is
    differentiable by the implicit function theorem (`_orbit.frc_peak_value`; `adjoint`
    `ImplicitReverse()` by default, `ImplicitForward()` for forward mode)."""
    if hint is None:
        hint = _locate_frc(params, op, settings)
    return frc_peak_value(params, op.force_n, hint,
                          ImplicitReverse() if adjoint is None else adjoint)


def _frc_peak_forward(params, op, settings=OrbitSettings(), hint=None):
    return frc_peak(params, op, settings, hint, ImplicitForward())


def _frc_hint_layout(params, op, settings):
    return peak_hint_layout(params, op.force_n, settings)


# The functions of each metric in `METRIC_INFO`:
# (fn, locate, locate_near, hint_layout, forward_fn).
_FUNCTIONS = {
    "frc_peak": (frc_peak, _locate_frc, _locate_frc_near, _frc_hint_layout,
                 _frc_peak_forward),
    "amplitude": (orbit_amplitude, None, None, None, None),
    "natural_frequency": (natural_frequency, None, None, None, None),
    "static_stiffness": (static_stiffness, None, None, None, None),
    "floquet": (floquet_modulus, None, None, None, None),
    "thermal_error": (thermal_error, None, None, None, None),
    "frf_peak": (frf_peak, None, None, None, None),
}
METRICS: dict[str, Metric] = {
    name: Metric(**dataclasses.asdict(info), fn=fn, locate=locate, locate_near=near,
                 hint_layout=layout, forward_fn=forward)
    for name, info in METRIC_INFO.items()
    for fn, locate, near, layout, forward in (_FUNCTIONS[name],)
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
