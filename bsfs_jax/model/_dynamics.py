"""The 3-DOF equations of motion (paper Eq. 31) as a diffrax vector field.

State y = (x_b, x_s, x_n, v_b, v_s, v_n) [m, m/s]. Forcing acts on the nut mass:

    m_b x_b'' + c_b x_b' + F_b(x_b) - c_s (x_s' - x_b') - F_s(x_s - x_b) = 0
    m_s x_s'' + c_s (x_s' - x_b') + F_s(x_s - x_b) - c_n (x_n' - x_s') - F_n(x_n - x_s) = 0
    m_n x_n'' + c_n (x_n' - x_s') + F_n(x_n - x_s) = P(t)
"""

import jax.numpy as jnp

from .. import physics
from ._system import System


def joint_forces(system: System, x):
    """(F_b, F_s, F_n) [N] at displacements x = (x_b, x_s, x_n); broadcasts over leading axes."""
    x_b, x_s, x_n = x[..., 0], x[..., 1], x[..., 2]
    f_b = physics.pair_force(x_b, system.bearing)
    f_s = system.screw_stiffness * (x_s - x_b)
    f_n = physics.pair_force(x_n - x_s, system.nut)
    return jnp.stack([f_b, f_s, f_n], axis=-1)


def restoring_forces(system: System, x, v):
    """Internal forces on (m_b, m_s, m_n) [N] (elastic + viscous), the left sides of Eq. 31."""
    f_b, f_s, f_n = jnp.moveaxis(joint_forces(system, x), -1, 0)
    c_b, c_s, c_n = system.damping
    v_b, v_s, v_n = v[..., 0], v[..., 1], v[..., 2]
    d_b = c_b * v_b
    d_s = c_s * (v_s - v_b)
    d_n = c_n * (v_n - v_s)
    return jnp.stack([f_b + d_b - f_s - d_s, f_s + d_s - f_n - d_n, f_n + d_n], axis=-1)


def accelerations(system: System, x, v, force):
    """x'' [m/s^2] of the three masses given the external nut force [N]."""
    external = jnp.stack([jnp.zeros_like(force), jnp.zeros_like(force), force], axis=-1)
    net = external - restoring_forces(system, x, v)
    return net / jnp.broadcast_to(system.mass, net.shape)


def vector_field(t, y, args):
    """diffrax vector field f(t, y, args) with args = (system, forcing)."""
    system, forcing = args
    x, v = y[:3], y[3:]
    return jnp.concatenate([v, accelerations(system, x, v, forcing(t))])


def mechanical_energy(system: System, y):
    """Kinetic + elastic energy [J] (conserved without damping and forcing)."""
    x, v = y[..., :3], y[..., 3:]
    kinetic = 0.5 * jnp.sum(jnp.broadcast_to(system.mass, v.shape) * v**2, axis=-1)
    x_b, x_s, x_n = x[..., 0], x[..., 1], x[..., 2]
    elastic = (physics.pair_potential(x_b, system.bearing)
               + 0.5 * system.screw_stiffness * (x_s - x_b) ** 2
               + physics.pair_potential(x_n - x_s, system.nut))
    return kinetic + elastic
