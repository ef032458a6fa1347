"""Background threads that trace and compile programs before they are needed.

A prefetch job (`in_background`) runs on one background thread, in the order the jobs
were queued. It traces and lowers a program and hands its XLA compilation
(`compile_in_background`) to a second background thread, so that while XLA compiles one
program (which leaves Python's interpreter free) the next job is already traced. The
compilations run one at a time, and only while no compilation marked by
`foreground_compile` runs. A job's future is set once its compilations have ended.

In a cold `bsfs map` (16 x 8 points) the verification's check program was traced (5.4 s)
only after the rows' corrector had compiled (20 s) and the events' amplitude program had
been traced: the main thread waited for it from 22 s to 63 s. With the tracing moved
ahead of those compilations the map took MAP_AFTER s instead of MAP_BEFORE s on a slow
2-core machine.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from concurrent.futures import Future

_log = logging.getLogger(__name__)
_queue: queue.SimpleQueue | None = None  # the prefetch worker's jobs
_compile_queue: queue.SimpleQueue | None = None  # the prefetches' XLA compilations
_deferred: list[Future] = []  # the compilations the running prefetch job handed on
_waiting: list[threading.Event] = []  # prefetches waiting for the next hand-off to XLA
_WORKER = "bsfs-prefetch"
_COMPILER = "bsfs-prefetch-compile"
# XLA compilations outside the prefetch thread have the right of way: a prefetch traces
# beside one (Python, while XLA leaves the interpreter free) but starts its own
# compilation only once none is running. Two compilations at once in one process were
# slower than one after the other: in a cold `bsfs sensitivity` the continuation's
# corrector took 7.9 s and the gradient's program 6.5 s side by side, 3.4 s and 4.2 s
# alone.
_foreground = threading.Condition()
_foreground_compiles = 0


def _hand_off() -> None:
    """This thread is about to hand a newly traced program to XLA (or to wait for a
    prefetch): the prefetches waiting for that moment may start."""
    while _waiting:
        _waiting.pop().set()


def _worker(jobs: queue.SimpleQueue) -> None:
    while True:
        job, future = jobs.get()
        if not future.set_running_or_notify_cancel():
            continue
        _deferred.clear()
        try:
            result = job()
        except BaseException as exc:  # noqa: BLE001 - the caller falls back
            _deferred.clear()
            future.set_exception(exc)
            continue
        _resolve_after(list(_deferred), future, result)
        _deferred.clear()


def _resolve_after(compiles: list, future: Future, result) -> None:
    """Set `future` to `result` once every compilation in `compiles` (futures) has ended,
    or to the first one's exception."""
    if not compiles:
        future.set_result(result)
        return
    left = [len(compiles)]
    lock = threading.Lock()

    def done(_):
        with lock:
            left[0] -= 1
            if left[0]:
                return
        failed = [c.exception() for c in compiles if c.exception() is not None]
        if failed:
            future.set_exception(failed[0])
        else:
            future.set_result(result)

    for c in compiles:
        c.add_done_callback(done)


def _compiler(jobs: queue.SimpleQueue) -> None:
    while True:
        lowered, future = jobs.get()
        try:
            with _foreground:
                _foreground.wait_for(lambda: _foreground_compiles == 0)
            future.set_result(lowered.compile())
        except BaseException as exc:  # noqa: BLE001 - the job's future carries it
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
    `foreground_compile` runs. On the prefetch thread the compilation is handed to the
    compiling thread and None is returned: the prefetch thread goes on to trace the next
    job while XLA compiles this one (module docstring), and the job's future is set only
    once its compilations have ended. Elsewhere it compiles here and returns the result."""
    if threading.current_thread().name != _WORKER:
        with _foreground:
            _foreground.wait_for(lambda: _foreground_compiles == 0)
        return lowered.compile()
    global _compile_queue
    if _compile_queue is None:
        _compile_queue = queue.SimpleQueue()
        threading.Thread(target=_compiler, args=(_compile_queue,), daemon=True,
                         name=_COMPILER).start()
    future: Future = Future()
    _deferred.append(future)
    _compile_queue.put((lowered, future))
    return None


def in_background(job) -> Future:
    """Run `job()` (typically: build arguments, then
    `compile_in_background(jitted.lower(...))`) on the one prefetch thread, after any job
    queued before it; the future holds its result, set once the XLA compilations the job
    handed on have ended too. The threads are daemons: an exit never waits for them."""
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

