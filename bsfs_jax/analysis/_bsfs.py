"""The ball screw as a `SweepProblem`: sweep the frequency, the force or any file key."""

import equinox as eqx
import jax.numpy as jnp

from ..machine import FORCE, FREQUENCY, BSFSFamily, parameter_unit
from ..model import kernel_vector_field, vector_field
from ..params import BallScrewParams, lookup_key

STATE_NAMES = ("x_b", "x_s", "x_n", "v_b", "v_s", "v_n")
STATE_UNITS = ("m", "m", "m", "m/s", "m/s", "m/s")


class BSFSSetup(eqx.Module):
    """setup(data, value) for the ball screw; data = (params, frequency_hz, force_n).

    The sweep's view of the one family protocol: it is `machine.BSFSFamily` (the family
    that continuation and the orbit metrics use) evaluated at the swept value."""

    param: str = eqx.field(static=True)

    def __call__(self, data, value):
        params, frequency, force = data
        return BSFSFamily(params, frequency, force, self.param)(value)


def bsfs_problem(params: BallScrewParams, param: str = FREQUENCY, *, frequency_hz=None,
                 force_n=None, y0=None, observe: int = 2):
    """A `SweepProblem` for the ball screw under P sin(2 pi f t) on the nut (Eq. 31).

    **Arguments:**
    - `params`: `BallScrewParams`.
    - `param`: "frequency_hz", "force_n" or any numeric key of the parameter vocabulary
      in file units, e.g. "nut.balls", "bearing.contact_angle_deg", "nut.preload_n",
      "thermal.speed_rpm".
    - `frequency_hz`, `force_n`: the fixed excitation (the swept one may be omitted).
    - `y0`: cold-start state (default: at rest at x = 0).
    - `observe`: state index for the spectrum and amplitude (default 2, the nut x_n).
    """
    if param not in (FREQUENCY, FORCE):
        key = lookup_key(param)  # raises ParameterError with suggestions
        if key.kind != "float":
            raise ValueError(f"'{param}' is a switch ({key.kind}), not a scalar parameter; "
                             "it cannot be swept")
    if frequency_hz is None and param != FREQUENCY:
        raise ValueError(f"sweeping {param} needs a fixed frequency_hz")
    if force_n is None and param != FORCE:
        raise ValueError(f"sweeping {param} needs a fixed force_n")
    frequency = 1.0 if frequency_hz is None else frequency_hz
    force = 0.0 if force_n is None else force_n
    if not float(frequency) > 0:
        raise ValueError(f"frequency_hz must be positive, got {frequency}")
    from ._sweep_problem import SweepProblem

    data = (params, jnp.asarray(frequency, dtype=float), jnp.asarray(force, dtype=float))
    return SweepProblem(vector_field, BSFSSetup(param), data,
                        jnp.zeros(6) if y0 is None else y0, param, parameter_unit(param),
                        observe, STATE_NAMES, STATE_UNITS, "s",
                        component_field=kernel_vector_field)
