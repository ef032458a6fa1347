"""An atlas's result: `Atlas` (verdicts over a (y, x) grid, bifurcation points per row and
the curves joining them), its NetCDF file (`Atlas.save`, `load_atlas`)."""

import dataclasses
import json
import re
from collections import Counter

import numpy as np

from .._files import jsonable, open_netcdf, save_netcdf_atomic
from ._block_verdict import UNRESOLVED
from ._verify_settings import VERDICT_FIELDS

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
