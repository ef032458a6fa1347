"""The ball screw on the generic solvers: simulation, static equilibrium, modes, linear FRF.

This layer sits between `solvers` (generic in the vector field) and `analysis`: it knows
the BSFS (`params`, `physics`, `model`) and runs it through `solvers.integrate` and
optimistix.

- `simulate` (checked, jitted), `simulate_core` (traceable), `Trajectory`, `Horizon`,
  `as_system`;
- `equilibrium`, `linearise`, `modes`, `Modes`, `linear_frf`; the joints' contact
  windows (`joint_windows`) and the linearised lift-off force (`linear_liftoff_force`);
- `BSFSFamily`, `bsfs_family`: the one family protocol p -> (args, period) for
  continuation, orbit metrics and sweeps; `BSFS_SCALE`.
"""

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
    from ._equilibrium import JOINTS as JOINTS
    from ._equilibrium import Modes as Modes
    from ._equilibrium import equilibrium as equilibrium
    from ._equilibrium import joint_windows as joint_windows
    from ._equilibrium import linear_frf as linear_frf
    from ._equilibrium import linear_liftoff_force as linear_liftoff_force
    from ._equilibrium import linearise as linearise
    from ._equilibrium import modes as modes
    from ._equilibrium import tangent_matrices as tangent_matrices
    from ._families import BSFS_SCALE as BSFS_SCALE
    from ._families import FORCE as FORCE
    from ._families import FREQUENCY as FREQUENCY
    from ._families import BSFSFamily as BSFSFamily
    from ._families import bsfs_family as bsfs_family
    from ._families import bsfs_parameter_family as bsfs_parameter_family
    from ._families import parameter_unit as parameter_unit
    from ._simulate import Horizon as Horizon
    from ._simulate import Trajectory as Trajectory
    from ._simulate import simulate as simulate
    from ._simulate import simulate_core as simulate_core
    from ._system_arg import as_system as as_system

_LAZY = {
    "JOINTS": "._equilibrium",
    "Modes": "._equilibrium",
    "equilibrium": "._equilibrium",
    "joint_windows": "._equilibrium",
    "linear_frf": "._equilibrium",
    "linear_liftoff_force": "._equilibrium",
    "linearise": "._equilibrium",
    "modes": "._equilibrium",
    "tangent_matrices": "._equilibrium",
    "BSFS_SCALE": "._families",
    "FORCE": "._families",
    "FREQUENCY": "._families",
    "BSFSFamily": "._families",
    "bsfs_family": "._families",
    "bsfs_parameter_family": "._families",
    "parameter_unit": "._families",
    "Horizon": "._simulate",
    "Trajectory": "._simulate",
    "as_system": "._system_arg",
    "simulate": "._simulate",
    "simulate_core": "._simulate",
}

__all__ = list(_LAZY)

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
