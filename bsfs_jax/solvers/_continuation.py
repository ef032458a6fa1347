"""Pseudo-arclength continuation of periodic orbits of forced systems, with bifurcations.

A family of T(p)-periodic systems is given by `family(p) -> (args, period)`, so a
frequency continuation changes both the forcing in `args` and the period. The unknowns
are u = (z, q) with z = y / scale (the orbit's state at t = 0, scaled) and q = p / p_scale.
Each step predicts along the unit tangent of the branch, u_pred = u + ds t, and corrects
with Newton on the augmented system

    F(z, q) = (Phi^n(z scale; p) - z scale) / scale = 0,      t . (u - u_pred) = 0,

(Keller's pseudo-arclength condition), so the branch is followed through folds where p
turns back. The corrector, the Jacobian [F_z, F_q], the new tangent and the orbit's
amplitudes are one jitted function, traced once per (family structure, vector field,
settings) and reused at every step.

Stability and bifurcations come from the Floquet multipliers mu (eigenvalues of
M = F_z + I). Test functions whose sign changes between two points mark an event:

- fold (saddle-node, turning point): the p-component of the tangent, dp/ds;
- branch point (a multiplier crosses +1 without p turning): prod(mu - 1);
- period doubling (a multiplier crosses -1): prod(mu + 1);
- Neimark-Sacker (a complex pair crosses the unit circle): prod_{i<j} (mu_i mu_j - 1)
  (its zeros with a real pair are neutral saddles, not bifurcations, and are skipped).

Each event is then located by regula falsi (Illinois) on the step length from the point
before it, with the same corrector.
"""

import collections
import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..model import Sinusoid
from ..model import vector_field as bsfs_vector_field
from ._integrate import SolverError, SolverSettings, integrate
from ._shooting import (
    SHOOTING_SETTINGS,
    BRANCH_POINT,
    FOLD,
    NEIMARK_SACKER,
    PERIOD_DOUBLING,
    default_scale,
    float_leaves_to_arrays,
    scaled_period_map,
)

#: How many times each jitted continuation kernel has been traced (for recompile checks).
TRACE_COUNTS: collections.Counter = collections.Counter()


@dataclasses.dataclass(frozen=True)
class Bifurcation:
    """A located bifurcation point of a branch.

    - `kind`: "fold", "branch-point", "period-doubling" or "neimark-sacker";
    - `p`: parameter value; `state`: orbit state at t = 0; `amplitude`: half peak-to-peak
      of the branch's amplitude coordinate; `amplitudes`: of every coordinate;
    - `multipliers`: Floquet multipliers there (largest modulus first);
    - `index`: the branch point just before the event; `located`: whether the location
      converged (else `p` is the best bracket estimate).
    """

    kind: str
    p: float
    state: np.ndarray
    amplitude: float
    amplitudes: np.ndarray
    multipliers: np.ndarray
    index: int
    located: bool

    def as_dict(self):
        return {"type": self.kind, "p": self.p, "amplitude": self.amplitude,
                "multipliers_real": self.multipliers.real.tolist(),
                "multipliers_imag": self.multipliers.imag.tolist(),
                "multiplier_moduli": np.abs(self.multipliers).tolist(),
                "state": self.state.tolist(), "branch_index": self.index,
                "located": self.located}


@dataclasses.dataclass(frozen=True)
class Branch:
    """A continued branch of periodic orbits (numpy arrays, one row per point).

    - `p` (n,): parameter values; `states` (n, N): orbit states at t = 0 (mod T);
    - `amplitudes` (n, N): half peak-to-peak of every coordinate over the orbit;
      `amplitude` (n,): that of coordinate `amplitude_index`;
    - `multipliers` (n, N) complex, largest modulus first; `stable` (n,) bool;
    - `arclength` (n,) in the scaled (z, q) space; `residuals` (n,); `newton_steps` (n,);
    - `bifurcations`: located `Bifurcation`s in branch order;
    - `n_periods`: orbits of period n T; `info`: run statistics (steps, rejections,
      why it stopped, traces of the jitted kernel during this run).
    """

    p: np.ndarray
    states: np.ndarray
    amplitudes: np.ndarray
    amplitude_index: int
    multipliers: np.ndarray
    stable: np.ndarray
    arclength: np.ndarray
    residuals: np.ndarray
    newton_steps: np.ndarray
    bifurcations: tuple
    n_periods: int
    info: dict

    @property
    def amplitude(self):
        return self.amplitudes[:, self.amplitude_index]

    def __len__(self):
        return int(self.p.shape[0])


