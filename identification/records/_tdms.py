"""TDMS records (NI LabVIEW / DAQmx files, via npTDMS; `pip install 'bsfs[tdms]'`).

Layout of a time record (see `_records.py` for the header keys)::

    file properties       header keys (optional; the group's properties override them)
    group "bsfs"          (or, if no group is named bsfs, the first group)
      properties          header keys: frequency_hz, force_amplitude_n, speed_rpm, ambient_c,
                          excitation, start_hz/stop_hz, force_rms_n, ... (as in a CSV header)
      channel force_n            unit_string "N"
      channel acceleration_m_s2  unit_string "m/s^2" ("m/s2"; "g" is converted, 9.80665 m/s^2)
      channel time_s             optional; unit_string "s"

- Channels are found by name (case-insensitive); where the names differ, by their
  `unit_string` property ("N" for the force; "m/s^2", "m/s2" or "g" for the acceleration),
  which must then single out one channel each. Other channels are ignored.
- A channel's `unit_string`, where present, gives its unit; units other than those above
  are refused (convert in LabVIEW, or fix the property).
- Sampling: the channels' `wf_increment` [s] (and `wf_start_offset`), as DAQmx writes
  them; or a `time_s` channel; or, failing both, a `sample_rate_hz` property.
  `sample_rate_hz` defaults to 1 / wf_increment (or to the time channel's rate).
- Property values: numbers are read as floats, strings as in a CSV header (converted to a
  float where they are one), booleans are kept, timestamps become ISO text.

`write_record_tdms` writes this layout (with a `time_s` channel, so a record's time comes
back exactly). A bad file is refused in one line naming the file and what to do.
"""

from __future__ import annotations

import datetime
import math
from pathlib import Path

import numpy as np

from bsfs_jax.files import write_atomic

from ._records import (
    SAMPLE_RATE_REL,
    Record,
    RecordError,
    excitation_of,
    finish,
    format_meta_value,
    parse_value,
    required_meta,
    unpack,
)

GROUP = "bsfs"
FORCE, ACC, TIME = "force_n", "acceleration_m_s2", "time_s"
STANDARD_GRAVITY = 9.80665  # m/s^2 per g
FORCE_UNITS = {"N": 1.0}
ACC_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY}
TIME_UNITS = {"s": 1.0}
_INSTALL = "pip install npTDMS (or pip install 'bsfs[tdms]')"


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _read(path: Path):
    try:
        from nptdms import TdmsFile
    except ImportError:
        raise RecordError(f"{path}: reading TDMS needs npTDMS, which is not installed "
                          f"({_INSTALL}).") from None
    try:
        return TdmsFile.read(str(path))
    except Exception as exc:  # npTDMS raises a variety of errors on bad files
        raise RecordError(f"{path}: not a readable TDMS file ({_one_line(exc)}). Save the "
                          "record from LabVIEW as TDMS, or export it as CSV.") from None


