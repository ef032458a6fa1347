"""bsfs: a differentiable simulator of ball screw feed systems under thermal deformation.

Model: Yang et al., "Nonlinear dynamic characteristics of ball screw feed system under
thermal deformation", Nonlinear Dynamics (2022), as fixed by physics.md. All quantities
are SI inside the package. Importing it (or any of its modules) changes no environment
variable, no `jax.config` value and no XLA flag: enable 64-bit floats at your entry point
(`jax.config.update("jax_enable_x64", True)`), and call `use_fast_compilation()` there for
the `bsfs` command's shorter compilations.
"""

from typing import TYPE_CHECKING

from ._lazy import lazy_names

if TYPE_CHECKING:
    from ._host import use_fast_compilation as use_fast_compilation
    from ._programs import cached_jit as cached_jit
    from .machine import Modes as Modes
    from .machine import Trajectory as Trajectory
    from .machine import equilibrium as equilibrium
    from .machine import linear_frf as linear_frf
    from .machine import modes as modes
    from .machine import simulate as simulate
    from .model import HarmonicForcing as HarmonicForcing
    from .model import Sinusoid as Sinusoid
    from .model import System as System
    from .model import build_system as build_system
    from .model import joint_forces as joint_forces
    from .model import mechanical_energy as mechanical_energy
    from .model import vector_field as vector_field
    from .params import BallScrewParams as BallScrewParams
    from .params import ParameterError as ParameterError
    from .params import list_presets as list_presets
    from .params import load_params as load_params
    from .params import params_to_toml as params_to_toml
    from .params import preset as preset
    from .params import save_params as save_params
    from .solvers import RESULTS as RESULTS
    from .solvers import SolverError as SolverError
    from .solvers import SolverSettings as SolverSettings
    from .solvers import integrate as integrate

_LAZY = {
    "use_fast_compilation": "._host",
    "cached_jit": "._programs",
    "Modes": ".machine",
    "Trajectory": ".machine",
    "equilibrium": ".machine",
    "linear_frf": ".machine",
    "modes": ".machine",
    "simulate": ".machine",
    "HarmonicForcing": ".model",
    "Sinusoid": ".model",
    "System": ".model",
    "build_system": ".model",
    "joint_forces": ".model",
    "mechanical_energy": ".model",
    "vector_field": ".model",
    "BallScrewParams": ".params",
    "ParameterError": ".params",
    "list_presets": ".params",
    "load_params": ".params",
    "params_to_toml": ".params",
    "preset": ".params",
    "save_params": ".params",
    "RESULTS": ".solvers",
    "SolverError": ".solvers",
    "SolverSettings": ".solvers",
    "integrate": ".solvers",
}

__all__ = list(_LAZY)


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("bsfs")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0.0.0+local"

__getattr__, __dir__ = lazy_names(__name__, _LAZY, {"__version__": _version})
