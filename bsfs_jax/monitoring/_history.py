"""A drive's test history: reading it (a CSV, or a manifest of `bsfs identify` folders)
and checking it."""

import csv
import dataclasses
import json
import math
from pathlib import Path

import numpy as np


class HistoryError(ValueError):
    """A history that cannot be monitored; the message is one line saying why."""


@dataclasses.dataclass(frozen=True)
class Series:
    """One quantity over the tests: `values` (n,) in `unit`, `std` (n,) each value's
    standard error in `unit` (None when the history gives none)."""

    name: str
    unit: str
    values: np.ndarray
    std: np.ndarray | None = None

    def to_dict(self) -> dict:
        return dict(name=self.name, unit=self.unit, values=self.values.tolist(),
                    std=None if self.std is None else self.std.tolist())


@dataclasses.dataclass(frozen=True)
class History:
    """Tests of one drive: `hours` (n,) operating hours, strictly increasing; `series`:
    one `Series` per quantity, by name; `source`: where it was read from."""

    hours: np.ndarray
    series: dict
    source: str = ""

    def __post_init__(self):
        check_history(self)


def check_history(h: History) -> None:
    """Raise HistoryError (one line) for fewer than 3 tests, hours not increasing, a
    series of another length, a non-finite value or a non-positive standard error."""
    t = np.asarray(h.hours, float)
    if t.ndim != 1 or len(t) < 3:
        raise HistoryError(f"{h.source or 'history'}: {len(t)} test(s); a trend needs at "
                           "least 3")
    if not np.all(np.isfinite(t)):
        raise HistoryError(f"{h.source or 'history'}: an hours value is not a number")
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0])
        raise HistoryError(f"{h.source or 'history'}: hours not increasing ({t[i]:g} then "
                           f"{t[i + 1]:g}, tests {i + 1} and {i + 2})")
    if not h.series:
        raise HistoryError(f"{h.source or 'history'}: no quantity to monitor")
    for s in h.series.values():
        if len(s.values) != len(t) or not np.all(np.isfinite(s.values)):
            raise HistoryError(f"{h.source or 'history'}: '{s.name}' needs a finite value "
                               "at every test")
        if s.std is not None:
            bad = np.nonzero(~(np.asarray(s.std) > 0) | ~np.isfinite(s.std))[0]
            if bad.size:
                raise HistoryError(f"{h.source or 'history'}: '{s.name}_std' must be a "
                                   f"positive number, got {s.std[bad[0]]:g} at "
                                   f"{t[bad[0]]:g} h")


def _number(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise HistoryError(f"{where}: '{text.strip()[:40]}' is not a number") from None
    if not math.isfinite(value):
        raise HistoryError(f"{where}: '{text.strip()[:40]}' is not a finite number")
    return value


def _rows(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise HistoryError(f"'{path}': no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise HistoryError(f"'{path}': cannot read it ({exc})") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise HistoryError(f"'{path}': empty file")
    rows = list(csv.reader(lines))
    return [c.strip() for c in rows[0]], rows[1:]


def _unit(name: str) -> tuple[str, str]:
    """'preload [N]' -> ('preload', 'N'); no bracket -> (name, '')."""
    if name.endswith("]") and "[" in name:
        base, unit = name[:-1].split("[", 1)
        return base.strip(), unit.strip()
    return name, ""


def read_history_csv(path) -> History:
    """A history CSV: a header line, first column `hours`, one column per quantity
    (`NAME` or `NAME [unit]`), optionally `NAME_std` with each value's standard error."""
    path = Path(path)
    header, rows = _rows(path)
    if not header or header[0].lower() != "hours":
        raise HistoryError(f"'{path}': the first column must be 'hours', got "
                           f"'{header[0] if header else ''}'")
    names = [_unit(h) for h in header]
    plain = [n for n, _ in names]
    if len(set(plain)) != len(plain):
        raise HistoryError(f"'{path}': a column name appears twice")
    cols = {n: [] for n in plain}
    for i, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise HistoryError(f"'{path}' line {i}: {len(row)} values for {len(header)} "
                               "columns")
        for n, cell in zip(plain, row):
            cols[n].append(_number(cell, f"'{path}' line {i}, column '{n}'"))
    hours = np.asarray(cols.pop(plain[0]), float)
    series = {}
    for (n, unit) in names[1:]:
        if n.endswith("_std"):
            if n[:-4] not in cols:
                raise HistoryError(f"'{path}': column '{n}' has no quantity '{n[:-4]}'")
            continue
        std = cols.get(n + "_std")
        series[n] = Series(n, unit, np.asarray(cols[n], float),
                           None if std is None else np.asarray(std, float))
    return History(hours, series, str(path))


def _folder_quantities(folder: Path) -> dict:
    """{name: (value, std, unit)} from report.json's parameters and, where present,
    prediction.json's quantities (std from the 95 % interval's half width / 1.96)."""
    report = folder / "report.json"
    if not report.is_file():
        raise HistoryError(f"'{folder}': no report.json (not a `bsfs identify --out` folder)")
    try:
        data = json.loads(report.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise HistoryError(f"'{report}': cannot read it ({exc})") from None
    out = {}
    for name, row in (data.get("parameters") or {}).items():
        if row.get("value") is not None:
            out[name] = (float(row["value"]), row.get("std"), row.get("unit", ""))
    pred = folder / "prediction.json"
    if pred.is_file():
        try:
            quantities = json.loads(pred.read_text()).get("quantities") or []
        except (OSError, json.JSONDecodeError) as exc:
            raise HistoryError(f"'{pred}': cannot read it ({exc})") from None
        for q in quantities:
            ci = q.get("ci95")
            if q.get("value") is None:
                continue
            std = (ci[1] - ci[0]) / (2 * 1.959964) if ci and None not in ci else None
            out[q["name"]] = (float(q["value"]), std, q.get("unit", ""))
    return out


def read_manifest(path) -> History:
    """A manifest CSV `folder,hours` of `bsfs identify --out` folders (relative paths
    from the manifest's folder): every identified parameter with a standard error at every
    test, and every `bsfs predict` quantity found in all folders, becomes a series."""
    path = Path(path)
    header, rows = _rows(path)
    if [h.lower() for h in header[:2]] != ["folder", "hours"]:
        raise HistoryError(f"'{path}': a manifest's header is 'folder,hours', got "
                           f"'{','.join(header)}'")
    folders, hours = [], []
    for i, row in enumerate(rows, start=2):
        if len(row) < 2:
            raise HistoryError(f"'{path}' line {i}: expected folder,hours")
        f = Path(row[0].strip())
        folders.append(f if f.is_absolute() else path.parent / f)
        hours.append(_number(row[1], f"'{path}' line {i}, column 'hours'"))
    per = [_folder_quantities(f) for f in folders]
    names = [n for n in per[0] if all(n in p for p in per)] if per else []
    series = {}
    for n in names:
        vals = [p[n] for p in per]
        if any(v[1] is None or not v[1] > 0 for v in vals):
            continue  # undetermined in some test: no standard error to weight it by
        series[n] = Series(n, vals[0][2] or "", np.array([v[0] for v in vals]),
                           np.array([float(v[1]) for v in vals]))
    if per and not series:
        raise HistoryError(f"'{path}': no quantity has a value and a standard error in "
                           "every folder")
    return History(np.asarray(hours, float), series, str(path))
