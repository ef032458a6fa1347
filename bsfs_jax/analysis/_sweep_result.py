"""What a sweep returns: `SweepResult` (arrays, derived quantities, NetCDF files) and the
detection of amplitude jumps (`Jump`, `detect_jumps`)."""

import dataclasses
import json

import numpy as np

from .._files import jsonable, open_netcdf, save_netcdf_atomic
from ..solvers import RESULTS, result_codes, result_from_codes, result_text
from ._sweep_problem import OK

FORMAT = "bsfs-sweep-2"  # the `format` attribute of sweep files


@dataclasses.dataclass
class Jump:
    """A jump of the response amplitude between neighbouring points of one sweep direction.

    `value_before`/`value_after` are the parameter values (in sweep order) and
    `amplitude_before`/`amplitude_after` the amplitudes of the observed coordinate.
    `hysteresis` (sweeps in both directions only): whether the other direction's amplitude
    differs by more than 10 % at either end point, i.e. the jump leaves a coexisting branch
    (a steep but single-valued flank on a coarse grid gives False).
    `fold_value`, `fold_amplitude`, `fold_located`: the fold that ends the branch left
    behind, located by continuation (`_jumps.locate_jump_folds`; None until located or
    where none was found).
    """

    direction: str
    index_before: int
    index_after: int
    value_before: float
    value_after: float
    amplitude_before: float
    amplitude_after: float
    hysteresis: bool | None = None
    fold_value: float | None = None
    fold_amplitude: float | None = None
    fold_located: bool | None = None

    @property
    def kind(self) -> str:
        return "jump-up" if self.amplitude_after > self.amplitude_before else "jump-down"

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["kind"] = self.kind
        return d


def detect_jumps(values, amplitude, *, direction: str = "up", rel: float = 0.3,
                 factor: float = 5.0) -> list[Jump]:
    """Jumps in an amplitude curve visited in the order given (the sweep order).

    A step i -> i+1 is a jump when its relative change |dA| / max(A_i, A_i+1) exceeds
    `rel` and |dA| exceeds `factor` times the median |dA| of the curve (so that steep but
    smooth resonance flanks on a coarse grid are not reported). Failed (NaN) points are
    skipped.
    """
    v = np.asarray(values, dtype=float)
    a = np.asarray(amplitude, dtype=float)
    good = np.flatnonzero(np.isfinite(a))
    if good.size < 3:
        return []
    da = np.abs(np.diff(a[good]))
    med = float(np.median(da))
    jumps = []
    for k in range(good.size - 1):
        i, j = int(good[k]), int(good[k + 1])
        big = max(a[i], a[j])
        if big <= 0:
            continue
        if da[k] / big > rel and da[k] > factor * med:
            jumps.append(Jump(direction, i, j, float(v[i]), float(v[j]), float(a[i]),
                              float(a[j])))
    return jumps


# Arrays of a sweep, as stored in files; "status" holds the integer codes of `result`.
_ARRAY_FIELDS = ("strobe", "amplitude", "mean", "peak", "spectrum", "lyapunov", "log_growth",
                 "status", "num_steps", "end_state")
_RESULT_FIELDS = tuple(n for n in _ARRAY_FIELDS if n != "status")


