"""Two-parameter atlases: one verified cold sweep per row, bifurcation curves across rows.

An atlas maps the verified motion (period-n, quasi-periodic, chaotic; else "unresolved"
with the reason) and the amplitude over a grid (y, x): each row fixes the second parameter
y and sweeps the problem's own parameter x (`sweep(..., verify=...)`: vectorised, sharded
and checkpointed per chunk). Optionally each row also gives the bifurcation points of its
periodic branch (e.g. by continuation); `Atlas.curves` joins them across rows into
polylines (fold, period-doubling, Neimark-Sacker): the codim-2 curves sampled row by row
from codim-1 runs, not continued in two parameters (cf. BifurcationKit's codim-2 runs).

Generic over any `SweepProblem`; nothing here knows the ball screw.
"""

import datetime
import hashlib
import json
import re
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._files import ChunkCheckpoint, jsonable
from ._atlas_grid import grid_problem
from ._atlas_remote import failed_rows, notes_apart, rows_elsewhere, run_row, stack_rows
from ._atlas_result import _POINT_KEYS, BIFURCATION_KINDS, Atlas
from ._sweep import sweep
from ._sweep_problem import SweepConfig
from ._verify_settings import VERDICT_FIELDS, VerifySettings


def _row_fingerprint(problem, x, y, config, verify, bif) -> str:
    import equinox as eqx
    import jax

    h = hashlib.sha256()
    leaves, treedef = jax.tree_util.tree_flatten(eqx.filter(problem, eqx.is_array))
    h.update(re.sub(r" at 0x[0-9a-fA-F]+", "", str(treedef)).encode())
    for leaf in leaves:
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    for part in (getattr(problem.vector_field, "__qualname__", ""), problem.param,
                 re.sub(r" at 0x[0-9a-fA-F]+", "", repr(problem.setup)),
                 json.dumps(jsonable(config.to_dict()), sort_keys=True),
                 json.dumps(jsonable(verify.to_dict()), sort_keys=True),
                 "" if bif is None else getattr(bif, "__qualname__", "bifurcations")):
        h.update(part.encode())
    h.update(np.ascontiguousarray(x, dtype=float).tobytes() + np.float64(y).tobytes())
    return h.hexdigest()[:24]


#: Worker threads for the rows' bifurcation runs beside the sweeps (`_rows_in_background`).
ROW_WORKERS = 2


def _row_done(data, fingerprint) -> bool:
    return data is not None and str(data.get("fingerprint")) == fingerprint


@contextmanager
def _rows_in_background(row_bifurcations, y, rows):
    """{row: future of `row_bifurcations(y[row])`} for `rows`, run by `ROW_WORKERS`
    threads while the caller runs the verified sweeps: the bifurcation runs are
    host-driven continuations whose every step is a compiled program, and XLA leaves
    Python's interpreter free while it computes, so both cores work. On leaving, the
    runs not started are cancelled and the running ones awaited."""
    if row_bifurcations is None or not rows:
        yield {}
        return
    pool = ThreadPoolExecutor(max_workers=ROW_WORKERS, thread_name_prefix="bsfs-row")
    try:
        yield {j: pool.submit(row_bifurcations, float(y[j])) for j in rows}
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _check_bifurcations(found, y) -> list:
    out = []
    for b in found or []:
        if not all(k in b for k in _POINT_KEYS) or b["kind"] not in BIFURCATION_KINDS:
            raise ValueError(f"row_bifurcations({y}) must return dicts with keys {_POINT_KEYS}"
                             f" and kind in {BIFURCATION_KINDS}, got {b}")
        out.append({**jsonable(dict(b)), "x": float(b["x"]), "y": float(y),
                    "amplitude": float(b["amplitude"])})
    return out


