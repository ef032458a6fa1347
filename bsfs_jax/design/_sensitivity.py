"""Gradients of a metric with respect to named design parameters, and their normalised form.

Parameters are addressed by their TOML vocabulary names ("nut.balls",
"bearing.contact_angle_deg", ...) and enter in file units, so gradients read
"um per ball", "Hz per degree", ... The normalised sensitivity

    S_i = d ln m / d ln p_i = (p_i / m) dm/dp_i

is unit-free: a 1 % increase of p_i changes the metric by about S_i %.
"""

import dataclasses
import functools
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._programs import cached_jit
from ..params import BallScrewParams, lookup_key
from ._catalogue import DEFAULT_FORCE_N, DEFAULT_FREQUENCY_HZ, DESIGN_PARAMETERS
from ._metrics import Metric, OperatingPoint, get_metric
from ._orbit import OrbitSettings

#: Threads for the perturbed searches of `finite_difference_sensitivities`.
FD_WORKERS = 2
#: `SensitivityResult.method` of `sensitivities` (exact gradients).
IMPLICIT_AD = "implicit AD"


def check_parameter_names(names) -> tuple[str, ...]:
    """Validate vocabulary names (ParameterError with suggestions); reject bools/optionals
    that are absent."""
    names = tuple(names)
    if not names:
        raise ValueError("no design parameters given")
    for name in names:
        key = lookup_key(name)
        if key.kind == "bool":
            raise ValueError(f"'{name}' is a switch, not a continuous design parameter")
    if len(set(names)) != len(names):
        raise ValueError(f"design parameters repeat a name: {', '.join(names)}")
    return names


def parameter_values(params: BallScrewParams, names) -> np.ndarray:
    """Current values of `names` in file units (ParameterError if an optional is absent)."""
    out = []
    for name in names:
        v = params.get(name)
        if v is None:
            raise ValueError(f"'{name}' is not set in these parameters (an optional key); "
                             "set it in the file or leave it out of the design parameters")
        out.append(float(v))
    return np.asarray(out)


def with_values(params: BallScrewParams, names, theta) -> BallScrewParams:
    """`params` with each `names[i]` set to `theta[i]` (file units; traceable)."""
    for i, name in enumerate(names):
        params = params.replace(name, theta[i])
    return params


def _value(theta, params, op, hint=None, *, metric_name, names, settings):
    return get_metric(metric_name).fn(with_values(params, names, theta), op, settings, hint)


def _value_and_grad(theta, params, op, hint=None, *, metric_name, names, settings):
    forward = get_metric(metric_name).forward_fn
    if forward is None:
        return jax.value_and_grad(_value)(theta, params, op, hint, metric_name=metric_name,
                                          names=names, settings=settings)

    # Forward mode (`Metric.forward_fn`): one tangent per parameter, the value once.
    def f(th):
        return forward(with_values(params, names, th), op, settings, hint)

    eye = jnp.eye(theta.shape[0], dtype=theta.dtype)
    return jax.vmap(lambda t: jax.jvp(f, (theta,), (t,)), out_axes=(None, 0))(eye)


# (value, value_and_grad) jitted: kept across processes (the package's own metrics) or not.
_KEPT = (cached_jit(_value, fast_compile=True), cached_jit(_value_and_grad, fast_compile=True))
_PLAIN = (eqx.filter_jit(_value), eqx.filter_jit(_value_and_grad))


@functools.lru_cache(maxsize=64)
def compiled(metric_name: str, names: tuple, settings: OrbitSettings):
    """(value_fn, value_and_grad_fn), each jitted once per (metric, names, settings).

    Both take (theta [file units], params, op, hint) and return the metric in SI units;
    reuse them with different arrays (no recompilation). `hint` is what `locate_hint`
    found on the host (the located FRC peak) or None. The package's own metrics keep
    their traced programs across processes (`cached_jit`: a warm `bsfs sensitivity` does
    not trace the FRC peak's implicit gradient again); a metric registered from outside
    the package is traced in every process (its code is not part of the programs' key).
    """
    kept = getattr(get_metric(metric_name).fn, "__module__", "").startswith("bsfs_jax.")
    static = dict(metric_name=metric_name, names=tuple(names), settings=settings)
    return tuple(functools.partial(f, **static) for f in (_KEPT if kept else _PLAIN))


