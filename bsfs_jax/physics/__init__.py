"""Pure, elementwise JAX physics of the ball screw feed system.

Every function takes and returns arrays in SI units, has no side effects, and has
finite derivatives everywhere (contact laws use a safe power). Each cites its equation
in the seed paper (Yang et al. 2022) and in physics.md.
"""

from ._hertz import contact_coefficient as contact_coefficient
from ._hertz import contact_radii as contact_radii
from ._hertz import curvature_sum_and_difference as curvature_sum_and_difference
from ._hertz import hertz_coefficient as hertz_coefficient
from ._joints import PreloadedPair as PreloadedPair
from ._joints import contact_angles as contact_angles
from ._joints import contact_deformations as contact_deformations
from ._joints import pair_force as pair_force
from ._joints import pair_potential as pair_potential
from ._joints import preloaded_pair as preloaded_pair
from ._joints import side_forces as side_forces
from ._safe import pos_pow as pos_pow
from ._screw import screw_stiffness as screw_stiffness
from ._screw import thermal_elongation as thermal_elongation
from ._thermal import STEEL_HEAT_CAPACITY_J_PER_KG_K as STEEL_HEAT_CAPACITY_J_PER_KG_K
from ._thermal import ball_thermal_offset as ball_thermal_offset
from ._thermal import bearing_heat as bearing_heat
from ._thermal import conductance_matrix as conductance_matrix
from ._thermal import nut_drag_torque as nut_drag_torque
from ._thermal import nut_heat as nut_heat
from ._thermal import palmgren_torque as palmgren_torque
from ._thermal import shaft_convection_coefficient as shaft_convection_coefficient
from ._thermal import steady_temperature_rise as steady_temperature_rise
from ._thermal import transient_temperature_rise as transient_temperature_rise
