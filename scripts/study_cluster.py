"""The studies' units of work (a drive, a batch of replicates) on a Dask cluster.

`add_args` gives a study `--workers N` (a local cluster) and `--scheduler ADDRESS` (a
running one; default $BSFS_SCHEDULER); `run_units` runs `fn(unit)` for every unit, here
one after another or on the cluster's workers, and hands each result to `on_result` in
this process as it comes back (the study appends its rows there: only this process writes
the results file, and a rerun resumes from it wherever the rows were computed).

The study scripts are not part of the installed package, so their functions travel to the
workers by value (cloudpickle's `register_pickle_by_value`); the workers need the same
bsfs, not the scripts. A unit that fails on every attempt is printed with its cause and
left out of the file, so that a rerun computes it.
"""

from __future__ import annotations

import sys


def add_args(parser) -> None:
    """--scheduler ADDRESS | --workers N, and --chunk-timeout SECONDS: the `bsfs`
    command's options (`bsfs_jax.cli._cluster_opts`), with their checks."""
    from bsfs_jax.cli import _cluster_opts

    _cluster_opts.add_args(parser, "the units of work")


def open_from(args):
    """The cluster the command line (or BSFS_SCHEDULER) names, or None; exits with one
    line where it cannot be opened."""
    from bsfs_jax.cluster import open_cluster

    try:
        cluster = open_cluster(args.scheduler, args.workers, chunk_timeout=args.chunk_timeout)
    except (RuntimeError, ValueError, OSError) as exc:
        raise SystemExit(str(exc).splitlines()[0]) from None
    if cluster is None and args.chunk_timeout is not None:
        raise SystemExit("--chunk-timeout limits units on a cluster: give --workers N or "
                         "--scheduler ADDRESS too, or drop it")
    if cluster is not None:
        print(f"units of work on {cluster.describe()}", flush=True)
    return cluster


def run_units(fn, units: list, on_result, cluster=None, modules=(),
              fresh_process: bool = False) -> list:
    """`on_result(unit, fn(unit))` for every unit, in this process (in order) or with
    `cluster` on its workers (as they finish); `modules`: the scripts' modules whose
    functions `fn` uses, sent by value; `fresh_process`: each unit in a new process of its
    worker (`Cluster.run`'s). Returns the units that failed on every attempt, as (unit,
    cause)."""
    if cluster is None:
        for unit in units:
            on_result(unit, fn(unit))
        return []
    import cloudpickle

    for module in {getattr(fn, "func", fn).__module__, *modules}:
        if module != "__main__":
            cloudpickle.register_pickle_by_value(sys.modules[module])
    failed = []
    for k, value in cluster.run(fn, units, name="bsfs-study", fresh_process=fresh_process):
        if isinstance(value, Exception):
            print(f"unit {units[k]!r} failed {value.attempts} times on the cluster "
                  f"({value.cause}); left out, a rerun computes it", flush=True)
            failed.append((units[k], value.cause))
            continue
        on_result(units[k], value)
    return failed