def locate_hint(metric: Metric, params: BallScrewParams, op, settings):
    """The host-side search a metric needs before its traced evaluation (None if none).

    Raises FloatingPointError naming the metric and the cause when the search fails."""
    return _locate(metric, params, op, settings)[0]


def _locate(metric: Metric, params, op, settings, near=None):
    """(hint, near): the metric's host-side search (`locate_hint`), with what it found for
    the next search to start from where the metric can reuse it (`Metric.locate_near`;
    given `near`, a search that starts from it), else (hint, None)."""
    if metric.locate is None:
        return None, None
    from ..solvers import SolverError

    try:
        if metric.locate_near is not None:
            return metric.locate_near(params, op, settings, near)
        return metric.locate(params, op, settings), None
    except SolverError as exc:
        raise FloatingPointError(f"metric '{metric.name}': {exc}") from None


def operating_point(metric: Metric, frequency_hz=None, force_n=None) -> OperatingPoint:
    """The operating point for `metric`, with defaults and checks (positive values)."""
    f = DEFAULT_FREQUENCY_HZ if frequency_hz is None else float(frequency_hz)
    p = DEFAULT_FORCE_N if force_n is None else float(force_n)
    if not f > 0:
        raise ValueError(f"frequency must be positive, got {f} Hz")
    if not p > 0:
        raise ValueError(f"force must be positive, got {p} N")
    return OperatingPoint(f, p)


def check_design_inputs(metric_name: str, params: BallScrewParams, names, *,
                        frequency_hz=None, force_n=None):
    """(metric, names, operating point) after every check that needs no computing: a known
    metric, known continuous parameters set in `params`, a positive operating point.
    ValueError (ParameterError for an unknown name) naming the bad input otherwise."""
    metric = get_metric(metric_name)
    names = check_parameter_names(names)
    parameter_values(params, names)
    return metric, names, operating_point(metric, frequency_hz, force_n)


def _check_finite(value, metric: Metric, op: OperatingPoint, what="metric"):
    if not np.all(np.isfinite(np.asarray(value))):
        where = (f" at {float(op.frequency_hz):g} Hz, {float(op.force_n):g} N"
                 if metric.uses_operating_point else "")
        raise FloatingPointError(
            f"{what} '{metric.name}' is not finite{where}: "
            + ("the periodic-orbit Newton solve did not converge (a strongly nonlinear or "
               "non-period-1 response?). Try a smaller force, another frequency, or more "
               "OrbitSettings.transient_periods / newton_steps."
               + (" For frc_peak this also means the frequency-response curve jumps (folds) "
                  "near its peak at this force, so the peak is not a smooth maximum: "
                  "lower --force." if metric.name == "frc_peak" else "")
               if metric.needs_orbit else "check the parameters (unphysical values?)."))


def evaluate(metric_name: str, params: BallScrewParams, *, frequency_hz=None, force_n=None,
             settings: OrbitSettings = OrbitSettings()) -> float:
    """Value of a metric for `params`, in the metric's reporting unit (`Metric.unit`)."""
    metric = get_metric(metric_name)
    op = operating_point(metric, frequency_hz, force_n)
    value_fn, _ = compiled(metric.name, ("nut.preload_n",), settings)
    theta = jnp.asarray(parameter_values(params, ("nut.preload_n",)))
    hint = locate_hint(metric, params, op, settings)
    value = float(value_fn(theta, params, op, hint))
    _check_finite(value, metric, op)
    return value * metric.scale


