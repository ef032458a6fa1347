"""Parameter sweeps of periodically forced systems: batched, continued, checkpointed, sharded.

A sweep runs one steady-state simulation per parameter value and keeps only what the
analyses need (stroboscopic samples, the spectrum of one observed coordinate, amplitudes,
the largest Lyapunov exponent, the end state): memory grows with the number of points, not
with the length of the trajectories.

- *Cold* mode: every point starts from `problem.y0` (or its own given state) and runs
  `transient_periods` before the recorded `periods`. Points are independent and run
  through `jax.lax.map(..., batch_size=...)` (lockstep batches of `batch_size`), chunk by
  chunk, optionally sharded over devices.
- *Continued* mode: each point starts from the previous point's end state and runs only
  `continued_transient_periods` (the first point, or one after a failure, runs the full
  transient from `problem.y0`). Directions "up", "down" or "both"; both directions run
  side by side (vmap), so hysteresis and jumps appear in one call.

After each chunk the results are written to the checkpoint folder; a rerun with the same
folder and the same inputs loads the finished chunks and computes only the rest.

Beyond one device (`shard=True`): each chunk of a cold sweep is split over a 1-D mesh
"points" of `jax.devices()` with `jax.shard_map`; every device runs `lax.map` over its
share. On several GPUs of one host nothing else is needed. On several hosts, start the
same script in every process with `jax.distributed.initialize(coordinator_address=...,
num_processes=..., process_id=...)` (or its automatic cluster detection) *before* any
other JAX call; `jax.devices()` then lists every process's devices, the mesh spans them
all, the chunk outputs are gathered to every process (`process_allgather`) and only
process 0 writes checkpoints. (Tested on one host with
`XLA_FLAGS=--xla_force_host_platform_device_count=2`; not tested across hosts.)
"""

import dataclasses
import datetime
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..solvers import (
    RESULTS,
    SolverSettings,
    integrate,
    result_code,
    result_codes,
    result_from_codes,
    result_text,
)
from ._lyapunov import benettin_steps, exponent_from_growth, first_failure
from ._spectrum import amplitude_spectrum

MODES = ("cold", "continued")
DIRECTIONS = ("up", "down", "both")
_OK = int(result_codes(RESULTS.successful))  # the code of a successful point in the arrays


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """How each sweep point is computed, and how points are batched (static: hashable).

    - `transient_periods`: forcing periods discarded before recording (cold starts).
    - `continued_transient_periods`: the same for points continued from their neighbour.
    - `periods`: recorded periods (stroboscopic samples = periods + 1).
    - `samples_per_period`: samples per period of the observed coordinate for the
      spectrum and the amplitude (the spectrum reaches samples_per_period / 2 harmonics).
    - `lyapunov`: also integrate the tangent dynamics (largest Lyapunov exponent; about
      doubles the cost of the recorded periods).
    - `lyapunov_align_periods`: the last periods of each transient in which the tangent
      vector is integrated (and renormalised) before its growth is recorded, so that it
      has aligned with the most unstable direction; must be shorter than either transient.
    - `batch_size`: points integrated in lockstep (vmap) inside `lax.map`; 0 = whole chunk.
    - `chunk_size`: points per jit call and per checkpoint file.
    - `window`: FFT window ("hann" or "rect").
    - `engine` (cold mode): "map" (`lax.map` over lockstep batches of `batch_size`) or
      "queue" (`batch_size` lanes integrating equal time slices and taking the next point
      when done; avoids the lockstep waste when horizons differ, e.g. frequency sweeps;
      without `lyapunov` only, falls back to "map" otherwise).
    - `max_slice_periods`: queue engine: at most this many periods per slice.
    - `settings`: `SolverSettings` (tolerances, max_steps, solver; default the fused
      Dormand-Prince 5(4) loop "dopri5-fused", or any diffrax solver name).
    """

    transient_periods: int = 200
    continued_transient_periods: int = 20
    periods: int = 64
    samples_per_period: int = 32
    lyapunov: bool = True
    lyapunov_align_periods: int = 16
    batch_size: int = 8
    chunk_size: int = 16
    window: str = "hann"
    engine: str = "map"
    max_slice_periods: int = 64
    # Sweeps are forward-only, so they default to the fused Dormand-Prince loop (about 3x
    # cheaper per step than diffrax's general loop here; cross-checked in tests/test_fused.py).
    settings: SolverSettings = SolverSettings(solver="dopri5-fused")

    def __post_init__(self):
        for name in ("transient_periods", "continued_transient_periods", "periods",
                     "samples_per_period", "chunk_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SweepConfig.{name} must be >= 1, got {getattr(self, name)}")
        limit = min(self.transient_periods, self.continued_transient_periods)
        if self.lyapunov and not 0 <= int(self.lyapunov_align_periods) < limit:
            raise ValueError(
                "SweepConfig.lyapunov_align_periods must be >= 0 and smaller than both "
                f"transients ({limit}), got {self.lyapunov_align_periods}")
        if int(self.batch_size) < 0:
            raise ValueError(f"SweepConfig.batch_size must be >= 0, got {self.batch_size}")
        if self.engine not in ("map", "queue"):
            raise ValueError(f"SweepConfig.engine must be 'map' or 'queue', got {self.engine!r}")
        if self.window not in ("hann", "rect"):
            raise ValueError(f"SweepConfig.window must be 'hann' or 'rect', got {self.window!r}")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        return d


