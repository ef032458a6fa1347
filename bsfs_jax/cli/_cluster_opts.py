"""--scheduler / --workers for the commands whose work splits into independent chunks
(`bsfs map`: its rows; `bsfs sweep`: its chunks; `bsfs identify`: its refits' batches;
`bsfs predict`: its draws' batches): the chunks then run on a Dask cluster
(`bsfs_jax.cluster`), and this process alone writes the output folder. Without either
option (and without BSFS_SCHEDULER) nothing changes."""

import argparse
import os
from contextlib import contextmanager

from . import _common as ui

ENV = "BSFS_SCHEDULER"  # (bsfs_jax.cluster.ENV, without importing it for --help)


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if not 1 <= value <= 4096:
        raise argparse.ArgumentTypeError(f"a number of workers from 1 to 4096, got '{text}'")
    return value


def _seconds(text: str) -> float:
    value = ui.finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"a positive number of seconds, got '{text}'")
    return value


def add_args(parser, what: str = "the independent chunks") -> None:
    """--scheduler ADDRESS | --workers N (mutually exclusive); `what`: what they run."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--scheduler", metavar="ADDRESS",
                       help=f"run {what} on the Dask cluster whose scheduler "
                       f"is at ADDRESS (e.g. tcp://login1:8786; default ${ENV}); only this "
                       "process writes --out (pip install 'bsfs[cluster]')")
    group.add_argument("--workers", type=_workers, metavar="N",
                       help="start a local Dask cluster of N worker processes (one thread "
                       f"each) and run {what} on it")
    parser.add_argument("--chunk-timeout", type=_seconds, metavar="SECONDS",
                        help="on a cluster: a chunk that runs longer is reported as failed "
                        "(its points unresolved; a rerun computes them) and its worker "
                        "restarted (default: no limit)")


def wanted(args) -> bool:
    """Whether the command line (or BSFS_SCHEDULER) asks for a cluster."""
    return bool(getattr(args, "scheduler", None) or getattr(args, "workers", None)
                or os.environ.get(ENV))


def explicit(args) -> bool:
    """Whether the command line itself names a cluster (not only BSFS_SCHEDULER)."""
    return bool(getattr(args, "scheduler", None) or getattr(args, "workers", None))


@contextmanager
def cluster_from_args(args, command: str, enabled: bool = True):
    """The `Cluster` named by --scheduler / --workers / BSFS_SCHEDULER, or None (the work
    runs in this process as before; also where not `enabled`); closed on leaving."""
    budget = getattr(args, "chunk_timeout", None)
    if budget is not None and not wanted(args):
        raise ui.CLIError("--chunk-timeout limits chunks on a cluster: give --workers N or "
                          f"--scheduler ADDRESS (or ${ENV}) too, or drop it")
    if not enabled or not wanted(args):
        yield None
        return
    from ..cluster import open_cluster

    try:
        cluster = open_cluster(getattr(args, "scheduler", None), getattr(args, "workers", None),
                               chunk_timeout=budget)
    except (RuntimeError, ValueError, OSError) as exc:
        raise ui.CLIError(str(exc).splitlines()[0]) from None
    print(f"bsfs {command}: independent chunks on {cluster.describe()}", flush=True)
    try:
        yield cluster
    finally:
        cluster.close()


def report(cluster, command: str, failed: list) -> dict | None:
    """The cluster's part of summary.json (None without a cluster): where the chunks ran,
    their seconds, the programs they compiled, and `failed` (the result's failed chunks or
    rows, `metadata["failed_chunks"]` / `["failed_rows"]`), each also printed as a
    warning with its cause."""
    out = account(cluster)
    if out is None:
        return None
    out["failed_chunks"] = failed
    for f in failed:
        lo, hi = f["values"]
        where = f"{lo:g}" if lo == hi else f"{lo:g} .. {hi:g}"
        print(f"bsfs {command}: warning: the {f['stage']} chunk at {where} failed "
              f"{f['attempts']} times ({f['cause']}); its points are marked; rerun the same "
              "command with the same --out to compute them", flush=True)
    return out


def account(cluster) -> dict | None:
    """`bsfs_jax.cluster.summary` of the cluster's chunks (None without a cluster), its
    "failed_chunks" being those that failed on every attempt, with their causes."""
    if cluster is None:
        return None
    from ..cluster import summary

    return summary(cluster)
