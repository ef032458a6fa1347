"""The ball screw as one-parameter families of forced systems: p -> (args, period).

One protocol for continuation (`solvers.continue_orbits`), the orbit metrics of `design`,
the identification's orbit model and sweeps: a family is an `eqx.Module` called with the
parameter value, returning `((system, forcing), period)` for `model.vector_field`, with
the attributes `vector_field`, `scale` (typical state magnitudes) and `unit`.

The swept value is converted to SI once, by the factor of its vocabulary key, where the
family puts it into the parameters (`eqx.tree_at` on the SI field); everything traced
downstream is SI.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._numerics import float_array
from ..model import Sinusoid, build_system, vector_field
from ..params import BallScrewParams, lookup_key, validate
from ..solvers import is_concrete

FREQUENCY, FORCE = "frequency_hz", "force_n"

#: Typical BSFS state magnitudes (x_b, x_s, x_n [m], v_b, v_s, v_n [m/s]) for scaling.
BSFS_SCALE = (1e-6, 1e-6, 1e-6, 1e-2, 1e-2, 1e-2)

# Units of the TOML vocabulary, read from the suffix of a key's name (longest first).
_SUFFIX_UNITS = (
    ("_m_per_n23", "m/N^(2/3)"), ("_n_s_per_m", "N s/m"), ("_n_per_um", "N/um"),
    ("_per_k", "1/K"), ("_gpa", "GPa"), ("_rpm", "r/min"), ("_deg", "deg"), ("_mm", "mm"),
    ("_um", "um"), ("_kg", "kg"), ("_hz", "Hz"), ("_n", "N"), ("_c", "degC"), ("_w", "W"),
)


def parameter_unit(name: str) -> str:
    """Unit of a family parameter ("frequency_hz", "force_n" or a `section.key`)."""
    key = name.split(".")[-1]
    for suffix, unit in _SUFFIX_UNITS:
        if key.endswith(suffix):
            return unit
    return ""


class BSFSFamily(eqx.Module):
    """The BSFS under P sin(2 pi f t) on the nut, as a family in one parameter `param`:
    "frequency_hz", "force_n" or a numeric vocabulary key (the value in file units).

    `params` (SI inside), `frequency_hz` and `force_n` give the fixed excitation; the
    family is differentiable in all of them (design metrics differentiate through it).
    """

    params: BallScrewParams
    frequency_hz: jax.Array = eqx.field(converter=float_array)
    force_n: jax.Array = eqx.field(converter=float_array)
    param: str = eqx.field(static=True, default=FREQUENCY)
    #: The built system, once `prepare` has built it (families in frequency or force only).
    system: object = None

    def prepare(self) -> "BSFSFamily":
        """This family with its system built once (`build_system`), where the system does
        not depend on the family's parameter (frequency or force). The continuation calls it
        once, before its corrector: without it every residual in the corrector's loops
        rebuilt the coefficients and the thermal chain, four times the vector field's
        program size in each copy (the compiled corrector was 16 400 HLO lines, 4.2 s)."""
        if self.param not in (FREQUENCY, FORCE) or self.system is not None:
            return self
        return eqx.tree_at(lambda f: f.system, self, build_system(self.params),
                           is_leaf=lambda x: x is None)

    def __call__(self, value):
        frequency, force, params = self.frequency_hz, self.force_n, self.params
        if self.param == FREQUENCY:
            frequency = jnp.asarray(value, dtype=float)
        elif self.param == FORCE:
            force = jnp.asarray(value, dtype=float)
        else:
            key = lookup_key(self.param)
            si = jnp.asarray(value, dtype=float) * key.to_si  # the one unit conversion
            section = eqx.tree_at(lambda m: getattr(m, key.field),
                                  getattr(params, key.section), si,
                                  is_leaf=lambda x: x is None)
            params = eqx.tree_at(lambda p: getattr(p, key.section), params, section)
        forcing = Sinusoid(force, frequency)
        system = self.system if self.system is not None else build_system(params)
        return (system, forcing), forcing.period

    @property
    def vector_field(self):
        return vector_field

    @property
    def scale(self):
        return jnp.asarray(BSFS_SCALE)

    @property
    def unit(self) -> str:
        return parameter_unit(self.param)


def bsfs_family(params: BallScrewParams, force_n=None, *, param: str = FREQUENCY,
                frequency_hz=None) -> BSFSFamily:
    """A checked `BSFSFamily`: in the frequency (default; give `force_n`), or in `param`
    (a vocabulary key or "force_n") at the fixed `frequency_hz` and `force_n`."""
    if param not in (FREQUENCY, FORCE):
        key = lookup_key(param)  # ParameterError with suggestions
        if key.kind != "float":
            raise ValueError(f"'{param}' is a switch ({key.kind}), not a scalar parameter")
    if force_n is None and param != FORCE:
        raise ValueError(f"a family in {param} needs a fixed force_n")
    if frequency_hz is None and param != FREQUENCY:
        raise ValueError(f"a family in {param} needs a fixed frequency_hz")
    frequency = 1.0 if frequency_hz is None else frequency_hz
    force = 0.0 if force_n is None else force_n
    if is_concrete((frequency, force)):
        if not float(frequency) > 0:
            raise ValueError(f"frequency_hz must be positive, got {frequency}")
        if param != FORCE and not float(force) > 0:
            raise ValueError(f"force_n must be positive, got {force}")
    if is_concrete(params):
        params = validate(params)
    return BSFSFamily(params, frequency, force, param)


def bsfs_parameter_family(params, name: str, frequency_hz, force_n) -> BSFSFamily:
    """`BSFSFamily` in the vocabulary parameter `name` (file units) at a fixed excitation."""
    return bsfs_family(params, force_n, param=name, frequency_hz=frequency_hz)
