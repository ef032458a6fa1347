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
`XLA_FLAGS=--xla_force_host_platform_device_count=2`; not tested across hosts.) For many
hosts, the independent chunks of a cold sweep go to a task scheduler instead (`runner=`,
`bsfs_jax.cluster`): no lockstep, and a lost process costs only its chunk.
"""

import datetime
import functools
import hashlib
import json
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._files import ChunkCheckpoint, jsonable
from ..solvers import RESULTS, result_codes, result_from_codes
from ._remote import failure, lost_chunk, run_elsewhere
from ._sweep_engines import (
    SettleRuns,
    _cold_chunk,
    _continued_chunk,
    _make_mesh,
    _periods,
    cold_chunk_size,
)
from ._sweep_problem import DIRECTIONS, MODES, OK
from ._sweep_problem import SweepConfig as SweepConfig
from ._sweep_problem import SweepProblem as SweepProblem
from ._sweep_result import _RESULT_FIELDS
from ._sweep_result import Jump as Jump
from ._sweep_result import SweepResult as SweepResult
from ._sweep_result import detect_jumps as detect_jumps
from ._sweep_result import load_sweep as load_sweep

# (The public names of the sweep modules above stay importable from here, as before the
# split into _sweep_problem, _sweep_point, _sweep_engines, _sweep_result and this driver.)


def _stable_text(obj) -> str:
    """repr-like text without memory addresses, so it is equal across processes."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", str(obj))


def _fingerprint(problem: SweepProblem, values, y0s, mode, directions, cfg,
                 transient=None) -> str:
    h = hashlib.sha256()
    leaves, treedef = jax.tree_util.tree_flatten(eqx.filter(problem, eqx.is_array))
    h.update(_stable_text(treedef).encode())
    for leaf in leaves:
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    for part in (getattr(problem.vector_field, "__qualname__", repr(problem.vector_field)),
                 getattr(problem.setup, "__qualname__", "") + _stable_text(repr(problem.setup)),
                 problem.param, mode, ",".join(directions),
                 json.dumps(jsonable(cfg.to_dict()), sort_keys=True)):
        h.update(part.encode())
    h.update(np.ascontiguousarray(values).tobytes())
    h.update(np.ascontiguousarray(y0s).tobytes())
    if transient is not None:  # per-point transients (None: config.transient_periods)
        h.update(b"transient:" + np.ascontiguousarray(transient, dtype=np.int64).tobytes())
    return h.hexdigest()[:24]


def _start_states(problem: SweepProblem, y0, n: int, mode: str):
    """(problem, y0s (n, n_states)) for the `y0` argument of `sweep`."""
    n_states = problem.n_states
    if y0 is None:
        return problem, np.broadcast_to(np.asarray(problem.y0), (n, n_states)).copy()
    y0 = np.asarray(y0, dtype=float)
    if mode == "continued" or y0.ndim == 1:
        if y0.shape != (n_states,):
            raise ValueError(f"y0 must have shape ({n_states},), got {y0.shape}")
        problem = eqx.tree_at(lambda p: p.y0, problem, jnp.asarray(y0))
        return problem, np.broadcast_to(y0, (n, n_states)).copy()
    if y0.shape == (n, n_states):
        return problem, y0
    raise ValueError(f"y0 must have shape ({n_states},) or ({n}, {n_states}), got {y0.shape}")


def _transients(transient, n: int, mode: str, config: SweepConfig):
    """The `transient` argument of `sweep` checked: None (all `config.transient_periods`),
    or an int array (n,) >= 1."""
    if transient is None:
        return None
    if mode != "cold":
        raise ValueError("transient= (transient periods per point) needs mode='cold'; "
                         "continued sweeps use config.transient_periods")
    t = np.asarray(transient)
    if t.shape != (n,) or t.dtype.kind not in "iu":
        raise ValueError(f"transient must be an int array of shape ({n},) (one per value), "
                         f"got shape {t.shape} dtype {t.dtype}")
    low = int(config.lyapunov_align_periods) + 1 if config.lyapunov else 1
    if np.any(t < low):
        raise ValueError(f"transient periods must be >= {low}" + (
            " (longer than config.lyapunov_align_periods)" if low > 1 else "")
            + f", got {int(t.min())}")
    if np.all(t == int(config.transient_periods)):
        return None  # the same computation as no argument (and the same fingerprint)
    return t.astype(np.int64)


def _split_by_cost(order, cost, segments: int):
    """Split `order` (indices) into `segments` contiguous pieces of about equal cost."""
    c = np.cumsum(cost[order])
    edges = np.searchsorted(c, c[-1] * np.arange(1, segments) / segments, side="right")
    pieces = [p for p in np.split(order, edges) if p.size]
    return pieces