class SweepProblem(eqx.Module):
    """A periodically forced system and the scalar parameter a sweep varies (generic).

    - `vector_field`: f(t, y, args) (diffrax signature; module-level function or Module).
    - `setup`: setup(data, value) -> (args, period): builds f's `args` and the forcing
      period [time unit] for parameter `value`; traceable (value is a traced scalar). The
      forcing must be periodic with that period from t = 0.
    - `data`: pytree of arrays that `setup` reads (traced: new values do not recompile).
    - `y0`: the state cold starts begin from.
    - `param`, `unit`: the swept parameter's name and unit (for files and plots).
    - `observe`: index of the state coordinate whose spectrum and amplitude are reported.
    - `state_names`, `state_units`, `time_unit`: labels for files and plots.
    """

    vector_field: Callable = eqx.field(static=True)
    setup: Callable = eqx.field(static=True)
    data: Any
    y0: jax.Array = eqx.field(converter=lambda x: jnp.asarray(x, dtype=float))
    param: str = eqx.field(static=True)
    unit: str = eqx.field(static=True, default="")
    observe: int = eqx.field(static=True, default=0)
    state_names: tuple = eqx.field(static=True, default=())
    state_units: tuple = eqx.field(static=True, default=())
    time_unit: str = eqx.field(static=True, default="s")

    def __check_init__(self):
        n = self.y0.shape[-1] if self.y0.ndim else 0
        if self.y0.ndim != 1:
            raise ValueError(f"SweepProblem.y0 must be a 1-D state, got shape {self.y0.shape}")
        if not 0 <= self.observe < n:
            raise ValueError(f"SweepProblem.observe={self.observe} is not a state index "
                             f"(state has {n} coordinates)")
        for name in ("state_names", "state_units"):
            v = getattr(self, name)
            if v and len(v) != n:
                raise ValueError(f"SweepProblem.{name} has {len(v)} entries for a state of {n}")

    @property
    def n_states(self) -> int:
        return int(self.y0.shape[0])

    def labels(self):
        n = self.n_states
        names = tuple(self.state_names) or tuple(f"y{i}" for i in range(n))
        units = tuple(self.state_units) or ("",) * n
        return names, units


# ----------------------------------------------------------------------------------------
# One point (traceable)


def _point(problem: SweepProblem, value, y_start, n_transient, cfg: SweepConfig):
    """Steady response at one parameter value: a dict of fixed-size arrays."""
    args, period = problem.setup(problem.data, value)
    period = jnp.asarray(period, dtype=float)
    settings = cfg.settings
    n_states = problem.n_states
    P, spp = cfg.periods, cfg.samples_per_period
    align = cfg.lyapunov_align_periods if cfg.lyapunov else 0
    t_plain = (n_transient - align) * period
    t1 = n_transient * period
    res = integrate(problem.vector_field, y_start, args, 0.0, t_plain, jnp.stack([t_plain]),
                    settings, throw=False)
    y = res.ys[-1]
    if cfg.lyapunov:
        tangent, steps_a = None, 0
        if align:
            y, tangent, _, _, st_a, steps_a = benettin_steps(
                problem.vector_field, y, args, t_plain, period, align, settings)
            res = eqx.tree_at(lambda r: r.result, res, first_failure(res.result, st_a))
        y_end, _, logs, samples, result2, steps2 = benettin_steps(
            problem.vector_field, y, args, t1, period, P, settings, tangent=tangent,
            ts_per_interval=spp)
        steps2 = steps2 + steps_a
        lyap = exponent_from_growth(logs, period, discard=0.0 if align else 0.25)
    else:
        frac = jnp.arange(1, P * spp + 1, dtype=float) / spp
        ts = t1 + period * frac
        res2 = integrate(problem.vector_field, y, args, t1, ts[-1], ts, settings, throw=False)
        samples = res2.ys.reshape(P, spp, n_states)
        y_end, result2, steps2 = res2.ys[-1], res2.result, res2.num_steps
        logs = jnp.full((P,), jnp.nan)
        lyap = jnp.asarray(jnp.nan)
    result = first_failure(res.result, result2)
    flat = samples.reshape(P * spp, n_states)
    ok = result == RESULTS.successful
    flat = jnp.where(ok, flat, jnp.nan)
    strobe = jnp.concatenate([y[None, :], samples[:, -1, :]], axis=0)
    strobe = jnp.where(ok, strobe, jnp.nan)
    _, spectrum = amplitude_spectrum(flat[:, problem.observe], period / spp, window=cfg.window)
    return {
        "strobe": strobe,
        "amplitude": 0.5 * (jnp.max(flat, axis=0) - jnp.min(flat, axis=0)),
        "mean": jnp.mean(flat, axis=0),
        "peak": jnp.max(jnp.abs(flat), axis=0),
        "spectrum": spectrum,
        "lyapunov": jnp.where(ok, lyap, jnp.nan),
        "log_growth": jnp.where(ok, logs, jnp.nan),
        "status": result_code(result),
        "num_steps": res.num_steps + steps2,
        "end_state": jnp.where(ok, y_end, jnp.nan),
        "period": period,
    }


