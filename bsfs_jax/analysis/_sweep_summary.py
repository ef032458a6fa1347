"""The per-point records of a sweep's summary: the label, whether it is verified, its
evidence and the reason (one home for the format that `bsfs sweep` and `bsfs map` write).
"""

import numpy as np

from ..solvers import result_codes, result_text
from ._verify_settings import VERDICT_FIELDS


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def evidence(verdicts, d: int, i: int) -> dict:
    """The evidence of point (d, i) from a verdicts dict (NaN -> None)."""
    v = {k: a[d, i] for k, a in verdicts.items()}
    return {
        "orbit_residual": _num(v["orbit_residual"]),
        "max_multiplier": _num(v["max_multiplier"]),
        "lyapunov_per_period": _num(v["lyapunov_per_period"]),
        "lyapunov_per_period_95": [_num(v["lyapunov_low"]), _num(v["lyapunov_high"])],
        "rotation_number": _num(v["rotation_number"]),
        "curve_error": _num(v["curve_error"]),
        "spectral_line_fraction": _num(v["line_fraction"]),
        "transient": _num(v["transient"]),
    }


def point_records(result, settings=None) -> list[dict]:
    """One record per (direction, point) of a `SweepResult`.

    With the verifier's verdicts in `result.verdicts` (a verified sweep) the motion,
    amplitude, evidence and reason are the verifier's. Without, the sample-based
    candidate label is reported with `verified: false` and a reason saying so: it is
    never presented as a finding.
    """
    codes, texts = result_codes(result.result), result_text(result.result)
    verdicts = result.verdicts
    if verdicts is not None and not set(VERDICT_FIELDS) <= set(verdicts):
        verdicts = None  # other per-point entries, not the verifier's
    motions = None if verdicts else result.motions(settings)
    time_key = "transient_s" if result.time_unit == "s" else "transient"
    out = []
    for d, direction in enumerate(result.directions):
        for i in range(result.values.size):
            rec = {"direction": direction, "index": i,
                   result.param: float(result.values[i])}
            if verdicts:
                ev = evidence(verdicts, d, i)
                ev[time_key] = ev.pop("transient")
                rec.update(amplitude=_num(verdicts["amplitude"][d, i]),
                           motion=str(verdicts["motion"][d, i]),
                           period_n=int(verdicts["period_n"][d, i]),
                           verified=bool(verdicts["verified"][d, i]), evidence=ev,
                           reason=str(verdicts["reason"][d, i]))
            else:
                m = motions[d][i]
                rec.update(amplitude=_num(result.amplitude[d, i, result.observe]),
                           motion=m.label, period_n=m.period, verified=False,
                           evidence={"lyapunov_per_period": _num(m.lyapunov_per_period),
                                     "spectral_line_fraction": _num(m.line_fraction)},
                           reason="not verified: a label read from the samples of a "
                                  "fixed transient (run the sweep with verification)")
            rec.update(status=int(codes[d, i]), status_message=str(texts[d, i]))
            out.append(rec)
    return out


def motion_counts(records) -> dict:
    """{label: count} over records, verified labels only; unverified ones under
    "unresolved" (failed ones under "failed")."""
    counts: dict = {}
    for r in records:
        label = r["motion"] if (r["verified"] or r["motion"] == "failed") else "unresolved"
        counts[label] = counts.get(label, 0) + 1
    return dict(sorted(counts.items()))
