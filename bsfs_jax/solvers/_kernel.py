"""The continuation's jitted corrector: one function per (family, field, method).

Where jax's persistent cache is on (the CLI), the corrector is also a kept program
(`bsfs_jax._programs.cached_jit`): a warm `bsfs continue`, `map`, `sensitivity` or
`predict` loads it instead of tracing it again; elsewhere (the library's default) it is
`jax.jit` of a closure over the static parts. Both compile at XLA's backend level 1."""

import collections
import dataclasses
import functools

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._programs import FAST_COMPILE, RUNS_LONG, cached_jit
from ._branch import HostPoint, as_host
from ._newton import newton
from ._orbit import orbit_amplitudes
from ._results import RESULTS

#: How many times the corrector has been traced (for recompile checks).
TRACE_COUNTS: collections.Counter = collections.Counter()


class CorrectedPoint(eqx.Module):
    u: jax.Array
    tangent: jax.Array
    jacobian: jax.Array
    lu: jax.Array
    pivots: jax.Array
    ok: jax.Array
    residual: jax.Array
    steps: jax.Array
    monodromy: jax.Array
    amplitudes: jax.Array
    slope: jax.Array
    error: jax.Array
    state: jax.Array


def family_residual(family, vector_field, method, scale, p_scale, n_periods, u,
                    ode_adjoint=None):
    """R(z; p) for u = (z, p / p_scale): the method's residual along the family."""
    n = u.shape[0] - 1
    args, period = family(u[n] * p_scale)
    return method.residual(vector_field, u[:n], args, period, n_periods, scale, ode_adjoint)


def family_amplitudes(family, vector_field, method, scale, p_scale, n_periods, u,
                      ode_adjoint=None):
    n = u.shape[0] - 1
    args, period = family(u[n] * p_scale)
    return orbit_amplitudes(method, vector_field, u[:n], args, period, n_periods, scale,
                            ode_adjoint or dfx.ForwardMode())


def _correct_core(family, vector_field, method, scale, p_scale, n_periods, tol, max_iter,
                  amplitude_index, u_pred, tangent, chord_lu):
    TRACE_COUNTS["corrector"] += 1
    n = u_pred.shape[0] - 1

    def augmented(u, data):
        u_p, t = data
        r = family_residual(family, vector_field, method, scale, p_scale, n_periods, u)
        return jnp.concatenate([r, jnp.dot(t, u - u_p)[None]])

    def assembled(u, data):
        """The augmented residual and Jacobian, dR/dz from the method's own assembly, dR/dp
        by one forward-mode pass in the parameter, the arclength row."""
        u_p, t = data
        args, period = family(u[n] * p_scale)
        r, r_z = method.residual_and_jacobian(vector_field, u[:n], args, period, n_periods,
                                              scale)
        r_p = jax.jvp(lambda q: family_residual(family, vector_field, method, scale, p_scale,
                                                n_periods, jnp.concatenate([u[:n], q[None]])),
                      (u[n],), (jnp.ones_like(u[n]),))[1]
        f = jnp.concatenate([r, jnp.dot(t, u - u_p)[None]])
        jac = jnp.concatenate([jnp.concatenate([r_z, r_p[:, None]], axis=1), t[None, :]])
        return f, jac

    sol = newton(augmented, u_pred, (u_pred, tangent), tol=tol, max_steps=max_iter,
                 chord_lu=chord_lu, keep_lu=True,
                 jacobian_fn=assembled if method.assembled_jacobian else None)
    u = sol.value
    jac_r = sol.jacobian[:n]
    # sol.jacobian = [R_u; tangent]: its LU gives the new tangent and starts the next
    # corrector's chord iterations.
    lu, piv = sol.lu
    t_new = jax.scipy.linalg.lu_solve((lu, piv), jnp.zeros(n + 1).at[n].set(1.0))
    t_new = t_new / jnp.linalg.norm(t_new)
    args, period = family(u[n] * p_scale)
    mono = method.monodromy(vector_field, u[:n], args, period, n_periods, scale, jac_r[:, :n])
    if amplitude_index < 0:
        # Not asked for (`continue_orbits(amplitudes=False)`): the orbit's samples and
        # their tangent were about 40 % of a shooting corrector's program (3.2 -> 1.9 s
        # to compile, 1.9 -> 1.2 s to trace).
        amps, slope = jnp.full(scale.shape, jnp.nan), jnp.zeros(())
    else:
        amps, d_amps = jax.jvp(
            lambda v: family_amplitudes(family, vector_field, method, scale, p_scale,
                                        n_periods, v), (u,), (t_new,))
        slope = d_amps[amplitude_index]
    err = method.error_estimate(vector_field, u[:n], args, period, n_periods, scale,
                                sol.residual)
    ok = (sol.result == RESULTS.successful) & jnp.all(jnp.isfinite(t_new))
    state = method.initial_state(u[:n], period, n_periods, scale)
    return CorrectedPoint(u, t_new, jnp.concatenate([jac_r, t_new[None, :]]), lu, piv, ok,
                          sol.residual, sol.steps, mono, amps, slope, err, state)


