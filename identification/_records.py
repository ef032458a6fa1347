"""Exciter records: reading (CSV with `# key = value` header, UFF58), checking and writing.

A record is one stationary sine test: the force on the worktable and the worktable
acceleration, sampled uniformly. The loader refuses a bad record with a `RecordError` that
names the file, the line (CSV) and what to do; it never drops or repairs data silently.

CSV layout::

    # frequency_hz = 120.0
    # force_amplitude_n = 100.0
    # sample_rate_hz = 10240.0
    # speed_rpm = 2000.0
    # ambient_c = 20.0
    time_s,force_n,acceleration_m_s2
    0.0000000,1.234,0.0123
    ...

Optional header keys: `force_range_n` and `acceleration_range_m_s2` (the full-scale ranges
of the acquisition channels; used for the clipping check), `description`, `source`, and
any other `key = value` (kept in `meta`, reported, not used).
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
from pathlib import Path

import numpy as np

from bsfs_jax.params import write_text_atomic

COLUMNS = ("time_s", "force_n", "acceleration_m_s2")
REQUIRED_META = ("frequency_hz", "force_amplitude_n", "sample_rate_hz", "speed_rpm", "ambient_c")
MIN_PERIODS = 20
# Relative tolerances of the checks (documented in the error messages).
TIME_JITTER_REL = 1e-2  # sample spacing may differ from the median by 1 %
SAMPLE_RATE_REL = 1e-3  # header sample rate vs time column
CLIP_FRACTION = 0.999  # |x| >= 99.9 % of a channel's full-scale range counts as clipped
CLIP_RUN = 3  # or >= 3 consecutive samples stuck at the channel's extreme value


class RecordError(ValueError):
    """A record file is malformed or unusable; the message names file, line and the fix."""


@dataclasses.dataclass(frozen=True)
class Record:
    """One exciter record (SI units).

    - `time` [s], `force` [N], `acceleration` [m/s^2]: 1-D arrays of equal length;
    - `frequency_hz`, `force_amplitude_n`, `sample_rate_hz`, `speed_rpm`, `ambient_c`;
    - `meta`: every header key (strings converted to float where possible);
    - `source`: the file name (for messages and reports).
    """

    time: np.ndarray
    force: np.ndarray
    acceleration: np.ndarray
    frequency_hz: float
    force_amplitude_n: float
    sample_rate_hz: float
    speed_rpm: float
    ambient_c: float
    meta: dict
    source: str

    @property
    def name(self) -> str:
        return Path(self.source).stem

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0] + 1.0 / self.sample_rate_hz)

    @property
    def periods(self) -> float:
        return self.duration * self.frequency_hz

    def summary(self) -> str:
        return (f"{self.name}: {self.frequency_hz:g} Hz, {self.force_amplitude_n:g} N, "
                f"{self.speed_rpm:g} r/min, {self.time.size} samples at "
                f"{self.sample_rate_hz:g} Hz ({self.duration:.2f} s)")


# ----------------------------------------------------------------------------- reading


def load_record(path) -> Record:
    """Read and check one record (`.csv` or `.uff`/`.unv` UFF58). Raises `RecordError`."""
    path = Path(path)
    if not path.exists():
        raise RecordError(f"{path}: no such file. Give the path of a record (.csv or .uff).")
    if path.suffix.lower() in (".uff", ".unv"):
        return _load_uff(path)
    return _load_csv(path)


def load_records(paths) -> list[Record]:
    """Read several records; refuses duplicates of the same file."""
    seen = set()
    out = []
    for p in paths:
        key = os.path.realpath(p)
        if key in seen:
            raise RecordError(f"{p}: named twice. Give each record once.")
        seen.add(key)
        out.append(load_record(p))
    if not out:
        raise RecordError("no records given")
    return out


def _parse_value(text: str):
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    try:
        return float(text)
    except ValueError:
        return text


def _load_csv(path: Path) -> Record:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordError(f"{path}: cannot read as text ({exc}).") from None
    meta: dict = {}
    header_line = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            body = stripped.lstrip("#").strip()
            if "=" in body:
                key, value = body.split("=", 1)
                meta[key.strip()] = _parse_value(value)
            continue
        header_line = i
        break
    if header_line is None:
        raise RecordError(f"{path}: no column header line found. After the '# key = value' "
                          f"lines, write the header '{','.join(COLUMNS)}' and the samples.")
    names = [c.strip() for c in lines[header_line].split(",")]
    where = f"{path}:{header_line + 1}"
    unknown = [c for c in names if c not in COLUMNS]
    if unknown:
        raise RecordError(f"{where}: unknown column(s) {', '.join(repr(c) for c in unknown)}. "
                          f"The columns must be exactly {', '.join(COLUMNS)} (SI units); rename "
                          "or remove the others.")
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise RecordError(f"{where}: missing column(s) {', '.join(repr(c) for c in missing)}. "
                          f"A record needs {', '.join(COLUMNS)}.")
    if len(set(names)) != len(names):
        raise RecordError(f"{where}: a column appears twice in {names}.")
    body = "\n".join(lines[header_line + 1:])
    first_data_line = header_line + 2  # 1-based line number of the first sample
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2)
    except ValueError:
        data = None
    if data is None or data.shape[1] != len(names):
        _locate_bad_row(path, lines[header_line + 1:], first_data_line, len(names))
    _check_meta(path, meta)
    cols = {n: data[:, j] for j, n in enumerate(names)}
    return _finish(path, cols["time_s"], cols["force_n"], cols["acceleration_m_s2"], meta,
                   lambda idx: f"{path}:{first_data_line + idx}")


def _locate_bad_row(path, rows, first_line, ncols):
    for j, row in enumerate(rows):
        if not row.strip():
            raise RecordError(f"{path}:{first_line + j}: empty line inside the data. Remove it "
                              "(the loader does not skip lines silently).")
        parts = row.split(",")
        if len(parts) != ncols:
            raise RecordError(f"{path}:{first_line + j}: {len(parts)} values, expected {ncols}. "
                              "Fix or remove this line.")
        for p in parts:
            try:
                float(p)
            except ValueError:
                raise RecordError(f"{path}:{first_line + j}: '{p.strip()}' is not a number. "
                                  "Fix the value or cut the record before it.") from None
    raise RecordError(f"{path}: could not parse the samples.")


def _check_meta(path, meta: dict) -> None:
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise RecordError(f"{path}: header key(s) {', '.join(missing)} missing. Add lines like "
                          f"'# {missing[0]} = ...' above the column header.")
    for k in REQUIRED_META:
        v = meta[k]
        if not isinstance(v, float) or not math.isfinite(v):
            raise RecordError(f"{path}: header '{k} = {v}' is not a finite number.")
    for k in ("frequency_hz", "force_amplitude_n", "sample_rate_hz"):
        if meta[k] <= 0:
            raise RecordError(f"{path}: header '{k} = {meta[k]:g}' must be positive.")
    if meta["speed_rpm"] < 0:
        raise RecordError(f"{path}: header 'speed_rpm = {meta['speed_rpm']:g}' must be >= 0.")


def _finish(path, t, force, acc, meta, line_of) -> Record:
    """All checks that do not depend on the file format. `line_of(i)` names sample i."""
    n = t.size
    if n < 16:
        raise RecordError(f"{path}: only {n} samples. Record at least {MIN_PERIODS} excitation "
                          "periods.")
    for name, x in (("time_s", t), ("force_n", force), ("acceleration_m_s2", acc)):
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise RecordError(f"{line_of(bad[0])}: {name} is {x[bad[0]]} (non-finite; {bad.size} "
                              "such sample(s) in all). Re-export the record, or cut it to a "
                              "clean stretch; the loader never drops samples.")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = bad[0] + 1
        raise RecordError(f"{line_of(i)}: time_s = {t[i]!r} does not increase (previous "
                          f"{t[i - 1]!r}). Time must increase strictly; fix the export.")
    fs = float(meta["sample_rate_hz"])
    dt_med = float(np.median(dt))
    jitter = np.abs(dt - dt_med) > TIME_JITTER_REL * dt_med
    bad = np.flatnonzero(jitter)
    if bad.size:
        i = bad[0] + 1
        raise RecordError(
            f"{line_of(i)}: non-uniform time step {dt[bad[0]]:.6g} s (median {dt_med:.6g} s; "
            f"{bad.size} irregular step(s)). The model needs uniform sampling: re-export without "
            "dropped or inserted samples, or resample the whole record yourself.")
    fs_time = 1.0 / float(np.mean(dt))
    if abs(fs_time - fs) > SAMPLE_RATE_REL * fs:
        raise RecordError(
            f"{path}: header sample_rate_hz = {fs:g} but the time column gives {fs_time:.6g} Hz. "
            "Correct the header (or the time column) so that they agree within 0.1 %.")
    f0 = float(meta["frequency_hz"])
    duration = n / fs
    if duration * f0 < MIN_PERIODS:
        raise RecordError(
            f"{path}: only {duration * f0:.1f} excitation periods ({duration:.3f} s at {f0:g} Hz);"
            f" at least {MIN_PERIODS} are needed for a steady-state estimate. Record longer.")
    if f0 >= 0.5 * fs:
        raise RecordError(f"{path}: frequency_hz = {f0:g} is not below the Nyquist frequency "
                          f"{0.5 * fs:g} Hz of sample_rate_hz = {fs:g}.")
    for name, x, key in (("force_n", force, "force_range_n"),
                         ("acceleration_m_s2", acc, "acceleration_range_m_s2")):
        _check_clipping(path, name, x, meta.get(key), line_of)
    f_dom = dominant_frequency(force, fs)
    tol = max(1.5 / duration, 0.01 * f0)
    if abs(f_dom - f0) > tol:
        raise RecordError(
            f"{path}: header frequency_hz = {f0:g} but the measured force's dominant frequency is "
            f"{f_dom:.4g} Hz. Correct the header (or check the channel assignment).")
    return Record(np.asarray(t, float), np.asarray(force, float), np.asarray(acc, float),
                  f0, float(meta["force_amplitude_n"]), fs, float(meta["speed_rpm"]),
                  float(meta["ambient_c"]), dict(meta), str(path))


def _check_clipping(path, name, x, full_scale, line_of):
    if isinstance(full_scale, float) and full_scale > 0:
        bad = np.flatnonzero(np.abs(x) >= CLIP_FRACTION * full_scale)
        if bad.size:
            raise RecordError(
                f"{line_of(bad[0])}: {name} = {x[bad[0]]:g} reaches the channel's full scale "
                f"{full_scale:g} ({bad.size} clipped sample(s)). Repeat the test with a larger "
                "input range.")
    for extreme in (np.max(x), np.min(x)):
        at = x == extreme
        # longest run of consecutive samples stuck at the extreme
        run = best = 0
        start = 0
        for i in np.flatnonzero(at):
            run = run + 1 if i > 0 and at[i - 1] else 1
            if run > best:
                best, start = run, i - run + 1
        if best >= CLIP_RUN and np.count_nonzero(at) >= CLIP_RUN:
            raise RecordError(
                f"{line_of(start)}: {name} stays at its extreme value {extreme:g} for {best} "
                f"consecutive samples ({np.count_nonzero(at)} samples at that value): the signal "
                "is clipped. Repeat the test with a larger input range.")


def dominant_frequency(x, fs: float) -> float:
    """Frequency [Hz] of the largest spectral peak of x (Hann window, parabolic refinement)."""
    x = np.asarray(x, float) - np.mean(x)
    n = x.size
    spec = np.abs(np.fft.rfft(x * np.hanning(n)))
    spec[0] = 0.0
    k = int(np.argmax(spec))
    if 0 < k < spec.size - 1:
        a, b, c = np.log(spec[k - 1:k + 2] + 1e-300)
        denom = a - 2 * b + c
        k = k + (0.5 * (a - c) / denom if denom != 0 else 0.0)
    return float(k * fs / n)


# ----------------------------------------------------------------------------- UFF58

_UFF_FORCE, _UFF_ACC = 13, 12  # UFF58 ordinate specific data types


def _load_uff(path: Path) -> Record:
    try:
        import pyuff
    except ImportError:
        raise RecordError(f"{path}: reading UFF needs pyuff (pip install 'bsfs[uff]').") from None
    try:
        sets = pyuff.UFF(str(path)).read_sets()
    except Exception as exc:  # pyuff raises a variety of errors on bad files
        raise RecordError(f"{path}: not a readable UFF file ({exc}).") from None
    if isinstance(sets, dict):
        sets = [sets]
    sets = [s for s in sets if s.get("type") == 58]
    by_kind: dict = {}
    for j, s in enumerate(sets):
        kind = int(s.get("ordinate_spec_data_type", 0))
        if kind in by_kind:
            raise RecordError(f"{path}: more than one UFF58 set of data type {kind}; export one "
                              "force and one acceleration function per file.")
        by_kind[kind] = s
    missing = [n for k, n in ((_UFF_FORCE, "force (type 13)"), (_UFF_ACC, "acceleration "
                                                                "(type 12)")) if k not in by_kind]
    if missing:
        raise RecordError(f"{path}: UFF58 function(s) {', '.join(missing)} missing. Export the "
                          "force and the worktable acceleration as time functions.")
    fs_set, acc_set = by_kind[_UFF_FORCE], by_kind[_UFF_ACC]
    meta: dict = {}
    for s in (fs_set, acc_set):
        for field in ("id4", "id5"):
            for item in str(s.get(field, "")).replace(";", ",").split(","):
                if "=" in item:
                    k, v = item.split("=", 1)
                    meta[k.strip()] = _parse_value(v)
    dt = float(fs_set["abscissa_inc"])
    meta.setdefault("sample_rate_hz", 1.0 / dt)
    _check_meta(path, meta)
    force = np.asarray(fs_set["data"], float).real
    acc = np.asarray(acc_set["data"], float).real
    t = np.asarray(fs_set.get("x", np.arange(force.size) * dt), float)
    if force.size != acc.size:
        raise RecordError(f"{path}: force has {force.size} samples, acceleration {acc.size}; "
                          "both functions must cover the same samples.")
    return _finish(path, t, force, acc, meta, lambda i: f"{path}: sample {i}")


def write_record_uff(path, record_or_arrays, meta: dict | None = None) -> Path:
    """Write force and acceleration as two UFF58 time functions (metadata in id4)."""
    import pyuff

    t, force, acc, meta = _unpack(record_or_arrays, meta)
    path = Path(path)
    # Written beside the target and renamed into place, so an existing file is replaced
    # only by a complete new one.
    tmp = path.with_name(f".{path.name}.tmp")
    if tmp.exists():
        tmp.unlink()
    # UFF id lines hold 80 characters: frequency/force/rate in id4, speed/ambient in id5.
    id4 = "; ".join(f"{k}={meta[k]:.9g}" for k in REQUIRED_META[:3] if k in meta)
    id5 = "; ".join(f"{k}={meta[k]:.9g}" for k in REQUIRED_META[3:] if k in meta)
    uff = pyuff.UFF(str(tmp))
    for kind, data, name in ((_UFF_FORCE, force, "force"), (_UFF_ACC, acc, "acceleration")):
        uff.write_sets(uff58_set(t, data, kind, id1=f"bsfs exciter record: {name}", id4=id4,
                                 id5=id5),
                       mode="add")
    os.replace(tmp, path)
    return path


def uff58_set(t, data, kind: int, *, id1: str = "", id4: str = "", id5: str = "") -> dict:
    """A complete UFF58 time-function data set for pyuff (ASCII, real, double)."""
    labels = {_UFF_FORCE: "N", _UFF_ACC: "m/s^2"}
    return dict(
        type=58, binary=0, id1=id1, id2="", id3="", id4=id4, id5=id5, func_type=1,
        ver_num=0, load_case_id=0, rsp_ent_name="TABLE", rsp_node=1, rsp_dir=1,
        ref_ent_name="EXCITER", ref_node=1, ref_dir=1, ord_data_type=4,
        num_pts=int(np.asarray(data).size), abscissa_spacing=1, abscissa_min=float(t[0]),
        abscissa_inc=float(t[1] - t[0]), z_axis_value=0.0, abscissa_spec_data_type=17,
        abscissa_len_unit_exp=0, abscissa_force_unit_exp=0, abscissa_temp_unit_exp=0,
        abscissa_axis_units_lab="s", ordinate_spec_data_type=int(kind),
        ordinate_len_unit_exp=0, ordinate_force_unit_exp=0, ordinate_temp_unit_exp=0,
        ordinate_axis_units_lab=labels.get(kind, "NONE"), orddenom_spec_data_type=0,
        orddenom_len_unit_exp=0, orddenom_force_unit_exp=0, orddenom_temp_unit_exp=0,
        orddenom_axis_units_lab="NONE", z_axis_spec_data_type=0, z_axis_len_unit_exp=0,
        z_axis_force_unit_exp=0, z_axis_temp_unit_exp=0, z_axis_axis_units_lab="NONE",
        data=np.asarray(data, float), x=np.asarray(t, float))


# ----------------------------------------------------------------------------- writing


def _unpack(record_or_arrays, meta):
    if isinstance(record_or_arrays, Record):
        r = record_or_arrays
        return r.time, r.force, r.acceleration, dict(r.meta)
    t, force, acc = record_or_arrays
    return np.asarray(t), np.asarray(force), np.asarray(acc), dict(meta or {})


def format_record_csv(t, force, acc, meta: dict, *, digits: int = 6) -> str:
    """CSV text of a record: `# key = value` header, column line, samples."""
    lines = []
    for k, v in meta.items():
        lines.append(f"# {k} = {v!r}" if isinstance(v, str) else f"# {k} = {v:.10g}")
    lines.append(",".join(COLUMNS))
    tdig = max(7, int(math.ceil(-math.log10(float(t[1] - t[0])))) + 3)
    tt = np.char.mod(f"%.{tdig}f", np.asarray(t, float))
    ff = np.char.mod(f"%.{digits}g", np.asarray(force, float))
    aa = np.char.mod(f"%.{digits}g", np.asarray(acc, float))
    rows = np.char.add(np.char.add(np.char.add(np.char.add(tt, ","), ff), ","), aa)
    return "\n".join(lines) + "\n" + "\n".join(rows.tolist()) + "\n"


def write_record_csv(path, record_or_arrays, meta: dict | None = None, *,
                     digits: int = 6) -> Path:
    """Write a record atomically (temp file + rename). `digits`: significant digits."""
    t, force, acc, meta = _unpack(record_or_arrays, meta)
    text = format_record_csv(t, force, acc, meta, digits=digits)
    path = Path(path)
    write_text_atomic(path, text)
    return path
