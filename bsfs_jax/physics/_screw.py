"""Screw shaft: linear axial spring (paper Eq. 29) and thermal elongation (Eq. 30)."""

import jax.numpy as jnp


def screw_stiffness(youngs_modulus, nominal_diameter, ball_diameter, contact_angle, length):
    """k_s = pi E (d_s0 - d_b cos(beta))^2 / (4 l_0) [N/m] (Eq. 29; HIWIN F 3.31).

    `contact_angle` is the screw-ball contact angle beta (physics.md section 7, item 3).
    """
    root = nominal_diameter - ball_diameter * jnp.cos(contact_angle)
    return jnp.pi * youngs_modulus * root**2 / (4.0 * length)


def thermal_elongation(expansion_per_k, length, mean_temperature_rise):
    """delta_s = gamma * integral_0^l0 (T - T0) dx [m] (Eq. 30) for a uniform mean rise.

    In the fixed-free arrangement this shifts the nut (a positioning error) but not the
    vibration.
    """
    return expansion_per_k * length * mean_temperature_rise
