"""Run each test file in its own pytest process (`make test`), two files at a time.

One process accumulating every compiled XLA program of the suite grew past 7 GB and once
crashed (a segmentation fault inside a compiled solve) on the 2-core CI machine; diffrax
runs its tests file by file for the same reason. Files run `BSFS_TEST_JOBS` at a time
(default: 2, or 1 on a one-core machine), the longest first, so that the 2-core CI machine
is kept busy (most of the suite's time is single-threaded XLA compilation). Each file's
output is printed whole when it ends. Arguments are passed on to pytest.
Exit status: 0 when every file passed, else 1 (the failing files are listed).
"""

import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

# Seconds per file on the 2-core machine (one at a time), to start the longest first.
_EXPECTED_S = {"test_identification.py": 480, "test_notebooks.py": 350, "test_design.py": 245,
               "test_periodic.py": 165, "test_verify.py": 85, "test_sweep.py": 85,
               "test_continuation.py": 75, "test_reproduce.py": 62, "test_simulate.py": 60}


def _run(path, extra, env):
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", str(path), *extra], env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return path, proc.returncode, proc.stdout, time.perf_counter() - t0


def main(argv=None) -> int:
    extra = list(sys.argv[1:] if argv is None else argv)
    files = sorted(Path(__file__).parent.glob("test_*.py"),
                   key=lambda p: (-_EXPECTED_S.get(p.name, 30), p.name))
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    jobs = int(os.environ.get("BSFS_TEST_JOBS", min(2, os.cpu_count() or 1)))
    failed = []
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        for path, code, output, seconds in pool.map(lambda p: _run(p, extra, env), files):
            print(output, end="", flush=True)
            print(f"== {path.name}: {'ok' if code in (0, 5) else 'FAILED'} ({seconds:.0f} s)",
                  flush=True)
            if code not in (0, 5):  # 5: no tests collected (e.g. all deselected)
                failed.append(path.name)
    total = time.perf_counter() - start
    if failed:
        print(f"FAILED files ({len(failed)}): {', '.join(failed)}; total {total:.0f} s")
        return 1
    print(f"all {len(files)} test files passed; total {total:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
