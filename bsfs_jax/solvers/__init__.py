"""Generic solvers: integration of any f(t, y, args), solver outcomes (`RESULTS`),
periodic orbits and continuation. The ball screw on these solvers is `bsfs_jax.machine`."""

from ._branch import Bifurcation as Bifurcation
from ._branch import Branch as Branch
from ._branch import Peak as Peak
from ._continuation import continue_orbits as continue_orbits
from ._harmonic import HarmonicBalance as HarmonicBalance
from ._implicit import AbstractOrbitAdjoint as AbstractOrbitAdjoint
from ._implicit import ImplicitForward as ImplicitForward
from ._implicit import ImplicitReverse as ImplicitReverse
from ._integrate import IntegrationResult as IntegrationResult
from ._integrate import SolverError as SolverError
from ._integrate import SolverSettings as SolverSettings
from ._integrate import check_result as check_result
from ._integrate import integrate as integrate
from ._integrate import is_concrete as is_concrete
from ._newton import NewtonSolution as NewtonSolution
from ._newton import newton as newton
from ._orbit import PeriodicOrbit as PeriodicOrbit
from ._orbit import classify_multipliers as classify_multipliers
from ._orbit import orbit_amplitudes as orbit_amplitudes
from ._orbit import periodic_orbit as periodic_orbit
from ._results import RESULTS as RESULTS
from ._results import result_code as result_code
from ._results import result_codes as result_codes
from ._results import result_from_codes as result_from_codes
from ._results import result_message as result_message
from ._results import result_ok as result_ok
from ._results import result_text as result_text
from ._shooting import SHOOTING_SETTINGS as SHOOTING_SETTINGS
from ._shooting import Shooting as Shooting
from ._shooting import period_map as period_map
from ._shooting import variational_monodromy as variational_monodromy