@dataclasses.dataclass
class SweepResult:
    """Everything a sweep keeps, as numpy arrays (self-describing when saved).

    Coordinates: `values` (N,) of parameter `param` [`unit`] in the order given;
    `directions` (D,): "cold", or "up"/"down" for continued sweeps (a "down" sweep visits
    `values` in reverse, but its rows are stored aligned with `values`).

    Per point, arrays with leading axes (D, N):
    - `strobe` (D, N, periods + 1, n): stroboscopic Poincare samples at t = kT;
    - `amplitude`, `mean`, `peak` (D, N, n): half peak-to-peak, mean, max |y| of each state;
    - `spectrum` (D, N, bins): one-sided amplitude spectrum of state `observe`, at
      frequencies `spectrum_order` x forcing frequency (`spectrum_order` in harmonics of
      the forcing; `spectrum_hz()` converts to Hz);
    - `lyapunov` (D, N): largest Lyapunov exponent [1/time unit] (NaN if not computed);
    - `log_growth` (D, N, periods): per-period tangent growth (Benettin);
    - `result` (D, N): the solver outcome of each point, a batched `RESULTS` item (files
      store its integer codes as `status`); failed points hold NaN; `num_steps` (D, N);
      `end_state` (D, N, n);
    - `period` (N,): forcing period [time unit];
    - `verdicts` (optional): {name: (D, N) array} of per-point judgements (float, int, bool
      or str), stored in files as variables `verdict_<name>` on (direction, point).

    `save` writes NetCDF4 (`to_xarray` gives the same labelled `xarray.Dataset`);
    `load_sweep` reads it back.
    """

    param: str
    unit: str
    values: np.ndarray
    directions: tuple
    mode: str
    period: np.ndarray
    spectrum_order: np.ndarray
    strobe: np.ndarray
    amplitude: np.ndarray
    mean: np.ndarray
    peak: np.ndarray
    spectrum: np.ndarray
    lyapunov: np.ndarray
    log_growth: np.ndarray
    result: RESULTS
    num_steps: np.ndarray
    end_state: np.ndarray
    state_names: tuple
    state_units: tuple
    observe: int
    time_unit: str
    config: dict
    metadata: dict = dataclasses.field(default_factory=dict)
    verdicts: dict | None = None

    # -- derived quantities --------------------------------------------------------------
    @property
    def failed(self) -> np.ndarray:
        """(D, N) bool: points whose solve failed (their data are NaN)."""
        return result_codes(self.result) != OK

    def point_result(self, d: int, i: int) -> RESULTS:
        """The `RESULTS` item of point `i` of direction `d`."""
        return result_from_codes(result_codes(self.result)[d, i])

    def direction_index(self, direction: str) -> int:
        try:
            return self.directions.index(direction)
        except ValueError:
            raise ValueError(f"direction '{direction}' not in this sweep; it has "
                             f"{list(self.directions)}") from None

    def steady_amplitude(self, coordinate: int | None = None) -> np.ndarray:
        """(D, N) amplitude of `coordinate` (default: the observed one): the verified
        orbit's where the verifier found one (observed coordinate only), else the
        record's (which may still hold a transient, e.g. just after a jump)."""
        c = self.observe if coordinate is None else coordinate
        amp = self.amplitude[..., c].copy()
        v = self.verdicts
        if c == self.observe and v is not None and "verified" in v and "amplitude" in v:
            use = np.asarray(v["verified"], bool) & np.isfinite(v["amplitude"])
            amp[use] = np.asarray(v["amplitude"], float)[use]
        return amp

    def frc(self, direction: str | None = None, coordinate: int | None = None):
        """(values, amplitude) of `coordinate` (default: the observed one) for a direction
        (`steady_amplitude`)."""
        d = 0 if direction is None else self.direction_index(direction)
        return self.values, self.steady_amplitude(coordinate)[d]

    def sweep_order(self, direction: str) -> np.ndarray:
        """Indices into `values` in the order the sweep visited them."""
        n = self.values.size
        return np.arange(n)[::-1] if direction == "down" else np.arange(n)

    def jumps(self, coordinate: int | None = None, **kwargs) -> list[Jump]:
        """Jumps of the amplitude (`steady_amplitude`: the verified orbits' where known)
        along each direction, in sweep order (`detect_jumps`)."""
        out = []
        amplitude = self.steady_amplitude(coordinate)
        for d, name in enumerate(self.directions):
            order = self.sweep_order(name)
            js = detect_jumps(self.values[order], amplitude[d, order],
                              direction=name, **kwargs)
            for j in js:
                j.index_before, j.index_after = int(order[j.index_before]), int(
                    order[j.index_after])
                if len(self.directions) == 2:
                    other = amplitude[1 - d]
                    mine = amplitude[d]
                    ends = [j.index_before, j.index_after]
                    j.hysteresis = bool(np.any(
                        np.abs(other[ends] - mine[ends]) > 0.1 * np.maximum(mine[ends],
                                                                           other[ends])))
            out.extend(js)
        return out

    def spectrum_hz(self):
        """(N, bins) frequency axis [Hz if the time unit is s] of each point's spectrum."""
        return self.spectrum_order[None, :] / self.period[:, None]

    def lyapunov_per_period(self) -> np.ndarray:
        """(D, N) lambda T: the exponent per forcing period (the classifier's measure)."""
        return self.lyapunov * self.period[None, :]

    def motions(self, settings=None):
        """(D, N) nested list of `Motion` classifications (see `classify_motion`)."""
        from ._classify import ClassifierSettings, classify_motion

        settings = settings or ClassifierSettings()
        lam = self.lyapunov_per_period()
        # Repetition is judged relative to the response amplitude; a strobe-only record
        # (one sample per period) has no within-period amplitude, so use max |y| there.
        spp = int(self.config.get("samples_per_period", 2)) if self.config else 2
        scale = self.amplitude if spp > 1 else self.peak
        out = []
        for d in range(len(self.directions)):
            row = []
            for i in range(self.values.size):
                # Spectral evidence from the densely sampled observed coordinate
                # (discrete lines for periodic/quasi-periodic, broadband for chaos).
                lyap = lam[d, i] if np.isfinite(lam[d, i]) else None
                row.append(classify_motion(
                    self.strobe[d, i], lyapunov_per_period=lyap,
                    spectrum=self.spectrum[d, i],
                    scale=scale[d, i], result=self.point_result(d, i),
                    settings=settings))
            out.append(row)
        return out

    def summary(self, settings=None, jumps=None) -> dict:
        """JSON-ready summary: per point the value, amplitude, motion label, whether it is
        verified, its evidence and the reason (`_sweep_summary.point_records`); `jumps`
        (default `self.jumps()`), e.g. with their folds located."""
        from ._sweep_summary import motion_counts, point_records

        names, units = self.state_names, self.state_units
        points = point_records(self, settings)
        return {
            "param": self.param,
            "unit": self.unit,
            "observed": names[self.observe] if names else self.observe,
            "amplitude_unit": units[self.observe] if units else "",
            "mode": self.mode,
            "directions": list(self.directions),
            "verified": self.verdicts is not None,
            "motion_counts": motion_counts(points),
            "failed_points": int(np.sum(self.failed)),
            "jumps": [j.to_dict() for j in (self.jumps() if jumps is None else jumps)],
            "points": points,
            "config": self.config,
            "metadata": self.metadata,
        }

    # -- files -----------------------------------------------------------------------------
    def to_xarray(self):
        """The sweep as a labelled `xarray.Dataset` (what `save` writes).

        Dimensions (direction, point, sample, state, bin, period); coordinates: the swept
        parameter (named after `param`, on `point`), `direction`, `state` (names) with
        `state_units`, `spectrum_order` (on `bin`); every variable has `units` and
        `long_name` attributes; `status` holds the result codes (messages in the global
        attribute `status_messages`); config and metadata are JSON global attributes.
        """
        return _to_dataset(self)

    def save(self, path) -> None:
        """Write a self-describing NetCDF4 file (engine h5netcdf), atomically."""
        save_netcdf_atomic(path, self.to_xarray())


