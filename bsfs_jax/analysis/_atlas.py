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

import dataclasses
import datetime
import hashlib
import json
import re
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._files import ChunkCheckpoint, jsonable, open_netcdf, save_netcdf_atomic
from ._atlas_grid import grid_problem
from ._atlas_remote import failed_rows, notes_apart, rows_elsewhere, run_row, stack_rows
from ._sweep import sweep
from ._sweep_problem import SweepConfig
from ._verify import UNRESOLVED, VERDICT_FIELDS, VerifySettings

FORMAT = "bsfs-atlas-1"  # the `format` attribute of atlas files
BIFURCATION_KINDS = ("fold", "period-doubling", "neimark-sacker", "branch-point")
_POINT_KEYS = ("x", "kind", "amplitude")


@dataclasses.dataclass
class Atlas:
    """Verdicts of a (y, x) parameter grid.

    - `x_name`, `x_unit`, `x` (Nx,): the parameter each row sweeps; `y_name`, `y_unit`,
      `y` (Ny,): the parameter fixed per row; `x_label`, `y_label`: names in words.
    - `verdicts`: {name: (Ny, Nx) array} with the keys of `VERDICT_FIELDS` (motion and
      reason str, verified bool, period_n int, the rest float); each is also an attribute
      (`atlas.motion`, `atlas.amplitude`, ...).
    - `bifurcations`: list of {"x", "y", "kind", "amplitude", ...} from the rows.
    - `amplitude_unit`, `time_unit`: units of the amplitude and of `transient`.
    - `config`, `verify`, `metadata`: settings (JSON-able dicts).
    """

    x_name: str
    x_unit: str
    y_name: str
    y_unit: str
    x: np.ndarray
    y: np.ndarray
    verdicts: dict
    bifurcations: list = dataclasses.field(default_factory=list)
    x_label: str = ""
    y_label: str = ""
    amplitude_unit: str = ""
    time_unit: str = ""
    config: dict = dataclasses.field(default_factory=dict)
    verify: dict = dataclasses.field(default_factory=dict)
    metadata: dict = dataclasses.field(default_factory=dict)

    def __getattr__(self, name):
        verdicts = self.__dict__.get("verdicts")
        if verdicts is not None and name in verdicts:
            return verdicts[name]
        raise AttributeError(f"'Atlas' object has no attribute '{name}'")

    @property
    def shape(self) -> tuple:
        return (np.size(self.y), np.size(self.x))

    def curves(self, tol_steps: float = 3.0) -> list[dict]:
        """Bifurcation points of one kind in adjacent rows joined into polylines.

        Row by row, the points of a kind are joined to the end points of the previous row's
        curves of that kind within `tol_steps` grid steps of x: as many pairs as possible,
        without crossing (curves of one kind keep their order in x between two rows),
        then the nearest; the others start new curves. Returns
        [{"kind", "x": [...], "y": [...], "amplitude": [...]}], single points included.
        """
        dx = float(np.median(np.abs(np.diff(self.x)))) if np.size(self.x) > 1 else np.inf
        out = []
        for kind in sorted({b["kind"] for b in self.bifurcations}):
            rows = {}
            for b in self.bifurcations:
                if b["kind"] == kind:
                    j = int(np.argmin(np.abs(np.asarray(self.y) - b["y"])))
                    rows.setdefault(j, []).append(b)
            open_ = []  # curves ending in the previous row, sorted by x
            for j in range(np.size(self.y)):
                pts = sorted(rows.get(j, []), key=lambda b: b["x"])
                pairs = dict(_match([c["x"][-1] for c in open_], [p["x"] for p in pts],
                                    tol_steps * dx))
                now = []
                for a, p in enumerate(pts):
                    c = open_[pairs[a]] if a in pairs else {"kind": kind, "x": [], "y": [],
                                                           "amplitude": []}
                    if a not in pairs:
                        out.append(c)
                    c["x"].append(float(p["x"]))
                    c["y"].append(float(p["y"]))
                    c["amplitude"].append(float(p.get("amplitude", np.nan)))
                    now.append(c)
                open_ = now
        return out

    def summary(self, points: bool = True) -> dict:
        """JSON-ready: counts per motion class, verified fraction, the reasons of the
        unresolved points tallied (numbers replaced by '#'), bifurcation curves and (with
        `points`) every point with its evidence."""
        motion, v = np.asarray(self.motion), self.verdicts
        reasons = Counter(re.sub(r"-?\d+(\.\d+)?(e[-+]?\d+)?", "#", str(r))
                          for r in np.asarray(v["reason"])[motion == UNRESOLVED])
        out = {
            "x_name": self.x_name, "x_unit": self.x_unit, "y_name": self.y_name,
            "y_unit": self.y_unit, "x": self.x, "y": self.y, "shape": list(self.shape),
            "amplitude_unit": self.amplitude_unit, "time_unit": self.time_unit,
            "motion_counts": dict(sorted(Counter(motion.ravel().tolist()).items())),
            "verified_fraction": float(np.mean(np.asarray(v["verified"], dtype=bool))),
            "unresolved_reasons": dict(reasons.most_common()),
            "bifurcations": self.bifurcations, "bifurcation_curves": self.curves(),
            "config": self.config, "verify": self.verify, "metadata": self.metadata,
        }
        if points:
            out["points"] = [self._point(j, i) for j in range(self.shape[0])
                             for i in range(self.shape[1])]
        return jsonable(out)

    def _point(self, j: int, i: int) -> dict:
        g = {k: np.asarray(a)[j, i].item() for k, a in self.verdicts.items()}
        ev = {k: g.get(k) for k in ("orbit_residual", "max_multiplier", "lyapunov_per_period")}
        ev.update(lyapunov_per_period_95=[g.get("lyapunov_low"), g.get("lyapunov_high")],
                  transient=g.get("transient"))
        return {"index": [j, i], self.x_name: float(self.x[i]), self.y_name: float(self.y[j]),
                **{k: g.get(k) for k in ("amplitude", "motion", "period_n", "verified")},
                "evidence": ev, "reason": g.get("reason", "")}

    # -- files -----------------------------------------------------------------------------
    def _coords(self):
        names = [_file_name(self.y_name), _file_name(self.x_name)]
        for k, other in ((0, "y"), (1, "x")):
            if names[k] in self.verdicts or names[k] == names[1 - k]:
                names[k] = other
        return names

    def to_xarray(self):
        """The atlas as an `xarray.Dataset`: dims (y, x) named after the two parameters
        (index coordinates with units and long_name), one variable per verdict (strings
        as str, bools as int8 with CF flag attributes), settings as JSON attributes."""
        import xarray as xr

        yc, xc = self._coords()
        units = {"amplitude": self.amplitude_unit, "transient": self.time_unit,
                 "lyapunov_per_period": "1", "lyapunov_low": "1", "lyapunov_high": "1",
                 "rotation_number": "1", "period_n": "1", "max_multiplier": "1"}
        data = {}
        for name, a in self.verdicts.items():
            a = np.asarray(a)
            attrs = {"long_name": VERDICT_FIELDS.get(name, name)}
            if name in units:
                attrs["units"] = units[name]
            if a.dtype.kind == "b":
                a = a.astype(np.int8)
                attrs.update(flag_values=np.array([0, 1], dtype=np.int8),
                             flag_meanings="false true", boolean=1)
            elif a.dtype.kind in "USO":
                a = np.array([str(s) for s in a.ravel()], dtype=object).reshape(a.shape)
            data[name] = ((yc, xc), a, attrs)
        coords = {
            yc: (yc, np.asarray(self.y, dtype=float), {"units": self.y_unit, "long_name":
                                                       self.y_label or self.y_name}),
            xc: (xc, np.asarray(self.x, dtype=float), {"units": self.x_unit, "long_name":
                                                       self.x_label or self.x_name}),
        }
        attrs = {"format": FORMAT, "x_coordinate": xc, "y_coordinate": yc,
                 "verdicts": json.dumps(list(self.verdicts))}
        for k in ("x_name", "x_unit", "y_name", "y_unit", "x_label", "y_label",
                  "amplitude_unit", "time_unit"):
            attrs[k] = str(getattr(self, k))
        for k in ("bifurcations", "config", "verify", "metadata"):
            attrs[k] = json.dumps(jsonable(getattr(self, k)))
        return xr.Dataset(data, coords=coords, attrs=attrs)

    def save(self, path) -> None:
        """Write a NetCDF4 file (engine h5netcdf), atomically (temporary file + rename)."""
        save_netcdf_atomic(path, self.to_xarray())


