"""A worker's settings at its start: `ready()` before any task's arguments arrive.

A task's arguments are unpickled before its function runs. A jax array sent as an
argument to a worker whose process has not yet chosen 64-bit floats arrives as float32
(jax turns the float64 buffer into its default precision when it rebuilds the array), and
the chunk computes a near miss: on a `bsfs predict` it moved the lift-off force's draws
by 7e-7 relative. So `Cluster` registers this plugin, which runs `ready()` on every worker
as it joins (those that start later or restart after a crash too). Imported only where a
cluster is opened (it needs distributed).
"""

from __future__ import annotations

from distributed import WorkerPlugin


class Ready(WorkerPlugin):
    """`ready(cache)` on each worker as it joins the cluster."""

    name = "bsfs-ready"

    def __init__(self, cache: str | None = None):
        self.cache = cache

    def setup(self, worker) -> None:
        from ._worker import ready

        ready(self.cache)
