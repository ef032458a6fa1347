"""The ball screw model: parameters -> coefficients -> the 3-DOF vector field (Eq. 31)."""

from ._dynamics import accelerations as accelerations
from ._dynamics import joint_forces as joint_forces
from ._dynamics import kernel_vector_field as kernel_vector_field
from ._dynamics import mechanical_energy as mechanical_energy
from ._dynamics import restoring_forces as restoring_forces
from ._dynamics import vector_field as vector_field
from ._dynamics import vector_field_components as vector_field_components
from ._forcing import HarmonicForcing as HarmonicForcing
from ._forcing import Sinusoid as Sinusoid
from ._system import System as System
from ._system import ThermalState as ThermalState
from ._system import bearing_hertz_k as bearing_hertz_k
from ._system import build_system as build_system
from ._system import helix_angle as helix_angle
from ._system import nut_hertz_k as nut_hertz_k
from ._system import screw_stiffness as screw_stiffness
from ._system import thermal_state as thermal_state
from ._system import warmup as warmup