class _Point(eqx.Module):
    u: jax.Array
    tangent: jax.Array
    converged: jax.Array
    residual: jax.Array
    steps: jax.Array
    monodromy: jax.Array
    amplitudes: jax.Array


def _family_residual(family, vector_field, z, q, scale, p_scale, n_periods, settings):
    args, period = family(q * p_scale)
    return scaled_period_map(vector_field, z, args, period, scale, n_periods, settings) - z


def _amplitudes(family, vector_field, y0, p, n_periods, settings, samples_per_period):
    args, period = family(p)
    period = jnp.asarray(period, dtype=float)
    n_save = n_periods * samples_per_period + 1
    t1 = n_periods * period
    ts = t1 * jnp.arange(n_save) / (n_save - 1)
    res = integrate(vector_field, y0, args, jnp.zeros_like(t1), t1, ts, settings)
    return 0.5 * (jnp.max(res.ys, axis=0) - jnp.min(res.ys, axis=0))


def _correct_core(family, vector_field, u_pred, tangent, scale, p_scale, n_periods, settings,
                  tol, max_iter, samples_per_period):
    """Newton on (F(u) = 0, tangent . (u - u_pred) = 0); then Jacobian, new tangent, amplitudes."""
    TRACE_COUNTS["corrector"] += 1
    n = u_pred.shape[0] - 1

    def f(u):
        return _family_residual(family, vector_field, u[:n], u[n], scale, p_scale, n_periods,
                                settings)

    def augmented(u, data):
        u_p, t = data
        return jnp.concatenate([f(u), jnp.dot(t, u - u_p)[None]])

    # Relative tolerance (see `shoot`): |G| <= tol * max(1, |u|).
    size = jnp.maximum(1.0, jnp.max(jnp.abs(u_pred)))
    sol = optx.root_find(augmented, optx.Newton(rtol=tol, atol=tol * size), u_pred,
                         args=(u_pred, tangent), max_steps=max_iter, throw=False)
    u = sol.value
    jac, fu = jax.jacfwd(lambda v: (f(v), f(v)), has_aux=True)(u)  # (n, n + 1)
    residual = jnp.max(jnp.abs(fu))
    # New tangent: null vector of jac, oriented so that t_new . t_old > 0.
    rows = jnp.concatenate([jac, tangent[None, :]], axis=0)
    rhs = jnp.zeros(n + 1).at[n].set(1.0)
    t_new = jnp.linalg.solve(rows, rhs)
    t_new = t_new / jnp.linalg.norm(t_new)
    monodromy = jac[:, :n] + jnp.eye(n)
    y = u[:n] * scale
    amps = _amplitudes(family, vector_field, y, u[n] * p_scale, n_periods, settings,
                       samples_per_period)
    ok = (residual <= 10 * tol * size) & jnp.all(jnp.isfinite(u)) & jnp.all(jnp.isfinite(t_new))
    return _Point(u, t_new, ok, residual, sol.stats["num_steps"], monodromy, amps)


_correct_jit = eqx.filter_jit(_correct_core)


def _multipliers(monodromy):
    mu = np.linalg.eigvals(np.asarray(monodromy))
    return mu[np.argsort(-np.abs(mu), kind="stable")]


def _test_values(mu, tangent):
    """(dp/ds, prod(mu - 1), prod(mu + 1), prod_{i<j}(mu_i mu_j - 1)) as real numbers."""
    pairs = [mu[i] * mu[j] - 1.0 for i in range(len(mu)) for j in range(i + 1, len(mu))]
    return np.array([float(tangent[-1]), np.prod(mu - 1.0).real, np.prod(mu + 1.0).real,
                     np.prod(pairs).real if pairs else 1.0])


_EVENT_KINDS = (FOLD, BRANCH_POINT, PERIOD_DOUBLING, NEIMARK_SACKER)


class _Kernel:
    """Holds the static parts and calls the jitted corrector with array arguments."""

    def __init__(self, family, vector_field, scale, p_scale, n_periods, settings, tol,
                 max_iter, samples_per_period):
        self.family = family
        self.vector_field = vector_field
        self.scale = scale
        self.p_scale = p_scale
        self.static = (int(n_periods), settings, float(tol), int(max_iter),
                       int(samples_per_period))
        self.calls = 0

    def correct(self, u_pred, tangent):
        self.calls += 1
        n_periods, settings, tol, max_iter, spp = self.static
        pt = _correct_jit(self.family, self.vector_field, jnp.asarray(u_pred),
                          jnp.asarray(tangent), self.scale, self.p_scale, n_periods,
                          settings, tol, max_iter, spp)
        return jax.tree_util.tree_map(np.asarray, pt)


