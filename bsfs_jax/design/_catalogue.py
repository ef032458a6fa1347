"""What the design layer offers, by name: its metrics (units, direction, description),
its default design parameters and operating point. Plain data, no JAX: the command line
builds its help from it without loading the solvers."""

import dataclasses


@dataclasses.dataclass(frozen=True)
class MetricInfo:
    """A response metric's description.

    - `name`: CLI / API name; `label`: plot label; `unit`: the reporting unit, and
      `scale`: SI value * scale = value in `unit`.
    - `direction`: "min" or "max", the sensible design direction (used by `optimize`).
    - `needs_orbit`: True when it solves periodic orbits (needs frequency and force).
    - `uses_operating_point`: True when its value depends on frequency and force.
    """

    name: str
    label: str
    unit: str
    scale: float
    direction: str
    needs_orbit: bool
    uses_operating_point: bool
    description: str


METRIC_INFO: dict[str, MetricInfo] = {
    m.name: m
    for m in (
        MetricInfo("frc_peak", "FRC peak amplitude", "um", 1e6, "min", True, True,
               "peak nut amplitude of the frequency-response curve near the first resonance "
               "at the given force: the maximum along the continued branch of periodic "
               "orbits (harmonic balance), folded or not"),
        MetricInfo("amplitude", "amplitude at the operating point", "um", 1e6, "min", True, True,
               "steady nut amplitude (half peak-to-peak of x_n) of the period-1 orbit at the "
               "given frequency and force"),
        MetricInfo("natural_frequency", "first natural frequency", "Hz", 1.0, "max", False, False,
               "first undamped natural frequency about the static equilibrium"),
        MetricInfo("static_stiffness", "static axial stiffness", "N/um", 1e-6, "max", False, False,
               "axial stiffness of the bearing-screw-nut chain at the nut"),
        MetricInfo("floquet", "largest Floquet multiplier modulus", "-", 1.0, "min", True, True,
               "stability margin of the period-1 orbit at the given frequency and force "
               "(< 1 stable; smaller is more stable)"),
        MetricInfo("thermal_error", "thermal positioning error", "um", 1e6, "min", False, False,
               "screw thermal elongation to the nut at the steady temperature of the "
               "given speed (Eq. 30)"),
        MetricInfo("frf_peak", "linear FRF peak compliance", "um/N", 1e6, "min", False, False,
               "peak of the linearised nut receptance near the first mode"),
    )
}

#: Default design parameters (TOML vocabulary): geometry, counts, preloads, the speed
#: (through the thermal chain), l_0, masses and damping.
DESIGN_PARAMETERS: tuple[str, ...] = (
    "nut.balls",
    "bearing.balls",
    "nut.ball_diameter_mm",
    "bearing.ball_diameter_mm",
    "nut.contact_angle_deg",
    "bearing.contact_angle_deg",
    "nut.preload_n",
    "bearing.preload_n",
    "thermal.speed_rpm",
    "screw.length_to_nut_mm",
    "masses.bearing_kg",
    "masses.screw_kg",
    "masses.nut_kg",
    "damping.bearing_n_s_per_m",
    "damping.screw_n_s_per_m",
    "damping.nut_n_s_per_m",
)

DEFAULT_FREQUENCY_HZ = 120.0  # the paper's exciter tests: 100 N at 100/120/150 Hz
DEFAULT_FORCE_N = 100.0
