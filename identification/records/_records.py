"""Exciter records: the record types and the checks shared by formats (the base of the
readers; loading by file type is `_load.py`).

Two kinds of record:

- `Record`: time data, force on the worktable and worktable acceleration sampled uniformly,
  from a stepped-sine (`excitation = sine`, the default), swept-sine (`chirp`) or random
  (`random`) test;
- `FrfRecord`: a frequency response function, worktable acceleration over exciter force
  (accelerance, (m/s^2)/N) with the variance of each line, from an analyser or hammer test
  or estimated from a chirp/random record (both in `_frf.py`).

`load_record(path)` (`_load.py`) dispatches on the extension (`.csv`: `_csv.py`;
`.uff`/`.unv` UFF58: `_uff.py`; `.tdms`: `_tdms.py`) and on the content (`# kind = frf` in a
CSV header; UFF58 function type 4). A bad file is refused with a `RecordError` that names
the file, the line or field, and what to do; the loaders never drop or repair data
silently.

Header keys of a time record (`# key = value` in CSV, `key=value` in the UFF id lines):

- all: `sample_rate_hz`, `speed_rpm`, `ambient_c`; optional `excitation` (sine),
  `force_range_n`, `acceleration_range_m_s2` (full-scale ranges, for the clipping check);
- sine: `frequency_hz`, `force_amplitude_n` (amplitude of the fundamental);
- chirp: `start_hz`, `stop_hz`, `force_amplitude_n` (the sweep's constant amplitude);
- random: `force_rms_n` (RMS force); optional `start_hz`, `stop_hz` (the drive band);
- optional `antialias_filter`, `antialias_order`, `antialias_cutoff_hz`,
  `antialias_design_rate_hz`: the acquisition's anti-alias filter (`_antialias.py`), divided
  out of a sine record's harmonics.

For chirp and random records `Record.frequency_hz` is NaN (there is no single frequency)
and `Record.force_amplitude_n` holds the header's force level (the RMS for random).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from ._antialias import filter_problem

COLUMNS = ("time_s", "force_n", "acceleration_m_s2")
EXCITATIONS = ("sine", "chirp", "random")
FRF_EXCITATIONS = ("chirp", "random", "hammer", "frf")
COMMON_META = ("sample_rate_hz", "speed_rpm", "ambient_c")
REQUIRED_META = ("frequency_hz", "force_amplitude_n", "sample_rate_hz", "speed_rpm", "ambient_c")
_LEVEL_KEY = {"sine": "force_amplitude_n", "chirp": "force_amplitude_n", "random": "force_rms_n"}
MIN_PERIODS = 20
MIN_BROADBAND_SAMPLES = 1024
MIN_BAND_LINES = 20  # a chirp's band must hold this many lines of 1/duration
BAND_POWER_MIN = 0.8  # share of the force's power inside a chirp/random record's band
# Relative tolerances of the checks (documented in the error messages).
TIME_JITTER_REL = 1e-2  # sample spacing may differ from the median by 1 %
SAMPLE_RATE_REL = 1e-3  # header sample rate vs time column
CLIP_FRACTION = 0.999  # |x| >= 99.9 % of a channel's full-scale range counts as clipped
CLIP_RUN = 3  # or >= 3 consecutive samples stuck at the channel's extreme value


class RecordError(ValueError):
    """A record file is malformed or unusable; the message names file, line and the fix."""


@dataclasses.dataclass(frozen=True)
class Record:
    """One exciter time record (SI units).

    - `time` [s], `force` [N], `acceleration` [m/s^2]: 1-D arrays of equal length;
    - `frequency_hz` (NaN for chirp/random), `force_amplitude_n` (the force level: amplitude
      for sine and chirp, RMS for random), `sample_rate_hz`, `speed_rpm`, `ambient_c`;
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
    def excitation(self) -> str:
        """"sine", "chirp" or "random" (header key `excitation`; default sine)."""
        return str(self.meta.get("excitation", "sine"))

    @property
    def start_hz(self) -> float | None:
        """Lower band edge of a chirp or random record [Hz] (None for a sine)."""
        v = self.meta.get("start_hz")
        return float(v) if isinstance(v, float) else None

    @property
    def stop_hz(self) -> float | None:
        """Upper band edge of a chirp or random record [Hz] (None for a sine)."""
        v = self.meta.get("stop_hz")
        return float(v) if isinstance(v, float) else None

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0] + 1.0 / self.sample_rate_hz)

    @property
    def periods(self) -> float:
        return self.duration * self.frequency_hz

    def summary(self) -> str:
        tail = (f"{self.speed_rpm:g} r/min, {self.time.size} samples at "
                f"{self.sample_rate_hz:g} Hz ({self.duration:.2f} s)")
        if self.excitation == "sine":
            return f"{self.name}: {self.frequency_hz:g} Hz, {self.force_amplitude_n:g} N, {tail}"
        band = (f" {self.start_hz:g}-{self.stop_hz:g} Hz" if self.start_hz is not None
                and self.stop_hz is not None else "")
        level = "N RMS" if self.excitation == "random" else "N"
        return f"{self.name}: {self.excitation}{band}, {self.force_amplitude_n:g} {level}, {tail}"