def load_sweep(path) -> SweepResult:
    """Read a file written by `SweepResult.save` (NetCDF4, format "bsfs-sweep-2")."""
    ds = open_netcdf(path, "sweep", FORMAT)
    return _from_dataset(ds)


def _code_messages(result) -> dict:
    """{code: message} for the result codes present (and 0, successful)."""
    codes = np.unique(np.append(result_codes(result), OK))
    return {str(int(c)): str(result_text(result_from_codes(c))) for c in codes}


_D2 = ("direction", "point")
# name: (dims, long_name); units follow from the result's labels (see `_to_dataset`).
_VARIABLES = {
    "strobe": (_D2 + ("sample", "state"), "stroboscopic samples at t = kT (Poincare section)"),
    "amplitude": (_D2 + ("state",), "half peak-to-peak amplitude over the recorded periods"),
    "mean": (_D2 + ("state",), "mean over the recorded periods"),
    "peak": (_D2 + ("state",), "maximum |y| over the recorded periods"),
    "spectrum": (_D2 + ("bin",), "one-sided amplitude spectrum of the observed coordinate"),
    "lyapunov": (_D2, "largest Lyapunov exponent"),
    "log_growth": (_D2 + ("period",), "log of the tangent growth in each recorded period"),
    "status": (_D2, "solver result code (bsfs_jax.RESULTS, 0 successful; the messages are "
                    "in the global attribute status_messages)"),
    "num_steps": (_D2, "solver steps"),
    "end_state": (_D2 + ("state",), "state at the end of the recorded periods"),
}
_RESERVED = {*_VARIABLES, *_D2, "sample", "state", "bin", "period", "state_units",
             "spectrum_order", "forcing_period"}


def _file_name(name: str) -> str:
    return str(name).replace("/", "_")  # "/" separates groups in HDF5


