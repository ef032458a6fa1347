"""One kernel in which every lane runs its own adaptive Dormand-Prince 5(4) loop (Pallas).

Why this exists: `vmap` over the fused loop (`_fused.py`) steps every lane of a batch in
lockstep, and on a GPU each step of that loop is several small kernel launches, so a sweep
costs the slowest lane's step count times a launch-bound step (tens of microseconds).
Here the whole integration of a lane, start to end, is one loop inside one kernel
(`jax.experimental.pallas`, Triton on a GPU): a block of `block` lanes (one warp by
default) shares a program, and each lane advances its own time, step size, phase and
sample counter, so the block only waits for its own slowest lane.

The method is the fused loop's, step for step: the same tableau, controller (I-control,
safety 0.9, factors in [0.2, 10], RMS error norm), clipping of steps onto save times, and
the same two runs per lane: from t = 0 to the start of the record `t_record` (the
transient), then, restarted with a fresh initial step, over `n_samples` save times
`t_record + period * k / samples_per_period`. So the results agree with the fused loop to
rounding (tested to 1e-8 relative on periodic responses).

The right-hand side is given on components: `field(t, ys, args) -> tuple`, where `ys` is a
tuple of the state's components, each an array of the block's lanes, and every leaf of
`args` arrives per lane (a leaf of shape (N,) as a (block,) array, one of shape (N, k) as
a tuple of k such arrays), so a field written elementwise on scalars (the ball screw's:
`bsfs_jax.model.vector_field_components`) runs unchanged. The sweep's kernel engine runs
it with `fast=True` (`model.kernel_vector_field`: no float64 division or square root) and
the kernel's own `fast` controller arithmetic; on an H100 that took a step of the slowest
lane from 13.0 to 4.3 us (benchmarks/results/gpu_b1.md).

With `looped=True` the step's six new stages are a loop over the stage index, so the
field is inlined once rather than eight times; Triton's and ptxas' time grows faster
than the program, so on an H200 the sweep's kernel then compiled in 4.4 s rather than
13.5 s and the orbit checks' three kernels in 18.5 s rather than 84.4 s, for runs about
1.2x as long (the tableau's zeros multiplied, its coefficients picked per stage).

On a CPU (or wherever Triton is not available) the kernel runs in Pallas' interpret mode:
slow, for tests; there the fused loop stays the default.
"""

import functools

import jax
import jax.numpy as jnp

from ._fused import _A, _B5, _C, _E, controller, first_step
from ._results import RESULTS, result_codes

_OK = int(result_codes(RESULTS.successful))
_MAX_STEPS = int(result_codes(RESULTS.max_steps_reached))
_STEP_FAILED = int(result_codes(RESULTS.step_size_failed))
_NON_FINITE = int(result_codes(RESULTS.non_finite))
_INVALID = int(result_codes(RESULTS.invalid_input))


def kernel_backend() -> str:
    """'triton' where the default backend is a GPU, else 'interpret'."""
    return "triton" if jax.default_backend() == "gpu" else "interpret"


def _leaf_layout(leaf, n_lanes):
    """(trailing shape, dtype) of a per-lane leaf with leading axis n_lanes."""
    leaf = jnp.asarray(leaf)
    if leaf.ndim == 0 or leaf.shape[0] != n_lanes:
        raise ValueError(f"integrate_lanes: every leaf of args needs a leading axis of "
                         f"{n_lanes} lanes, got shape {leaf.shape}")
    return leaf.shape[1:], leaf.dtype


def _rebuild(rows, shape, dtype):
    """A leaf from its flattened per-lane rows: an array (scalar leaf) or nested tuples."""
    if not shape:
        row = next(rows)
        return row if jnp.issubdtype(dtype, jnp.floating) else row.astype(dtype)
    return tuple(_rebuild(rows, shape[1:], dtype) for _ in range(shape[0]))


def _rms(xs):
    return jnp.sqrt(sum(x * x for x in xs) / len(xs))


def _error_norm(err, y, y_new, rtol, atol, fast):
    """RMS of err / (atol + rtol max(|y|, |y_new|)); `fast`: its square (no square root;
    `controller(fast=True)` takes it so), the quotients as products by reciprocal square
    roots of the squared scales (a few ulp, no float64 division)."""
    scales = [atol + rtol * jnp.maximum(jnp.abs(a), jnp.abs(b)) for a, b in zip(y, y_new)]
    if not fast:
        return _rms([e / sc for e, sc in zip(err, scales)])
    terms = [e * jax.lax.rsqrt(sc * sc) for e, sc in zip(err, scales)]
    return sum(x * x for x in terms) * (1.0 / len(terms))


