"""The 3-DOF equations of motion (paper Eq. 31) as a diffrax vector field.

State y = (x_b, x_s, x_n, v_b, v_s, v_n) [m, m/s]. Forcing acts on the nut mass:

    m_b x_b'' + c_b x_b' + F_b(x_b) - c_s (x_s' - x_b') - F_s(x_s - x_b) = 0
    m_s x_s'' + c_s (x_s' - x_b') + F_s(x_s - x_b) - c_n (x_n' - x_s') - F_n(x_n - x_s) = 0
    m_n x_n'' + c_n (x_n' - x_s') + F_n(x_n - x_s) = P(t)
"""

import jax.numpy as jnp

from .. import physics
from ._system import System


def _internal_forces(system: System, x_b, x_s, x_n, v_b, v_s, v_n, fast=False):
    """Elastic + viscous forces of the three joints (bearing, screw, nut) [N], elementwise.

    Written on scalars (broadcasting over any leading axes) so that the vector field, which
    runs at every solver stage, is a handful of fused scalar operations.
    """
    c_b, c_s, c_n = system.damping[0], system.damping[1], system.damping[2]
    f_b = physics.pair_force(x_b, system.bearing, fast) + c_b * v_b
    f_s = system.screw_stiffness * (x_s - x_b) + c_s * (v_s - v_b)
    f_n = physics.pair_force(x_n - x_s, system.nut, fast) + c_n * (v_n - v_s)
    return f_b, f_s, f_n


def _accelerations(system: System, x_b, x_s, x_n, v_b, v_s, v_n, force, fast=False):
    """Eq. 31 solved for (x_b'', x_s'', x_n'') [m/s^2], elementwise (`fast`: products by
    1 / m, a constant of the run, instead of divisions; see `physics.pair_force`)."""
    f_b, f_s, f_n = _internal_forces(system, x_b, x_s, x_n, v_b, v_s, v_n, fast)
    m = system.mass  # an array, or a tuple of per-lane arrays in the kernel
    if fast:
        return ((f_s - f_b) * (1.0 / m[0]), (f_n - f_s) * (1.0 / m[1]),
                (force - f_n) * (1.0 / m[2]))
    return (f_s - f_b) / m[0], (f_n - f_s) / m[1], (force - f_n) / m[2]


def _split(a):
    return a[..., 0], a[..., 1], a[..., 2]


def joint_forces(system: System, x):
    """(F_b, F_s, F_n) [N] at displacements x = (x_b, x_s, x_n); broadcasts over leading axes."""
    zero = jnp.zeros_like(x[..., 0])
    return jnp.stack(_internal_forces(system, *_split(x), zero, zero, zero), axis=-1)


def restoring_forces(system: System, x, v):
    """Internal forces on (m_b, m_s, m_n) [N] (elastic + viscous), the left sides of Eq. 31."""
    f_b, f_s, f_n = _internal_forces(system, *_split(x), *_split(v))
    return jnp.stack([f_b - f_s, f_s - f_n, f_n], axis=-1)


def accelerations(system: System, x, v, force):
    """x'' [m/s^2] of the three masses given the external nut force [N]."""
    return jnp.stack(_accelerations(system, *_split(x), *_split(v), force), axis=-1)


def vector_field_components(t, y, args, fast=False):
    """The vector field on a tuple of the six state components, elementwise (each component
    any shape; `args`' leaves may be per-lane arrays, or tuples for vector fields): the
    form the per-lane integrator kernel (`solvers.integrate_lanes`) runs. `fast`: the
    force law without divisions or square roots (see `physics.pair_force`) and the
    forcing's branch-free form where it has one (`Sinusoid.fast`)."""
    system, forcing = args
    force = forcing.fast(t) if fast and hasattr(forcing, "fast") else forcing(t)
    acc = _accelerations(system, y[0], y[1], y[2], y[3], y[4], y[5], force, fast)
    return (y[3], y[4], y[5], *acc)


def kernel_vector_field(t, y, args):
    """`vector_field_components` with `fast=True`: what the GPU kernel engine runs."""
    return vector_field_components(t, y, args, fast=True)


def vector_field(t, y, args):
    """diffrax vector field f(t, y, args) with args = (system, forcing)."""
    return jnp.stack(vector_field_components(t, y, args))


def mechanical_energy(system: System, y):
    """Kinetic + elastic energy [J] (conserved without damping and forcing)."""
    x, v = y[..., :3], y[..., 3:]
    kinetic = 0.5 * jnp.sum(jnp.broadcast_to(system.mass, v.shape) * v**2, axis=-1)
    x_b, x_s, x_n = x[..., 0], x[..., 1], x[..., 2]
    elastic = (physics.pair_potential(x_b, system.bearing)
               + 0.5 * system.screw_stiffness * (x_s - x_b) ** 2
               + physics.pair_potential(x_n - x_s, system.nut))
    return kinetic + elastic