def _reduce(problem, cfg: SweepConfig, samples, y_start, y_end, status, steps, period):
    """Per-point outputs from the recorded samples (P, spp, n); `status` a result code."""
    P, spp, n_states = cfg.periods, cfg.samples_per_period, problem.n_states
    ok = status == _OK
    flat = jnp.where(ok, samples.reshape(P * spp, n_states), jnp.nan)
    strobe = jnp.concatenate([y_start[None, :], samples[:, -1, :]], axis=0)
    _, spectrum = amplitude_spectrum(flat[:, problem.observe], period / spp, window=cfg.window)
    return {
        "strobe": jnp.where(ok, strobe, jnp.nan),
        "amplitude": 0.5 * (jnp.max(flat, axis=0) - jnp.min(flat, axis=0)),
        "mean": jnp.mean(flat, axis=0),
        "peak": jnp.max(jnp.abs(flat), axis=0),
        "spectrum": spectrum,
        "lyapunov": jnp.asarray(jnp.nan),
        "log_growth": jnp.full((P,), jnp.nan),
        "status": status,
        "num_steps": steps,
        "end_state": jnp.where(ok, y_end, jnp.nan),
        "period": period,
    }


def _queue_points(problem, values, y0s, cfg: SweepConfig):
    """Cold points through a work queue of `batch_size` lanes integrating equal time slices.

    vmap runs its members in lockstep, so a batch of points with different horizons (the
    low frequencies of a frequency sweep need far more steps) waits for the slowest. Here
    each lane integrates its point in slices of about the same duration (whole forcing
    periods, about the longest period in the chunk), and a lane whose point is finished
    takes the next point of the chunk. Without the tangent dynamics only.
    """
    settings = cfg.settings
    N, n = values.shape[0], problem.n_states
    P, spp, n_tr = cfg.periods, cfg.samples_per_period, cfg.transient_periods
    lanes = min(cfg.batch_size or N, N)
    periods = jax.vmap(lambda v: jnp.asarray(problem.setup(problem.data, v)[1], dtype=float))(
        values)
    slice_t = jnp.max(periods)
    # Whole periods per slice for each point (>= 1), and the most samples one slice saves.
    m_per = jnp.maximum(jnp.floor(slice_t / periods), 1.0)
    m_max = int(cfg.max_slice_periods)
    m_per = jnp.minimum(m_per, m_max)
    n_save = m_max * spp
    total = float(n_tr + P)

    def lane_slice(i, y, k):
        """Integrate point i from period k over its slice; k, k_end in periods."""
        args, period = problem.setup(problem.data, values[i])
        period = jnp.asarray(period, dtype=float)
        k_cap = jnp.where(k < n_tr, float(n_tr), total)
        k_end = jnp.minimum(k + m_per[i], k_cap)
        t_a, t_b = k * period, k_end * period
        j = jnp.arange(1, n_save + 1, dtype=float) / spp
        ts = jnp.minimum(t_a + period * j, t_b)
        res = integrate(problem.vector_field, y, args, t_a, t_b, ts, settings, throw=False)
        # Rows of the point's record (P * spp samples after the transient) these fill.
        row = jnp.round((k - n_tr) * spp + j * spp).astype(int) - 1
        valid = (k + j <= k_end + 1e-9) & (k + j > n_tr + 1e-9)
        row = jnp.where(valid, row, P * spp)  # out of range: dropped
        return res.ys[-1], k_end, result_code(res.result), res.num_steps, res.ys, row

    def cond(state):
        return jnp.any(state["active"])

    def body(state):
        i, y, k = state["i"], state["y"], state["k"]
        y_new, k_new, st, nst, ys, rows = jax.vmap(lane_slice)(i, y, k)
        act = state["active"]
        # Inactive lanes recompute a finished point; none of their results are kept.
        record = state["record"]
        rows = jnp.where(act[:, None], rows, P * spp)
        record = record.at[i[:, None], rows].set(ys, mode="drop")
        status = state["status"].at[jnp.where(act, i, N)].max(st, mode="drop")
        steps = state["steps"].at[jnp.where(act, i, N)].add(nst, mode="drop")
        at_start = act & (k_new == n_tr)
        start = state["start"].at[jnp.where(at_start, i, N)].set(y_new, mode="drop")
        failed = st != _OK
        done = act & ((k_new >= total) | failed)
        end = state["end"].at[jnp.where(done, i, N)].set(y_new, mode="drop")
        # Finished lanes take the next points of the queue, in lane order.
        nxt = state["next"] + jnp.cumsum(done) - 1
        has_next = done & (nxt < N)
        i_new = jnp.where(has_next, nxt, i)
        y_out = jnp.where(has_next[:, None], y0s[jnp.minimum(nxt, N - 1)], y_new)
        k_out = jnp.where(has_next, 0.0, k_new)
        active = jnp.where(done, has_next, act)
        return dict(i=i_new, y=y_out, k=k_out, active=active, record=record, status=status,
                    steps=steps, start=start, end=end, next=state["next"] + jnp.sum(done))

    state = dict(
        i=jnp.arange(lanes), y=y0s[:lanes], k=jnp.zeros(lanes), active=jnp.ones(lanes, bool),
        record=jnp.full((N, P * spp, n), jnp.nan), status=jnp.full(N, _OK, dtype=jnp.int32),
        steps=jnp.zeros(N, int), start=jnp.full((N, n), jnp.nan),
        end=jnp.full((N, n), jnp.nan), next=jnp.asarray(lanes))
    state = jax.lax.while_loop(cond, body, state)
    samples = state["record"].reshape(N, P, spp, n)
    return jax.vmap(lambda *a: _reduce(problem, cfg, *a))(
        samples, state["start"], state["end"], state["status"], state["steps"], periods)