def parse_value(text: str):
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    try:
        return float(text)
    except ValueError:
        return text


def excitation_of(path, meta: dict, allowed=EXCITATIONS, default="sine") -> str:
    kind = meta.get("excitation", default)
    if kind not in allowed:
        raise RecordError(f"{path}: header 'excitation = {kind}' is not one of "
                          f"{', '.join(allowed)}.")
    return str(kind)


def required_meta(excitation: str) -> tuple:
    if excitation == "chirp":
        return ("start_hz", "stop_hz", "force_amplitude_n", *COMMON_META)
    if excitation == "random":
        return ("force_rms_n", *COMMON_META)
    return REQUIRED_META


def check_numbers(path, meta: dict, keys, positive=(), line_hint="above the column header"):
    missing = [k for k in keys if k not in meta]
    if missing:
        raise RecordError(f"{path}: header key(s) {', '.join(missing)} missing. Add lines like "
                          f"'# {missing[0]} = ...' {line_hint}.")
    for k in keys:
        v = meta[k]
        if not isinstance(v, float) or not math.isfinite(v):
            raise RecordError(f"{path}: header '{k} = {v}' is not a finite number.")
    for k in positive:
        if k in meta and meta[k] <= 0:
            raise RecordError(f"{path}: header '{k} = {meta[k]:g}' must be positive.")
    if "speed_rpm" in keys and meta["speed_rpm"] < 0:
        raise RecordError(f"{path}: header 'speed_rpm = {meta['speed_rpm']:g}' must be >= 0.")


def check_meta(path, meta: dict) -> str:
    """Check a time record's header; returns its excitation."""
    kind = excitation_of(path, meta)
    keys = required_meta(kind)
    optional_band = [k for k in ("start_hz", "stop_hz") if k in meta and k not in keys]
    check_numbers(path, meta, (*keys, *optional_band),
                  positive=("frequency_hz", "force_amplitude_n", "force_rms_n", "sample_rate_hz",
                            "start_hz", "stop_hz"))
    if ("start_hz" in meta) != ("stop_hz" in meta):
        raise RecordError(f"{path}: give both start_hz and stop_hz (the excited band) or "
                          "neither.")
    if "start_hz" in meta and not meta["start_hz"] < meta["stop_hz"]:
        raise RecordError(f"{path}: header start_hz = {meta['start_hz']:g} must be below "
                          f"stop_hz = {meta['stop_hz']:g}.")
    problem = filter_problem(meta)
    if problem:
        raise RecordError(f"{path}: {problem}")
    return kind


def finish(path, t, force, acc, meta, line_of) -> Record:
    """All checks of a time record that do not depend on the file format. `line_of(i)`
    names sample i."""
    kind = check_meta(path, meta)
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
    _check_time(path, t, float(meta["sample_rate_hz"]), line_of)
    fs = float(meta["sample_rate_hz"])
    for name, x, key in (("force_n", force, "force_range_n"),
                         ("acceleration_m_s2", acc, "acceleration_range_m_s2")):
        _check_clipping(path, name, x, meta.get(key), line_of)
    if kind == "sine":
        _check_sine(path, force, meta, n / fs)
        f0 = float(meta["frequency_hz"])
    else:
        _check_broadband(path, force, meta, kind, n)
        f0 = math.nan
    return Record(np.asarray(t, float), np.asarray(force, float), np.asarray(acc, float),
                  f0, float(meta[_LEVEL_KEY[kind]]), fs, float(meta["speed_rpm"]),
                  float(meta["ambient_c"]), dict(meta), str(path))


