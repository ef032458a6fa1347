"""The forecast's coverage pooled over every replicate set run with the same interval
method (docs/COVERAGE.md, "The forecast").

The coverage rows in docs/data come from runs of `scripts/forecast_coverage.py` at
different commits. A quantity is pooled only over the sets whose code computed it the
same way:

- modal quantities and preloads (delta, the model over the refits): replicates 0-399;
- the FRC quantities (the quadratic model over the refits, floored at the delta
  half-width): 0-199 and 300-399 (200-299 ran before the floor);
- the first joint's lift-off (`liftoff_force_n`, the bearing's; the search itself at
  each refit): 0-199, the lift-off pass `--part liftoff` run again at that commit
  (before, the quadratic model with the carried Hessian, over 0-199 and 300-399);
- the second joint's (`liftoff_force_nut_n`, searched on the orbits): 0-199 (the same
  pass; its method is unchanged);
- the FRC's peak and folds (the model itself at each refit): replicates 0-99 run again
  with that method, and 100-199 with the lift-off also searched at each refit. These sets
  repeat seeds of 0-199, so they contribute those four quantities only, and 0-199 no
  longer does.

    python scripts/forecast_coverage_pool.py            # the table (Markdown) on stdout

Each set's replicates use their own seeds (`coverage_study.record_seeds`), so the sets are
independent draws of the same study.
"""

from __future__ import annotations

import gzip
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from forecast_coverage import markdown, overlay, summarize  # noqa: E402

DATA = ROOT / "docs" / "data"
WHOLE = {  # replicates -> the whole forecast's rows
    "0-199": "forecast_coverage_100N_refits_floor_0_199.jsonl.gz",
    "200-299": "forecast_coverage_100N_refits_200_299.jsonl.gz",
    "300-399": "forecast_coverage_100N_refits_floor_300_399.jsonl.gz",
    "0-99 followed": "forecast_coverage_100N_followed_0_99.jsonl.gz",
    "100-199 followed": "forecast_coverage_100N_followed_100_199.jsonl.gz",
}
LIFTOFF = {"0-199": "forecast_coverage_100N_liftoff_draws_0_199.jsonl.gz"}
FRC = ("peak_frequency_hz", "peak_amplitude_um", "fold_up_hz", "fold_down_hz",
       "liftoff_force_n", "liftoff_force_bearing_n")  # floored at the delta half-width
FOLLOWED = FRC[:4]  # the model itself at each refit
SEARCHED = FRC[4:]  # the lift-off search at each refit


def contributes(sets: str, quantity: str) -> bool:
    """Whether replicate set `sets` computed `quantity` as the current code does."""
    if quantity in FOLLOWED:
        return sets.endswith("followed")
    if sets.endswith("followed"):  # their seeds repeat 0-199's
        return False
    if quantity == "liftoff_force_nut_n" or quantity in SEARCHED:
        return sets in LIFTOFF
    return not (quantity in FRC and sets == "200-299")


def read(name: str) -> list[dict]:
    with gzip.open(DATA / name, "rt", encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]


def pooled() -> list[dict]:
    """One row per replicate with the quantities that set may contribute (others
    dropped, so `summarize` counts each quantity over its own sets only)."""
    rows = []
    for sets, name in WHOLE.items():
        part = read(name)
        if sets in LIFTOFF:
            part = overlay(part, read(LIFTOFF[sets]))
        rows += [dict(r, quantities={q: v for q, v in r["quantities"].items()
                                     if contributes(sets, q)}) for r in part]
    return rows


def main() -> int:
    rows = pooled()
    names = []
    for r in rows:  # every quantity that any set contributes, in first-seen order
        names += [q for q in r["quantities"] if q not in names]
    out = None
    for q in names:  # each quantity over the rows (sets) that carry it
        mine = [dict(r, quantities={q: r["quantities"][q]}) for r in rows
                if q in r["quantities"]]
        s = summarize(mine)
        if out is None:
            out = s
        else:
            out["quantities"].update(s["quantities"])
    out["replicates"] = len(rows)
    text = markdown(out, 100.0).splitlines()
    text[0] = (f"Forecast at 100 N, pooled over {len(rows)} replicates ({', '.join(WHOLE)}); "
               "each quantity over the sets whose code computed it as now (this script's "
               "docstring), so the counts differ.")
    sys.stdout.write("\n".join(text) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
