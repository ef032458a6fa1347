"""Side-by-side comparison of our sensitivity signs with the paper's one-at-a-time trends.

Yang et al. (2022) vary one parameter at a time at a few levels and read the trend off
amplitude-frequency curves, bifurcation diagrams and time histories at large forces
(5000 N, chaotic regimes). Our sensitivities are local derivatives at one design and one
operating point. `paper_crosscheck` lines them up and says, per row, whether the signs
agree; the mechanisms behind agreements and differences are discussed in the notebook
and in the CLI report.
"""

import numpy as np

#: (parameter, figure, the paper's statement, metric, expected sign of d metric / d p).
#: Expected sign 0 marks a non-monotone claim (an interior optimum near the current value).
PAPER_TRENDS: tuple[dict, ...] = (
    {"parameter": "nut.balls", "figure": "Fig. 25",
     "claim": "more nut balls: more stable (no chaos in the main resonance at 60)",
     "metric": "floquet", "expected": -1},
    {"parameter": "bearing.balls", "figure": "Fig. 24",
     "claim": "more bearing balls: more stable (fewer period-n windows)",
     "metric": "floquet", "expected": -1},
    {"parameter": "nut.contact_angle_deg", "figure": "Fig. 27",
     "claim": "larger nut contact angle: less stable (extra jump at 50 deg)",
     "metric": "floquet", "expected": +1},
    {"parameter": "bearing.contact_angle_deg", "figure": "Fig. 26",
     "claim": "larger bearing contact angle: less stable; resonance moves up",
     "metric": "floquet", "expected": +1},
    {"parameter": "bearing.contact_angle_deg", "figure": "Fig. 26",
     "claim": "resonance frequency rises with the bearing contact angle",
     "metric": "natural_frequency", "expected": +1},
    {"parameter": "thermal.speed_rpm", "figure": "Figs. 14-15",
     "claim": "lower speed: smaller amplitude (37.0 / 41.8 / 60.5 um at 1000/2000/3000 r/min)",
     "metric": "amplitude", "expected": +1},
    {"parameter": "thermal.speed_rpm", "figure": "Figs. 14-15",
     "claim": "lower speed: smaller resonance amplitude",
     "metric": "frc_peak", "expected": +1},
    {"parameter": "nut.preload_n", "figure": "Figs. 16-17",
     "claim": "1500 N preload best (51.4 / 41.8 / 51.8 um at 1000/1500/2000 N)",
     "metric": "amplitude", "expected": 0},
    {"parameter": "nut.preload_n", "figure": "Figs. 16-17",
     "claim": "1500 N preload best (resonance amplitude)", "metric": "frc_peak", "expected": 0},
    {"parameter": "nut.ball_diameter_mm", "figure": "Fig. 23",
     "claim": "larger nut balls: larger amplitudes", "metric": "amplitude", "expected": +1},
    {"parameter": "bearing.ball_diameter_mm", "figure": "Fig. 22",
     "claim": "larger bearing balls: larger amplitudes", "metric": "amplitude",
     "expected": +1},
)

_SIGN = {1: "+", -1: "-", 0: "0 (optimum)"}


def _sign_text(s, tol):
    if not np.isfinite(s):
        return "n/a"
    if abs(s) < tol:
        return f"~0 ({s:+.2g})"
    return f"{'+' if s > 0 else '-'} ({s:+.3g})"


def paper_crosscheck(results: dict, *, negligible: float = 1e-3) -> list[dict]:
    """Rows comparing the paper's trends with our normalised sensitivities.

    `results` maps metric name -> `SensitivityResult`. A normalised sensitivity below
    `negligible` in magnitude counts as "no effect". Rows whose metric or parameter is
    missing from `results` are skipped. Each row: parameter, figure, claim, metric,
    expected, ours (text), normalised (float), agrees (True/False/None).
    """
    rows = []
    for trend in PAPER_TRENDS:
        res = results.get(trend["metric"])
        if res is None or trend["parameter"] not in res.names:
            continue
        s = float(res.normalised[res.names.index(trend["parameter"])])
        exp = trend["expected"]
        if not np.isfinite(s):
            agrees = None
        elif exp == 0:
            agrees = abs(s) < 0.05  # an interior optimum: a small local slope
        else:
            agrees = bool(abs(s) >= negligible and np.sign(s) == exp)
        rows.append({**trend, "expected_text": _SIGN[exp], "ours": _sign_text(s, negligible),
                     "normalised": s, "agrees": agrees})
    return rows


def crosscheck_markdown(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = ["| parameter | paper (figure) | metric | paper's sign | our d ln m / d ln p | "
             "agree? |", "|---|---|---|---|---|---|"]
    for r in rows:
        agree = {True: "yes", False: "**no**", None: "n/a"}[r["agrees"]]
        lines.append(f"| `{r['parameter']}` | {r['claim']} ({r['figure']}) | {r['metric']} | "
                     f"{r['expected_text']} | {r['ours']} | {agree} |")
    return "\n".join(lines)