def load_atlas(path) -> Atlas:
    """Read a file written by `Atlas.save`."""
    ds = open_netcdf(path, "atlas", FORMAT)
    a = ds.attrs
    verdicts = {}
    for name in json.loads(a["verdicts"]):
        v = ds[name]
        arr = v.values
        if v.attrs.get("boolean"):
            arr = arr.astype(bool)
        elif arr.dtype.kind in "OS":
            arr = arr.astype(str)
        verdicts[name] = arr
    return Atlas(x=ds[a["x_coordinate"]].values, y=ds[a["y_coordinate"]].values,
                 verdicts=verdicts, **{k: str(a[k]) for k in (
                     "x_name", "x_unit", "y_name", "y_unit", "x_label", "y_label",
                     "amplitude_unit", "time_unit")},
                 **{k: json.loads(a[k]) for k in ("bifurcations", "config", "verify",
                                                  "metadata")})


def _match(a, b, tol) -> list:
    """Non-crossing pairs (j, i) of sorted `b` and `a` within `tol`: most pairs, then the
    least total distance (an alignment by dynamic programming)."""
    best = [[(0, 0.0)] * (len(b) + 1) for _ in range(len(a) + 1)]
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            cands = [best[i - 1][j], best[i][j - 1]]
            d = abs(a[i - 1] - b[j - 1])
            if d <= tol:
                n, dist = best[i - 1][j - 1]
                cands.append((n + 1, dist - d))
            best[i][j] = max(cands)
    pairs, i, j = [], len(a), len(b)
    while i and j:
        if best[i][j] == best[i - 1][j]:
            i -= 1
        elif best[i][j] == best[i][j - 1]:
            j -= 1
        else:
            pairs.append((j - 1, i - 1))
            i, j = i - 1, j - 1
    return pairs


def _file_name(name: str) -> str:
    return str(name).replace("/", "_")  # "/" separates groups in HDF5


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