@dataclasses.dataclass(frozen=True)
class SensitivityResult:
    """Sensitivities of one metric at one design.

    - `metric`, `unit`, `value` (in `unit`), `frequency_hz`, `force_n`;
    - `names` (vocabulary), `values` (file units), `units` (file units of each name);
    - `gradient`: d metric [unit] / d parameter [file unit];
    - `normalised`: d ln metric / d ln parameter;
    - `method`: "implicit AD" or "central FD (rel. step h)".
    """

    metric: str
    unit: str
    value: float
    frequency_hz: float | None
    force_n: float | None
    names: tuple
    values: np.ndarray
    gradient: np.ndarray
    normalised: np.ndarray
    method: str

    def ranked(self):
        """Indices by decreasing |normalised sensitivity|."""
        return list(np.argsort(-np.abs(self.normalised), kind="stable"))

    def to_dict(self) -> dict:
        return {
            "metric": self.metric, "unit": self.unit, "value": self.value,
            "frequency_hz": self.frequency_hz, "force_n": self.force_n, "method": self.method,
            "parameters": [
                {"name": n, "value": float(v), "d_metric_d_param": float(g),
                 "normalised": float(s)}
                for n, v, g, s in zip(self.names, self.values, self.gradient,
                                      self.normalised, strict=True)
            ],
        }

    def table_markdown(self) -> str:
        """Markdown table ranked by |d ln m / d ln p|."""
        lines = [f"| parameter | value | d m / d p [{self.unit} per file unit] | "
                 "d ln m / d ln p |", "|---|---|---|---|"]
        for i in self.ranked():
            lines.append(f"| `{self.names[i]}` | {self.values[i]:.6g} | "
                         f"{self.gradient[i]:+.4g} | {self.normalised[i]:+.4f} |")
        return "\n".join(lines)


def _pinned(settings: OrbitSettings, hint) -> OrbitSettings:
    """The settings of the finite differences' searches around a nominal `hint`: every
    perturbed search uses the nominal discretisation (method and harmonic count), as a
    change of either between two evaluations would swamp the quotient."""
    if hint is None or not hasattr(hint, "method"):
        return settings
    if hasattr(hint.method, "harmonics"):
        h = int(hint.method.harmonics)
        return dataclasses.replace(settings, frc_method="hb", frc_harmonics=h,
                                   frc_max_harmonics=h, frc_tol=1.0)
    return dataclasses.replace(settings, frc_method="shooting")


def prefetch_programs(metric_name: str, params: BallScrewParams, names=DESIGN_PARAMETERS,
                      *, frequency_hz=None, force_n=None,
                      settings: OrbitSettings = OrbitSettings(), value: bool = True,
                      gradient: bool = True) -> int:
    """Start compiling the metric's value and/or value-and-gradient programs on a
    background thread (`cached_jit`'s `prefetch_now`), where its host-side search (the FRC
    peak's continuation) returns a hint of a layout known before it
    (`Metric.hint_layout`): the programs then compile on the second core while the search
    runs, and `sensitivities` / the finite-difference probes (whose searches keep the
    nominal discretisation, `_pinned`) find them ready. Returns how
    many were started (0 for a metric without a search, or whose hint's layout the search
    decides, or one registered outside the package)."""
    metric = get_metric(metric_name)
    if metric.hint_layout is None:
        return 0
    names = check_parameter_names(names)
    op = operating_point(metric, frequency_hz, force_n)
    layout = metric.hint_layout(params, op, settings)
    if layout is None:
        return 0
    theta = jnp.asarray(parameter_values(params, names))
    _, grad_fn = compiled(metric.name, names, settings)
    value_fn, _ = compiled(metric.name, names, _pinned(settings, layout))  # the probes'
    started = 0
    for fn, wanted in ((grad_fn, gradient), (value_fn, value)):
        start = getattr(fn.func, "prefetch", None)
        if wanted and start is not None:
            started += bool(start(theta, params, op, layout, **fn.keywords))
    return started


def sensitivities(metric_name: str, params: BallScrewParams, names=DESIGN_PARAMETERS, *,
                  frequency_hz=None, force_n=None,
                  settings: OrbitSettings = OrbitSettings()) -> SensitivityResult:
    """All sensitivities of a metric in one reverse-mode pass (implicit differentiation).

    `names` are TOML vocabulary names (default `DESIGN_PARAMETERS`). Orbit metrics use
    the operating point `frequency_hz`, `force_n` (defaults 120 Hz, 100 N).
    """
    metric = get_metric(metric_name)
    names = check_parameter_names(names)
    op = operating_point(metric, frequency_hz, force_n)
    theta = parameter_values(params, names)
    _, value_and_grad = compiled(metric.name, names, settings)
    prefetch_programs(metric.name, params, names, frequency_hz=frequency_hz,
                      force_n=force_n, settings=settings, value=False)
    hint = locate_hint(metric, params, op, settings)
    value, grad = value_and_grad(jnp.asarray(theta), params, op, hint)
    value, grad = float(value), np.asarray(grad)
    _check_finite(value, metric, op)
    _check_finite(grad, metric, op, what="gradient of")
    return _result(metric, op, names, theta, value, grad, IMPLICIT_AD)


