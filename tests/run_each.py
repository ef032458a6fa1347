"""Run each test file in its own pytest process (`make test`).

One process accumulating every compiled XLA program of the suite grew past 7 GB and once
crashed (a segmentation fault inside a compiled solve) on the 2-core CI machine; diffrax
runs its tests file by file for the same reason. Arguments are passed on to pytest.
Exit status: 0 when every file passed, else 1 (the failing files are listed).
"""

import os
import subprocess
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    extra = list(sys.argv[1:] if argv is None else argv)
    files = sorted(Path(__file__).parent.glob("test_*.py"))
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    failed = []
    start = time.perf_counter()
    for path in files:
        t0 = time.perf_counter()
        code = subprocess.call([sys.executable, "-m", "pytest", "-q", str(path), *extra],
                               env=env)
        print(f"== {path.name}: {'ok' if code in (0, 5) else 'FAILED'} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
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
