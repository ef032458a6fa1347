"""An atlas's rows as independent chunks run elsewhere (a Dask cluster, `bsfs_jax.cluster`).

Each row is one chunk: on the worker, `row_problem(y)`, the row's cold verified sweep
(the very function the local run calls, so the verdicts are the same) and
`row_bifurcations(y)`; the verdicts and points come back to the caller, which alone writes
the checkpoint. A row whose chunk failed on every attempt gets "unresolved" verdicts whose
reason names the cause, and is not checkpointed: a rerun computes it again.

`runner(fn, items)`: see `_remote.py` (`bsfs_jax.cluster.Cluster.run` is one; nothing here
imports the cluster layer).
"""

import functools

import numpy as np

from ._block_verdict import UNRESOLVED
from ._remote import cause_of, failure, run_elsewhere
from ._sweep import sweep
from ._verify_settings import VERDICT_FIELDS


def run_row(problem, x, config, verify, folder, shard):
    """Verdicts (dict of (Nx,) arrays) of one row by one cold verified sweep: the local
    run's row (`_atlas.atlas`), and a worker's."""
    res = sweep(problem, x, config=config, verify=verify, checkpoint_dir=folder,
                progress=False, shard=shard)
    return {k: np.asarray(v)[0] for k, v in res.verdicts.items() if k in VERDICT_FIELDS}


def _row_task(spec, y: float):
    """(verdicts of the row at y, what `row_bifurcations(y)` returns, or None): runs on a
    worker, the row's sweep by the local run's own function (`run_row`), and beside it on
    a thread, as the local run does, `row_bifurcations(y)` (host-driven continuation: the
    interpreter is free while XLA computes the sweep)."""
    from concurrent.futures import ThreadPoolExecutor

    row_problem, x, config, verify, row_bifurcations = spec
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="bsfs-row") as pool:
        found = None if row_bifurcations is None else pool.submit(row_bifurcations, y)
        verdicts = run_row(row_problem(y), x, config, verify, None, False)
        return verdicts, None if found is None else found.result()


def rows_elsewhere(runner, row_problem, x, y, rows, config, verify, row_bifurcations,
                   finish, progress: bool, desc: str) -> dict:
    """{row j: `finish(j, verdicts, found)` (which saves it), or the exception of a failed
    chunk} for `rows`; each row is finished as it comes back, with a progress bar."""
    from tqdm.auto import tqdm

    task = functools.partial(_row_task, (row_problem, x, config, verify, row_bifurcations))
    done = {}

    def save(j, out):
        done[j] = finish(j, *out)

    with tqdm(total=len(rows), unit="row", disable=not progress, desc=desc) as bar:
        got = run_elsewhere(runner, task, {j: float(y[j]) for j in rows}, save, bar)
    return {j: done.get(j, value) for j, value in got.items()}


def notes_apart(found) -> tuple:
    """(points, notes) of what `row_bifurcations` returned: points, or (points, notes)."""
    if isinstance(found, tuple) and len(found) == 2 and isinstance(found[1], list):
        return found[0], [str(n) for n in found[1]]
    return found, []


def _failed_row(template: dict, n: int, cause) -> dict:
    """Verdicts (n,) of a row whose chunk failed: unresolved, the reason naming `cause`,
    each array typed as `template`'s (a finished row)."""
    reason = f"not computed: the row's chunk failed ({cause_of(cause)})"
    out = {}
    for name, a in template.items():
        kind = np.asarray(a).dtype.kind
        if name == "motion":
            out[name] = np.full(n, UNRESOLVED)
        elif name == "reason":
            out[name] = np.full(n, reason)
        elif kind in "USO":
            out[name] = np.full(n, "")
        elif kind == "b":
            out[name] = np.zeros(n, dtype=bool)
        elif kind in "iu":
            out[name] = np.zeros(n, dtype=np.asarray(a).dtype)
        else:
            out[name] = np.full(n, np.nan, dtype=np.asarray(a).dtype)
    return out


def stack_rows(rows: list, failed: dict, n: int) -> dict:
    """{name: (rows, n) array} of the rows' verdicts, a failed row (None in `rows`, its
    exception in `failed`) unresolved; a RuntimeError where every row failed."""
    done = [r for r in rows if r is not None]
    if not done:
        first = failed[min(failed)]
        raise RuntimeError(f"every row of the atlas failed; the first: {first}")
    rows = [_failed_row(done[0], n, failed[j]) if r is None else r
            for j, r in enumerate(rows)]
    return {k: np.stack([np.asarray(r[k]) for r in rows]) for k in done[0]}


def failed_rows(failed: dict, y) -> list[dict]:
    """JSON-ready: the failed rows (`_remote.failure`, stage "row") with their causes."""
    return [failure("row", j, [y[j]], e) for j, e in sorted(failed.items())]
