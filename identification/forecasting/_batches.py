"""Where the model runs at an identification's draws: batches of draws, threads, a cluster.

A program over the draws (the FRC's points followed to each draw, the lift-off search at
each draw) is vmapped over a batch of them (`draw_batches`); the batches run on this
process's threads (`lane_threads`: XLA runs one such program on one core) or, where the
identification carries a cluster (`Identified.cluster`), a batch a chunk on its workers
(`run_batches`).
"""

from __future__ import annotations

import numpy as np

from ._intervals import DRAW_BATCH, Identified


def draw_batches(ident: Identified, round_to: int = DRAW_BATCH, parts: int = 1) -> list:
    """The identification's draws in batches of at most `DRAW_BATCH` rows for the
    vmapped programs that push them through the model, the last padded with the estimate
    to a multiple of `round_to`: `DRAW_BATCH` for cheap lanes (one program for any count
    of draws), a small number for costly ones (200 refits run as 200 lanes, not 256).
    `parts`: at least this many batches (of equal size), for `run_batches`' threads."""
    n = len(ident.draws)
    per_part = -(-n // parts)
    batch = min(DRAW_BATCH, -(-per_part // round_to) * round_to)
    thetas = np.concatenate([ident.draws, np.repeat(ident.theta[None], -n % batch, axis=0)])
    return [thetas[i:i + batch] for i in range(0, len(thetas), batch)]


def lane_threads() -> int:
    """How many threads `run_batches` uses (and how many batches costly lanes are cut
    into): on the CPU its cores, at most 4 (XLA runs one such program on one core); on an
    accelerator 1 (there the lanes of one batch already run in parallel)."""
    import os

    import jax

    if jax.default_backend() != "cpu":
        return 1
    return max(1, min(4, os.cpu_count() or 1))


def lane_parts(ident: Identified) -> int:
    """How many batches costly lanes are cut into: `lane_threads()`, or on a cluster two
    per worker (the batches' times differ by a third: a worker that finishes early takes
    another). A lane's values do not depend on the cut: the lift-off's 200 draws of the
    bundled drive cut into 2, 4 and 8 batches were the same to the last bit."""
    if ident.cluster is None:
        return lane_threads()
    return max(lane_threads(), 2 * ident.cluster.n_workers)


def on_threads(fn, items: list, workers: int) -> list:
    """[fn(x) for x in items], on up to `workers` threads (in order; in this thread where
    one is enough). XLA runs a compiled program without Python's lock, so host-driven
    jobs that spend their time in programs share the cores."""
    workers = min(len(items), workers)
    if workers <= 1:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(fn, items))


def numpy_call(fn, args):
    """fn(*args) as a numpy tree (a batch's chunk, in this process or on a worker)."""
    import jax

    return jax.tree_util.tree_map(np.asarray, fn(*args))


def run_batches(fn, calls: list, cluster=None) -> list:
    """[fn(*args) for args in calls] as numpy trees, the calls on `lane_threads()`
    threads (`on_threads`), or with `cluster` (`Identified.cluster`) on its workers, a
    call a chunk (`fn`, a module-level function, travels by reference; a chunk that
    failed on every attempt there runs here instead, and stays in the cluster's
    `failures`). The FRC's three points followed by shooting to 200 refits and 10
    central steps on the 2-core machine: 18.4 s as one batch, 8.5 s as two on two
    threads."""
    import functools

    job = functools.partial(numpy_call, fn)
    if cluster is None:
        return on_threads(job, calls, lane_threads())
    out: list = [None] * len(calls)
    for k, value in cluster.run(job, calls, name="bsfs-draws"):
        out[k] = job(calls[k]) if isinstance(value, Exception) else value
    return out
