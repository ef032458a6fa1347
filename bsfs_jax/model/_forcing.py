"""Excitation forces acting on the nut mass, as small Modules evaluated at time t."""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._numerics import float_array, sin_turns


class Sinusoid(eqx.Module):
    """P sin(2 pi f t + phase) [N] (the paper's excitation, Eq. 31)."""

    amplitude: jax.Array = eqx.field(converter=float_array)
    frequency: jax.Array = eqx.field(converter=float_array)
    phase: jax.Array = eqx.field(converter=float_array, default=0.0)

    @property
    def period(self):
        return 1.0 / self.frequency

    def __call__(self, t):
        return self.amplitude * jnp.sin(2.0 * jnp.pi * self.frequency * t + self.phase)

    def fast(self, t):
        """The same force with a branch-free sine of the phase in turns (`sin_turns`, a
        few ulp of the sine of f t + phase / 2 pi; from `__call__` by the rounding of the
        argument): for the per-lane GPU kernel."""
        return self.amplitude * sin_turns(self.frequency * t + self.phase * (0.5 / jnp.pi))


class HarmonicForcing(eqx.Module):
    """Offset + sum_k [a_k cos(2 pi k f t) + b_k sin(2 pi k f t)] [N], k = 1..H.

    For exciter records: the measured force's fitted harmonics drive the model.
    """

    frequency: jax.Array = eqx.field(converter=float_array)
    cos_coeffs: jax.Array = eqx.field(converter=float_array)
    sin_coeffs: jax.Array = eqx.field(converter=float_array)
    offset: jax.Array = eqx.field(converter=float_array, default=0.0)

    @property
    def period(self):
        return 1.0 / self.frequency

    def __call__(self, t):
        k = jnp.arange(1, self.cos_coeffs.shape[-1] + 1)
        arg = 2.0 * jnp.pi * self.frequency * k * t
        return self.offset + jnp.sum(self.cos_coeffs * jnp.cos(arg)
                                     + self.sin_coeffs * jnp.sin(arg))