def _property(v):
    """A TDMS property value as a record meta value (None: not usable, skipped)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    if isinstance(v, str):
        return parse_value(v)
    if isinstance(v, np.datetime64):
        return str(v)
    if isinstance(v, datetime.datetime):
        return v.isoformat()
    return None


def _meta_of(*property_dicts) -> dict:
    meta: dict = {}
    for props in property_dicts:
        for k, v in props.items():
            value = _property(v)
            if value is not None:
                meta[str(k)] = value
    return meta


def _unit(ch) -> str | None:
    u = ch.properties.get("unit_string")
    if u is None:
        return None
    u = str(u).strip()
    return u or None


def _describe(channels) -> str:
    return ", ".join(f"'{c.name}'" + (f" ({_unit(c)})" if _unit(c) else "") for c in channels)


def _find(path, group, channels, name, units, what):
    """The channel called `name`, or else the one channel whose unit_string is in `units`."""
    named = [c for c in channels if c.name.strip().lower() == name]
    if len(named) > 1:
        raise RecordError(f"{path}: group '{group}' has {len(named)} channels named '{name}'; "
                          "keep one.")
    if named:
        return named[0]
    by_unit = [c for c in channels if _unit(c) in units]
    if len(by_unit) > 1:
        raise RecordError(f"{path}: group '{group}' has several {what} channels by unit_string "
                          f"({_describe(by_unit)}); name the one to use '{name}'.")
    if by_unit:
        return by_unit[0]
    return None


def _data(path, ch, units, what) -> np.ndarray:
    """The channel's samples in SI units (its unit_string, where present, must be known)."""
    unit = _unit(ch)
    if unit is not None and unit not in units:
        raise RecordError(f"{path}: channel '{ch.name}' ({what}) has unit_string '{unit}', not "
                          f"one of {', '.join(repr(u) for u in units)}. Scale the channel to one "
                          "of those units (or correct unit_string).")
    x = np.asarray(ch[:])
    if x.dtype.kind not in "biuf":
        raise RecordError(f"{path}: channel '{ch.name}' ({what}) holds {x.dtype} data, not "
                          "real numbers. Save the scaled (real) samples.")
    return x.astype(float) * (units[unit] if unit is not None else 1.0)


def _increment(path, chans):
    """The common wf_increment [s] of the channels that have one (None if none has)."""
    found = []
    for ch in chans:
        v = ch.properties.get("wf_increment")
        if v is None:
            continue
        try:
            dt = float(v)
        except (TypeError, ValueError):
            dt = math.nan
        if not (math.isfinite(dt) and dt > 0):
            raise RecordError(f"{path}: channel '{ch.name}' has wf_increment = {v!r}, not a "
                              "positive sample interval in seconds. Correct the property.")
        found.append((ch, dt))
    if len(found) == 2 and abs(found[0][1] - found[1][1]) > 1e-9 * found[0][1]:
        (a, da), (b, db) = found
        raise RecordError(f"{path}: channels '{a.name}' (wf_increment {da:g} s) and '{b.name}' "
                          f"({db:g} s) are sampled at different rates; record both at one "
                          "rate.")
    return (found[0][0], found[0][1]) if found else (None, None)