def _check_time(path, t, fs, line_of):
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = bad[0] + 1
        raise RecordError(f"{line_of(i)}: time_s = {float(t[i])!r} does not increase (previous "
                          f"{float(t[i - 1])!r}). Time must increase strictly; fix the export.")
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


def _check_sine(path, force, meta, duration):
    fs, f0 = float(meta["sample_rate_hz"]), float(meta["frequency_hz"])
    if duration * f0 < MIN_PERIODS:
        raise RecordError(
            f"{path}: only {duration * f0:.1f} excitation periods ({duration:.3f} s at {f0:g} Hz);"
            f" at least {MIN_PERIODS} are needed for a steady-state estimate. Record longer.")
    if f0 >= 0.5 * fs:
        raise RecordError(f"{path}: frequency_hz = {f0:g} is not below the Nyquist frequency "
                          f"{0.5 * fs:g} Hz of sample_rate_hz = {fs:g}.")
    f_dom = dominant_frequency(force, fs)
    tol = max(1.5 / duration, 0.01 * f0)
    if abs(f_dom - f0) > tol:
        raise RecordError(
            f"{path}: header frequency_hz = {f0:g} but the measured force's dominant frequency is "
            f"{f_dom:.4g} Hz. Correct the header (or check the channel assignment).")


def _check_broadband(path, force, meta, kind, n):
    fs = float(meta["sample_rate_hz"])
    if n < MIN_BROADBAND_SAMPLES:
        raise RecordError(f"{path}: only {n} samples; a {kind} record needs at least "
                          f"{MIN_BROADBAND_SAMPLES} for an FRF estimate. Record longer.")
    if "stop_hz" not in meta:
        return
    lo, hi = float(meta["start_hz"]), float(meta["stop_hz"])
    if hi >= 0.5 * fs:
        raise RecordError(f"{path}: stop_hz = {hi:g} is not below the Nyquist frequency "
                          f"{0.5 * fs:g} Hz of sample_rate_hz = {fs:g}.")
    if (hi - lo) * n / fs < MIN_BAND_LINES:
        raise RecordError(f"{path}: the band {lo:g}-{hi:g} Hz holds only "
                          f"{(hi - lo) * n / fs:.1f} lines of 1/duration; record longer or "
                          "sweep a wider band.")
    x = np.asarray(force, float) - np.mean(force)
    spec = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(n, 1.0 / fs)
    slack = 0.1 * (hi - lo)
    share = float(np.sum(spec[(f >= lo - slack) & (f <= hi + slack)]) / max(np.sum(spec), 1e-300))
    if share < BAND_POWER_MIN:
        raise RecordError(
            f"{path}: only {100 * share:.0f} % of the force's power lies in the header's band "
            f"{lo:g}-{hi:g} Hz (at least {100 * BAND_POWER_MIN:.0f} % expected). Correct "
            "start_hz/stop_hz (or check the channel assignment).")


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



def unpack(record_or_arrays, meta):
    """(t, force, acc, meta) of a `Record` or of a (t, force, acc) tuple plus `meta`."""
    if isinstance(record_or_arrays, Record):
        r = record_or_arrays
        return r.time, r.force, r.acceleration, dict(r.meta)
    t, force, acc = record_or_arrays
    return np.asarray(t), np.asarray(force), np.asarray(acc), dict(meta or {})


def format_meta_value(v, digits: int = 10) -> str | None:
    """Header text of a meta value (None: not writable, skipped)."""
    if isinstance(v, str):
        return repr(v)
    if isinstance(v, bool):
        return repr(str(v).lower())
    if isinstance(v, (int, float, np.integer, np.floating)):
        return f"{float(v):.{digits}g}"
    return None
