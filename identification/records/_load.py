"""Loading records: each file is read by the reader of its suffix (`.csv`, `.uff`/`.unv`
UFF58, `.tdms`). The readers build on `_records.py` (the `Record` type and its checks); this
module sits above them, so that the base does not import its own readers."""

from __future__ import annotations

import os
from pathlib import Path

from ._csv import load_csv
from ._frf import FrfRecord
from ._records import Record, RecordError
from ._tdms import load_tdms
from ._uff import load_uff


def load_record(path) -> Record | FrfRecord:
    """Read and check one record (`.csv`, `.uff`/`.unv` UFF58 or `.tdms`): a time `Record` or an
    `FrfRecord`. Raises `RecordError`."""
    path = Path(path)
    if not path.exists():
        raise RecordError(f"{path}: no such file. Give the path of a record (.csv, .uff or "
                          ".tdms).")
    if path.suffix.lower() in (".uff", ".unv"):
        return load_uff(path)
    if path.suffix.lower() == ".tdms":
        return load_tdms(path)
    return load_csv(path)


# Peak memory of reading a time record and estimating its FRF, per sample, and the rest of
# an identification (measured on the 2-core machine: a 120 s chirp at 51.2 kHz, 6.1 M
# samples, 1.8 GB to read and transform; an identification of a short record, 0.9 GB).
BYTES_PER_SAMPLE = 300
BASE_BYTES = 1.0e9
# The fewest file bytes one sample takes, by format (a CSV row of time, force and
# acceleration is about 29; TDMS stores two float64 channels), so that the sample count
# is, if anything, overestimated.
_FILE_BYTES_PER_SAMPLE = {".csv": 20, ".uff": 20, ".unv": 20, ".tdms": 16}


def available_memory() -> float | None:
    """Bytes of memory free for a new process (Linux's MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        return None
    return None


def check_memory(paths, available: float | None = None) -> None:
    """Refuse, before any is read, records whose estimated peak memory exceeds what the
    machine has free (`available` bytes; default `available_memory()`): one line naming
    the file, its size, the estimate and what to do. Raises `RecordError`."""
    available = available_memory() if available is None else available
    if available is None:
        return
    total = BASE_BYTES
    biggest = None
    for p in paths:
        try:
            size = os.path.getsize(p)
        except OSError:
            continue  # `load_record` names a missing file
        samples = size / _FILE_BYTES_PER_SAMPLE.get(Path(p).suffix.lower(), 20)
        total += BYTES_PER_SAMPLE * samples
        if biggest is None or size > biggest[1]:
            biggest = (p, size, samples)
    if biggest is not None and total > 0.9 * available:
        p, size, samples = biggest
        raise RecordError(
            f"{p}: {size / 1e6:.0f} MB (up to {samples / 1e6:.1f} M samples) would need about "
            f"{total / 1e9:.1f} GB of memory, more than the {available / 1e9:.1f} GB free. "
            "Decimate the record (a lower sample rate that still covers the band), shorten it, "
            "or export its FRF and fit that (with --max-lines for very many lines).")


def load_records(paths) -> list[Record | FrfRecord]:
    """Read several records; refuses duplicates of the same file, and records too large
    for the machine's free memory (`check_memory`) before reading any."""
    check_memory(paths)
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
