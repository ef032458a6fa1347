"""The public parameter-file vocabulary (physics.md section 2), in one table.

Each entry maps a TOML `[section] key` (unit in the name) to the SI field of the
parameter Modules, with its unit factor, allowed range and whether it is optional.
This is the public contract: extend it, never rename a key.
"""

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Key:
    section: str
    key: str
    field: str  # attribute of the section's Module
    to_si: float  # multiply the file value by this to get SI
    low: float | None  # allowed range (None: unbounded); see `low_open` / `high_open`
    high: float | None
    low_open: bool = True
    high_open: bool = True
    optional: bool = False  # optional keys override computed values
    kind: str = "float"  # "float" or "bool"
    doc: str = ""

    @property
    def name(self) -> str:
        return f"{self.section}.{self.key}"

    def range_text(self) -> str:
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        return f"{'(' if self.low_open else '['}{lo}, {hi}{')' if self.high_open else ']'}"


DEG = math.pi / 180.0
MM = 1e-3
UM = 1e-6

KEYS: tuple[Key, ...] = (
    # [masses]
    Key("masses", "bearing_kg", "bearing", 1.0, 0.0, None, doc="bearing-joint mass m_b"),
    Key("masses", "screw_kg", "screw", 1.0, 0.0, None, doc="screw mass m_s"),
    Key("masses", "nut_kg", "nut", 1.0, 0.0, None, doc="nut + worktable mass m_n"),
    # [damping]
    Key("damping", "bearing_n_s_per_m", "bearing", 1.0, 0.0, None, low_open=False,
        doc="bearing-joint damping c_b"),
    Key("damping", "screw_n_s_per_m", "screw", 1.0, 0.0, None, low_open=False,
        doc="screw damping c_s"),
    Key("damping", "nut_n_s_per_m", "nut", 1.0, 0.0, None, low_open=False,
        doc="screw-nut joint damping c_n"),
    # [nut]
    Key("nut", "balls", "balls", 1.0, 1.0, None, low_open=False, doc="balls per nut half Z"),
    Key("nut", "ball_diameter_mm", "ball_diameter", MM, 0.0, 50.0, doc="d_b"),
    Key("nut", "contact_angle_deg", "contact_angle", DEG, 0.0, 90.0, doc="beta"),
    Key("nut", "conformity_screw", "conformity_screw", 1.0, 0.5, 1.0, high_open=False,
        doc="f_s = screw groove radius / d_b"),
    Key("nut", "conformity_nut", "conformity_nut", 1.0, 0.5, 1.0, high_open=False,
        doc="f_n = nut groove radius / d_b"),
    Key("nut", "pitch_diameter_mm", "pitch_diameter", MM, 0.0, None, doc="ball-centre d_m"),
    Key("nut", "lead_mm", "lead", MM, 0.0, None, doc="screw lead l"),
    Key("nut", "preload_n", "preload", 1.0, 0.0, None, doc="preload F_pn"),
    Key("nut", "hertz_k_m_per_n23", "hertz_k", 1.0, 0.0, None, optional=True,
        doc="K_n; computed from geometry when absent"),
    # [bearing]
    Key("bearing", "balls", "balls", 1.0, 1.0, None, low_open=False, doc="balls per row m"),
    Key("bearing", "ball_diameter_mm", "ball_diameter", MM, 0.0, 50.0, doc="D_b"),
    Key("bearing", "contact_angle_deg", "contact_angle", DEG, 0.0, 90.0, doc="alpha"),
    Key("bearing", "conformity_inner", "conformity_inner", 1.0, 0.5, 1.0, high_open=False,
        doc="f_i"),
    Key("bearing", "conformity_outer", "conformity_outer", 1.0, 0.5, 1.0, high_open=False,
        doc="f_o"),
    Key("bearing", "pitch_diameter_mm", "pitch_diameter", MM, 0.0, None, doc="d_m"),
    Key("bearing", "preload_n", "preload", 1.0, 0.0, None, doc="preload F_pb"),
    Key("bearing", "static_load_rating_n", "static_load_rating", 1.0, 0.0, None,
        doc="C0 per row, for the Palmgren load torque (extension)"),
    Key("bearing", "hertz_k_m_per_n23", "hertz_k", 1.0, 0.0, None, optional=True,
        doc="K_b; computed from geometry when absent"),
    # [screw]
    Key("screw", "nominal_diameter_mm", "nominal_diameter", MM, 0.0, None, doc="d_s0"),
    Key("screw", "length_to_nut_mm", "length_to_nut", MM, 0.0, None, doc="l_0"),
    Key("screw", "total_length_mm", "total_length", MM, 0.0, None,
        doc="whole shaft, for convection (extension)"),
    Key("screw", "youngs_modulus_gpa", "youngs_modulus", 1e9, 0.0, None, doc="E"),
    Key("screw", "poisson_ratio", "poisson_ratio", 1.0, 0.0, 0.5, doc="nu"),
    Key("screw", "stiffness_n_per_um", "stiffness", 1e6, 0.0, None, optional=True,
        doc="k_s; computed from Eq. 29 when absent"),
    # [thermal]
    Key("thermal", "enabled", "enabled", 1.0, None, None, kind="bool",
        doc="include thermal offsets"),
    Key("thermal", "speed_rpm", "speed_rpm", 1.0, 0.0, 20000.0, low_open=False,
        doc="screw speed n"),
    Key("thermal", "ambient_c", "ambient_c", 1.0, -50.0, 100.0, doc="T0"),
    Key("thermal", "expansion_per_k", "expansion_per_k", 1.0, 0.0, 1e-4, low_open=False,
        doc="gamma"),
    Key("thermal", "nut_offset_um", "nut_offset", UM, None, None, optional=True,
        doc="explicit D_n (signed; overrides the thermal model)"),
    Key("thermal", "bearing_offset_um", "bearing_offset", UM, None, None, optional=True,
        doc="explicit D_b (signed; overrides the thermal model)"),
    Key("thermal", "oil_viscosity_mm2_s", "oil_viscosity", 1.0, 0.0, None,
        doc="bearing lubricant viscosity (extension)"),
    Key("thermal", "bearing_friction_f0", "bearing_f0", 1.0, 0.0, None,
        doc="Palmgren f0 per row (extension)"),
    Key("thermal", "nut_heat_factor", "nut_heat_factor", 1.0, 0.0, None, low_open=False,
        doc="Eq. 2's f0 v0 as a calibration factor (extension)"),
    Key("thermal", "bearing_screw_w_per_k", "g_bearing_screw", 1.0, 0.0, None,
        doc="network conductance (extension)"),
    Key("thermal", "nut_screw_w_per_k", "g_nut_screw", 1.0, 0.0, None,
        doc="network conductance (extension)"),
    Key("thermal", "bearing_frame_w_per_k", "g_bearing_ambient", 1.0, 0.0, None,
        low_open=False, doc="bearing housing to frame (extension)"),
    Key("thermal", "nut_frame_w_per_k", "g_nut_ambient", 1.0, 0.0, None, low_open=False,
        doc="nut flange to table/air (extension)"),
    Key("thermal", "shaft_natural_convection_w_per_m2k", "natural_convection", 1.0, 0.0,
        None, low_open=False, doc="film coefficient at standstill (extension)"),
)

