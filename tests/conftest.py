"""Global test configuration: 64-bit floats, strict rank promotion (as diffrax does), and
XLA's earlier CPU fusion emitters, as the `bsfs` command uses them.

Importing bsfs changes nothing of the process (tests/test_host.py checks that in fresh
processes); the suite itself chooses the `bsfs` command's settings by the explicit
`bsfs_jax.use_fast_compilation()`: XLA's earlier fusion emitters and EQX_ON_ERROR=nan, under
which equinox's checks leave no host callback in a program, so that the test processes
share compiled programs through the persistent cache (a callback keeps a program out of it).
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# One BLAS thread: jaxlib's CPU linear algebra calls LAPACK from scipy's OpenBLAS, whose
# threads oversubscribe a small machine next to XLA's (a 199 x 199 LU measured 120 ms
# instead of 1 ms on the 2-core CI machine under load).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys

import jax
import pytest

jax.config.update("jax_enable_x64", True)
if os.environ.get("BSFS_CACHE_DIR"):  # CI: share compiled programs across test processes
    jax.config.update("jax_compilation_cache_dir", os.environ["BSFS_CACHE_DIR"])
    # every program, however short its compilation: thousands of small ones recur across
    # the files (the suite from an empty cache: 852 s against 973 s with a 0.5 s floor)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_numpy_rank_promotion", "raise")

from bsfs_jax import use_fast_compilation  # noqa: E402 - importing bsfs changes nothing

# XLA's earlier CPU fusion emitters for the test processes, as the `bsfs` command uses them
# (about a quarter fewer XLA seconds): the suite's own choice, made here, before any test
# file computes (XLA reads XLA_FLAGS when jax starts its backend); not where XLA_FLAGS names
# the option or BSFS_XLA_DEFAULTS=0; EQX_ON_ERROR=nan where the environment leaves it unset.
_XLA_FLAGS_BEFORE = os.environ.get("XLA_FLAGS")
_XLA_FLAGS_CHOSEN = use_fast_compilation().get("XLA_FLAGS")


def use_xla_default_code() -> bool:
    """For a file measured against XLA's default CPU code (`test_lanes.py`), at its import:
    take back the suite's choice of XLA_FLAGS above where jax has not started its backend
    yet (the file is the first of its process to compute, as in a process of its own).
    Whether the process runs XLA's default CPU code."""
    from jax._src import xla_bridge

    if (_XLA_FLAGS_CHOSEN is not None and os.environ.get("XLA_FLAGS") == _XLA_FLAGS_CHOSEN
            and not xla_bridge.backends_are_initialized()):
        if _XLA_FLAGS_BEFORE is None:
            del os.environ["XLA_FLAGS"]
        else:
            os.environ["XLA_FLAGS"] = _XLA_FLAGS_BEFORE
    return "xla_cpu_use_fusion_emitters=false" not in os.environ.get("XLA_FLAGS", "")


# `tests/run_each.py` names a file per test process (BSFS_TEST_COMPILE_STATS): the seconds
# jax spent tracing, lowering and compiling (its compile events; XLA's seconds include the
# persistent cache's reads, and "programs" the executables read from it, "cache_hits"),
# written at the session's end, so that the record shows where the suite's time goes.
_COMPILE = {"programs": 0, "compile_s": 0.0, "trace_s": 0.0, "lower_s": 0.0,
            "cache_hits": 0}
_EVENTS = {"/jax/core/compile/backend_compile_duration": "compile_s",
           "/jax/core/compile/jaxpr_trace_duration": "trace_s",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s"}
_BY_PROGRAM: dict = {}  # function name -> [XLA s, tracing s, executables]
_TOP_PROGRAMS = 12  # per file, by XLA + tracing seconds


def _on_compile_event(event, seconds, **kwargs):
    name = _EVENTS.get(event)
    if name is not None:
        _COMPILE[name] += seconds
        _COMPILE["programs"] += name == "compile_s"  # compiled, or read from the cache
        if name != "lower_s":
            fun = str(kwargs.get("fun_name", "?"))  # XLA's events say "jit(name)"
            fun = fun[4:-1] if fun.startswith("jit(") and fun.endswith(")") else fun
            row = _BY_PROGRAM.setdefault(fun, [0.0, 0.0, 0])
            row[0 if name == "compile_s" else 1] += seconds
            row[2] += name == "compile_s"
    elif event == "/jax/compilation_cache/cache_retrieval_time_sec":
        _COMPILE["cache_hits"] += 1


if os.environ.get("BSFS_TEST_COMPILE_STATS"):
    jax.monitoring.register_event_duration_secs_listener(_on_compile_event)


# A test process started by `tests/run_each.py` (BSFS_TEST_FAST_EXIT=1) ends at once after
# pytest has reported and finished its session, with pytest's exit status: the
# interpreter's teardown (freeing every compiled program and array of the file) took about
# 3 s of a file such as test_periodic.py, out of the CI's time. Plain `pytest` exits as usual.
_SESSION = {}


def pytest_sessionfinish(session, exitstatus):
    _SESSION["status"] = int(exitstatus)
    path = os.environ.get("BSFS_TEST_COMPILE_STATS")
    if path:
        import json

        top = sorted(_BY_PROGRAM.items(), key=lambda kv: -(kv[1][0] + kv[1][1]))
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(dict({k: round(v, 2) for k, v in _COMPILE.items()}, top_programs={
                name: {"compile_s": round(c, 2), "trace_s": round(t, 2), "executables": n}
                for name, (c, t, n) in top[:_TOP_PROGRAMS]}), fh)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if os.environ.get("BSFS_TEST_FAST_EXIT") == "1" and "status" in _SESSION:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os._exit(_SESSION["status"])
