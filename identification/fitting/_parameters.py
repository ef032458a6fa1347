"""The fitted parameters' vocabulary: names, keys, transforms, default priors, fit sets,
and parsing of the `--fit` and `--prior` options (see `_problem.py` for the
parametrisation theta)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class FitParameter:
    key: str  # vocabulary key written to identified.toml
    transform: str  # "log" (positive) or "offset" (signed, micrometres)
    unit: str
    doc: str
    prior_sigma: float  # default prior std of theta (log: relative; offset: um)
    per_speed: bool = False


FIT_PARAMETERS = {
    "nut_k": FitParameter("nut.hertz_k_m_per_n23", "log", "m/N^(2/3)",
                          "Hertz coefficient K_n of the screw-nut joint (larger = softer)", 0.5),
    "bearing_k": FitParameter("bearing.hertz_k_m_per_n23", "log", "m/N^(2/3)",
                              "Hertz coefficient K_b of the bearing joint (larger = softer)",
                              0.5),
    "nut_preload": FitParameter("nut.preload_n", "log", "N",
                                "preload F_pn of the double nut (Hertz coefficient from the "
                                "geometry)", 0.5),
    "bearing_preload": FitParameter("bearing.preload_n", "log", "N",
                                    "preload F_pb of the bearing pair (Hertz coefficient from "
                                    "the geometry)", 0.5),
    "screw_k": FitParameter("screw.stiffness_n_per_um", "log", "N/um", "screw stiffness k_s",
                            0.5),
    "c_b": FitParameter("damping.bearing_n_s_per_m", "log", "N s/m", "bearing damping c_b", 1.0),
    "c_s": FitParameter("damping.screw_n_s_per_m", "log", "N s/m", "screw damping c_s", 1.0),
    "c_n": FitParameter("damping.nut_n_s_per_m", "log", "N s/m", "nut-joint damping c_n", 1.0),
    "expansion": FitParameter("thermal.expansion_per_k", "log", "1/K",
                              "thermal expansion coefficient (scales D_n and D_b at all speeds)",
                              0.3),
    "d_n": FitParameter("thermal.nut_offset_um", "offset", "um",
                        "thermal offset D_n of the nut joint, one per spindle speed", 1.0, True),
    "d_b": FitParameter("thermal.bearing_offset_um", "offset", "um",
                        "thermal offset D_b of the bearing joint, one per spindle speed", 1.0,
                        True),
}
DEFAULT_FIT = ("nut_k", "bearing_k", "screw_k", "c_b", "c_s", "c_n", "expansion")
PRELOAD_FIT = ("nut_preload", "bearing_preload", "c_b", "c_s", "c_n")
# Harmonics above this fraction of the sample rate are not used (anti-alias filter phase).
MAX_HARMONIC_FRACTION = 0.25


def parse_fit(text: str | None) -> tuple[str, ...]:
    """'nut_k,c_n' -> ('nut_k', 'c_n'); validates names (ValueError naming the bad one)."""
    if not text:
        return DEFAULT_FIT
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    for n in names:
        if n not in FIT_PARAMETERS:
            raise ValueError(f"--fit: unknown parameter '{n}'. Choose from "
                             f"{', '.join(FIT_PARAMETERS)}.")
    if len(set(names)) != len(names):
        raise ValueError(f"--fit: a name appears twice in '{text}'")
    if "expansion" in names and ({"d_n", "d_b"} & set(names)):
        raise ValueError("--fit: choose either 'expansion' (thermal model) or per-speed "
                         "offsets 'd_n'/'d_b', not both")
    for joint in ("nut", "bearing"):
        if {f"{joint}_k", f"{joint}_preload"} <= set(names):
            raise ValueError(f"--fit: '{joint}_k' and '{joint}_preload' set the same joint "
                             f"stiffness (k ~ F_p^(1/3) / K); fit one of them (the preload, "
                             f"with K from the geometry, is what wears in service)")
    return names


def parse_priors(text: str | None, names) -> dict:
    """'c_n=0.3,nut_preload=1' -> {name: sigma}; the defaults for the others."""
    sig = {n: FIT_PARAMETERS[n].prior_sigma for n in names}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in sig:
            raise ValueError(f"--prior: '{name}' is not a fitted parameter ({', '.join(names)})")
        try:
            v = float(value)
        except ValueError:
            raise ValueError(f"--prior: '{item.strip()}' needs NAME=SIGMA with a number") from None
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"--prior: sigma of '{name}' must be a positive number, got {value}")
        sig[name] = v
    return sig