def _stages(f, t, y, h, k1, n):
    """The step's seven stages, unrolled: the field inlined six times."""
    ks = [k1]
    for i in range(1, 7):
        yi = tuple(y[c] + h * sum(_A[i][j] * ks[j][c] for j in range(i) if _A[i][j] != 0.0)
                   for c in range(n))
        ks.append(f(t + _C[i] * h, yi))
    return ks


def _pick(i, values):
    """values[i] for a traced scalar index i over a constant row (no gather in a kernel;
    the constants strongly typed: Pallas-Triton types a weak one in a select as the
    predicate)."""
    zero = jnp.asarray(0.0, dtype=float)
    return sum(jnp.where(i == r, jnp.asarray(v, dtype=float), zero)
               for r, v in enumerate(values) if v != 0.0)


def _stages_looped(f, t, y, h, k1, n):
    """The same stages as a loop over the stage index: the field is inlined once, so the
    kernel's program is several times smaller (compile time on a GPU), for the tableau's
    coefficients picked per stage and its zeros multiplied."""
    zero = jnp.zeros_like(k1[0])
    a = [[_A[i][j] if j < i else 0.0 for i in range(7)] for j in range(6)]

    def stage(i, ks):
        coef = [_pick(i, a[j]) for j in range(6)]  # this stage's row, once for all c
        yi = tuple(y[c] + h * sum(coef[j] * ks[j][c] for j in range(6)) for c in range(n))
        ki = f(t + _pick(i, _C) * h, yi)
        return tuple(tuple(jnp.where(i == j, ki[c], ks[j][c]) for c in range(n))
                     if j > 0 else ks[j] for j in range(7))

    ks = (tuple(k1),) + tuple(tuple(zero for _ in range(n)) for _ in range(6))
    return list(jax.lax.fori_loop(1, 7, stage, ks))


