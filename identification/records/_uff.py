"""UFF58 records (universal file format, data set 58, via pyuff).

- Time record: two time functions (function type 1), force (ordinate data type 13) and
  worktable acceleration (12), SI, sampled uniformly.
- FRF: one frequency response function (function type 4, complex, abscissa in Hz),
  worktable acceleration (12; velocity 11 or displacement 8 are converted) over exciter
  force (13), optionally with a coherence function (type 6) and, as this package writes
  it, a general function (type 0, id1 "bsfs std") holding std_re + i std_im.

Header keys (see `_records.py`) are `key=value` items, separated by ";" or ",", in the
id2..id5 lines of any set (80 characters each). Files from other software usually lack
`speed_rpm` and `ambient_c`: add them to an id line (e.g. id4 "speed_rpm=0; ambient_c=20").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bsfs_jax.files import write_atomic

from ._records import RecordError, finish, format_meta_value, parse_value, unpack

_UFF_FORCE, _UFF_ACC = 13, 12  # UFF58 ordinate specific data types
_TIME, _FRF, _COHERENCE, _GENERAL = 1, 4, 6, 0  # UFF58 function types
_FUNC_NAMES = {0: "general", 1: "time response", 2: "auto spectrum", 3: "cross spectrum",
               4: "FRF", 5: "transmissibility", 6: "coherence", 9: "PSD", 12: "spectrum"}
_STD_ID = "bsfs std"
_ID_FIELDS = ("id2", "id3", "id4", "id5")
# Ordinate data types an FRF may have, with the power of (i w) that makes it accelerance.
_TO_ACCELERANCE = {12: 0, 11: 1, 8: 2}
_FORCE_DENOMS = (13, 9, 0)  # excitation force, reaction force, unknown (taken as force)


def _read_sets(path: Path) -> list[dict]:
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
    if not sets:
        raise RecordError(f"{path}: no UFF58 data set. Export the record as UFF58 functions.")
    return sets


def _meta_of(sets) -> dict:
    meta: dict = {}
    for s in sets:
        for field in _ID_FIELDS:
            for item in str(s.get(field, "")).replace(";", ",").split(","):
                if "=" in item:
                    k, v = item.split("=", 1)
                    meta[k.strip()] = parse_value(v)
    return meta


def load_uff(path: Path):
    """A time `Record` (function type 1) or an `FrfRecord` (function type 4)."""
    sets = _read_sets(path)
    types = [int(s.get("func_type", 0)) for s in sets]
    if _FRF in types:
        return _load_frf(path, sets, types)
    for j, (s, ft) in enumerate(zip(sets, types)):
        if ft not in (_TIME, _GENERAL):
            raise RecordError(
                f"{path}: UFF58 set {j + 1} has function type {ft} "
                f"({_FUNC_NAMES.get(ft, 'other')}). A record is either time functions (type 1: "
                "force, data type 13, and acceleration, 12) or an FRF (type 4); export one of "
                "those.")
    return _load_time(path, sets)


def _load_time(path, sets):
    by_kind: dict = {}
    for s in sets:
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
    meta = _meta_of((fs_set, acc_set))
    dt = float(fs_set["abscissa_inc"])
    meta.setdefault("sample_rate_hz", 1.0 / dt)
    force = np.asarray(fs_set["data"]).real.astype(float)
    acc = np.asarray(acc_set["data"]).real.astype(float)
    t = np.asarray(fs_set.get("x", np.arange(force.size) * dt), float)
    if force.size != acc.size:
        raise RecordError(f"{path}: force has {force.size} samples, acceleration {acc.size}; "
                          "both functions must cover the same samples.")
    return finish(path, t, force, acc, meta, lambda i: f"{path}: sample {i}")


def _only(path, sets, types, ft, what):
    found = [(j, s) for j, (s, t) in enumerate(zip(sets, types)) if t == ft
             and (ft != _GENERAL or str(s.get("id1", "")).startswith(_STD_ID))]
    if len(found) > 1:
        raise RecordError(f"{path}: {len(found)} UFF58 {what} sets; export one FRF (worktable "
                          "acceleration over exciter force) per file.")
    return found[0] if found else (None, None)


def _load_frf(path, sets, types):
    from ._frf import finish_frf

    j, frf = _only(path, sets, types, _FRF, "FRF (function type 4)")
    field = f"{path}: UFF58 set {j + 1} (FRF)"
    ordinate = int(frf.get("ordinate_spec_data_type", 0))
    if ordinate not in _TO_ACCELERANCE:
        raise RecordError(f"{field}: ordinate data type {ordinate}; the FRF must be the "
                          "worktable acceleration (12), velocity (11) or displacement (8) over "
                          "the exciter force.")
    denom = int(frf.get("orddenom_spec_data_type", 0))
    if denom not in _FORCE_DENOMS:
        raise RecordError(f"{field}: ordinate denominator data type {denom}; the FRF must be "
                          "per exciter force (13).")
    abscissa = int(frf.get("abscissa_spec_data_type", 18))
    if abscissa not in (18, 0, 1):
        raise RecordError(f"{field}: abscissa data type {abscissa}; an FRF's abscissa must be "
                          "frequency in Hz (18).")
    units = str(frf.get("ordinate_axis_units_lab", "")).strip().lower()
    if units.startswith("g") or "mm" in units or "in" in units:
        raise RecordError(f"{field}: ordinate units '{units}'; convert the FRF to SI "
                          "((m/s^2)/N) before importing.")
    data = np.asarray(frf["data"])
    if not np.iscomplexobj(data):
        raise RecordError(f"{field}: the FRF data are real (ord_data_type "
                          f"{frf.get('ord_data_type')}); an FRF must be complex (5 or 6).")
    f = np.asarray(frf["x"], float)
    h = data.astype(complex) * (2j * np.pi * f) ** _TO_ACCELERANCE[ordinate]
    meta = _meta_of(sets)
    if ordinate != _UFF_ACC:
        meta["converted_from"] = {11: "mobility", 8: "receptance"}[ordinate]
    extra = {}
    for ft, what in ((_COHERENCE, "coherence (function type 6)"), (_GENERAL, "bsfs std")):
        k, s = _only(path, sets, types, ft, what)
        if s is None:
            continue
        x = np.asarray(s["x"], float)
        if x.shape != f.shape or not np.allclose(x, f, rtol=1e-9, atol=0.0):
            raise RecordError(f"{path}: UFF58 set {k + 1} ({what}) does not have the FRF's "
                              "frequency lines; export it on the same lines.")
        extra[ft] = np.asarray(s["data"])
    std = (np.stack([extra[_GENERAL].real, extra[_GENERAL].imag], axis=1).astype(float)
           if _GENERAL in extra else None)
    coherence = extra[_COHERENCE].real.astype(float) if _COHERENCE in extra else None
    return finish_frf(path, f, h, std, coherence, meta,
                      lambda i: f"{field}, line {i} (f = {f[i]:g} Hz)",
                      line_hint="to an id line (id2..id5) of the UFF58 set")


# ----------------------------------------------------------------------------- writing


def _pack_ids(meta: dict, first: tuple) -> dict:
    """`key=value` items packed into the 80-character lines id2..id5 (keys in `first`
    first; items that do not fit, or whose value holds a separator, are left out)."""
    order = [k for k in first if k in meta] + [k for k in meta if k not in first]
    lines = [""]
    for k in order:
        v = meta[k]
        if format_meta_value(v) is None or isinstance(v, bool):
            continue
        text = v if isinstance(v, str) else f"{float(v):.9g}"
        if any(c in text for c in ";,="):
            continue
        item = f"{k}={text}"
        if len(item) > 80:
            continue
        if len(lines[-1]) + len(item) + 2 > 80:
            if len(lines) == len(_ID_FIELDS):
                continue
            lines.append("")
        lines[-1] = f"{lines[-1]}; {item}" if lines[-1] else item
    return dict(zip(_ID_FIELDS, lines))


def _write_sets(path: Path, sets) -> Path:
    import pyuff

    def write(tmp: Path):
        tmp.unlink()  # pyuff appends to an existing file
        uff = pyuff.UFF(str(tmp))
        for s in sets:
            uff.write_sets(s, mode="add")

    # An existing file is replaced only by a complete new one.
    return write_atomic(path, write)


_TIME_FIRST = ("excitation", "start_hz", "stop_hz", "frequency_hz", "force_amplitude_n",
               "force_rms_n", "sample_rate_hz", "speed_rpm", "ambient_c")


def write_record_uff(path, record_or_arrays, meta: dict | None = None) -> Path:
    """Write force and acceleration as two UFF58 time functions. The header keys go into
    id2..id5 (the record's required keys first; others as far as 4 x 80 characters hold)."""
    t, force, acc, meta = unpack(record_or_arrays, meta)
    ids = _pack_ids(meta, _TIME_FIRST)
    return _write_sets(path, [uff58_set(t, data, kind, id1=f"bsfs exciter record: {name}", **ids)
                              for kind, data, name in ((_UFF_FORCE, force, "force"),
                                                       (_UFF_ACC, acc, "acceleration"))])


def write_frf_uff(path, frf, *, binary: bool = True) -> Path:
    """Write an `FrfRecord` as UFF58: the FRF (type 4), its coherence (type 6) if known, and
    its standard errors (type 0, id1 "bsfs std", std_re + i std_im). `binary=True` (58b)
    keeps the uneven line frequencies exactly; ASCII stores them to 6 digits."""
    from ._csv import frf_header

    ids = _pack_ids(frf_header(frf), ("excitation", "speed_rpm", "ambient_c", "n_averages",
                                      "force_amplitude_n", "force_rms_n", "force_level"))
    f = frf.frequency_hz
    common = dict(binary=int(binary), abscissa_spacing=0, abscissa_spec_data_type=18,
                  abscissa_axis_units_lab="Hz", orddenom_spec_data_type=_UFF_FORCE,
                  orddenom_axis_units_lab="N", **ids)
    sets = [dict(uff58_set(f, frf.accelerance, _UFF_ACC,
                           id1="bsfs FRF: worktable acceleration / exciter force"),
                 func_type=_FRF, ord_data_type=6, **common)]
    if frf.coherence is not None:
        sets.append(dict(uff58_set(f, frf.coherence, 0, id1="bsfs coherence"),
                         func_type=_COHERENCE, **common))
    sets.append(dict(uff58_set(f, frf.std[:, 0] + 1j * frf.std[:, 1], _UFF_ACC,
                               id1=f"{_STD_ID}: std_re + i std_im of the FRF"),
                     func_type=_GENERAL, ord_data_type=6, **common))
    return _write_sets(path, sets)


def uff58_set(t, data, kind: int, *, id1: str = "", id2: str = "", id3: str = "",
              id4: str = "", id5: str = "") -> dict:
    """A complete UFF58 time-function data set for pyuff (ASCII, real, double); complex
    `data` are kept complex (set `ord_data_type=6` for them)."""
    labels = {_UFF_FORCE: "N", _UFF_ACC: "m/s^2"}
    data = np.asarray(data)
    data = data.astype(complex) if np.iscomplexobj(data) else data.astype(float)
    return dict(
        type=58, binary=0, id1=id1, id2=id2, id3=id3, id4=id4, id5=id5, func_type=_TIME,
        ver_num=0, load_case_id=0, rsp_ent_name="TABLE", rsp_node=1, rsp_dir=1,
        ref_ent_name="EXCITER", ref_node=1, ref_dir=1, ord_data_type=4,
        num_pts=int(data.size), abscissa_spacing=1, abscissa_min=float(t[0]),
        abscissa_inc=float(t[1] - t[0]), z_axis_value=0.0, abscissa_spec_data_type=17,
        abscissa_len_unit_exp=0, abscissa_force_unit_exp=0, abscissa_temp_unit_exp=0,
        abscissa_axis_units_lab="s", ordinate_spec_data_type=int(kind),
        ordinate_len_unit_exp=0, ordinate_force_unit_exp=0, ordinate_temp_unit_exp=0,
        ordinate_axis_units_lab=labels.get(kind, "NONE"), orddenom_spec_data_type=0,
        orddenom_len_unit_exp=0, orddenom_force_unit_exp=0, orddenom_temp_unit_exp=0,
        orddenom_axis_units_lab="NONE", z_axis_spec_data_type=0, z_axis_len_unit_exp=0,
        z_axis_force_unit_exp=0, z_axis_temp_unit_exp=0, z_axis_axis_units_lab="NONE",
        data=data, x=np.asarray(t, float))
