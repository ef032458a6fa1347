"""Compiled programs that a warm run neither traces nor compiles again.

jax's persistent compilation cache skips XLA's compilation on a second run, but not the
tracing in Python that comes before it: on the bundled through-resonance identification
the warm run spent 13 of its 19.5 s tracing (optimistix's solve with the periodic-orbit
model, the branch kernel), against 1.5 s running the programs.

`cached_jit(fn)` is `equinox.filter_jit(fn)` that also keeps each traced program, as
`jax.export` serialises it, in `<compilation cache dir>/programs/`, keyed by

- the function (module and name) and a digest of the source files of its package and of
  `bsfs_jax` (any edit of the code makes new keys),
- the versions of jax, jaxlib and the numerical libraries, the backend, 64-bit mode, the
  default matmul precision and `EQX_ON_ERROR` (equinox's runtime checks),
- the static arguments and the layout (tree structure, shapes, dtypes) of the traced ones;
  a static function of bsfs_jax (a sweep problem's vector field) by its module and name,
  its code being in the digest; a program with any other function is not kept.

A later process deserialises the program and compiles it, which jax's persistent cache
answers from disk. It is used only where jax's persistent cache is on (the CLI turns it on,
`cli._common.setup_jax`); otherwise, and wherever a program cannot be exported (a static
argument without a stable text, an output that is not built of tuples, lists and dicts of
arrays, a host callback such as equinox's runtime checks make under its default
`EQX_ON_ERROR=raise`, an export error), the call is plain `filter_jit`, so results never
depend on it.
A stale or unreadable file is exported again and replaced (written atomically).

Prefetches (`cached_jit`'s `prefetch`) run on the background thread of `_prefetch`.

`cached_jit(fn, fast_compile=True)` compiles the kept program with XLA's backend (LLVM)
optimisation at level 1 instead of 2: for a large program that runs for a fraction of a
second (the identification's solve and branch check) XLA's compilation is about 15 %
shorter (6.4 -> 5.4 s and 4.8 -> 4.1 s) and the run no slower. The results agree with
level 2's to rounding (an identification's report to 1e-14 relative). The plain
`filter_jit` path compiles as usual.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.metadata
import inspect
import logging
import os
import re
import sys
import threading
from concurrent.futures import Future
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from jax import export

from ._files import write_bytes_atomic
from ._prefetch import (  # noqa: F401 - re-exported: the prefetch API lives here too
    compile_in_background,
    foreground_compile,
    hand_off,
    in_background,
    prefetch_jit,
    settle,
    start_at_next_hand_off,
)

_DISABLED = os.environ.get("BSFS_PROGRAM_CACHE", "1") == "0"
_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "diffrax", "numpy")
_ADDRESS = re.compile(r" at 0x[0-9a-f]+")
_log = logging.getLogger(__name__)
_loaded: dict[str, object] = {}  # key -> jitted caller of the deserialised program
_pending: dict[str, Future] = {}  # key -> a prefetch's future caller (`prefetch`)
# One export at a time: two threads exporting at once made one fail inside jax
# ("StoreException: Store occupied"; the continuation's corrector was then not kept).
_export_lock = threading.Lock()
# Keys being obtained by a thread (`cached_jit`'s `obtain`): another thread that needs the
# same program waits for it instead of exporting and compiling it a second time (the
# rows of `bsfs map` continue on two threads with one corrector).
_obtaining: dict[str, Future] = {}
_obtaining_lock = threading.Lock()


@functools.cache
def _package_digest(package: str) -> str:
    root = Path(sys.modules[package].__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


@functools.cache
def _environment() -> str:
    versions = []
    for name in _LIBRARIES:
        try:
            versions.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name}=none")
    return ";".join(versions)


def _program_dir() -> Path | None:
    if _DISABLED:
        return None
    root = jax.config.jax_compilation_cache_dir
    return Path(root) / "programs" if root else None


def _stable_text(obj, names: dict | None = None) -> str | None:
    """A text of `obj` that is the same in every process, or None (an object address).
    `names`: {a function's repr: its stable name} to substitute first (`_own_functions`)."""
    text = repr(obj)
    for old, new in (names or {}).items():
        text = text.replace(old, new)
    return None if _ADDRESS.search(text) else text


def _own_functions(obj, found: dict | None = None, depth: int = 0) -> dict:
    """{repr: stable name} of the module-level functions of bsfs_jax in `obj` (a static
    part: its leaves, and the fields of the equinox Modules and dataclasses in it, where
    a sweep problem keeps its vector field). Their code is in the key's digest of the
    package, so the name is enough; any other function keeps its address and the program
    is not kept."""
    found = {} if found is None else found
    if depth > 8:
        return found
    if inspect.isfunction(obj):
        mod, name = obj.__module__ or "", obj.__qualname__
        if (mod == "bsfs_jax" or mod.startswith("bsfs_jax.")) and "<" not in name \
                and getattr(sys.modules.get(mod), name, None) is obj:
            found[repr(obj)] = f"<function {mod}.{name}>"
    elif isinstance(obj, list | tuple):
        for x in obj:
            _own_functions(x, found, depth + 1)
    elif isinstance(obj, dict):
        for x in obj.values():
            _own_functions(x, found, depth + 1)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            _own_functions(getattr(obj, f.name, None), found, depth + 1)
    return found


def _key(fn, static, treedef, leaves) -> str | None:
    names = _own_functions(static)
    static_text = _stable_text(jax.tree_util.tree_flatten(static), names)
    tree_text = _stable_text(treedef, names)
    if static_text is None or tree_text is None:
        return None
    package = fn.__module__.split(".")[0]
    h = hashlib.sha256()
    for part in (fn.__module__, fn.__qualname__, _package_digest("bsfs_jax"),
                 _package_digest(package) if package in sys.modules else "",
                 _environment(), jax.default_backend(), str(jax.config.jax_enable_x64),
                 str(jax.config.jax_default_matmul_precision),
                 os.environ.get("EQX_ON_ERROR", ""),  # read by equinox while tracing
                 static_text, tree_text,
                 repr([(np.shape(x), str(x.dtype), _weak(x)) for x in leaves])):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def _weak(x) -> bool:
    return bool(getattr(x, "weak_type", False))


def _export(fn, static, treedef, leaves):
    def flat(*xs):
        args, kwargs = eqx.combine(jax.tree_util.tree_unflatten(treedef, xs), static)
        return fn(*args, **kwargs)

    flat.__name__ = flat.__qualname__ = fn.__name__
    specs = [jax.ShapeDtypeStruct(np.shape(x), x.dtype, weak_type=_weak(x))
             for x in leaves]
    # Only this jax version ever reads the file back: custom calls without a
    # cross-version guarantee (LAPACK on CPU) are fine.
    with _export_lock:
        return export.export(jax.jit(flat), disabled_checks=[
            export.DisabledSafetyCheck.custom_call(".*")])(*specs)


#: XLA's options for `cached_jit(..., fast_compile=True)` (module docstring).
FAST_COMPILE = {"xla_backend_optimization_level": 1}
#: XLA's options for `cached_jit(..., runs_long=True)`: the CPU compiler's newer fusion
#: emitters, which the `bsfs` command (and `use_fast_compilation`, `bsfs_jax/_host.py`)
#: turns off for every other program: they take longer to compile and give faster code,
#: which pays only where a program runs for seconds (a continuation's corrector called a
#: thousand times).
RUNS_LONG = {"xla_cpu_use_fusion_emitters": True}


def _jit_call(exp, name: str, options: dict | None = None):
    """The deserialised program as a jitted function named like the original (compile
    events and profiles then name it), compiled with XLA `options`."""
    def run(*xs):
        return exp.call(*xs)

    run.__name__ = run.__qualname__ = name
    return jax.jit(run, compiler_options=options)


def _caller(fn, static, treedef, leaves, key: str, folder: Path, options=None):
    path = folder / f"{key}.jaxexport"
    if path.exists():
        try:
            exp = export.deserialize(bytearray(path.read_bytes()))
            return _jit_call(exp, fn.__name__, options)
        except Exception:  # noqa: BLE001 - unreadable or stale: export it again
            pass
    exp = _export(fn, static, treedef, leaves)
    payload = exp.serialize()  # raises for an output tree it cannot write
    try:
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, bytes(payload))
    except OSError:
        pass  # a read-only cache: the program still runs
    return _jit_call(exp, fn.__name__, options)