def continue_orbits(family, y_guess, p_start, p_stop, *, ds: float = 0.02,
                    vector_field=None, ds_min: float | None = None,
                    ds_max: float | None = None, max_points: int = 400,
                    n_periods: int = 1, settings: SolverSettings = SHOOTING_SETTINGS,
                    scale=None, p_scale: float | None = None, tol: float = 1e-8,
                    max_newton: int = 8, max_angle: float = 0.3,
                    amplitude_index: int = 0, samples_per_period: int = 64,
                    locate: bool = True, locate_iters: int = 12, normalise: bool = True,
                    progress=False) -> Branch:
    """Follow a branch of n T-periodic orbits from p_start towards p_stop (pseudo-arclength).

    **Main arguments:**
    - `family`: p -> (args, period): the system at parameter p (a function or an
      `eqx.Module`; a Module's arrays are traced, so new values do not recompile).
    - `y_guess`: a state near the orbit at p_start, t = 0 (e.g. after a transient).
    - `p_start`, `p_stop`: the branch starts at p_start and the run stops once p leaves
      the interval between them (it may fold back and forth inside).
    - `ds`: initial step in the scaled space (z = y / scale, q = p / p_scale), adapted
      between `ds_min` (default ds / 1000) and `ds_max` (default 10 ds).
    - `vector_field`: f(t, y, args); default `family.vector_field`.

    **Other arguments:**
    - `n_periods`: continue orbits of period n T.
    - `scale`: per-component state scale (default `family.scale`, else from `y_guess`);
      with `normalise` (default) it is multiplied by the rms of the first orbit's scaled
      state, so that ds weighs relative changes of the orbit; `p_scale`: default
      |p_stop - p_start|.
    - `tol`, `max_newton`: relative corrector tolerance (on the scaled residual, times
      max(1, max|u|)) and iterations; a step
      whose corrector fails or turns the tangent by more than `max_angle` [rad] is halved.
    - `amplitude_index`: which coordinate's half peak-to-peak is `Branch.amplitude`;
      amplitudes are measured on `samples_per_period` points per period.
    - `locate`: locate bifurcations by regula falsi (`locate_iters` corrector calls each).
    - `progress`: True for a tqdm bar over steps, or a callable(n_points, p).

    **Returns:** a `Branch`; raises `SolverError` if the first orbit cannot be found.
    """
    if vector_field is None:
        vector_field = getattr(family, "vector_field", None)
        if vector_field is None:
            raise ValueError("give vector_field=f(t, y, args): the family has no "
                             "`vector_field` attribute")
    p_start, p_stop, ds = float(p_start), float(p_stop), float(ds)
    if not p_stop != p_start:
        raise ValueError(f"p_start and p_stop must differ, got {p_start} and {p_stop}")
    if not ds > 0:
        raise ValueError(f"ds must be positive, got {ds}")
    ds_min = ds / 1000 if ds_min is None else float(ds_min)
    ds_max = 10 * ds if ds_max is None else float(ds_max)
    family = float_leaves_to_arrays(family)
    y_guess = jnp.asarray(y_guess, dtype=float)
    if not bool(jnp.all(jnp.isfinite(y_guess))):
        raise ValueError(f"y_guess must be finite, got {y_guess}")
    n = y_guess.shape[0]
    if scale is None:
        scale = getattr(family, "scale", None)
    scale = default_scale(y_guess) if scale is None else jnp.broadcast_to(
        jnp.asarray(scale, dtype=float), y_guess.shape)
    p_scale = abs(p_stop - p_start) if p_scale is None else float(p_scale)
    direction = 1.0 if p_stop > p_start else -1.0
    lo, hi = min(p_start, p_stop), max(p_start, p_stop)
    kernel = _Kernel(family, vector_field, scale, jnp.asarray(p_scale, dtype=float),
                     n_periods, settings, tol, max_newton, samples_per_period)
    traces_before = TRACE_COUNTS["corrector"]

    # First point: shooting at fixed p (the constraint row e_q fixes q = q_start).
    e_q = np.zeros(n + 1)
    e_q[n] = 1.0
    u0 = np.concatenate([np.asarray(y_guess / scale), [p_start / p_scale]])
    first = kernel.correct(u0, e_q)
    if not bool(first.converged):
        raise SolverError(
            f"continuation: no periodic orbit found at p = {p_start:g} from the guess "
            f"(scaled residual {float(first.residual):.3g}, relative tol {tol:g}, after "
            f"{int(first.steps)} Newton steps). Start from the end of a transient "
            f"simulation, or give `scale` (typical state magnitudes).")
    if normalise:
        # Rescale so that the first orbit's scaled state has unit rms: the arclength then
        # weighs a relative change of the orbit like a change of p by p_scale.
        rms = float(np.sqrt(np.mean(np.square(first.u[:n]))))
        if np.isfinite(rms) and rms > 0:
            scale = scale * rms
            kernel.scale = scale
            u0 = np.concatenate([first.u[:n] / rms, [first.u[n]]])
            first = kernel.correct(u0, e_q)
    first = dataclasses.replace(_as_host(first), tangent=first.tangent * direction)

    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_points, desc="continuation", unit="pt")
    callback = progress if callable(progress) else None

    points = [first]
    arclength = [0.0]
    steps_taken = rejected = 0
    stop_reason = "max_points"
    events = []
    tests_prev = _test_values(first.mu, first.tangent)
    cos_max = math.cos(max_angle)
    try:
        while len(points) < max_points:
            prev = points[-1]
            steps_taken += 1
            pt = kernel.correct(prev.u + ds * prev.tangent, prev.tangent)
            ok = bool(pt.converged) and float(np.dot(pt.tangent, prev.tangent)) >= cos_max
            if not ok:
                rejected += 1
                ds *= 0.5
                if ds < ds_min:
                    stop_reason = (f"step size fell below ds_min = {ds_min:g} at p = "
                                   f"{prev.u[n] * p_scale:g} (corrector failed)")
                    break
                continue
            cur = _as_host(pt, ds_used=ds)
            points.append(cur)
            arclength.append(arclength[-1] + float(np.linalg.norm(cur.u - prev.u)))
            tests = _test_values(cur.mu, cur.tangent)
            for k, kind in enumerate(_EVENT_KINDS):
                if np.sign(tests[k]) != np.sign(tests_prev[k]) and tests[k] != tests_prev[k]:
                    if kind == BRANCH_POINT and np.sign(tests[0]) != np.sign(tests_prev[0]):
                        continue  # the +1 crossing of a fold is the fold itself
                    events.append((len(points) - 2, k, kind))
            tests_prev = tests
            # Step-size adaptation from the corrector's effort.
            if int(pt.steps) <= 3:
                ds = min(ds * 1.5, ds_max)
            elif int(pt.steps) >= max_newton - 2:
                ds = max(ds * 0.7, ds_min)
            p_now = float(cur.u[n] * p_scale)
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

    bifurcations = []
    for index, k, kind in events:
        bif = _locate(kernel, points[index], points[index + 1], index, k, kind, p_scale,
                      amplitude_index, locate_iters if locate else 0)
        if bif is not None:
            bifurcations.append(bif)

    states = np.stack([pt.u[:n] for pt in points]) * np.asarray(scale)[None, :]
    mus = np.stack([pt.mu for pt in points])
    return Branch(
        p=np.array([pt.u[n] for pt in points]) * p_scale,
        states=states,
        amplitudes=np.stack([pt.amplitudes for pt in points]),
        amplitude_index=int(amplitude_index),
        multipliers=mus,
        stable=np.max(np.abs(mus), axis=1) < 1.0,
        arclength=np.array(arclength),
        residuals=np.array([pt.residual for pt in points]),
        newton_steps=np.array([pt.steps for pt in points]),
        bifurcations=tuple(bifurcations),
        n_periods=int(n_periods),
        info={"steps": steps_taken, "rejected": rejected, "points": len(points),
              "stop_reason": stop_reason, "corrector_calls": kernel.calls,
              "corrector_traces": TRACE_COUNTS["corrector"] - traces_before,
              "p_scale": p_scale, "scale": np.asarray(scale).tolist()},
    )