def _map_points(problem, values, y0s, cfg: SweepConfig):
    if cfg.engine == "queue" and not cfg.lyapunov:
        return _queue_points(problem, values, y0s, cfg)
    n_tr = jnp.asarray(float(cfg.transient_periods))

    def one(vy):
        return _point(problem, vy[0], vy[1], n_tr, cfg)

    batch = cfg.batch_size or values.shape[0]
    if batch == 1:
        # A plain scan: vmap (even of one member) turns the solver's internal `cond`s
        # into `select`s that evaluate both branches, which costs on the CPU.
        return jax.lax.map(one, (values, y0s))
    if batch >= values.shape[0]:
        return jax.vmap(one)((values, y0s))
    return jax.lax.map(one, (values, y0s), batch_size=batch)


@eqx.filter_jit
def _cold_chunk(problem, values, y0s, cfg: SweepConfig, mesh):
    if mesh is None:
        return _map_points(problem, values, y0s, cfg)
    from jax.sharding import PartitionSpec as P

    dynamic, static = eqx.partition(problem, eqx.is_array)

    def local(dyn, v, y):
        return _map_points(eqx.combine(dyn, static), v, y, cfg)

    axis = mesh.axis_names[0]
    return jax.shard_map(local, mesh=mesh, in_specs=(P(), P(axis), P(axis)),
                         out_specs=P(axis), check_vma=False)(dynamic, values, y0s)


@eqx.filter_jit
def _continued_chunk(problem, values, y_carry, ok_carry, first, cfg: SweepConfig):
    """values (D, C); carries (D, n), (D,), (D,): scan along C, vmap over directions D."""
    n_cold = jnp.asarray(float(cfg.transient_periods))
    n_cont = jnp.asarray(float(cfg.continued_transient_periods))

    def direction(vals, y, ok, is_first):
        def step(carry, v):
            y, ok, is_first = carry
            cold = is_first | ~ok | ~jnp.all(jnp.isfinite(y))
            y_in = jnp.where(cold, problem.y0, y)
            out = _point(problem, v, y_in, jnp.where(cold, n_cold, n_cont), cfg)
            return (out["end_state"], out["status"] == _OK, jnp.asarray(False)), out

        return jax.lax.scan(step, (y, ok, is_first), vals)

    if values.shape[0] == 1:  # one lane: no vmap (see `_map_points`)
        carry, out = direction(values[0], y_carry[0], ok_carry[0], first[0])
        return jax.tree_util.tree_map(lambda a: a[None], (carry, out))
    carry, out = jax.vmap(direction)(values, y_carry, ok_carry, first)
    return carry, out


# ----------------------------------------------------------------------------------------
# Results


@dataclasses.dataclass
class Jump:
    """A jump of the response amplitude between neighbouring points of one sweep direction.

    `value_before`/`value_after` are the parameter values (in sweep order) and
    `amplitude_before`/`amplitude_after` the amplitudes of the observed coordinate.
    `hysteresis` (sweeps in both directions only): whether the other direction's amplitude
    differs by more than 10 % at either end point, i.e. the jump leaves a coexisting branch
    (a steep but single-valued flank on a coarse grid gives False).
    """

    direction: str
    index_before: int
    index_after: int
    value_before: float
    value_after: float
    amplitude_before: float
    amplitude_after: float
    hysteresis: bool | None = None

    @property
    def kind(self) -> str:
        return "jump-up" if self.amplitude_after > self.amplitude_before else "jump-down"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["kind"] = self.kind
        return d


def detect_jumps(values, amplitude, *, direction: str = "up", rel: float = 0.3,
                 factor: float = 5.0) -> list[Jump]:
    """Jumps in an amplitude curve visited in the order given (the sweep order).

    A step i -> i+1 is a jump when its relative change |dA| / max(A_i, A_i+1) exceeds
    `rel` and |dA| exceeds `factor` times the median |dA| of the curve (so that steep but
    smooth resonance flanks on a coarse grid are not reported). Failed (NaN) points are
    skipped.
    """
    v = np.asarray(values, dtype=float)
    a = np.asarray(amplitude, dtype=float)
    good = np.flatnonzero(np.isfinite(a))
    if good.size < 3:
        return []
    da = np.abs(np.diff(a[good]))
    med = float(np.median(da))
    jumps = []
    for k in range(good.size - 1):
        i, j = int(good[k]), int(good[k + 1])
        big = max(a[i], a[j])
        if big <= 0:
            continue
        if da[k] / big > rel and da[k] > factor * med:
            jumps.append(Jump(direction, i, j, float(v[i]), float(v[j]), float(a[i]),
                              float(a[j])))
    return jumps


# Arrays of a sweep, as stored in files; "status" holds the integer codes of `result`.
_ARRAY_FIELDS = ("strobe", "amplitude", "mean", "peak", "spectrum", "lyapunov", "log_growth",
                 "status", "num_steps", "end_state")
_RESULT_FIELDS = tuple(n for n in _ARRAY_FIELDS if n != "status")