def sweep(problem: SweepProblem, values, *, mode: str = "cold", direction: str = "up",
          config: SweepConfig = SweepConfig(), y0=None, transient=None, checkpoint_dir=None,
          progress: bool = True, shard=False, segments: int = 1,
          metadata: dict | None = None, verify=None, runner=None) -> SweepResult:
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
    - `transient` (cold mode): None (`config.transient_periods` for every point) or an int
      array (N,) of transient periods per point (each >= 1, and longer than
      `config.lyapunov_align_periods` with `lyapunov`); it is part of the checkpoint
      fingerprint and is recorded in `metadata["transient_periods_per_point"]`.
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
    - `verify`: a `VerifySettings` to verify every label (`_verify.py`): each point then
      gets `result.verdicts` (motion, verified, evidence, reason). In cold mode with
      `transient=None` the transient is then set per point from the slowest linear decay
      rate (`minimum_transient`) instead of `config.transient_periods`: the orbit engine
      jumps to the orbit, and points without one are continued until they stop drifting.
      The verdicts are saved in the checkpoint folder chunk by chunk (a rerun verifies
      only the chunks not yet done).
    - `runner(fn, items)` (cold mode, not sharded): compute the chunks not yet
      checkpointed elsewhere, e.g. on a Dask cluster (`bsfs_jax.cluster.Cluster.run`;
      `_remote.py`): each chunk, and each chunk of the verification, is one item, computed
      by the same function as here; this process saves them in the same checkpoint, so the
      answers and the files are the local run's. A chunk that failed on every attempt
      leaves its points NaN with the result `chunk_lost` (the verdict "failed", the cause
      in the reason) and is listed in `metadata["failed_chunks"]`; a rerun computes it.
      `problem` must then be picklable (cloudpickle).

    **Returns:** a `SweepResult`. Failed points (a `result` other than
    `RESULTS.successful`) hold NaN; they never stop the sweep.
    """
    if verify is not None:
        return _verified_sweep(problem, values, mode=mode, direction=direction,
                               config=config, y0=y0, transient=transient,
                               checkpoint_dir=checkpoint_dir, progress=progress, shard=shard,
                               segments=segments, metadata=metadata, verify=verify,
                               runner=runner)
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
    if runner is not None and (mode != "cold" or shard):
        raise ValueError("runner= computes the independent chunks of a cold sweep elsewhere; "
                         "a continued sweep (each point starts from the last) and a sharded "
                         "one (the devices of this process) run here")
    n, n_states = vals.size, problem.n_states
    problem, y0s = _start_states(problem, y0, n, mode)
    n_tr = _transients(transient, n, mode, config)

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

    fingerprint = _fingerprint(problem, vals, y0s, mode, directions, config, n_tr)
    if segments > 1:
        fingerprint = hashlib.sha256(f"{fingerprint}/{segments}".encode()).hexdigest()[:24]
    mesh = _make_mesh(shard, n) if mode == "cold" else None
    chunk = cold_chunk_size(config, length, mesh) if mode == "cold" else \
        min(config.chunk_size, length)
    n_chunks = -(-length // chunk)
    ckpt = ChunkCheckpoint(checkpoint_dir, fingerprint, n_chunks)

    from tqdm.auto import tqdm

    bar = tqdm(total=n * len(directions), unit="pt", disable=not progress,
               desc=f"sweep {problem.param}")
    spec = (problem, vals, y0s, n_tr, config, lane_idx[0], chunk, length, mesh)
    remote, failed = {}, []
    if runner is not None:
        todo = {k: k for k in range(n_chunks) if ckpt.load(k) is None}
        remote = run_elsewhere(runner, functools.partial(_cold_part, spec), todo, ckpt.save,
                               bar, {k: min(chunk, length - k * chunk) for k in todo})
    parts = []
    y_carry = np.broadcast_to(np.asarray(problem.y0), (L, n_states)).copy()
    ok_carry = np.ones(L, dtype=bool)
    first = np.ones(L, dtype=bool)
    recomputed = 0
    try:
        for k in range(n_chunks):
            lo, hi = k * chunk, min((k + 1) * chunk, length)
            real = hi - lo
            if k in remote:
                data = remote[k]
                if isinstance(data, BaseException):
                    failed.append(failure("integration", k, vals[lo:hi], data))
                    data = None
                recomputed += 1
                parts.append(data)
                continue  # (its points were counted as it came back)
            data = ckpt.load(k)
            if data is None:
                recomputed += 1
                if mode == "cold":
                    data = _cold_part(spec, k)
                else:
                    pos = np.concatenate([np.arange(lo, hi), np.full(chunk - real, hi - 1)])
                    _, out = _continued_chunk(
                        problem, jnp.asarray(vals[lane_idx[:, pos]]), jnp.asarray(y_carry),
                        jnp.asarray(ok_carry), jnp.asarray(first), config)
                    data = {name: np.asarray(a)[:, :real] for name, a in out.items()}
                ckpt.save(k, data)
            if mode == "continued":
                y_carry = data["end_state"][:, real - 1].copy()
                ok_carry = data["status"][:, real - 1] == OK
                first = np.zeros(L, dtype=bool)
            parts.append(data)
            done = sum(min(max(p.size - lo, 0), real) for p in lanes)
            bar.update(done)
    finally:
        bar.close()
    if failed:
        done = [p for p in parts if p is not None]
        if not done:
            raise RuntimeError(f"every chunk of the sweep failed; the first: "
                               f"{failed[0]['cause']}")
        code = int(np.asarray(result_codes(RESULTS.chunk_lost)))
        parts = [lost_chunk(done[0], min(chunk, length - k * chunk), code) if p is None
                 else p for k, p in enumerate(parts)]

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
    if n_tr is not None:
        meta["transient_periods_per_point"] = n_tr.tolist()
    if failed:
        meta["failed_chunks"] = failed
    meta.update(metadata or {})
    return SweepResult(
        param=problem.param, unit=problem.unit, values=vals, directions=directions,
        mode=mode, period=period, spectrum_order=order,
        state_names=names, state_units=units, observe=problem.observe,
        time_unit=problem.time_unit, config=jsonable(config.to_dict()), metadata=meta,
        result=result_from_codes(out_arrays["status"]),
        **{name: out_arrays[name] for name in _RESULT_FIELDS})


def _cold_part(spec, k: int) -> dict:
    """The arrays (1, points, ...) of chunk `k` of a cold sweep: run here, or elsewhere by
    a `runner` (the same function, so the same numbers)."""
    problem, vals, y0s, n_tr, config, order, chunk, length, mesh = spec
    lo, hi = k * chunk, min((k + 1) * chunk, length)
    pos = np.concatenate([np.arange(lo, hi), np.full(chunk - (hi - lo), hi - 1)])
    idx = order[pos]
    tr = None if n_tr is None else jnp.asarray(n_tr[idx], dtype=float)
    out = _cold_chunk(problem, jnp.asarray(vals[idx]), jnp.asarray(y0s[idx]), tr, config, mesh)
    if mesh is not None and jax.process_count() > 1:
        from jax.experimental import multihost_utils

        out = multihost_utils.process_allgather(out, tiled=True)
    return {name: np.asarray(a)[None][:, :hi - lo] for name, a in out.items()}


def _verified_sweep(problem, values, *, mode, direction, config, y0, transient,
                    checkpoint_dir, progress, shard, segments, metadata, verify, runner):
    """`sweep` followed by `verify_sweep`, with the per-point minimum transient."""
    from pathlib import Path

    from ._orbit_trials import OrbitTrials
    from ._verify import minimum_transient, verify_sweep

    vals = np.asarray(values, dtype=float)
    if mode == "cold" and transient is None and vals.ndim == 1 and vals.size:
        periods = np.asarray(_periods(problem, jnp.asarray(vals)))
        if np.all(np.isfinite(periods) & (periods > 0)):
            transient = minimum_transient(problem, vals, periods, verify,
                                          fallback=config.transient_periods)
            if config.lyapunov:
                transient = np.maximum(transient, config.lyapunov_align_periods + 1)
    on_kernel = mode == "cold" and problem.resolved_engine(config) == "kernel"
    kernel = None
    if on_kernel if verify.kernel_checks is None else verify.kernel_checks:
        if problem.component_field is None:
            raise ValueError("VerifySettings(kernel_checks=True) needs a problem with a "
                             "component_field (the per-lane kernel's form of the field)")
        kernel = {"fast": bool(config.kernel_fast), "block": int(config.kernel_block),
                  "looped": bool(config.kernel_looped)}
    # The verifier's orbit checks compile on the second core while the sweep integrates
    # (for the lanes `verify_sweep` will use: its chunk's, wide; else `verify.batch`).
    chunk = max(int(config.chunk_size), 16)
    # (the points `verify_sweep` will see: every value once per direction)
    n_keys = max(vals.size, 1) * (2 if mode != "cold" and direction == "both" else 1)
    if runner is None:  # (elsewhere, the workers compile them)
        OrbitTrials(problem, verify, problem.observe,
                    lanes=verify.lanes_for(min(chunk, n_keys)), kernel=kernel).prefetch()
    res = sweep(problem, values, mode=mode, direction=direction, config=config, y0=y0,
                transient=transient, checkpoint_dir=checkpoint_dir, progress=progress,
                shard=shard, segments=segments, metadata=metadata, runner=runner)
    n = res.values.size
    if mode == "cold":
        n_tr = np.full(n, config.transient_periods) if transient is None else \
            np.asarray(transient)
    else:  # continued: the first point of each lane ran the cold transient
        n_tr = np.full(n, config.continued_transient_periods)
    settle = None
    if mode == "cold" and (on_kernel if verify.settle is None else verify.settle):
        mesh = _make_mesh(shard, n)
        settle = SettleRuns(problem, config, mesh, cold_chunk_size(config, n, mesh),
                            verify.block_periods)
    failed = res.metadata.get("failed_chunks", [])
    stored = verify_sweep(problem, res, settings=verify, transient=n_tr, progress=progress,
                          checkpoint_dir=None if checkpoint_dir is None else
                          Path(checkpoint_dir) / "verdicts",
                          chunk=chunk, settle=settle, kernel=kernel, runner=runner,
                          failures=failed)
    if failed:
        res.metadata["failed_chunks"] = failed
    res.verdicts = stored
    res.metadata["verify_settings"] = jsonable(verify.to_dict())
    return res
