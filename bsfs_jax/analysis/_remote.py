"""Chunks of a sweep, of its verification or of an atlas computed elsewhere.

A `runner(fn, items)` (`bsfs_jax.cluster.Cluster.run` on a Dask cluster; nothing here
imports it) runs `fn(item)` for every item, each item on some worker, and yields
`(position, value)` as they finish; the value of an item that failed on every attempt is
an exception whose `cause` (one line) and `attempts` describe it. The functions it runs
are the very ones the local run calls for a chunk, so the values are the local run's.
Only this process saves: each chunk that comes back goes into the local run's
checkpoint, under the local run's name, so either kind of run resumes from the other's.
"""

import numpy as np


def run_elsewhere(runner, fn, items: dict, save, bar=None, sizes: dict | None = None) -> dict:
    """{key: value, or the exception of a failed item} for `items` ({key: item}), run by
    `runner`; each value is passed to `save(key, value)` as it comes back (this process
    alone writes). `bar`: a tqdm bar advanced by `sizes[key]` (default 1) per item."""
    keys = list(items)
    out = {}
    if not keys:
        return out
    for pos, value in runner(fn, [items[k] for k in keys]):
        k = keys[pos]
        out[k] = value
        if not isinstance(value, BaseException):
            save(k, value)
        if bar is not None:
            bar.update(1 if sizes is None else sizes[k])
    return out


def cause_of(exc: BaseException) -> str:
    """The one-line cause of a failed chunk."""
    return str(getattr(exc, "cause", None) or f"{type(exc).__name__}: {exc}").splitlines()[0]


def failure(stage: str, chunk: int, values, exc: BaseException) -> dict:
    """JSON-ready record of a chunk that failed on every attempt: the stage
    ("integration", "verification", "row"), its index, the parameter values of its points
    (first and last), its attempts and its cause."""
    v = np.atleast_1d(np.asarray(values, dtype=float))
    return {"stage": stage, "chunk": int(chunk), "values": [float(v[0]), float(v[-1])],
            "points": int(v.size), "attempts": int(getattr(exc, "attempts", 1)),
            "cause": cause_of(exc)}


def lost_chunk(template: dict, n: int, code: int) -> dict:
    """A cold sweep chunk's arrays for `n` points that were not computed: shaped as
    `template`'s (a computed chunk, (1, points, ...)), NaN (0, False) where they hold
    numbers, status `code`."""
    out = {}
    for name, a in template.items():
        a = np.asarray(a)
        shape = (a.shape[0], n) + a.shape[2:]
        if name == "status":
            out[name] = np.full(shape, code, a.dtype)
        elif a.dtype.kind in "fc":
            out[name] = np.full(shape, np.nan, a.dtype)
        else:
            out[name] = np.zeros(shape, a.dtype)
    return out