def load_tdms(path) -> Record:
    """Read and check a TDMS time record (layout in the module docstring). Raises
    `RecordError`."""
    path = Path(path)
    tdms = _read(path)
    groups = list(tdms.groups())
    if not groups:
        raise RecordError(f"{path}: the TDMS file has no group. Write the channels force_n and "
                          f"acceleration_m_s2 into a group (named '{GROUP}').")
    named = [g for g in groups if g.name.strip().lower() == GROUP]
    group = named[0] if named else groups[0]
    channels = list(group.channels())
    gname = group.name
    force_ch = _find(path, gname, channels, FORCE, FORCE_UNITS, "force")
    acc_ch = _find(path, gname, channels, ACC, ACC_UNITS, "acceleration")
    missing = [n for n, c in ((FORCE, force_ch), (ACC, acc_ch)) if c is None]
    if missing:
        have = _describe(channels) or "none"
        raise RecordError(
            f"{path}: group '{gname}' has no {' or '.join(missing)} channel (channels: {have}). "
            "Name the channels force_n and acceleration_m_s2, or give them unit_string 'N' and "
            "'m/s^2' (or 'g').")
    force = _data(path, force_ch, FORCE_UNITS, "force")
    acc = _data(path, acc_ch, ACC_UNITS, "acceleration")
    if force.size != acc.size:
        raise RecordError(f"{path}: channel '{force_ch.name}' has {force.size} samples, "
                          f"'{acc_ch.name}' {acc.size}; both must cover the same samples.")
    meta = _meta_of(tdms.properties, group.properties)
    if _unit(acc_ch) == "g":
        meta["acceleration_converted_from"] = "g"
    time_ch = next((c for c in channels if c.name.strip().lower() == TIME), None)
    inc_ch, dt = _increment(path, (force_ch, acc_ch))
    if time_ch is not None:
        t = _data(path, time_ch, TIME_UNITS, "time")
        if t.size != force.size:
            raise RecordError(f"{path}: channel '{time_ch.name}' has {t.size} samples, "
                              f"'{force_ch.name}' {force.size}; the time must cover the same "
                              "samples.")
        span = float(t[-1] - t[0]) if t.size > 1 else math.nan
        fs_time = (t.size - 1) / span if math.isfinite(span) and span > 0 else None
        if dt is not None and fs_time is not None \
                and abs(fs_time - 1.0 / dt) > SAMPLE_RATE_REL / dt:
            raise RecordError(
                f"{path}: channel '{inc_ch.name}' has wf_increment {dt:g} s ({1.0 / dt:.6g} Hz) "
                f"but channel '{time_ch.name}' gives {fs_time:.6g} Hz. Correct one of them so "
                "that they agree within 0.1 %.")
        rate = 1.0 / dt if dt is not None else fs_time
        if rate is not None:
            meta.setdefault("sample_rate_hz", rate)
    elif dt is not None:
        t0 = _property(inc_ch.properties.get("wf_start_offset", 0.0))
        t0 = t0 if isinstance(t0, float) and math.isfinite(t0) else 0.0
        t = t0 + np.arange(force.size) * dt
        meta.setdefault("sample_rate_hz", 1.0 / dt)
    else:
        fs = meta.get("sample_rate_hz")
        if not (isinstance(fs, float) and math.isfinite(fs) and fs > 0):
            raise RecordError(
                f"{path}: no sample rate: channels '{force_ch.name}' and '{acc_ch.name}' have no "
                f"wf_increment property, group '{gname}' has no time_s channel and no "
                "sample_rate_hz property. Save the waveform's timing (wf_increment) or add one "
                "of those.")
        t = np.arange(force.size) / fs
    kind = excitation_of(path, meta)
    missing = [k for k in required_meta(kind) if k not in meta]
    if missing:
        raise RecordError(
            f"{path}: property(ies) {', '.join(missing)} missing. Add them as properties of "
            f"group '{gname}' (or of the file), e.g. {missing[0]} = <number>.")
    return finish(path, t, force, acc, meta, lambda i: f"{path}: sample {i}")


# ----------------------------------------------------------------------------- writing


def _tdms_value(v):
    """A meta value as a TDMS property (None: not writable, skipped)."""
    if format_meta_value(v) is None:
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, str):
        return v
    return float(v)


def write_record_tdms(path, record_or_arrays, meta: dict | None = None) -> Path:
    """Write a record as TDMS: group 'bsfs' holding the header keys as properties and the
    channels force_n (N), acceleration_m_s2 (m/s^2) and time_s (s); the data channels carry
    wf_increment and wf_start_offset. Written beside the target and renamed into place."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    t, force, acc, meta = unpack(record_or_arrays, meta)
    t = np.asarray(t, float)
    fs = meta.get("sample_rate_hz")
    dt = (1.0 / float(fs) if isinstance(fs, (int, float)) and not isinstance(fs, bool)
          and float(fs) > 0 else float(np.mean(np.diff(t))))
    props = {k: p for k, v in meta.items() if (p := _tdms_value(v)) is not None}
    timing = {"wf_increment": dt, "wf_start_offset": float(t[0]), "wf_samples": int(t.size)}
    objects = [RootObject(), GroupObject(GROUP, props)]
    for name, data, unit, extra in ((FORCE, force, "N", timing), (ACC, acc, "m/s^2", timing),
                                    (TIME, t, "s", {})):
        objects.append(ChannelObject(GROUP, name, np.asarray(data, float),
                                     properties={"unit_string": unit, **extra}))
    def write(tmp: Path):
        with TdmsWriter(str(tmp)) as writer:
            writer.write_segment(objects)

    return write_atomic(path, write)
