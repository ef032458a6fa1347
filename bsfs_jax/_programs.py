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
- the static arguments and the layout (tree structure, shapes, dtypes) of the traced ones.

A later process deserialises the program and compiles it, which jax's persistent cache
answers from disk. It is used only where jax's persistent cache is on (the CLI turns it on,
`cli._common.setup_jax`); otherwise, and wherever a program cannot be exported (a static
argument without a stable text, an output that is not built of tuples, lists and dicts of
arrays, an export error), the call is plain `filter_jit`, so results never depend on it.
A stale or unreadable file is exported again and replaced (written atomically).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import logging
import os
import re
import sys
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from jax import export

from ._files import write_bytes_atomic

_DISABLED = os.environ.get("BSFS_PROGRAM_CACHE", "1") == "0"
_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "diffrax", "numpy")
_ADDRESS = re.compile(r" at 0x[0-9a-f]+")
_log = logging.getLogger(__name__)
_loaded: dict[str, object] = {}  # key -> jitted caller of the deserialised program


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


def _stable_text(obj) -> str | None:
    """A text of `obj` that is the same in every process, or None (an object address)."""
    text = repr(obj)
    return None if _ADDRESS.search(text) else text


def _key(fn, static, treedef, leaves) -> str | None:
    static_text = _stable_text(jax.tree_util.tree_flatten(static))
    tree_text = _stable_text(treedef)
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
    return export.export(jax.jit(flat), disabled_checks=[
        export.DisabledSafetyCheck.custom_call(".*")])(*specs)


def _jit_call(exp, name: str):
    """The deserialised program as a jitted function named like the original (compile
    events and profiles then name it)."""
    def run(*xs):
        return exp.call(*xs)

    run.__name__ = run.__qualname__ = name
    return jax.jit(run)


def _caller(fn, static, treedef, leaves, key: str, folder: Path):
    path = folder / f"{key}.jaxexport"
    if path.exists():
        try:
            exp = export.deserialize(bytearray(path.read_bytes()))
            return _jit_call(exp, fn.__name__)
        except Exception:  # noqa: BLE001 - unreadable or stale: export it again
            pass
    exp = _export(fn, static, treedef, leaves)
    payload = exp.serialize()  # raises for an output tree it cannot write
    try:
        folder.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, bytes(payload))
    except OSError:
        pass  # a read-only cache: the program still runs
    return _jit_call(exp, fn.__name__)


def cached_jit(fn):
    """`equinox.filter_jit(fn)` whose traced programs are kept across processes (module
    docstring). Arrays are traced, everything else is static, as with `filter_jit`."""
    jitted = eqx.filter_jit(fn)
    failed: set[str] = set()

    def named() -> bool:
        # The key names the function: only a module-level function, found under its name.
        if "<" in fn.__qualname__ or "." in fn.__qualname__:
            return False
        return getattr(sys.modules.get(fn.__module__), fn.__qualname__, None) in (fn, call)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        folder = _program_dir()
        if folder is None or not named():
            return jitted(*args, **kwargs)
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(dynamic)
        key = _key(fn, static, treedef, leaves)
        if key is None:
            _log.debug("%s: arguments without a stable text, not kept", fn.__qualname__)
        if key is None or key in failed:
            return jitted(*args, **kwargs)
        caller = _loaded.get(key)
        if caller is None:
            try:
                caller = _caller(fn, static, treedef, leaves, key, folder)
            except Exception as exc:  # noqa: BLE001 - not exportable: the plain program
                _log.debug("%s not kept: %r", fn.__qualname__, exc)
                failed.add(key)
                return jitted(*args, **kwargs)
            _loaded[key] = caller
        return caller(*leaves)

    call.plain = jitted
    return call