@dataclasses.dataclass
class SweepResult:
    """Everything a sweep keeps, as numpy arrays (self-describing when saved).

    Coordinates: `values` (N,) of parameter `param` [`unit`] in the order given;
    `directions` (D,): "cold", or "up"/"down" for continued sweeps (a "down" sweep visits
    `values` in reverse, but its rows are stored aligned with `values`).

    Per point, arrays with leading axes (D, N):
    - `strobe` (D, N, periods + 1, n): stroboscopic Poincare samples at t = kT;
    - `amplitude`, `mean`, `peak` (D, N, n): half peak-to-peak, mean, max |y| of each state;
    - `spectrum` (D, N, bins): one-sided amplitude spectrum of state `observe`, at
      frequencies `spectrum_order` x forcing frequency (`spectrum_order` in harmonics of
      the forcing; `spectrum_hz()` converts to Hz);
    - `lyapunov` (D, N): largest Lyapunov exponent [1/time unit] (NaN if not computed);
    - `log_growth` (D, N, periods): per-period tangent growth (Benettin);
    - `result` (D, N): the solver outcome of each point, a batched `RESULTS` item (files
      store its integer codes as `status`); failed points hold NaN; `num_steps` (D, N);
      `end_state` (D, N, n);
    - `period` (N,): forcing period [time unit].
    """

    param: str
    unit: str
    values: np.ndarray
    directions: tuple
    mode: str
    period: np.ndarray
    spectrum_order: np.ndarray
    strobe: np.ndarray
    amplitude: np.ndarray
    mean: np.ndarray
    peak: np.ndarray
    spectrum: np.ndarray
    lyapunov: np.ndarray
    log_growth: np.ndarray
    result: RESULTS
    num_steps: np.ndarray
    end_state: np.ndarray
    state_names: tuple
    state_units: tuple
    observe: int
    time_unit: str
    config: dict
    metadata: dict = dataclasses.field(default_factory=dict)

    # -- derived quantities --------------------------------------------------------------
    @property
    def failed(self) -> np.ndarray:
        """(D, N) bool: points whose solve failed (their data are NaN)."""
        return result_codes(self.result) != _OK

    def point_result(self, d: int, i: int) -> RESULTS:
        """The `RESULTS` item of point `i` of direction `d`."""
        return result_from_codes(result_codes(self.result)[d, i])

    def direction_index(self, direction: str) -> int:
        try:
            return self.directions.index(direction)
        except ValueError:
            raise ValueError(f"direction '{direction}' not in this sweep; it has "
                             f"{list(self.directions)}") from None

    def frc(self, direction: str | None = None, coordinate: int | None = None):
        """(values, amplitude) of `coordinate` (default: the observed one) for a direction."""
        d = 0 if direction is None else self.direction_index(direction)
        c = self.observe if coordinate is None else coordinate
        return self.values, self.amplitude[d, :, c]

    def sweep_order(self, direction: str) -> np.ndarray:
        """Indices into `values` in the order the sweep visited them."""
        n = self.values.size
        return np.arange(n)[::-1] if direction == "down" else np.arange(n)

    def jumps(self, coordinate: int | None = None, **kwargs) -> list[Jump]:
        """Jumps of the amplitude along each direction, in sweep order (`detect_jumps`)."""
        out = []
        for d, name in enumerate(self.directions):
            order = self.sweep_order(name)
            c = self.observe if coordinate is None else coordinate
            js = detect_jumps(self.values[order], self.amplitude[d, order, c],
                              direction=name, **kwargs)
            for j in js:
                j.index_before, j.index_after = int(order[j.index_before]), int(
                    order[j.index_after])
                if len(self.directions) == 2:
                    other = self.amplitude[1 - d, :, c]
                    mine = self.amplitude[d, :, c]
                    ends = [j.index_before, j.index_after]
                    j.hysteresis = bool(np.any(
                        np.abs(other[ends] - mine[ends]) > 0.1 * np.maximum(mine[ends],
                                                                           other[ends])))
            out.extend(js)
        return out

    def spectrum_hz(self):
        """(N, bins) frequency axis [Hz if the time unit is s] of each point's spectrum."""
        return self.spectrum_order[None, :] / self.period[:, None]

    def lyapunov_per_period(self) -> np.ndarray:
        """(D, N) lambda T: the exponent per forcing period (the classifier's measure)."""
        return self.lyapunov * self.period[None, :]

    def motions(self, settings=None):
        """(D, N) nested list of `Motion` classifications (see `classify_motion`)."""
        from ._classify import ClassifierSettings, classify_motion

        settings = settings or ClassifierSettings()
        lam = self.lyapunov_per_period()
        # Repetition is judged relative to the response amplitude; a strobe-only record
        # (one sample per period) has no within-period amplitude, so use max |y| there.
        spp = int(self.config.get("samples_per_period", 2)) if self.config else 2
        scale = self.amplitude if spp > 1 else self.peak
        out = []
        for d in range(len(self.directions)):
            row = []
            for i in range(self.values.size):
                # Spectral evidence from the densely sampled observed coordinate
                # (discrete lines for periodic/quasi-periodic, broadband for chaos).
                lyap = lam[d, i] if np.isfinite(lam[d, i]) else None
                row.append(classify_motion(
                    self.strobe[d, i], lyapunov_per_period=lyap,
                    spectrum=self.spectrum[d, i],
                    scale=scale[d, i], result=self.point_result(d, i),
                    settings=settings))
            out.append(row)
        return out

    def summary(self, settings=None) -> dict:
        """JSON-ready summary: per point value, amplitude, motion class, exponent, status."""
        motions = self.motions(settings)
        names, units = self.state_names, self.state_units
        codes, texts = result_codes(self.result), result_text(self.result)
        points = []
        for d, name in enumerate(self.directions):
            for i in range(self.values.size):
                m = motions[d][i]
                points.append({
                    "direction": name,
                    "index": i,
                    self.param: float(self.values[i]),
                    "amplitude": float(self.amplitude[d, i, self.observe]),
                    "motion": m.label,
                    "period_n": m.period,
                    "lyapunov_per_s" if self.time_unit == "s" else "lyapunov":
                        float(self.lyapunov[d, i]),
                    "lyapunov_per_period": m.lyapunov_per_period,
                    "spectral_line_fraction": m.line_fraction,
                    "evidence_consistent": m.consistent,
                    "converged": m.converged,
                    "status": int(codes[d, i]),
                    "status_message": str(texts[d, i]),
                })
        return {
            "param": self.param,
            "unit": self.unit,
            "observed": names[self.observe] if names else self.observe,
            "amplitude_unit": units[self.observe] if units else "",
            "mode": self.mode,
            "directions": list(self.directions),
            "failed_points": int(np.sum(self.failed)),
            "jumps": [j.to_dict() for j in self.jumps()],
            "points": points,
            "config": self.config,
            "metadata": self.metadata,
        }

    # -- files -----------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write a self-describing .npz (arrays + a JSON `attrs` entry), atomically."""
        attrs = {
            "format": "bsfs-sweep-1",
            "param": self.param, "unit": self.unit, "mode": self.mode,
            "directions": list(self.directions), "state_names": list(self.state_names),
            "state_units": list(self.state_units), "observe": self.observe,
            "time_unit": self.time_unit, "config": self.config, "metadata": self.metadata,
            "dims": {
                "values": ["point"], "period": ["point"], "spectrum_order": ["bin"],
                "strobe": ["direction", "point", "sample", "state"],
                "amplitude": ["direction", "point", "state"],
                "mean": ["direction", "point", "state"], "peak": ["direction", "point", "state"],
                "spectrum": ["direction", "point", "bin"], "lyapunov": ["direction", "point"],
                "log_growth": ["direction", "point", "period"],
                "status": ["direction", "point"], "num_steps": ["direction", "point"],
                "end_state": ["direction", "point", "state"],
            },
            "units": {
                "values": self.unit, "period": self.time_unit,
                "spectrum_order": "harmonics of the forcing frequency",
                "strobe": "state units", "amplitude": "state units (half peak-to-peak)",
                "mean": "state units", "peak": "state units",
                "spectrum": self.state_units[self.observe] if self.state_units else "",
                "lyapunov": f"1/{self.time_unit}", "log_growth": "1 (per period)",
                "status": "solver result code (bsfs_jax.RESULTS; 0 successful); the messages "
                          "are in status_messages",
            },
            "status_messages": _code_messages(self.result),
        }
        arrays = {name: getattr(self, name) for name in _RESULT_FIELDS}
        arrays["status"] = result_codes(self.result)
        _save_npz_atomic(path, values=self.values, period=self.period,
                         spectrum_order=self.spectrum_order,
                         attrs=np.array(json.dumps(_jsonable(attrs))), **arrays)