def _to_dataset(res: SweepResult):
    import xarray as xr

    n = np.shape(res.end_state)[-1]
    names = tuple(res.state_names) or tuple(f"y{i}" for i in range(n))
    units = tuple(res.state_units) or ("",) * n
    common = units[0] if len(set(units)) == 1 else "per state: " + ", ".join(
        f"{a} {u or '1'}" for a, u in zip(names, units, strict=True))
    obs_unit = units[res.observe]
    var_units = {"strobe": common, "amplitude": common, "mean": common, "peak": common,
                 "end_state": common, "spectrum": obs_unit, "lyapunov": f"1/{res.time_unit}",
                 "log_growth": "1", "status": "1", "num_steps": "1"}
    arrays = {name: getattr(res, name) for name in _RESULT_FIELDS}
    arrays["status"] = result_codes(res.result)
    data = {name: (dims, np.asarray(arrays[name]), {"units": var_units[name],
                                                     "long_name": long})
            for name, (dims, long) in _VARIABLES.items()}
    data["spectrum"][2]["long_name"] += f" {names[res.observe]}"
    data["forcing_period"] = ("point", np.asarray(res.period),
                              {"units": res.time_unit, "long_name": "forcing period"})
    shape = (len(res.directions), np.size(res.values))
    for name, value in (res.verdicts or {}).items():
        a = np.asarray(value)
        if a.shape[:2] != shape or a.dtype.kind not in "biufUSO" or (
                a.ndim > 2 and a.dtype.kind not in "biuf"):
            raise ValueError(f"verdict '{name}' must be a {shape} array of floats, ints, bools "
                             f"or strings (numbers may have further axes), got shape "
                             f"{a.shape} dtype {a.dtype}")
        key = "verdict_" + _file_name(name)
        if key in data:
            raise ValueError(f"verdict '{name}' clashes with another verdict in the file")
        if a.dtype.kind in "USO":
            a = np.array([str(x) for x in a.ravel()], dtype=object).reshape(shape)
        extra = tuple(f"{key}_axis{k}" for k in range(a.ndim - 2))
        data[key] = (_D2 + extra, a, {"long_name": f"verdict {name}",
                                      "verdict_name": str(name)})
    pname = _file_name(res.param)
    pname = "values" if pname in _RESERVED or pname.startswith("verdict_") else pname
    coords = {
        pname: ("point", np.asarray(res.values, dtype=float),
                {"units": res.unit, "long_name": f"swept parameter {res.param}"}),
        "direction": ("direction", np.array(res.directions, dtype=str),
                      {"long_name": "sweep direction (cold, or up/down when continued)"}),
        "state": ("state", np.array(names, dtype=str), {"long_name": "state coordinate"}),
        "state_units": ("state", np.array(units, dtype=str),
                        {"long_name": "unit of each state coordinate"}),
        "spectrum_order": ("bin", np.asarray(res.spectrum_order, dtype=float),
                           {"units": "1", "long_name": "frequency in harmonics of the "
                                                       "forcing frequency"}),
    }
    attrs = {
        "format": FORMAT, "param": res.param, "param_coordinate": pname, "unit": res.unit,
        "mode": res.mode, "observe": int(res.observe), "time_unit": res.time_unit,
        "config": json.dumps(jsonable(res.config)),
        "metadata": json.dumps(jsonable(res.metadata)),
        "status_messages": json.dumps(_code_messages(res.result)),
        "verdicts": json.dumps(None if res.verdicts is None else [str(k) for k in res.verdicts]),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def _from_dataset(ds) -> SweepResult:
    attrs = ds.attrs
    arrays = {name: ds[name].values for name in _RESULT_FIELDS}
    verdicts, names = None, json.loads(attrs.get("verdicts", "null"))
    if names is not None:
        found = {v.attrs["verdict_name"]: v.values for v in ds.data_vars.values()
                 if "verdict_name" in v.attrs}
        verdicts = {k: found[k].astype(str) if found[k].dtype.kind in "OS" else found[k]
                    for k in names}
    return SweepResult(
        result=result_from_codes(ds["status"].values), param=attrs["param"],
        unit=attrs["unit"], values=ds[attrs["param_coordinate"]].values,
        directions=tuple(str(d) for d in ds["direction"].values), mode=attrs["mode"],
        period=ds["forcing_period"].values, spectrum_order=ds["spectrum_order"].values,
        state_names=tuple(str(s) for s in ds["state"].values),
        state_units=tuple(str(s) for s in ds["state_units"].values),
        observe=int(attrs["observe"]), time_unit=attrs["time_unit"],
        config=json.loads(attrs["config"]), metadata=json.loads(attrs["metadata"]),
        verdicts=verdicts, **arrays)