@eqx.filter_jit
def _prepare_jit(family):
    return family.prepare()


def prepare_outside(family):
    """`family.prepare()` (an optional part of the family protocol: the family with the
    work that does not depend on the continued parameter done once) by its own small
    program, where the family has one; else the family itself. `continue_orbits` calls it
    once, so that work is neither compiled into every corrector program nor run op by
    op."""
    return _prepare_jit(family) if callable(getattr(family, "prepare", None)) else family


@functools.lru_cache(maxsize=64)
def _compiled(static_family, vector_field, method, n_periods, max_iter, amplitude_index,
              use_chord, long=True):
    """The corrector jitted over arrays only (the static parts closed over), cached per
    static structure: low dispatch overhead and no retrace across continuation runs (the
    tolerance is traced too: a tighter search reuses the program). `long`: XLA's newer CPU
    fusion emitters (`_long`), keyed as such, so a brief and a full continuation of a
    method that never gets them share one program."""
    def fn(dynamic_family, scale, p_scale, tol, u_pred, tangent, lu, pivots):
        family = eqx.combine(dynamic_family, static_family)
        return _correct_core(family, vector_field, method, scale, p_scale, n_periods, tol,
                             max_iter, amplitude_index, u_pred, tangent,
                             (lu, pivots) if use_chord else None)

    return jax.jit(fn, compiler_options={**FAST_COMPILE, **(RUNS_LONG if long else {})})


@functools.lru_cache(maxsize=64)
def _amplitude_program(static_family, vector_field, method, n_periods):
    """The half peak-to-peak of every coordinate of the orbit with unknowns u (scaled,
    then p / p_scale), jitted over arrays only: the amplitudes at a branch's located
    events where the corrector leaves them out (`continue_orbits(amplitudes="events")`)."""
    def fn(dynamic_family, scale, p_scale, u):
        family = eqx.combine(dynamic_family, static_family)
        return family_amplitudes(family, vector_field, method, scale, p_scale, n_periods, u)

    return jax.jit(fn, compiler_options=dict(FAST_COMPILE))


def _long(method, brief: bool) -> bool:
    """Whether the corrector of `method` gets XLA's newer CPU fusion emitters: where the
    method says its calls run long (`runs_long`) and the continuation is not `brief`."""
    return bool(method.runs_long) and not brief


def _options(method, brief: bool = False) -> dict:
    """XLA's options for the corrector of `method`: backend level 1, and the CPU's newer
    fusion emitters where its calls run long (`_long`), as `_compiled` and `_kept_for`
    choose them."""
    return {**FAST_COMPILE, **(RUNS_LONG if _long(method, brief) else {})}


def _corrector_fields(family, scale, p_scale, tol, u_pred, tangent, lu, pivots,
                      vector_field, method, n_periods, max_iter, amplitude_index, use_chord):
    pt = _correct_core(family, vector_field, method, scale, p_scale, n_periods, tol,
                       max_iter, amplitude_index, u_pred, tangent,
                       (lu, pivots) if use_chord else None)
    return tuple(getattr(pt, f.name) for f in dataclasses.fields(pt))


@cached_jit(fast_compile=True, runs_long=True)
def _kept_corrector(family, scale, p_scale, tol, u_pred, tangent, lu, pivots, vector_field,
                    method, n_periods, max_iter, amplitude_index, use_chord):
    """`_correct_core` as a kept program (arrays traced, the rest static): its fields as a
    tuple of arrays (what `jax.export` writes). For a method whose corrector runs long
    (shooting: ODE solves in every call), with XLA's newer CPU fusion emitters."""
    return _corrector_fields(family, scale, p_scale, tol, u_pred, tangent, lu, pivots,
                             vector_field, method, n_periods, max_iter, amplitude_index,
                             use_chord)