SECTIONS: tuple[str, ...] = ("masses", "damping", "nut", "bearing", "screw", "thermal")
BY_NAME = {k.name: k for k in KEYS}
BY_SECTION = {s: tuple(k for k in KEYS if k.section == s) for s in SECTIONS}


#: Plausible ranges (file units) of a machine-tool ball screw drive, beyond which a value is
#: legal but almost certainly a typo or a unit slip (a warning, not an error). From
#: catalogue ranges of precision ball screws and angular-contact support bearings (shaft
#: 6-200 mm, lead 1-60 mm, balls 0.8-25 mm; preloads up to tens of kN) and the model's
#: own scales (the default preset's values sit well inside).
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "masses.bearing_kg": (0.01, 5000.0),
    "masses.screw_kg": (0.01, 5000.0),
    "masses.nut_kg": (0.01, 5000.0),
    "damping.bearing_n_s_per_m": (0.0, 1e6),
    "damping.screw_n_s_per_m": (0.0, 1e6),
    "damping.nut_n_s_per_m": (0.0, 1e6),
    "nut.balls": (5.0, 200.0),
    "nut.ball_diameter_mm": (0.8, 25.0),
    "nut.contact_angle_deg": (20.0, 70.0),
    "nut.pitch_diameter_mm": (6.0, 250.0),
    "nut.lead_mm": (1.0, 60.0),
    "nut.preload_n": (10.0, 50000.0),
    "bearing.balls": (5.0, 100.0),
    "bearing.ball_diameter_mm": (0.8, 25.0),
    "bearing.contact_angle_deg": (10.0, 70.0),
    "bearing.pitch_diameter_mm": (6.0, 300.0),
    "bearing.preload_n": (10.0, 50000.0),
    "screw.nominal_diameter_mm": (6.0, 200.0),
    "screw.length_to_nut_mm": (10.0, 10000.0),
    "screw.total_length_mm": (50.0, 15000.0),
    "screw.youngs_modulus_gpa": (150.0, 250.0),
    "thermal.speed_rpm": (0.0, 10000.0),
}