def load_sweep(path) -> SweepResult:
    """Read a file written by `SweepResult.save`."""
    with np.load(path, allow_pickle=False) as z:
        if "attrs" not in z:
            raise ValueError(f"{path}: not a bsfs sweep file (no 'attrs' entry)")
        attrs = json.loads(str(z["attrs"]))
        arrays = {name: z[name] for name in _RESULT_FIELDS}
        return SweepResult(result=result_from_codes(z["status"]),
            param=attrs["param"], unit=attrs["unit"], values=z["values"],
            directions=tuple(attrs["directions"]), mode=attrs["mode"], period=z["period"],
            spectrum_order=z["spectrum_order"], state_names=tuple(attrs["state_names"]),
            state_units=tuple(attrs["state_units"]), observe=int(attrs["observe"]),
            time_unit=attrs["time_unit"], config=attrs["config"], metadata=attrs["metadata"],
            **arrays)


def _code_messages(result) -> dict:
    """{code: message} for the result codes present (and 0, successful)."""
    codes = np.unique(np.append(result_codes(result), _OK))
    return {str(int(c)): str(result_text(result_from_codes(c))) for c in codes}


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _jsonable(dataclasses.asdict(obj))
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _save_npz_atomic(path, **arrays) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# ----------------------------------------------------------------------------------------
# The driver