@cached_jit(fast_compile=True)
def _kept_corrector_short(family, scale, p_scale, tol, u_pred, tangent, lu, pivots,
                          vector_field, method, n_periods, max_iter, amplitude_index,
                          use_chord):
    """`_kept_corrector` with XLA's earlier CPU fusion emitters (harmonic balance: FFTs and
    an LU, no ODE loop): at 64 harmonics on the ball screw it compiles in 2.2 s instead of
    4.2 s, and its calls took as long (1.5-2.2 ms at 32 harmonics, 5.0-6.7 ms at 64 either
    way, within the machine's noise)."""
    return _corrector_fields(family, scale, p_scale, tol, u_pred, tangent, lu, pivots,
                             vector_field, method, n_periods, max_iter, amplitude_index,
                             use_chord)


def _kept_for(method, brief: bool = False):
    return _kept_corrector if _long(method, brief) else _kept_corrector_short


def _corrector_call(family, vector_field, method, n_periods, max_iter, amplitude_index,
                    use_chord, example, brief=False):
    """(fn, kept): fn a function of (scale, p_scale, tol, u_pred, tangent, lu, pivots) ->
    CorrectedPoint, the kept program where there is one (kept True), else the cached
    `jax.jit` (`_compiled`). `example`: arguments of the right layout (used only where
    the program is exported). `brief`: see `continue_orbits`."""
    statics = (vector_field, method, int(n_periods), int(max_iter), int(amplitude_index),
               bool(use_chord))
    kept = _kept_for(method, brief).bind(family, *example, *statics)
    if kept is not None:
        leaves = jax.tree_util.tree_leaves(eqx.filter(family, eqx.is_array))
        return (lambda *xs: CorrectedPoint(*kept(*leaves, *xs))), True
    dyn, static = eqx.partition(family, eqx.is_array)
    fn = _compiled(static, *statics, _long(method, brief))
    return (lambda *xs: fn(dyn, *xs)), False


def no_chord(n: int, committed: bool = False):
    """(lu, pivots) that make the corrector's chord stage stop at once (NaN), placed as a
    previous point's matrices are, so that the program compiled for the first point serves
    the chord calls that follow: `committed` (on the device) for the kept program, whose
    outputs are committed there (numpy placeholders made jit compile it a second time,
    1.9 s); numpy for the plain jit, whose outputs from uncommitted inputs stay
    uncommitted (committed placeholders there made every output committed, and the
    design's programs, prefetched for numpy hints, compile twice)."""
    lu, piv = np.full((n, n), np.nan), np.arange(n, dtype=np.int32)
    if not committed:
        return lu, piv
    dev = jax.devices()[0]
    return jax.device_put(lu, dev), jax.device_put(piv, dev)


def prefetch_corrector(family, vector_field, method, y_guess, p, *, n_periods: int = 1,
                       max_newton: int = 8, amplitude_index: int = 0,
                       amplitudes: bool | str = True, brief: bool = False):
    """Start compiling, on the background thread (`bsfs_jax._programs.in_background`), the
    corrector program that `continue_orbits(family, y_guess, p, ..., method=method)` with
    these arguments will call; its first call then finds it in jit's cache. For a
    continuation that follows the current one (`bsfs continue`'s cross-check of the folds
    by the other method): its tracing runs on the second core while this thread computes.
    `brief` as that continuation's. Returns the future; wait for it before that
    continuation (`_programs.settle`; else both compile it)."""
    from .._programs import compile_in_background, in_background
    from ._orbit import _init_core
    from ._shooting import default_scale, float_leaves_to_arrays

    def job():
        fam = prepare_outside(float_leaves_to_arrays(family))
        y = jnp.asarray(y_guess, dtype=float)
        scale = getattr(fam, "scale", None)
        scale = default_scale(y) if scale is None else jnp.broadcast_to(
            jnp.asarray(scale, dtype=float), y.shape)
        z = eqx.filter_eval_shape(lambda: _init_core(method, vector_field, y, *fam(float(p)),
                                                     n_periods, scale))
        n = z.shape[0] + 1
        head = (scale, np.asarray(1.0), np.asarray(1e-8), np.zeros(n), np.zeros(n))
        statics = (vector_field, method, int(n_periods), int(max_newton),
                   int(amplitude_index) if amplitudes is True else -1,
                   bool(method.uses_chord))
        example = (*head, *no_chord(n, committed=True))
        dyn, static = eqx.partition(fam, eqx.is_array)
        kept = _kept_for(method, brief)
        if kept.keeps(fam, *example, *statics):
            # The kept program's own prefetch (queued next; its `bind` later waits for it).
            kept.prefetch_now(fam, *example, *statics)
        else:
            compile_in_background(_compiled(static, *statics, _long(method, brief)).lower(
                dyn, *head, *no_chord(n)))
        if amplitudes == "events":  # the events' amplitudes (`Kernel.amplitudes`), queued
            # after the corrector, which every point needs first
            program = _amplitude_program(static, vector_field, method, int(n_periods))
            in_background(lambda: compile_in_background(program.lower(
                dyn, np.asarray(scale, float), np.asarray(1.0), np.zeros(n))))

    return in_background(job)