def cached_jit(fn=None, *, fast_compile: bool = False, runs_long: bool = False):
    """`equinox.filter_jit(fn)` whose traced programs are kept across processes (module
    docstring). Arrays are traced, everything else is static, as with `filter_jit`.
    `fast_compile`: XLA's backend optimisation at level 1 (`FAST_COMPILE`) for the kept
    program; `runs_long`: XLA's newer CPU fusion emitters (`RUNS_LONG`) for the kept
    program. (A caller that compiles the plain program itself passes the same options to
    its own jit, as the continuation's `_compiled` does.) Use as `@cached_jit` or
    `@cached_jit(fast_compile=True)`."""
    if fn is None:
        return functools.partial(cached_jit, fast_compile=fast_compile, runs_long=runs_long)
    options = {**(FAST_COMPILE if fast_compile else {}),
               **(RUNS_LONG if runs_long else {})} or None
    jitted = eqx.filter_jit(fn)
    failed: set[str] = set()

    def named() -> bool:
        # The key names the function: only a module-level function, found under its name.
        if "<" in fn.__qualname__ or "." in fn.__qualname__:
            return False
        return getattr(sys.modules.get(fn.__module__), fn.__qualname__, None) in (fn, call)

    def prepare(args, kwargs):
        """(key, static, treedef, leaves, folder) of a call, or None: the plain program."""
        folder = _program_dir()
        if folder is None or not named():
            return None
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dynamic)
        key = _key(fn, static, treedef, leaves)
        if key is None:
            _log.debug("%s: arguments without a stable text, not kept", fn.__qualname__)
        if key is None or key in failed:
            return None
        return key, static, treedef, leaves, folder

    def obtain(prep):
        """The kept program's caller for a prepared call, compiled for its arguments, or
        None (not exportable). One thread obtains a key at a time; the others wait."""
        key = prep[0]
        caller = _loaded.get(key)
        if caller is not None:
            return caller
        with _obtaining_lock:
            running = _obtaining.get(key)
            if running is None:
                mine = _obtaining[key] = Future()
        if running is not None:
            return running.result()
        caller = None
        try:
            caller = obtain_here(prep)
        finally:
            if caller is not None:
                _loaded[key] = caller  # compiled: other threads may call it now
            with _obtaining_lock:
                del _obtaining[key]
            mine.set_result(caller)
        return caller

    def obtain_here(prep):
        key, static, treedef, leaves, folder = prep
        if key in _pending:
            hand_off()  # the prefetch may still be waiting for this thread
            try:  # a prefetch of this program: wait for it rather than compile it twice
                return _pending.pop(key).result()  # compiled by the prefetch
            except Exception as exc:  # noqa: BLE001 - the usual way below
                _log.debug("%s: prefetch failed: %r", fn.__qualname__, exc)
        try:
            caller = _caller(fn, static, treedef, leaves, key, folder, options)
        except Exception as exc:  # noqa: BLE001 - not exportable: the plain program
            _log.debug("%s not kept: %r", fn.__qualname__, exc)
            failed.add(key)
            return None
        hand_off()
        try:
            with foreground_compile():  # here, once (jit's cache: the call finds it)
                caller.lower(*leaves).compile()
        except Exception as exc:  # noqa: BLE001 - the call compiles it (or fails) itself
            _log.debug("%s: compile failed here: %r", fn.__qualname__, exc)
        return caller

    @functools.wraps(fn)
    def call(*args, **kwargs):
        prep = prepare(args, kwargs)
        caller = None if prep is None else obtain(prep)
        return jitted(*args, **kwargs) if caller is None else caller(*prep[3])

    def bind(*args, **kwargs):
        """For many calls whose arrays change but whose static parts and layout do not
        (a continuation's corrector): the kept program as a function of the flat array
        leaves of `(args, kwargs)` (`jax.tree_util.tree_leaves` order), obtained once, so
        that each call skips the key and the partition; None where the plain program is
        used (then call `call` or a jit of your own)."""
        prep = prepare(args, kwargs)
        return None if prep is None else obtain(prep)

    def prefetch(*args, **kwargs) -> bool:
        """Trace, export and compile the program of `call(*args, **kwargs)` on a
        background thread, so that the call later finds it ready (it waits if the work is
        still under way, and never does it twice). The work starts when this thread next
        hands a newly traced program to XLA: tracing is Python and holds the interpreter,
        while XLA's compilation leaves it free, so the prefetch's tracing runs on the
        second core beside that compilation rather than slowing the tracing in front of
        it. The values of the arrays do not matter, only their layout. Returns
        whether a prefetch was started (not where the plain program is used, or the
        program is loaded or pending already)."""
        prep = prepare(args, kwargs)
        return False if prep is None else _prefetch(prep, wait=True)

    def prefetch_now(*args, **kwargs) -> bool:
        """`prefetch` that starts at once, for a program the main thread needs only after
        work that is not a kept program's compilation (a continuation running)."""
        prep = prepare(args, kwargs)
        return False if prep is None else _prefetch(prep, wait=False)

    def keeps(*args, **kwargs) -> bool:
        """Whether `call(*args, **kwargs)` runs a kept program (else the plain `filter_jit`
        one, which `prefetch` does not compile: see `prefetch_jit`)."""
        return prepare(args, kwargs) is not None

    def _prefetch(prep, wait: bool) -> bool:
        key, static, treedef, leaves, folder = prep
        if key in _loaded or key in _pending:
            return False
        start = threading.Event()
        if wait:
            start_at_next_hand_off(start)
        else:
            start.set()

        def job():
            start.wait()
            caller = _caller(fn, static, treedef, leaves, key, folder, options)
            # the call's own executable (jit's cache)
            compile_in_background(caller.lower(*leaves))
            return caller

        _pending[key] = in_background(job)
        return True

    call.plain = jitted
    call.bind = bind
    call.prefetch = prefetch
    call.prefetch_now = prefetch_now
    call.keeps = keeps
    return call
