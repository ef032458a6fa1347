"""Solvers: generic integration, BSFS simulation, equilibrium and modes."""

from ._equilibrium import Modes as Modes
from ._equilibrium import equilibrium as equilibrium
from ._equilibrium import linear_frf as linear_frf
from ._equilibrium import linearise as linearise
from ._equilibrium import modes as modes
from ._integrate import STATUS_MESSAGES as STATUS_MESSAGES
from ._integrate import IntegrationResult as IntegrationResult
from ._integrate import SolverError as SolverError
from ._integrate import SolverSettings as SolverSettings
from ._integrate import check_status as check_status
from ._integrate import integrate as integrate
from ._integrate import is_concrete as is_concrete
from ._simulate import Horizon as Horizon
from ._simulate import Trajectory as Trajectory
from ._simulate import as_system as as_system
from ._simulate import simulate as simulate
from ._simulate import simulate_core as simulate_core
