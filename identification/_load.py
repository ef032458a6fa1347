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


def load_records(paths) -> list[Record | FrfRecord]:
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