def _stable_text(obj) -> str:
    """repr-like text without memory addresses, so it is equal across processes."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", str(obj))


def _fingerprint(problem: SweepProblem, values, y0s, mode, directions, cfg) -> str:
    h = hashlib.sha256()
    leaves, treedef = jax.tree_util.tree_flatten(eqx.filter(problem, eqx.is_array))
    h.update(_stable_text(treedef).encode())
    for leaf in leaves:
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    for part in (getattr(problem.vector_field, "__qualname__", repr(problem.vector_field)),
                 getattr(problem.setup, "__qualname__", "") + _stable_text(repr(problem.setup)),
                 problem.param, mode, ",".join(directions),
                 json.dumps(_jsonable(cfg.to_dict()), sort_keys=True)):
        h.update(part.encode())
    h.update(np.ascontiguousarray(values).tobytes())
    h.update(np.ascontiguousarray(y0s).tobytes())
    return h.hexdigest()[:24]


class _Checkpoint:
    """A folder of per-chunk .npz files plus a manifest naming the sweep they belong to."""

    def __init__(self, folder, fingerprint: str, n_chunks: int):
        self.folder = None if folder is None else Path(folder)
        self.fingerprint = fingerprint
        if self.folder is None:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        manifest = self.folder / "manifest.json"
        if manifest.exists():
            old = json.loads(manifest.read_text())
            if old.get("fingerprint") != fingerprint:
                raise ValueError(
                    f"checkpoint folder '{self.folder}' holds a different sweep (fingerprint "
                    f"{old.get('fingerprint')} != {fingerprint}: other values, parameters or "
                    "settings). Use a new folder, or delete this one to start over.")
        else:
            payload = json.dumps({"fingerprint": fingerprint, "n_chunks": n_chunks}).encode()
            fd, tmp = tempfile.mkstemp(dir=self.folder, prefix=".manifest.", suffix=".tmp")
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
            os.replace(tmp, manifest)

    def _path(self, k: int) -> Path:
        return self.folder / f"chunk_{k:05d}.npz"

    def load(self, k: int):
        if self.folder is None or not self._path(k).exists():
            return None
        try:
            with np.load(self._path(k), allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except (OSError, ValueError, EOFError):
            return None  # a damaged file is recomputed

    def save(self, k: int, data: dict) -> None:
        if self.folder is not None and jax.process_index() == 0:
            _save_npz_atomic(self._path(k), **data)


def _make_mesh(shard, n_points_hint: int):
    if shard is False or shard is None:
        return None
    from jax.sharding import Mesh

    if isinstance(shard, Mesh):
        return shard
    devices = jax.devices()
    if len(devices) < 2:
        return None
    return Mesh(np.array(devices), ("points",))


@eqx.filter_jit
def _periods(problem, values):
    return jax.vmap(lambda v: jnp.asarray(problem.setup(problem.data, v)[1], dtype=float))(
        values)


def _split_by_cost(order, cost, segments: int):
    """Split `order` (indices) into `segments` contiguous pieces of about equal cost."""
    c = np.cumsum(cost[order])
    edges = np.searchsorted(c, c[-1] * np.arange(1, segments) / segments, side="right")
    pieces = [p for p in np.split(order, edges) if p.size]
    return pieces


def sweep(problem: SweepProblem, values, *, mode: str = "cold", direction: str = "up",
          config: SweepConfig = SweepConfig(), y0=None, checkpoint_dir=None,
          progress: bool = True, shard=False, segments: int = 1,
          metadata: dict | None = None) -> SweepResult:
    """Sweep `problem.param` over `values`, recording the steady response at each point.

    **Main arguments:**
    - `problem`: a `SweepProblem` (see `bsfs_problem` for the ball screw).
    - `values`: 1-D parameter values, in sweep order for "up" (any order is allowed).
    - `mode`: "cold" (independent points, batched/sharded) or "continued" (each point
      starts from the previous one's end state; shows hysteresis and jumps).
    - `direction` (continued mode): "up" (order given), "down" (reverse) or "both".

    **Other arguments:**
    - `config`: `SweepConfig` (horizon, batching, tolerances, Lyapunov on/off).
    - `y0`: initial state(s) for cold starts: (n,) for all points or (N, n) per point
      (cold mode); default `problem.y0`.
    - `checkpoint_dir`: folder for per-chunk results; rerunning with the same folder and
      the same inputs resumes (finished chunks are loaded, not recomputed).
    - `progress`: tqdm progress bar over points.
    - `shard`: False; True (shard cold-mode chunks over all `jax.devices()` with
      `jax.shard_map` on a 1-D mesh "points"); or a `jax.sharding.Mesh` with one axis.
    - `segments` (continued mode): split each direction into this many contiguous pieces
      of about equal cost (sum of forcing periods) that run side by side (vmap); each piece
      starts cold. 1 (default) is a single continuation per direction; more pieces use
      the batching of the CPU/GPU but restart the continuation at the piece boundaries.
    - `metadata`: extra JSON-able entries stored in the result (e.g. the parameter file).

    **Returns:** a `SweepResult`. Failed points (a `result` other than
    `RESULTS.successful`) hold NaN; they never stop the sweep.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
    vals = np.asarray(values, dtype=float)
    if vals.ndim != 1 or vals.size < 1:
        raise ValueError(f"values must be a non-empty 1-D array, got shape {vals.shape}")
    if not np.all(np.isfinite(vals)):
        bad = vals[~np.isfinite(vals)][0]
        raise ValueError(f"values must be finite; got {bad} for {problem.param}")
    if int(segments) < 1:
        raise ValueError(f"segments must be >= 1, got {segments}")
    n, n_states = vals.size, problem.n_states
    if y0 is not None:
        y0 = np.asarray(y0, dtype=float)
        if mode == "continued" or y0.ndim == 1:
            if y0.shape != (n_states,):
                raise ValueError(f"y0 must have shape ({n_states},), got {y0.shape}")
            problem = eqx.tree_at(lambda p: p.y0, problem, jnp.asarray(y0))
            y0s = np.broadcast_to(y0, (n, n_states)).copy()
        elif y0.shape == (n, n_states):
            y0s = y0
        else:
            raise ValueError(f"y0 must have shape ({n_states},) or ({n}, {n_states}), "
                             f"got {y0.shape}")
    else:
        y0s = np.broadcast_to(np.asarray(problem.y0), (n, n_states)).copy()

    if mode == "cold":
        directions = ("cold",)
        segments = 1
    else:
        directions = ("up", "down") if direction == "both" else (direction,)
    periods = np.asarray(_periods(problem, jnp.asarray(vals)))
    if not np.all(np.isfinite(periods) & (periods > 0)):
        i = int(np.flatnonzero(~(np.isfinite(periods) & (periods > 0)))[0])
        raise ValueError(f"the forcing period at {problem.param} = {vals[i]} is {periods[i]}; "
                         "it must be positive and finite")
    # Lanes: the sequences of value indices run side by side (one per direction and
    # segment in continued mode; a single lane in cold mode).
    orders = [np.arange(n)[::-1] if d == "down" else np.arange(n) for d in directions]
    lanes, lane_dir = [], []
    for d, order in enumerate(orders):
        pieces = _split_by_cost(order, periods, int(segments)) if mode == "continued" else [
            order]
        lanes.extend(pieces)
        lane_dir.extend([d] * len(pieces))
    L = len(lanes)
    length = max(p.size for p in lanes)
    lane_idx = np.stack([np.concatenate([p, np.full(length - p.size, p[-1])]) for p in lanes])

    fingerprint = _fingerprint(problem, vals, y0s, mode, directions, config)
    if segments > 1:
        fingerprint = hashlib.sha256(f"{fingerprint}/{segments}".encode()).hexdigest()[:24]
    mesh = _make_mesh(shard, n) if mode == "cold" else None
    chunk = min(config.chunk_size, length)
    if mesh is not None:
        k = mesh.devices.size
        chunk = -(-chunk // k) * k
    n_chunks = -(-length // chunk)
    ckpt = _Checkpoint(checkpoint_dir, fingerprint, n_chunks)

    from tqdm.auto import tqdm

    bar = tqdm(total=n * len(directions), unit="pt", disable=not progress,
               desc=f"sweep {problem.param}")
    parts = []
    y_carry = np.broadcast_to(np.asarray(problem.y0), (L, n_states)).copy()
    ok_carry = np.ones(L, dtype=bool)
    first = np.ones(L, dtype=bool)
    recomputed = 0
    try:
        for k in range(n_chunks):
            lo, hi = k * chunk, min((k + 1) * chunk, length)
            real = hi - lo
            data = ckpt.load(k)
            if data is None:
                recomputed += 1
                pos = np.concatenate([np.arange(lo, hi), np.full(chunk - real, hi - 1)])
                idx = lane_idx[:, pos]
                if mode == "cold":
                    out = _cold_chunk(problem, jnp.asarray(vals[idx[0]]),
                                      jnp.asarray(y0s[idx[0]]), config, mesh)
                    if mesh is not None and jax.process_count() > 1:
                        from jax.experimental import multihost_utils

                        out = multihost_utils.process_allgather(out, tiled=True)
                    out = jax.tree_util.tree_map(lambda a: np.asarray(a)[None], out)
                else:
                    _, out = _continued_chunk(
                        problem, jnp.asarray(vals[idx]), jnp.asarray(y_carry),
                        jnp.asarray(ok_carry), jnp.asarray(first), config)
                    out = jax.tree_util.tree_map(np.asarray, out)
                data = {name: a[:, :real] for name, a in out.items()}
                ckpt.save(k, data)
            if mode == "continued":
                y_carry = data["end_state"][:, real - 1].copy()
                ok_carry = data["status"][:, real - 1] == _OK
                first = np.zeros(L, dtype=bool)
            parts.append(data)
            done = sum(min(max(p.size - lo, 0), real) for p in lanes)
            bar.update(done)
    finally:
        bar.close()

    merged = {name: np.concatenate([p[name] for p in parts], axis=1) for name in parts[0]}
    # Scatter the lanes back onto (direction, value index).
    out_arrays = {}
    for name, a in merged.items():
        full = np.empty((len(directions), n) + a.shape[2:], dtype=a.dtype)
        for lane, piece in enumerate(lanes):
            full[lane_dir[lane], piece] = a[lane, :piece.size]
        out_arrays[name] = full
    period = out_arrays.pop("period")[0]
    bins = out_arrays["spectrum"].shape[-1]
    order = np.arange(bins) / config.periods
    names, units = problem.labels()
    meta = {
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "fingerprint": fingerprint,
        "chunks": n_chunks,
        "chunks_computed_this_run": recomputed,
        "sharded_over_devices": 0 if mesh is None else int(mesh.devices.size),
        "segments": int(segments),
        "segment_starts": [float(vals[p[0]]) for p in lanes] if mode == "continued" else [],
        "vector_field": getattr(problem.vector_field, "__qualname__",
                                type(problem.vector_field).__name__),
    }
    meta.update(metadata or {})
    return SweepResult(
        param=problem.param, unit=problem.unit, values=vals, directions=directions,
        mode=mode, period=period, spectrum_order=order,
        state_names=names, state_units=units, observe=problem.observe,
        time_unit=problem.time_unit, config=_jsonable(config.to_dict()), metadata=meta,
        result=result_from_codes(out_arrays["status"]),
        **{name: out_arrays[name] for name in _RESULT_FIELDS})
