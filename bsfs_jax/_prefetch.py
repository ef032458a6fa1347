"""The background thread that traces and compiles programs before they are needed.

A prefetch job (`in_background`, `prefetch_jit`, `cached_jit`'s `prefetch`) runs on one
background thread, in the order the jobs were queued. Its XLA compilation
(`compile_in_background`) waits while a compilation marked by `foreground_compile` runs.
`settle` waits for a job.

A second thread that compiled one job while the first traced the next one was tried
(2026-11-29): on the 2-core machine it gave nothing, since a cold run keeps both cores
busy anyway. A cold `bsfs map` (16 x 8) took 68.0 and 73.6 s with it against 67.0 and
66.4 s without (`bench_ab.py`, alternating rounds, on a slow Intel Xeon).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from concurrent.futures import Future

_log = logging.getLogger(__name__)
_queue: queue.SimpleQueue | None = None  # the prefetch worker's jobs
_waiting: list[threading.Event] = []  # prefetches waiting for the next hand-off to XLA
_WORKER = "bsfs-prefetch"
# XLA compilations outside the prefetch thread have the right of way: a prefetch traces
# beside one (Python, while XLA leaves the interpreter free) but starts its own
# compilation only once none is running. Two compilations at once in one process were
# slower than one after the other: in a cold `bsfs sensitivity` the continuation's
# corrector took 7.9 s and the gradient's program 6.5 s side by side, 3.4 s and 4.2 s
# alone.
_foreground = threading.Condition()
_foreground_compiles = 0


def hand_off() -> None:
    """This thread is about to hand a newly traced program to XLA (or to wait for a
    prefetch): the prefetches waiting for that moment may start."""
    while _waiting:
        _waiting.pop().set()


def start_at_next_hand_off(start: threading.Event) -> None:
    """Set `start` at this process's next `hand_off` (a prefetch's tracing then runs
    beside that compilation, not in front of it)."""
    _waiting.append(start)


def _worker(jobs: queue.SimpleQueue) -> None:
    while True:
        job, future = jobs.get()
        if future.set_running_or_notify_cancel():
            try:
                future.set_result(job())
            except BaseException as exc:  # noqa: BLE001 - the caller falls back
                future.set_exception(exc)


@contextlib.contextmanager
def foreground_compile():
    """Mark an XLA compilation outside the prefetch thread: prefetches wait with theirs
    until it ends (`compile_in_background`). `cached_jit` marks its own; use it around an
    explicit `.compile()` whose result the caller waits for."""
    global _foreground_compiles
    if threading.current_thread().name == _WORKER:
        yield
        return
    with _foreground:
        _foreground_compiles += 1
    try:
        yield
    finally:
        with _foreground:
            _foreground_compiles -= 1
            _foreground.notify_all()


def compile_in_background(lowered):
    """`lowered.compile()` for a prefetch job, once no compilation marked by
    `foreground_compile` runs."""
    with _foreground:
        _foreground.wait_for(lambda: _foreground_compiles == 0)
    return lowered.compile()


def in_background(job) -> Future:
    """Run `job()` (typically: build arguments, then
    `compile_in_background(jitted.lower(...))`) on the one prefetch thread, after any job
    queued before it; the future holds its result. The thread is a daemon: an exit never
    waits for it."""
    global _queue
    if _queue is None:
        _queue = queue.SimpleQueue()
        threading.Thread(target=_worker, args=(_queue,), daemon=True,
                         name=_WORKER).start()
    future: Future = Future()
    _queue.put((job, future))
    return future


def settle(future: Future | None) -> None:
    """Wait for a prefetch (`in_background`, `prefetch_jit`) before the call that uses its
    program; a failed one is ignored (the call then compiles the program itself)."""
    if future is not None:
        try:
            future.result()
        except Exception as exc:  # noqa: BLE001 - the call compiles it instead
            _log.debug("prefetch failed: %r", exc)


def prefetch_jit(jitted, *args, **kwargs) -> Future:
    """Compile the program of `jitted(*args, **kwargs)` (a `jax.jit` or
    `equinox.filter_jit` function) on the background thread, starting now; the call made
    later with arguments of the same layout finds it in jit's cache. The caller waits for
    the returned future before that call (else both would compile it). For a program that
    the main thread needs only after other work (an integration running, another program
    compiling): its tracing then runs on the second core."""
    return in_background(lambda: compile_in_background(jitted.lower(*args, **kwargs)))

