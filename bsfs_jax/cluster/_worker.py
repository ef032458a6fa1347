"""What runs on a worker: its process settings, once, and each chunk with its record.

A worker is an ordinary single-host JAX process. Before the first chunk's function is
unpickled (which imports equinox and jax), `ready()` chooses the `bsfs` command's
settings for the process: 64-bit floats, the persistent compilation cache in this host's
CPU folder of `BSFS_CACHE_DIR` (`host_cache_dir`), EQX_ON_ERROR=nan and XLA's earlier CPU
fusion emitters (`bsfs_jax._host.apply`), one BLAS thread. Every chunk then returns its
value with a record: its seconds, the worker, and the programs it compiled (jax's compile
events: XLA compilations and persistent-cache reads, and the traces), so that "a worker's
second chunk compiles nothing" can be checked and the per-chunk time measured.
"""

from __future__ import annotations

import os
import pickle
import socket
import threading
import time

_READY = threading.Lock()
_STATE: dict = {}
#: jax's compile events, counted per process since `ready()`.
_COUNTS = {"programs": 0, "cache_hits": 0, "traces": 0, "compile_s": 0.0}
_EVENTS = {"/jax/core/compile/backend_compile_duration": "compile_s",
           "/jax/core/compile/jaxpr_trace_duration": "traces"}


def _on_duration(event, seconds, **_):
    name = _EVENTS.get(event)
    if name == "compile_s":
        _COUNTS["programs"] += 1
        _COUNTS["compile_s"] += seconds
    elif name == "traces":
        _COUNTS["traces"] += 1


def _on_event(event, **_):
    if event == "/jax/compilation_cache/cache_hits":
        _COUNTS["cache_hits"] += 1


def ready(cache: str | None = None) -> str:
    """Choose this worker's process settings (module docstring), once per process; the
    cache folder in use. `cache`: the shared cache's root (default `BSFS_CACHE_DIR`, else
    `~/.cache/bsfs/jax`); this host's CPU folder under it is used."""
    with _READY:
        if "cache" in _STATE:
            return _STATE["cache"]
        from .._host import apply

        apply()  # EQX_ON_ERROR and XLA_FLAGS where they still take effect
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")
        import jax

        from ._host_key import host_cache_dir

        jax.config.update("jax_enable_x64", True)
        folder = host_cache_dir(cache)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            jax.config.update("jax_compilation_cache_dir", str(folder))
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
        except OSError:
            folder = None  # a read-only cache: compile in memory only
        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        jax.monitoring.register_event_listener(_on_event)
        _STATE["cache"] = "" if folder is None else str(folder)
        _STATE["chunks"] = {}
        return _STATE["cache"]


def run_chunk(payload: bytes, item, cache: str | None = None, kind: str = "chunk",
              budget: float | None = None):
    """(fn(item), record) on a worker, `fn` being `payload` unpickled after `ready()`.
    `kind`: the chunk's kind (its function's name); the record's `chunk_of_worker` counts
    this worker's chunks of that kind (1 for its first). `budget`: seconds the chunk may
    run; past them the value is None and the record's `timed_out` True (`_within`)."""
    cache_dir = ready(cache)
    fn = pickle.loads(payload)
    before = dict(_COUNTS)
    t0 = time.perf_counter()
    value, timed_out = (fn(item), False) if budget is None else _within(fn, item, budget)
    seconds = time.perf_counter() - t0
    _STATE["chunks"][kind] = _STATE["chunks"].get(kind, 0) + 1
    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = f"{socket.gethostname()}:{os.getpid()}"
    record = {"seconds": seconds, "worker": worker, "pid": os.getpid(), "timed_out": timed_out,
              "kind": kind, "chunk_of_worker": _STATE["chunks"][kind], "cache": cache_dir,
              **{k: _COUNTS[k] - before[k] for k in _COUNTS}}
    record["compiled"] = record["programs"] - record["cache_hits"]  # by XLA, not read
    return value, record


def _within(fn, item, budget: float):
    """(fn(item), False), or (None, True) where it runs past `budget` seconds. The chunk
    runs in a thread of its own that this one waits for; one that overruns cannot be
    stopped (a compiled program runs to its end, a deadlocked one never ends), so it is
    left behind and the client restarts this worker (`Cluster.run`)."""
    box: dict = {}

    def work():
        try:
            box["value"] = fn(item)
        except BaseException as exc:  # noqa: BLE001 - raised again in the waiting thread
            box["error"] = exc

    thread = threading.Thread(target=work, name="bsfs-chunk", daemon=True)
    thread.start()
    thread.join(budget)
    if thread.is_alive():
        return None, True
    if "error" in box:
        raise box["error"]
    return box["value"], False