def _kernel(field, treedef, layouts, n, n_samples, spp, rtol, atol, max_steps, block, n_pad,
            fast, unroll, per_lane, looped, p_ref, y0_ref, start_ref, end_ref, samples_ref,
            code_ref, steps_ref):
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    base = pl.program_id(0) * block
    # Every ref is flat: row r of a (rows, n_pad) array starts at r * n_pad.
    rows = lambda ref, r: ref[pl.ds(r * n_pad + base, block)]
    t_rec, period = rows(p_ref, 0), rows(p_ref, 1)
    # `per_lane`: row 2 holds each lane's own number of samples (<= n_samples)
    head = 3 if per_lane else 2
    n_last = rows(p_ref, 2) if per_lane else float(n_samples)
    flat = iter([rows(p_ref, head + i) for i in range(p_ref.shape[0] // n_pad - head)])
    args = jax.tree_util.tree_unflatten(treedef, [_rebuild(flat, s, d) for s, d in layouts])
    lanes = base + jnp.arange(block, dtype=jnp.int32)
    y0 = tuple(rows(y0_ref, c) for c in range(n))
    zero = jnp.zeros(block, dtype=float)
    t_end = t_rec + period * (n_last / spp)

    def f(t, y):
        return tuple(jnp.asarray(v, dtype=float) + zero for v in field(t, y, args))

    def restart_step(t0, t1, y, f0):
        scale = [atol + rtol * jnp.abs(v) for v in y]
        return first_step(_rms([v / sc for v, sc in zip(y, scale)]),
                          _rms([v / sc for v, sc in zip(f0, scale)]), t1 - t0)

    finite0 = functools.reduce(jnp.logical_and, [jnp.isfinite(v) for v in y0])
    f0 = f(zero, y0)
    code0 = jnp.where(finite0, _OK, _INVALID).astype(jnp.int32)
    state = dict(t=zero, y=y0, h=restart_step(zero, t_rec, y0, f0), k1=f0,
                 n=jnp.zeros(block, jnp.int32), total=jnp.zeros(block, jnp.int32),
                 code=code0, phase=jnp.zeros(block, jnp.int32),
                 k=jnp.ones(block, jnp.int32), active=finite0)

    def cond(s):
        return jnp.max(s["active"].astype(jnp.int32)) > 0

    def step(s):
        t, y, h, k1, act = s["t"], s["y"], s["h"], s["k1"], s["active"]
        recording = s["phase"] == 1
        target = jnp.where(recording, t_rec + period * (s["k"].astype(float) / spp), t_rec)
        clipped = t + h >= target
        h_eff = jnp.where(clipped, target - t, h)
        ks = (_stages_looped if looped else _stages)(f, t, y, h_eff, k1, n)
        y_new = tuple(y[c] + h_eff * sum(_B5[j] * ks[j][c] for j in range(6) if _B5[j] != 0.0)
                      for c in range(n))
        err = [h_eff * sum(_E[j] * ks[j][c] for j in range(7) if _E[j] != 0.0)
               for c in range(n)]
        en = _error_norm(err, y, y_new, rtol, atol, fast)
        finite_new = functools.reduce(jnp.logical_and, [jnp.isfinite(v) for v in y_new])
        finite = jnp.isfinite(en) & finite_new
        accept, h_new = controller(en, finite, h, h_eff, clipped, fast)
        t_new = jnp.where(clipped, target, t + h_eff)
        y_fin = functools.reduce(jnp.logical_and, [jnp.isfinite(v) for v in y])
        tiny = ~(h_new >= 1e-14 * jnp.maximum(jnp.abs(t), 1e-3))
        code = jnp.where(tiny, jnp.where(y_fin, _STEP_FAILED, _NON_FINITE), s["code"])
        n_new = s["n"] + 1
        reached = accept & clipped
        code = jnp.where((n_new >= max_steps) & ~reached, _MAX_STEPS, code).astype(jnp.int32)
        ok = act & (code == _OK)
        t_out = jnp.where(accept, t_new, t)
        y_out = tuple(jnp.where(accept, a, b) for a, b in zip(y_new, y))
        k1_out = tuple(jnp.where(accept, a, b) for a, b in zip(ks[6], k1))
        # A lane reached its save time (the transient's end, or a sample's).
        hit = ok & reached
        # The transient ends: keep the state, restart the controller as a new run would.
        switch = hit & ~recording
        # A sample is due; the lane's last one ends it.
        save = hit & recording
        last = save & ((s["k"] >= n_samples) if not per_lane else
                       (s["k"].astype(float) >= n_last))
        active = ok & ~last
        idx = (s["k"] - 1) * n_pad + lanes

        def restart():
            for c in range(n):
                plgpu.store(start_ref.at[c * n_pad + lanes], y_out[c], mask=switch)
            # Looped: the step's last stage is the field at (t_out, y_out) already (a
            # switching lane took an accepted, clipped step; first same as last), so the
            # kernel holds the field once more only for the start, not for the restart.
            f_rec = k1_out if looped else f(t_out, y_out)
            return f_rec, restart_step(t_out, t_end, y_out, f_rec)

        def events():
            for c in range(n):
                plgpu.store(samples_ref.at[c * n_samples * n_pad + idx], y_out[c], mask=save)
            return jax.lax.cond(jnp.max(switch.astype(jnp.int32)) > 0, restart,
                                lambda: (k1_out, h_new))

        # Work that only some steps need sits in a `cond`, skipped where no lane of the
        # block needs it, rather than computed and masked (8 % of a step on an H100); one
        # block-wide test per step for both kinds of save time, the restart's own test
        # only on those steps.
        f_rec, h_rec = jax.lax.cond(jnp.max(hit.astype(jnp.int32)) > 0, events,
                                    lambda: (k1_out, h_new))
        k_next = jnp.where(save, s["k"] + 1, s["k"])
        new = dict(
            t=t_out, y=y_out,
            h=jnp.where(switch, h_rec, h_new),
            k1=tuple(jnp.where(switch, a, b) for a, b in zip(f_rec, k1_out)),
            n=jnp.where(switch, 0, n_new).astype(jnp.int32),
            total=(s["total"] + act.astype(jnp.int32)).astype(jnp.int32),
            code=jnp.where(act, code, s["code"]).astype(jnp.int32),
            phase=jnp.where(switch, 1, s["phase"]).astype(jnp.int32),
            k=k_next.astype(jnp.int32), active=active)
        # A finished lane keeps its state while the others of its block go on.
        keep = lambda a, b: jnp.where(act, a, b).astype(b.dtype)
        out = jax.tree_util.tree_map(keep, {k: v for k, v in new.items() if k != "active"},
                                     {k: v for k, v in s.items() if k != "active"})
        out["active"] = active
        return out

    def body(s):
        # `unroll` steps per test of the loop's condition: a step of a finished lane
        # changes nothing, so the results are the same for any `unroll`.
        for _ in range(unroll):
            s = step(s)
        return s

    s = jax.lax.while_loop(cond, body, state)
    for c in range(n):
        end_ref[pl.ds(c * n_pad + base, block)] = s["y"][c]
    code_ref[pl.ds(base, block)] = s["code"]
    steps_ref[pl.ds(base, block)] = s["total"]


def integrate_lanes(field, y0, args, t_record, period, *, n_samples: int,
                    samples_per_period: int, rtol: float, atol: float, max_steps: int,
                    block: int = 32, num_warps: int = 1, backend: str | None = None,
                    fast: bool = False, unroll: int = 1, lane_samples=None,
                    looped: bool = False):
    """Integrate N independent lanes of y' = field(t, y, args), each in its own loop.

    Lane i runs from t = 0 and state `y0[i]` to `t_record[i]` (its transient), then on over
    the save times `t_record[i] + period[i] * k / samples_per_period`, k = 1..n_samples,
    as two runs of the fused loop would (`integrate` with `solver="dopri5-fused"`).

    **Arguments:**
    - `field`: field(t, ys, args) -> tuple of derivatives, on a tuple of components (see
      the module's docstring); traced once.
    - `y0` (N, n); `args`: a pytree whose leaves all have a leading axis of N lanes;
      `t_record`, `period` (N,).
    - `n_samples`, `samples_per_period`: static.
    - `rtol`, `atol`, `max_steps`: as `SolverSettings` (`max_steps` per run).
    - `block`, `num_warps`: lanes per program and the warps that run them (Triton).
    - `backend`: "triton" (GPU) or "interpret" (any device; slow); default by the device.
    - `fast`: the error norm without float64 divisions or square root and the
      controller's power in float32 (`_fused.controller(fast=True)`): the same controller
      to about 1e-7 on each step size, so the step sequence, not the accuracy, may differ
      from the fused loop's. With `fast=False` and the same field the kernel repeats the
      fused loop step for step.
    - `unroll`: steps per test of the loop's block-wide condition (the same results).
    - `looped`: the step's stages as a loop, the field inlined once rather than eight
      times (a smaller program, compiled faster on a GPU; the same method to rounding).
    - `lane_samples` (N,) ints in 1..n_samples, optional: lane i stops after its own
      first `lane_samples[i]` samples (the rest of its samples are undefined).

    Returns (start (N, n): the state at t_record, samples (N, n_samples, n), end (N, n),
    codes (N,) int32: `RESULTS` codes, 0 where successful; num_steps (N,) int32, both runs).
    Samples and states of a lane that failed are undefined: mask them with its code.
    """
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as plgpu

    y0 = jnp.asarray(y0, dtype=float)
    N, n = y0.shape
    backend = backend or kernel_backend()
    if backend not in ("triton", "interpret"):
        raise ValueError(f"integrate_lanes: backend must be 'triton' or 'interpret', got "
                         f"{backend!r}")
    leaves, treedef = jax.tree_util.tree_flatten(args)
    layouts = [_leaf_layout(leaf, N) for leaf in leaves]
    n_pad = -(-N // block) * block
    pad = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], n_pad - N, axis=0)]) \
        if n_pad > N else a
    cols = [jnp.broadcast_to(jnp.asarray(t_record, dtype=float), (N,)),
            jnp.broadcast_to(jnp.asarray(period, dtype=float), (N,))]
    per_lane = lane_samples is not None
    if per_lane:
        cols.append(jnp.clip(jnp.broadcast_to(jnp.asarray(lane_samples, dtype=float), (N,)),
                             1.0, float(n_samples)))
    cols += [jnp.asarray(leaf, dtype=float).reshape(N, -1).T for leaf in leaves]
    p = jnp.concatenate([jnp.atleast_2d(c) if c.ndim == 1 else c for c in cols], axis=0)
    p = pad(p.T).T
    kernel = functools.partial(
        _kernel, field, treedef, tuple(layouts), n, int(n_samples), float(samples_per_period),
        float(rtol), float(atol), int(max_steps), int(block), int(n_pad), bool(fast),
        int(unroll), per_lane, bool(looped))
    out_shape = (jax.ShapeDtypeStruct((n * n_pad,), float),
                 jax.ShapeDtypeStruct((n * n_pad,), float),
                 jax.ShapeDtypeStruct((n * n_samples * n_pad,), float),
                 jax.ShapeDtypeStruct((n_pad,), jnp.int32),
                 jax.ShapeDtypeStruct((n_pad,), jnp.int32))
    params = None
    if backend == "triton":
        params = plgpu.CompilerParams(num_warps=int(num_warps), num_stages=1)
    start, end, samples, codes, steps = pl.pallas_call(
        kernel, out_shape=out_shape, grid=(n_pad // block,),
        interpret=backend == "interpret", compiler_params=params)(p.ravel(), pad(y0).T.ravel())
    samples = samples.reshape(n, n_samples, n_pad)[:, :, :N].transpose(2, 1, 0)
    start, end = (a.reshape(n, n_pad)[:, :N].T for a in (start, end))
    return start, samples, end, codes[:N], steps[:N]

