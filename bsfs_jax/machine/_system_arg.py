"""The model argument of every machine function: parameters or a built `System`."""

from ..model import System, build_system
from ..params import BallScrewParams


def as_system(model) -> System:
    """Accept `BallScrewParams` or an already-built `System`."""
    if isinstance(model, System):
        return model
    if isinstance(model, BallScrewParams):
        return build_system(model)
    raise TypeError(f"expected BallScrewParams or System, got {type(model).__name__}")