@dataclasses.dataclass(frozen=True)
class _HostPoint:
    u: np.ndarray
    tangent: np.ndarray
    residual: float
    steps: int
    mu: np.ndarray
    amplitudes: np.ndarray
    ds_used: float = 0.0


def _as_host(pt, ds_used: float = 0.0) -> _HostPoint:
    return _HostPoint(np.asarray(pt.u), np.asarray(pt.tangent), float(pt.residual),
                      int(pt.steps), _multipliers(pt.monodromy), np.asarray(pt.amplitudes),
                      ds_used)


def _locate(kernel, before, after, index, k, kind, p_scale, amplitude_index, iters):
    """Regula falsi (Illinois) on the step length h in (0, ds) for the k-th test function."""
    n = before.u.shape[0] - 1
    g_lo = _test_values(before.mu, before.tangent)[k]
    g_hi = _test_values(after.mu, after.tangent)[k]
    h_lo, h_hi = 0.0, after.ds_used
    g_tol = 1e-6 * max(abs(g_lo), abs(g_hi))
    best, located = after if abs(g_hi) < abs(g_lo) else before, False
    side = 0
    for _ in range(iters):
        h = (h_lo * g_hi - h_hi * g_lo) / (g_hi - g_lo)
        if not h_lo < h < h_hi:
            h = 0.5 * (h_lo + h_hi)
        raw = kernel.correct(before.u + h * before.tangent, before.tangent)
        if not bool(raw.converged):
            break
        pt = _as_host(raw, ds_used=h)
        g = _test_values(pt.mu, pt.tangent)[k]
        best = pt
        if abs(g) <= g_tol:
            located = True
            break
        if np.sign(g) == np.sign(g_lo):
            h_lo, g_lo = h, g
            if side == -1:
                g_hi *= 0.5
            side = -1
        else:
            h_hi, g_hi = h, g
            if side == 1:
                g_lo *= 0.5
            side = 1
        if abs(h_hi - h_lo) < 1e-7 * after.ds_used:
            located = True
            break
    mu = best.mu
    if kind == NEIMARK_SACKER:
        # A genuine NS point has a complex pair on the unit circle; otherwise the test
        # function vanished at a real pair mu_i mu_j = 1 (a neutral saddle): skip it.
        near = np.abs(np.abs(mu) - 1.0) < 1e-2
        if not np.any(near & (np.abs(mu.imag) > 1e-6)):
            return None
    return Bifurcation(kind=kind, p=float(best.u[n] * p_scale),
                       state=best.u[:n] * np.asarray(kernel.scale),
                       amplitude=float(best.amplitudes[amplitude_index]),
                       amplitudes=best.amplitudes, multipliers=mu, index=int(index),
                       located=located)


