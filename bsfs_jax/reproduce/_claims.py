"""The paper's claims (physics.md section 6) and how this model's numbers are judged.

Each `Claim` holds the paper's figure(s), condition and result as physics.md states them.
`judge_*` functions turn the numbers a reproduction run computed into a verdict with its
reason; the rules are written out here so the report is reproducible and auditable.
"""

import dataclasses

REPRODUCED, PARTLY, NOT_REPRODUCED, NOT_CHECKABLE = (
    "reproduced", "partly", "not reproduced", "not checkable")


@dataclasses.dataclass(frozen=True)
class Claim:
    """One row of physics.md section 6."""

    key: str
    figures: str
    condition: str
    paper: str


CLAIMS = (
    Claim("fig13", "13", "with vs without thermal deformation",
          "amplitude clearly larger with thermal deformation"),
    Claim("fig14_15", "14-15", "n = 1000 / 2000 / 3000 r/min",
          "amplitude 37.04 / 41.84 / 60.48 um (grows with speed)"),
    Claim("fig16_17", "16-17", "preload 1000 / 1500 / 2000 N",
          "51.40 / 41.80 / 51.82 um (1500 N best)"),
    Claim("fig18", "18", "500 Hz, 5000 N", "period-1, amplitude 250 um"),
    Claim("fig19", "19", "1082 Hz, 5000 N", "period-7, max amplitude 85.12 um"),
    Claim("fig20", "20", "382 Hz, 5000 N", "quasi-periodic, 226 um"),
    Claim("fig21", "21", "636.6 Hz, 5000 N", "chaotic, 544.5 um"),
    Claim("fig22_23", "22-23", "bearing / nut ball diameter",
          "dominant and multiple-frequency amplitudes grow with diameter"),
    Claim("fig24", "24", "bearing balls 13/16/20",
          "chaos in resonance zone for all; 13: period-2, period-3; 20: quasi-periodic at "
          "3342 Hz"),
    Claim("fig25", "25", "nut balls 40/50/60",
          "chaos in main resonance for 40, 50; none for 60; 60: period-2/3/3/5 at "
          "986.8/1401/1432/2196 Hz"),
    Claim("fig26", "26", "bearing contact angle 30/40/50 deg",
          "resonance rises with angle; hard jump at peak; secondary jumps ~1200 Hz (30), "
          "~1500 Hz (40); soft near 200 Hz"),
    Claim("fig27", "27", "nut contact angle 30/40/50 deg",
          "hard jump at peak; secondary jump ~1460 Hz at 50 deg; soft near 200 Hz"),
    Claim("fig10_12", "10-12", "exciter 100 N at 100/120/150 Hz",
          "measured worktable acceleration agrees with the model"),
)

CLAIM_KEYS = tuple(c.key for c in CLAIMS)


def by_key(key: str) -> Claim:
    for c in CLAIMS:
        if c.key == key:
            return c
    raise KeyError(f"no claim '{key}'; known: {', '.join(CLAIM_KEYS)}")


def _um(x) -> str:
    return f"{x * 1e6:.1f} um"


def judge_increase(with_amp: float, without_amp: float, *, clear: float = 0.05):
    """Fig. 13: amplitude with thermal deformation vs without."""
    ratio = with_amp / without_amp
    if ratio > 1.0 + clear:
        return REPRODUCED, f"{_um(with_amp)} with vs {_um(without_amp)} without (x{ratio:.3f})"
    if ratio > 1.0:
        return PARTLY, (f"larger with thermal deformation, but only by {100 * (ratio - 1):.1f} % "
                        f"({_um(with_amp)} vs {_um(without_amp)}), not 'clearly'")
    return NOT_REPRODUCED, (f"not larger: {_um(with_amp)} with vs {_um(without_amp)} without "
                            f"(x{ratio:.3f})")


def judge_monotone_growth(amps, paper_amps):
    """Figs. 14-15: amplitude grows with speed (paper: +63 % from 1000 to 3000 r/min)."""
    growing = all(b > a for a, b in zip(amps, amps[1:]))
    gain = amps[-1] / amps[0] - 1.0
    paper_gain = paper_amps[-1] / paper_amps[0] - 1.0
    text = " / ".join(f"{a * 1e6:.2f}" for a in amps) + " um"
    if growing and gain > 0.5 * paper_gain:
        return REPRODUCED, (f"{text}: grows with speed (+{100 * gain:.1f} %, paper "
                            f"+{100 * paper_gain:.0f} %)")
    if growing:
        return PARTLY, (f"{text}: grows with speed as in the paper, but by +{100 * gain:.1f} % "
                        f"instead of +{100 * paper_gain:.0f} %")
    return NOT_REPRODUCED, f"{text}: does not grow monotonically with speed"


def judge_preload_optimum(amps):
    """Figs. 16-17: 1500 N (middle) has the smallest amplitude."""
    text = " / ".join(f"{a * 1e6:.2f}" for a in amps) + " um"
    if amps[1] < amps[0] and amps[1] < amps[2]:
        return REPRODUCED, f"{text}: the middle preload (1500 N) is the minimum"
    best = ("1000", "1500", "2000")[min(range(3), key=lambda i: amps[i])]
    return NOT_REPRODUCED, (f"{text}: the minimum is at {best} N, not 1500 N (in this model a "
                            "higher preload stiffens the joints more than it heats them)")


def judge_motion(found_kind: str, found_label: str, wanted_kind: str, wanted_label: str,
                 amp: float, paper_amp: float, *, reason: str = ""):
    """Figs. 18-21: motion type at one frequency, from the *verified* label.

    Reproduced: the same motion and an amplitude within 25 %; partly: the same motion with
    another amplitude, or a subharmonic (period-n > 1) of another order; an "unresolved"
    or "failed" label (no evidence for any motion) is not checkable, with the verifier's
    `reason`, never a guess; otherwise not reproduced. `found_kind`/`wanted_kind` are kept
    for the callers' records."""
    amp_text = f"{_um(amp)} (paper {paper_amp * 1e6:.1f} um)"
    if found_label in ("unresolved", "failed"):
        return NOT_CHECKABLE, (f"{found_label} (paper: {wanted_label}): "
                               f"{reason or 'no evidence for any motion'}")
    if found_label == wanted_label:
        return REPRODUCED if abs(amp / paper_amp - 1.0) < 0.25 else PARTLY, (
            f"{found_label} as in the paper; amplitude {amp_text}")
    subharmonic = (found_label.startswith("period-") and found_label != "period-1"
                   and wanted_label.startswith("period-") and wanted_label != "period-1")
    if subharmonic:
        return PARTLY, (f"{found_label} (paper: {wanted_label}): subharmonic motion, but of "
                        f"another order; amplitude {amp_text}")
    return NOT_REPRODUCED, f"{found_label} here (paper: {wanted_label}); amplitude {amp_text}"
