"""bsfs: a differentiable simulator of ball screw feed systems under thermal deformation.

Model: Yang et al., "Nonlinear dynamic characteristics of ball screw feed system under
thermal deformation", Nonlinear Dynamics (2022), as fixed by physics.md. All quantities
are SI inside the package; the library never changes `jax.config` (enable 64-bit floats
at your entry point: `jax.config.update("jax_enable_x64", True)`).
"""

import os
from typing import TYPE_CHECKING

# Equinox's runtime checks (diffrax's `saveat.ts` order, lineax, optimistix) default to a
# host callback that raises; a program with a host callback is never written to jax's
# persistent compilation cache, so every run recompiled every integration. Here a failed
# check gives NaN instead (the package maps every solver's result to `RESULTS` and checks
# it itself; nothing relies on those raises). Set EQX_ON_ERROR=raise before importing to
# keep equinox's default. Read by equinox at its import: this must come first.
os.environ.setdefault("EQX_ON_ERROR", "nan")

# XLA's CPU compiler with its earlier fusion emitters (`--xla_cpu_use_fusion_emitters=
# false`): measured on the 2-core machine, the test suite's XLA seconds 1750 -> 1307 and a
# cold `bsfs sensitivity` 29.5 -> 24.6 s (BENCHMARKS.md C2), the same results to rounding;
# the few programs that run long enough for the newer emitters' faster code to pay ask for
# them themselves (`cached_jit(..., runs_long=True)`). XLA reads XLA_FLAGS when jax starts its
# backend (a process that has computed with jax already keeps its flags). Name the option
# in XLA_FLAGS yourself to choose, or set BSFS_XLA_DEFAULTS=0 to leave XLA's defaults.
_XLA_DEFAULT = "--xla_cpu_use_fusion_emitters=false"
if (os.environ.get("BSFS_XLA_DEFAULTS", "1") != "0"
        and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", "")):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_XLA_DEFAULT}".strip()

from ._lazy import lazy_names  # noqa: E402 - after the environment variable

if TYPE_CHECKING:
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