def finite_difference_sensitivities(metric_name: str, params: BallScrewParams,
                                    names=DESIGN_PARAMETERS, *, frequency_hz=None,
                                    force_n=None, rel_step: float = 1e-4,
                                    settings: OrbitSettings = OrbitSettings(), only=None,
                                    gradient_program: bool = False) -> SensitivityResult:
    """The same by central finite differences (2 evaluations per parameter), for checks.

    `only`: difference just these of `names` (a probe of the largest entries); the value
    function is still the one compiled for all of `names`, so a probe reuses it. The
    result then holds the entries of `only`. `gradient_program`: take the values from
    the value-and-gradient program that `sensitivities` compiled (for a probe after it:
    a few evaluations then cost less than compiling the value program; the value is the
    same computation, the gradient is dropped).
    """
    metric, names, op = check_design_inputs(metric_name, params, names,
                                            frequency_hz=frequency_hz, force_n=force_n)
    theta = parameter_values(params, names)
    missing = [n for n in (only or ()) if n not in names]
    if missing:
        raise ValueError(f"cannot probe {', '.join(missing)}: not among {', '.join(names)}")
    which = list(range(len(names))) if only is None else [names.index(n) for n in only]
    # The perturbed searches start from the nominal one's result (the FRC peak: a short
    # continuation around the nominal peak instead of the whole band).
    hint0, near = _locate(metric, params, op, settings)
    pinned = _pinned(settings, hint0)
    # the gradient's program as `sensitivities` compiled it, its value taken (with a hint
    # it ignores `settings`), or the value program of the pinned discretisation
    value_fn = (_first(compiled(metric.name, names, settings)[1]) if gradient_program
                else compiled(metric.name, names, pinned)[0])
    settings = pinned

    def at(th, hint=None):  # a metric with a host-side search (the FRC peak) searches again
        if hint is None:
            hint = _locate(metric, with_values(params, names, jnp.asarray(th)), op, settings,
                           near)[0]
        return float(value_fn(jnp.asarray(th), params, op, hint))

    value = at(theta, hint0)  # the nominal search is the one already done
    steps, points = [], []
    for i in which:
        h = rel_step * max(abs(theta[i]), 1e-12)
        up, down = theta.copy(), theta.copy()
        up[i] += h
        down[i] -= h
        steps.append(h)
        points += [up, down]
    if metric.locate is not None and len(points) > 1:
        # Each perturbed search is a host loop of small programs (a continuation): two at
        # a time on two threads, as `bsfs map` continues its rows (same results: each
        # search is independent and deterministic).
        with ThreadPoolExecutor(max_workers=FD_WORKERS,
                                thread_name_prefix="bsfs-fd") as pool:
            values = list(pool.map(at, points))
    else:
        values = [at(th) for th in points]
    grad = np.array([(values[2 * j] - values[2 * j + 1]) / (2 * h)
                     for j, h in enumerate(steps)])
    _check_finite(value, metric, op)
    _check_finite(grad, metric, op, what="finite-difference gradient of")
    return _result(metric, op, tuple(names[i] for i in which), theta[which], value, grad,
                   f"central FD (rel. step {rel_step:g})")


def _first(fn):
    return lambda *args: fn(*args)[0]


def _result(metric, op, names, theta, value_si, grad_si, method) -> SensitivityResult:
    with np.errstate(divide="ignore", invalid="ignore"):
        normalised = np.where(value_si != 0, theta * grad_si / value_si, np.nan)
    uses = metric.uses_operating_point
    return SensitivityResult(
        metric.name, metric.unit, value_si * metric.scale,
        float(op.frequency_hz) if uses and metric.name != "frc_peak" else None,
        float(op.force_n) if uses else None, names, np.asarray(theta, dtype=float),
        grad_si * metric.scale, normalised, method)