# -- the ball screw feed system as a family in the excitation frequency --------------------

#: Typical BSFS state magnitudes (x_b, x_s, x_n [m], v_b, v_s, v_n [m/s]) for scaling.
BSFS_SCALE = (1e-6, 1e-6, 1e-6, 1e-2, 1e-2, 1e-2)


class BSFSFamily(eqx.Module):
    """The BSFS under P sin(2 pi f t) on the nut, as a family in f [Hz]: f -> (args, 1/f).

    `system` is a built `System`; `force_n` the force amplitude [N]. Use with
    `continue_orbits(bsfs_family(params, 3000.0), y_guess, f_start, f_stop, ds=...)`.
    """

    system: object
    force_n: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))

    def __call__(self, frequency_hz):
        f = jnp.asarray(frequency_hz, dtype=float)
        return (self.system, Sinusoid(self.force_n, f)), 1.0 / f

    @property
    def vector_field(self):
        return bsfs_vector_field

    @property
    def scale(self):
        return jnp.asarray(BSFS_SCALE)


def bsfs_family(model, force_n) -> BSFSFamily:
    """`BSFSFamily` from `BallScrewParams` (built with its thermal chain) or a `System`."""
    from ._simulate import as_system

    if not float(force_n) > 0:
        raise ValueError(f"force_n must be positive, got {force_n}")
    return BSFSFamily(as_system(model), force_n)


class BSFSParameterFamily(eqx.Module):
    """The BSFS at a fixed excitation, as a family in one parameter p (file units).

    p -> (args, period) with the system rebuilt from `params.replace(name, p)` (thermal
    chain included), e.g. name = "nut.preload_n" [N] or "thermal.speed_rpm" [r/min].
    """

    params: object
    frequency_hz: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))
    force_n: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))
    name: str = eqx.field(static=True, default="nut.preload_n")

    def __call__(self, value):
        from ..model import build_system

        system = build_system(self.params.replace(self.name, value))
        return (system, Sinusoid(self.force_n, self.frequency_hz)), 1.0 / self.frequency_hz

    @property
    def vector_field(self):
        return bsfs_vector_field

    @property
    def scale(self):
        return jnp.asarray(BSFS_SCALE)


def bsfs_parameter_family(params, name: str, frequency_hz, force_n) -> BSFSParameterFamily:
    """`BSFSParameterFamily` for continuing the BSFS orbit in parameter `name` (file units)."""
    from ..params import lookup_key

    key = lookup_key(name)  # raises ParameterError naming the key, with suggestions
    if key.kind == "bool":
        raise ValueError(f"cannot continue in the on/off parameter '{name}'")
    if not float(frequency_hz) > 0 or not float(force_n) > 0:
        raise ValueError(f"frequency_hz and force_n must be positive, got {frequency_hz} "
                         f"and {force_n}")
    return BSFSParameterFamily(params, frequency_hz, force_n, name)
