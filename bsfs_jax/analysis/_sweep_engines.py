"""The sweep engines: chunks of cold points (lockstep batches, a work queue, or one kernel
of per-point loops; optionally sharded over devices) and chunks of continued points (a scan
per lane, lanes vmapped).

Every engine returns the dict of `_point` with a leading points axis (cold) or leading
(lanes, points) axes (continued).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._programs import cached_jit
from ..solvers import integrate, integrate_lanes, result_code
from ._sweep_point import _point, _reduce
from ._sweep_problem import OK, SweepConfig


def _queue_points(problem, values, y0s, n_transient, cfg: SweepConfig):
    """Cold points through a work queue of `batch_size` lanes integrating equal time slices.

    vmap runs its members in lockstep, so a batch of points with different horizons (the
    low frequencies of a frequency sweep need far more steps) waits for the slowest. Here
    each lane integrates its point in slices of about the same duration (whole forcing
    periods, about the longest period in the chunk), and a lane whose point is finished
    takes the next point of the chunk. Without the tangent dynamics only. `n_transient`
    (N,): the transient periods of each point.
    """
    settings = cfg.settings
    N, n = values.shape[0], problem.n_states
    P, spp = cfg.periods, cfg.samples_per_period
    n_trs = jnp.asarray(n_transient, dtype=float)
    lanes = min(cfg.batch_size or N, N)
    periods = jax.vmap(lambda v: jnp.asarray(problem.setup(problem.data, v)[1], dtype=float))(
        values)
    slice_t = jnp.max(periods)
    # Whole periods per slice for each point (>= 1), and the most samples one slice saves.
    m_per = jnp.maximum(jnp.floor(slice_t / periods), 1.0)
    m_max = int(cfg.max_slice_periods)
    m_per = jnp.minimum(m_per, m_max)
    n_save = m_max * spp
    totals = n_trs + P

    def lane_slice(i, y, k):
        """Integrate point i from period k over its slice; k, k_end in periods."""
        args, period = problem.setup(problem.data, values[i])
        period = jnp.asarray(period, dtype=float)
        n_tr = n_trs[i]
        k_cap = jnp.where(k < n_tr, n_tr, totals[i])
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
        at_start = act & (k_new == n_trs[i])
        start = state["start"].at[jnp.where(at_start, i, N)].set(y_new, mode="drop")
        failed = st != OK
        done = act & ((k_new >= totals[i]) | failed)
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
        record=jnp.full((N, P * spp, n), jnp.nan), status=jnp.full(N, OK, dtype=jnp.int32),
        steps=jnp.zeros(N, int), start=jnp.full((N, n), jnp.nan),
        end=jnp.full((N, n), jnp.nan), next=jnp.asarray(lanes))
    state = jax.lax.while_loop(cond, body, state)
    samples = state["record"].reshape(N, P, spp, n)
    return jax.vmap(lambda *a: _reduce(problem, cfg, *a))(
        samples, state["start"], state["end"], state["status"], state["steps"], periods)


def _kernel_points(problem, values, y0s, n_transient, cfg: SweepConfig):
    """Cold points through one kernel in which each point runs its own adaptive loop
    (`solvers.integrate_lanes`); without the tangent dynamics. The same two runs per point
    as `_point` (transient, then the record), so the same outputs."""
    settings = cfg.settings
    N, n = values.shape[0], problem.n_states
    P, spp = cfg.periods, cfg.samples_per_period
    # vmap gives every leaf of args a leading axis of N points, as the kernel needs.
    args, periods = jax.vmap(lambda v: problem.setup(problem.data, v))(values)
    periods = jnp.asarray(periods, dtype=float)
    n_tr = jnp.broadcast_to(jnp.asarray(float(cfg.transient_periods) if n_transient is None
                                        else n_transient, dtype=float), (N,))
    start, samples, end, codes, steps = integrate_lanes(
        problem.component_field, y0s, args, n_tr * periods, periods, n_samples=P * spp,
        samples_per_period=spp, rtol=settings.rtol, atol=settings.atol,
        max_steps=settings.max_steps, block=int(cfg.kernel_block),
        fast=bool(cfg.kernel_fast), unroll=int(cfg.kernel_unroll),
        looped=bool(cfg.kernel_looped))
    samples = samples.reshape(N, P, spp, n)
    return jax.vmap(lambda *a: _reduce(problem, cfg, *a))(
        samples, start, end, codes, steps.astype(int), periods)


def _map_points(problem, values, y0s, n_transient, cfg: SweepConfig):
    """Cold points: values (N,), start states (N, n), transient periods (N,) or None
    (`cfg.transient_periods` for every point, kept unbatched)."""
    engine = problem.resolved_engine(cfg)
    if engine == "kernel":
        return _kernel_points(problem, values, y0s, n_transient, cfg)
    if engine == "queue" and not cfg.lyapunov:
        if n_transient is None:
            n_transient = jnp.full(values.shape[0], float(cfg.transient_periods))
        return _queue_points(problem, values, y0s, n_transient, cfg)
    if n_transient is None:
        n_tr = jnp.asarray(float(cfg.transient_periods))
        xs = (values, y0s)

        def one(x):
            return _point(problem, x[0], x[1], n_tr, cfg)
    else:
        xs = (values, y0s, jnp.asarray(n_transient, dtype=float))

        def one(x):
            return _point(problem, x[0], x[1], x[2], cfg)

    batch = cfg.batch_size or values.shape[0]
    if batch == 1:
        # A plain scan: vmap (even of one member) turns the solver's internal `cond`s
        # into `select`s that evaluate both branches, which costs on the CPU.
        return jax.lax.map(one, xs)
    if batch >= values.shape[0]:
        return jax.vmap(one)(xs)
    return jax.lax.map(one, xs, batch_size=batch)


@cached_jit
def _cold_chunk(problem, values, y0s, n_transient, cfg: SweepConfig, mesh):
    """One chunk of cold points (see `_map_points`), sharded over `mesh` if given."""
    if mesh is None:
        return _map_points(problem, values, y0s, n_transient, cfg)
    from jax.sharding import PartitionSpec as P

    dynamic, static = eqx.partition(problem, eqx.is_array)
    axis = mesh.axis_names[0]
    args = (dynamic, values, y0s) + (() if n_transient is None else (n_transient,))

    def local(dyn, v, y, *t):
        return _map_points(eqx.combine(dyn, static), v, y, t[0] if t else None, cfg)

    return jax.shard_map(local, mesh=mesh, in_specs=(P(),) + (P(axis),) * (len(args) - 1),
                         out_specs=P(axis), check_vma=False)(*args)


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
            return (out["end_state"], out["status"] == OK, jnp.asarray(False)), out

        return jax.lax.scan(step, (y, ok, is_first), vals)

    if values.shape[0] == 1:  # one lane: no vmap (see `_map_points`)
        carry, out = direction(values[0], y_carry[0], ok_carry[0], first[0])
        return jax.tree_util.tree_map(lambda a: a[None], (carry, out))
    carry, out = jax.vmap(direction)(values, y_carry, ok_carry, first)
    return carry, out


def cold_chunk_size(config: SweepConfig, n_points: int, mesh) -> int:
    """Points per chunk of a cold sweep of `n_points` (a multiple of the mesh's devices)."""
    chunk = min(int(config.chunk_size), int(n_points))
    if mesh is not None:
        k = mesh.devices.size
        chunk = -(-chunk // k) * k
    return chunk


class SettleRuns:
    """The verifier's settle blocks on a cold sweep's own program: `periods` forcing
    periods from given states, the last `config.periods` (`record_periods`) recorded as
    the sweep records them. Called with (values (B,), states (B, n)), it returns (strobes
    (B, P + 1, n), amplitudes (B, n), ok (B,)), the strobe's last point the state reached.
    Runs are padded to the sweep's chunk of `chunk` points (the last one repeated), so
    where the sweep ran per-point transients (a verified cold sweep's minimum transients)
    its compiled program serves them (on a GPU: the kernel, where a lane runs its own
    loop; the verifier's long runs with the tangent dynamics are lockstep). Not with the
    tangent dynamics (`config.lyapunov`)."""

    def __init__(self, problem, config: SweepConfig, mesh, chunk: int, periods: int):
        if config.lyapunov:
            raise ValueError("settle blocks (VerifySettings.settle) run without the tangent "
                             "dynamics: set SweepConfig(lyapunov=False) or settle=False")
        self.problem, self.config, self.mesh, self.chunk = problem, config, mesh, int(chunk)
        self.record_periods = int(config.periods)
        self.periods = max(int(periods), self.record_periods + 1)

    def __call__(self, values, states):
        values = np.asarray(values, dtype=float)
        states = np.asarray(states, dtype=float)
        B, C = values.shape[0], self.chunk
        n_tr = jnp.full(C, float(self.periods - self.config.periods))
        parts = []
        for lo in range(0, B, C):
            hi = min(lo + C, B)
            pos = np.concatenate([np.arange(lo, hi), np.full(C - (hi - lo), hi - 1)])
            out = _cold_chunk(self.problem, jnp.asarray(values[pos], dtype=float),
                              jnp.asarray(states[pos], dtype=float), n_tr, self.config,
                              self.mesh)
            if self.mesh is not None and jax.process_count() > 1:
                from jax.experimental import multihost_utils

                out = multihost_utils.process_allgather(out, tiled=True)
            parts.append([np.asarray(out[k])[:hi - lo] for k in
                          ("strobe", "amplitude", "status")])
        strobe, amp, status = (np.concatenate(a) for a in zip(*parts, strict=True))
        ok = (status == OK) & np.all(np.isfinite(strobe), axis=(1, 2))
        return strobe, amp, ok


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
