"""The model argument of every machine function: parameters or a built `System`."""

import equinox as eqx

from ..model import System, build_system
from ..params import BallScrewParams

# Parameters are built into a `System` by one program: called eagerly (a report's modes, a
# design check, a plan, a synthetic record), `build_system` ran op by op, each operation a
# small compiled program of its own (39 in a cold `bsfs synth`). Under an outer jit the
# program is inlined.
_build = eqx.filter_jit(build_system)


def as_system(model) -> System:
    """Accept `BallScrewParams` or an already-built `System`."""
    if isinstance(model, System):
        return model
    if isinstance(model, BallScrewParams):
        return _build(model)
    raise TypeError(f"expected BallScrewParams or System, got {type(model).__name__}")
