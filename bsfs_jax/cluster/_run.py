"""The client side: a Dask cluster to connect to or start, and chunks run on it.

`Cluster.run(fn, items)` sends `fn(item)` for every item to the workers as independent
tasks and yields `(position, value)` as they finish, the value of a chunk that failed
being a `ChunkFailed` with its cause: the caller (only the client) writes the results.

Faults:
- a chunk that raises is run again (`retries`, default 1: two attempts in all), on any
  worker; if it fails again, its `ChunkFailed` carries the cause and the other chunks go
  on;
- a chunk that runs past the cluster's `chunk_timeout` is reported at once (attempts 1:
  it would overrun again), and its worker, whose thread cannot be stopped, is restarted;
- a worker that dies (kill -9, a node lost) takes only its running chunks with it: the
  scheduler gives them to the other workers (it does so up to
  `distributed.scheduler.allowed-failures` times, 3 by default); a chunk it gives up on
  (`KilledWorker`) is submitted once more (`resubmits`) before it is reported.
"""

from __future__ import annotations

import itertools
import os
import time

ENV = "BSFS_SCHEDULER"
#: Seconds to wait for a scheduler to answer before giving up.
CONNECT_TIMEOUT_S = 20


def _dask():
    try:
        import distributed
    except ImportError:
        raise RuntimeError("a cluster (--scheduler/--workers) needs dask and distributed: "
                           "pip install 'bsfs[cluster]'") from None
    return distributed


class ChunkFailed(RuntimeError):
    """A chunk that failed on every attempt: `position`, `item`, `cause` (one line),
    `attempts`."""

    def __init__(self, position: int, item, cause: str, attempts: int):
        super().__init__(f"chunk {position} failed {attempts} times: {cause}")
        self.position, self.item, self.cause, self.attempts = position, item, cause, attempts