def _run_grid(problems, x, config, verify, folder, shard, progress, prints, pending) -> dict:
    """{row: verdicts} of the rows `pending` (not yet checkpointed), by one sweep of all
    their points; empty where fewer than two rows are left or they cannot be stacked."""
    problem = grid_problem([problems[j] for j in pending], x) if len(pending) > 1 else None
    if problem is None:
        return {}
    tag = hashlib.sha256(",".join(prints[j] for j in pending).encode()).hexdigest()[:12]
    res = sweep(problem, np.arange(len(pending) * x.size, dtype=float), config=config,
                verify=verify, progress=progress,
                checkpoint_dir=None if folder is None else folder / f"grid_{tag}", shard=shard)
    out = {k: np.asarray(v)[0].reshape(len(pending), x.size)
           for k, v in res.verdicts.items() if k in VERDICT_FIELDS}
    return {j: {k: v[r] for k, v in out.items()} for r, j in enumerate(pending)}


def atlas(row_problem, x_values, y_values, *, y_name: str, y_unit: str = "",
          config: SweepConfig = SweepConfig(), verify: VerifySettings = VerifySettings(),
          checkpoint_dir=None, progress: bool = True, shard=False, row_bifurcations=None,
          metadata: dict | None = None, x_label: str = "", y_label: str = "",
          batch: str = "auto", runner=None) -> Atlas:
    """Verified motion and amplitude over the grid `y_values` x `x_values`.

    **Main arguments:**
    - `row_problem(y) -> SweepProblem`: the problem of one row, the second parameter fixed
      at y; x is the problem's swept parameter (`problem.param`, `problem.unit`).
    - `x_values`, `y_values`: 1-D grids; `y_name`, `y_unit`: the second parameter.
    - `config`, `verify`: the `SweepConfig` and `VerifySettings` of every row's cold sweep.

    **Other arguments:**
    - `checkpoint_dir`: row j's sweep checkpoints its chunks in `row_{j:04d}/`; each
      finished row (verdicts and bifurcations) is saved there too, so a rerun with the same
      folder and inputs loads finished rows and computes only the rest
      (`metadata["rows_computed_this_run"]`); a folder of another atlas is refused.
    - `progress`: a tqdm bar over rows; `shard`: as for `sweep`.
    - `row_bifurcations(y) -> [{"x", "kind", "amplitude", ...}]`: bifurcation points of row
      y (kind "fold", "period-doubling", "neimark-sacker" or "branch-point"); called from
      `ROW_WORKERS` worker threads while the sweeps run, so it must be thread-safe.
    - `metadata`: JSON-able entries kept in the atlas; `x_label`, `y_label`: names in words.
    - `batch`: "rows" (one sweep per row), "grid" (the rows still to compute as one sweep
      of all their points, `_atlas_grid.py`: one batch, sharded like any sweep; where the
      rows differ in more than their arrays, row by row), or "auto" (the default: "grid"
      where the sweep engine is the kernel, i.e. on a GPU, else "rows").
    - `runner(fn, items)`: run the rows still to compute elsewhere, one chunk per row
      (`_atlas_remote.py`; `bsfs_jax.cluster.Cluster.run` on a Dask cluster): the same
      sweep per row as here, the rows saved here as they come back; a row whose chunk
      failed is unresolved with the cause (`metadata["failed_rows"]`) and not saved.
      `row_problem` and `row_bifurcations` must then be picklable (cloudpickle).

    `row_bifurcations(y)` may also return `(points, notes)`: notes (strings) about the
    row, kept with the row's checkpoint and gathered in `metadata["row_notes"]`.
    """
    if batch not in ("auto", "rows", "grid"):
        raise ValueError(f"batch must be 'auto', 'rows' or 'grid', got {batch!r}")
    if runner is not None and (shard or batch == "grid"):
        raise ValueError("runner= computes the rows elsewhere, one chunk per row: not with "
                         "shard or batch='grid'")
    x = np.asarray(x_values, dtype=float)
    y = np.asarray(y_values, dtype=float)
    for name, v in (("x_values", x), ("y_values", y)):
        if v.ndim != 1 or v.size < 1 or not np.all(np.isfinite(v)):
            raise ValueError(f"{name} must be a non-empty 1-D array of finite numbers")
    problems = [row_problem(float(v)) for v in y]
    p0 = problems[0]
    if y_name == p0.param:
        raise ValueError(f"x and y are the same parameter '{y_name}'")
    prints = [_row_fingerprint(p, x, v, config, verify, row_bifurcations)
              for p, v in zip(problems, y, strict=True)]
    folder = None if checkpoint_dir is None else Path(checkpoint_dir)
    whole = hashlib.sha256(",".join(prints).encode()).hexdigest()[:24]
    ckpt = ChunkCheckpoint(folder, whole, y.size, prefix="atlas_row")
    from tqdm.auto import tqdm

    rows, bifs, notes, computed = [], [], [], 0
    saved = [ckpt.load(j) for j in range(y.size)]  # finished rows (a resumed run)
    todo = [j for j in range(y.size) if not _row_done(saved[j], prints[j])]

    def finish(j, verdicts, found):
        """The row's checkpoint data (saved here, by this process alone)."""
        found, said = notes_apart(found)
        found = [] if row_bifurcations is None else _check_bifurcations(found, y[j])
        data = {k: (v.astype(str) if v.dtype.kind in "USO" else v)
                for k, v in verdicts.items()}
        data.update(fingerprint=np.array(prints[j]), bifurcations=np.array(json.dumps(found)),
                    notes=np.array(json.dumps(said)))
        ckpt.save(j, data)
        return data

    failed = {}
    if runner is not None and todo:
        for j, data in rows_elsewhere(runner, row_problem, x, y, todo, config, verify,
                                      row_bifurcations, finish, progress,
                                      f"atlas {y_name}").items():
            if isinstance(data, BaseException):
                failed[j] = data
            else:
                saved[j], computed = data, computed + 1
        todo = []
    with _rows_in_background(row_bifurcations, y, todo) as found_later:
        grid = {}
        if todo and (batch == "grid" or (batch == "auto"
                                         and p0.resolved_engine(config) == "kernel")):
            grid = _run_grid(problems, x, config, verify, folder, shard, progress, prints,
                             todo)
        for j in tqdm(range(y.size), unit="row", disable=not progress or bool(grid)
                      or runner is not None, desc=f"atlas {y_name}"):
            if j in failed:
                rows.append(None)
                continue
            data = saved[j]
            if not _row_done(data, prints[j]):
                computed += 1
                sub = None if folder is None else folder / f"row_{j:04d}"
                verdicts = grid[j] if j in grid else run_row(problems[j], x, config,
                                                              verify, sub, shard)
                data = finish(j, verdicts, None if row_bifurcations is None else
                              found_later[j].result() if j in found_later else
                              row_bifurcations(float(y[j])))
            bifs += json.loads(str(data["bifurcations"]))
            notes += json.loads(str(data["notes"])) if "notes" in data else []
            rows.append({k: v for k, v in data.items() if k not in ("fingerprint",
                                                                     "bifurcations", "notes")})
    verdicts = stack_rows(rows, failed, x.size)
    _, units = p0.labels()
    meta = {"created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "fingerprint": whole, "rows": int(y.size), "rows_computed_this_run": computed,
            "rows_batched_as_one_grid": len(grid),
            "vector_field": getattr(p0.vector_field, "__qualname__", "")}
    if notes:
        meta["row_notes"] = notes
    if failed:
        meta["failed_rows"] = failed_rows(failed, y)
    meta.update(metadata or {})
    return Atlas(x_name=p0.param, x_unit=p0.unit, y_name=y_name, y_unit=y_unit, x=x, y=y,
                 verdicts=verdicts, bifurcations=bifs, x_label=x_label, y_label=y_label,
                 amplitude_unit=units[p0.observe], time_unit=p0.time_unit,
                 config=jsonable(config.to_dict()), verify=jsonable(verify.to_dict()),
                 metadata=meta)
