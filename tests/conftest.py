"""Global test configuration: 64-bit floats, strict rank promotion (as diffrax does)."""

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


# A test process started by `tests/run_each.py` (BSFS_TEST_FAST_EXIT=1) ends at once after
# pytest has reported and finished its session, with pytest's exit status: the
# interpreter's teardown (freeing every compiled program and array of the file) took about
# 3 s of a file such as test_periodic.py, out of the CI's time. Plain `pytest` exits as usual.
_SESSION = {}


def pytest_sessionfinish(session, exitstatus):
    _SESSION["status"] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if os.environ.get("BSFS_TEST_FAST_EXIT") == "1" and "status" in _SESSION:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os._exit(_SESSION["status"])