def _cause(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _dumps(fn) -> bytes:
    import cloudpickle

    return cloudpickle.dumps(fn)


class Cluster:
    """A Dask client for bsfs's chunks: `Cluster(scheduler="tcp://host:8786")` connects to
    a running scheduler, `Cluster(workers=N)` starts a local cluster of N worker
    processes of one thread each (spawned by Dask's nannies, never forked from a process
    that runs jax). Use as a context manager, or call `close()`.

    - `cache`: the persistent compilation cache's root that the workers share (default
      their `BSFS_CACHE_DIR`, else `~/.cache/bsfs/jax`); each host uses its CPU's folder in
      it (`host_cache_dir`). It holds trusted code: only the cluster's own workers may
      write it.
    - `retries`: extra attempts of a chunk that raises (1); `resubmits`: extra submissions
      of a chunk whose workers died more often than the scheduler allows (1).
    - `timeout`: seconds to wait for the scheduler to answer (`CONNECT_TIMEOUT_S`).
    - `chunk_timeout`: seconds a chunk may run on its worker (None: no limit); one that
      runs past them fails with a `TimeoutError` cause and its worker is restarted.
    - `records`: one dict per finished chunk (seconds, worker, programs compiled), in
      the order they came back; `failures`: the `ChunkFailed` of the run's chunks.
    """

    def __init__(self, scheduler: str | None = None, workers: int | None = None, *,
                 cache: str | None = None, retries: int = 1, resubmits: int = 1,
                 timeout: float = CONNECT_TIMEOUT_S, chunk_timeout: float | None = None,
                 client=None):
        if client is None and not scheduler and workers is None:
            raise ValueError("Cluster needs a scheduler address or a number of workers")
        if chunk_timeout is not None and not float(chunk_timeout) > 0:
            raise ValueError(f"chunk_timeout must be a positive number of seconds, got "
                             f"{chunk_timeout}")
        self.chunk_timeout = None if chunk_timeout is None else float(chunk_timeout)
        if workers is not None and int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.scheduler, self.workers = scheduler, None if workers is None else int(workers)
        self.cache, self.retries, self.resubmits = cache, int(retries), int(resubmits)
        self.timeout = float(timeout)
        self.records: list[dict] = []
        self.failures: list[ChunkFailed] = []
        self._local = None
        self._runs = itertools.count()
        self.client = client
        if client is None:
            self._start()
        else:
            self._register()  # a client of the caller's: its workers choose their settings

    def _start(self) -> None:
        distributed = _dask()
        import dask

        if self.scheduler:
            try:
                self.client = distributed.Client(self.scheduler, timeout=f"{self.timeout}s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise ConnectionError(
                    f"no Dask scheduler answered at {self.scheduler} within "
                    f"{self.timeout:g} s ({type(exc).__name__}): start one (`dask "
                    "scheduler`, then `dask worker ADDRESS` on each node) or correct "
                    f"--scheduler / ${ENV}") from None
            self._register()
            return
        # One thread per worker process: each chunk is one JAX program on its host. The
        # nannies start the workers as new processes ("spawn"), never by forking a process
        # in which jax runs (jax #17329).
        with dask.config.set({"distributed.worker.multiprocessing-method": "spawn"}):
            self._local = distributed.LocalCluster(
                n_workers=self.workers, threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=50)  # (failures: in our summary)
        self.client = distributed.Client(self._local)
        self._register()

    def _register(self) -> None:
        """Every worker, now and joining later, chooses its settings as it joins
        (`_plugin.Ready`): before it unpickles a task's arguments."""
        from ._plugin import Ready

        self.client.register_plugin(Ready(self.cache))

    @property
    def n_workers(self) -> int:
        return len(self.client.scheduler_info().get("workers", {}))

    def describe(self) -> str:
        where = self.scheduler or f"a local cluster of {self.workers} worker processes"
        return f"{where} ({self.n_workers} workers)"

    def run(self, fn, items, *, name: str = "bsfs-chunk", fresh_process: bool = False):
        """Yield `(position, fn(item))` for every item as the chunks finish; a chunk that
        failed on every attempt yields its `ChunkFailed` (also kept in `failures`). Runs
        from several threads of the client at once may share the cluster.
        `fresh_process`: each chunk in a new process of its worker (`_fresh`), for jobs
        whose memory grows from chunk to chunk; its programs then come from the shared
        compilation cache."""
        distributed = _dask()
        from ._worker import run_chunk

        items = list(items)
        if not items:
            return
        if fresh_process:
            import functools

            from ._fresh import in_fresh_process

            fn = functools.partial(in_fresh_process, _dumps(fn), cache=self.cache)
        payload = _dumps(fn)
        kind = getattr(getattr(fn, "func", fn), "__qualname__", "chunk")
        stamp = f"{name}-{time.time_ns():x}-{next(self._runs)}"  # (runs from two threads)
        submits = {}

        def submit(k: int):
            submits[k] = submits.get(k, 0) + 1
            fut = self.client.submit(run_chunk, payload, items[k], self.cache, kind,
                                     self.chunk_timeout, key=f"{stamp}-{k}-{submits[k]}",
                                     pure=False, retries=self.retries)
            where[fut.key] = k
            return fut

        where: dict = {}
        done = distributed.as_completed([submit(k) for k in range(len(items))])
        for fut in done:
            k = where.pop(fut.key)
            try:
                value, record = fut.result()
            except Exception as exc:  # noqa: BLE001 - the chunk's own error, or its worker's
                killed = type(exc).__name__ in ("KilledWorker", "CommClosedError",
                                                "FutureCancelledError", "CancelledError")
                if killed and submits[k] <= self.resubmits:
                    done.add(submit(k))
                    continue
                attempts = (self.retries + 1) * submits[k] if not killed else submits[k]
                failed = ChunkFailed(k, items[k], _cause(exc), attempts)
                self.failures.append(failed)
                yield k, failed
                continue
            finally:
                fut.release()
            if record.get("timed_out"):
                failed = ChunkFailed(k, items[k], f"TimeoutError: ran past its budget of "
                                     f"{self.chunk_timeout:g} s on {record['worker']}", 1)
                self.failures.append(failed)
                self._restart(record["worker"])
                yield k, failed
                continue
            record.update(position=k, submits=submits[k])
            self.records.append(record)
            yield k, value

    def _restart(self, worker: str) -> None:
        """Restart `worker` (its overrunning chunk's thread goes with its process); a
        worker without a nanny cannot be restarted and keeps the thread."""
        try:
            self.client.restart_workers([worker], raise_for_error=False)
        except Exception:  # noqa: BLE001 - the chunk is reported either way
            pass

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self._local is not None:
            self._local.close()
        self.client = self._local = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_cluster(scheduler: str | None = None, workers: int | None = None, **kwargs):
    """A `Cluster` where `scheduler` or `workers` is given, else where the BSFS_SCHEDULER
    variable names a scheduler; else None: the work then runs in this process as before."""
    if workers is not None and scheduler:
        raise ValueError("give either a scheduler address or a number of workers, not both")
    if workers is None:
        scheduler = scheduler or os.environ.get(ENV) or None
    if not scheduler and workers is None:
        return None
    return Cluster(scheduler=scheduler, workers=workers, **kwargs)


def summary(cluster) -> dict:
    """JSON-ready: where the chunks ran, how many came back, their seconds and the
    programs they compiled (per worker), and the chunks that failed on every attempt with
    their causes."""
    recs = cluster.records
    secs = [r["seconds"] for r in recs]
    workers: dict = {}
    for r in recs:
        w = workers.setdefault(r["worker"], {"chunks": 0, "seconds": 0.0, "compiled": 0,
                                             "loaded_from_cache": 0})
        w["chunks"] += 1
        w["seconds"] += r["seconds"]
        w["compiled"] += r["compiled"]
        w["loaded_from_cache"] += r["cache_hits"]
    return {"cluster": cluster.describe(), "chunks_done": len(recs),
            "chunk_seconds": {"total": sum(secs), "max": max(secs, default=0.0),
                              "mean": sum(secs) / len(secs) if secs else 0.0},
            "programs_compiled": sum(r["compiled"] for r in recs),
            "resubmitted": sum(r["submits"] > 1 for r in recs), "workers": workers,
            "failed_chunks": [{"chunk": f.position, "cause": f.cause, "attempts": f.attempts}
                              for f in cluster.failures]}