@functools.lru_cache(maxsize=64)
def _with_harmonics(method, h: int):
    """`method.with_harmonics(h)`, built once per (method, h) (host-side conversions)."""
    return method.with_harmonics(int(h))


@dataclasses.dataclass
class Kernel:
    """Holds the static parts and calls the jitted corrector with array arguments."""

    family: object
    vector_field: object
    method: object
    scale: jax.Array
    p_scale: float
    n_periods: int
    tol: float
    max_newton: int
    amplitude_index: int
    brief: bool = False
    calls: int = 0
    _fn: object = None
    _kept: bool = False
    _no_chord: object = None
    # The method's host-side facts, read once: a method of an eqx Module is bound anew
    # (a Module built) at every access, about 0.1-0.2 ms, a third of a harmonic-balance
    # continuation's host time when read per corrector call.
    _accurate_tol: object = dataclasses.field(default=None, init=False, repr=False)
    # unknowns of a point (the method's and the parameter) and per harmonic coefficient;
    # 0 and d for a method of fixed size
    _size: int = dataclasses.field(default=0, init=False, repr=False)
    _width: int = dataclasses.field(default=0, init=False, repr=False)

    def __post_init__(self):
        d = int(np.asarray(self.scale).shape[0])
        self._accurate_tol = self.method.accurate_tol()
        size, width = getattr(self.method, "size", None), getattr(self.method, "width", None)
        # (Only harmonic balance, whose harmonic count changes along a branch, has them.)
        self._size = int(size(d)) + 1 if size is not None else 0
        self._width = int(width(d)) if width is not None else d

    @property
    def accurate_tol(self):
        return self._accurate_tol

    def correct(self, u_pred, tangent, ds_used: float = 0.0, chord=None) -> HostPoint:
        """Correct a predicted point; `chord` is a nearby point whose Newton matrix starts
        the corrector as chord iterations (None: plain Newton)."""
        self.calls += 1
        u_pred = np.asarray(u_pred, dtype=float)
        n = u_pred.shape[0]
        use_chord = bool(self.method.uses_chord)
        head = (self.scale, np.asarray(self.p_scale, dtype=float),
                np.asarray(self.tol, dtype=float), u_pred, np.asarray(tangent, dtype=float))
        if self._fn is None:
            committed = no_chord(n, committed=True)  # as the kept program's calls pass them
            self._fn, self._kept = _corrector_call(
                self.family, self.vector_field, self.method, self.n_periods,
                self.max_newton, self.amplitude_index, use_chord, (*head, *committed),
                self.brief)
            if self._kept:
                self._no_chord = committed
        if use_chord and chord is not None and chord.lu is not None and \
                chord.lu[0].shape[0] == n:
            lu, piv = chord.lu
        else:  # no chord matrix: NaN makes the chord stage stop at once (same trace)
            if self._no_chord is None or self._no_chord[0].shape[0] != n:
                self._no_chord = no_chord(n, committed=self._kept)
            lu, piv = self._no_chord
        pt = self._fn(*head, lu, piv)
        return as_host(pt, self.accurate_tol, ds_used)

    def amplitudes(self, u) -> np.ndarray:
        """Half peak-to-peak of every coordinate of the orbit with unknowns `u`, by its own
        small program (`_amplitude_program`)."""
        dyn, static = eqx.partition(self.family, eqx.is_array)
        fn = _amplitude_program(static, self.vector_field, self.method, int(self.n_periods))
        return np.asarray(fn(dyn, np.asarray(self.scale, float),
                             np.asarray(self.p_scale, float), np.asarray(u, float)))

    def with_method(self, method) -> "Kernel":
        return dataclasses.replace(self, method=method, _fn=None, _kept=False, _no_chord=None)

    def convert(self, point: HostPoint) -> HostPoint:
        """A point of another harmonic count in this kernel's unknowns (host side)."""
        if point.u.size == self._size:
            return point
        d = int(np.asarray(self.scale).shape[0])
        old = _with_harmonics(self.method, (point.u.size - 1) // self._width // 2)
        coefficients = self.method.from_coefficients

        def pad(v):
            v = np.asarray(v)
            return np.concatenate([coefficients(old, v[:-1], d, xp=np), v[-1:]])

        u, t = pad(point.u), pad(point.tangent)
        return dataclasses.replace(point, u=u, tangent=t / np.linalg.norm(t), jacobian=None,
                                   lu=None)
