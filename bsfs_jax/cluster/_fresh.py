"""A chunk in a fresh process of its worker, for jobs whose memory grows from chunk to chunk.

A process keeps every program it compiled or loaded (jax's caches, bsfs's kept programs);
a long study of forecasts, each continuing its own FRC, grew a process past 24 GB in 13 of
them. `in_fresh_process(payload, item)` runs `fn(item)` (`payload`: `fn` pickled by
cloudpickle) in a new Python process started by the worker, with the worker's settings
and compilation cache (`ready`), and returns its value; the memory goes with the process.
The programs come back from the shared compilation cache, a few seconds a chunk.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

_CHILD = "from bsfs_jax.cluster._fresh import child_main; child_main()"


def in_fresh_process(payload: bytes, item, cache: str | None = None):
    """`fn(item)` in a new process (`payload` = cloudpickle.dumps(fn)); its error, if it
    raises, as a RuntimeError with the child's last line."""
    proc = subprocess.run([sys.executable, "-c", _CHILD],
                          input=pickle.dumps((payload, pickle.dumps(item), cache)),
                          capture_output=True, env=dict(os.environ))
    if proc.returncode != 0:
        lines = proc.stderr.decode(errors="replace").strip().splitlines()
        raise RuntimeError(f"the chunk's process exited {proc.returncode}: "
                           f"{lines[-1] if lines else 'no message'}")
    return pickle.loads(proc.stdout)


def child_main() -> None:
    """The fresh process: read (payload, pickled item, cache) from stdin, choose the
    worker's settings, then unpickle the item (a jax array in it keeps its float64:
    `_plugin`'s docstring) and write pickle(fn(item)) to stdout (the function's own prints
    go to stderr)."""
    payload, item, cache = pickle.loads(sys.stdin.buffer.read())
    out = sys.stdout.buffer
    sys.stdout = sys.stderr  # prints of the chunk must not mix with its result
    from ._worker import ready

    ready(cache)
    fn, item = pickle.loads(payload), pickle.loads(item)
    out.write(pickle.dumps(fn(item)))
    out.flush()
