"""From parameters to the coefficients the equations of motion use (computed once per run).

`build_system(params)` is pure JAX and differentiable in every parameter: Hertz
coefficients from geometry, preloaded-pair geometry, screw stiffness and the thermal
chain speed -> heat -> temperatures -> offsets D_n, D_b and elongation delta_s.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import physics
from ..params import BallScrewParams


class ThermalState(eqx.Module):
    """Result of the thermal chain (all SI). Zero rises and offsets when thermal is off."""

    heat_w: jax.Array  # (Q_bearing, Q_nut) [W]
    temperature_rise_k: jax.Array  # (bearing, screw, nut) [K]
    temperatures_c: jax.Array  # (bearing, screw, nut) [deg C]
    nut_offset: jax.Array  # D_n [m]
    bearing_offset: jax.Array  # D_b [m]
    elongation: jax.Array  # delta_s [m], positioning error of the nut (Eq. 30)
    conductance: jax.Array  # (3, 3) [W/K]
    capacity: jax.Array  # (3,) [J/K]


class System(eqx.Module):
    """Everything the vector field needs: masses, damping, joints, screw spring, thermal."""

    mass: jax.Array  # (m_b, m_s, m_n) [kg]
    damping: jax.Array  # (c_b, c_s, c_n) [N s/m]
    nut: physics.PreloadedPair
    bearing: physics.PreloadedPair
    screw_stiffness: jax.Array  # k_s [N/m]
    thermal: ThermalState


def helix_angle(params: BallScrewParams):
    """lambda = atan(lead / (pi d_m)) [rad]."""
    return jnp.arctan(params.nut.lead / (jnp.pi * params.nut.pitch_diameter))


def nut_hertz_k(params: BallScrewParams):
    """K_n [m/N^(2/3)]: the file's explicit value, else Hamrock-Brewe from geometry."""
    n, s = params.nut, params.screw
    if n.hertz_k is not None:
        return n.hertz_k
    return physics.hertz_coefficient(n.ball_diameter, n.conformity_screw, n.conformity_nut,
                                     n.pitch_diameter, n.contact_angle, s.youngs_modulus,
                                     s.poisson_ratio)


def bearing_hertz_k(params: BallScrewParams):
    """K_b [m/N^(2/3)]: the file's explicit value, else Hamrock-Brewe from geometry."""
    b, s = params.bearing, params.screw
    if b.hertz_k is not None:
        return b.hertz_k
    return physics.hertz_coefficient(b.ball_diameter, b.conformity_inner, b.conformity_outer,
                                     b.pitch_diameter, b.contact_angle, s.youngs_modulus,
                                     s.poisson_ratio)


def screw_stiffness(params: BallScrewParams):
    """k_s [N/m]: explicit value, else Eq. 29."""
    s, n = params.screw, params.nut
    if s.stiffness is not None:
        return s.stiffness
    return physics.screw_stiffness(s.youngs_modulus, s.nominal_diameter, n.ball_diameter,
                                   n.contact_angle, s.length_to_nut)


def thermal_state(params: BallScrewParams) -> ThermalState:
    """Steady thermal chain at `thermal.speed_rpm` (physics.md sections 1 and 4).

    Explicit offsets in the file override the computed ones; with `enabled = false` the
    offsets and elongation are zero (temperatures are still reported).
    """
    th, n, b, s, m = params.thermal, params.nut, params.bearing, params.screw, params.masses
    torque_b = physics.palmgren_torque(th.speed_rpm, th.oil_viscosity, b.pitch_diameter,
                                       b.preload, b.static_load_rating, th.bearing_f0)
    q_b = physics.bearing_heat(th.speed_rpm, torque_b)
    q_n = physics.nut_heat(th.speed_rpm, physics.nut_drag_torque(n.preload, n.lead,
                                                                 n.pitch_diameter),
                           th.nut_heat_factor)
    h = physics.shaft_convection_coefficient(th.speed_rpm, s.nominal_diameter,
                                             th.natural_convection)
    g_screw = h * jnp.pi * s.nominal_diameter * s.total_length
    conductance = physics.conductance_matrix(th.g_bearing_screw, th.g_nut_screw,
                                             th.g_bearing_ambient, g_screw, th.g_nut_ambient)
    heat = jnp.stack([q_b, jnp.zeros_like(q_b), q_n])
    rise = physics.steady_temperature_rise(conductance, heat)
    capacity = physics.STEEL_HEAT_CAPACITY_J_PER_KG_K * jnp.stack([m.bearing, m.screw, m.nut])
    zero = jnp.zeros_like(rise[0])
    if th.enabled:
        d_n = physics.ball_thermal_offset(th.expansion_per_k, n.ball_diameter, rise[2])
        d_b = physics.ball_thermal_offset(th.expansion_per_k, b.ball_diameter, rise[0])
        d_n = d_n if th.nut_offset is None else th.nut_offset
        d_b = d_b if th.bearing_offset is None else th.bearing_offset
        elong = physics.thermal_elongation(th.expansion_per_k, s.length_to_nut, rise[1])
    else:
        d_n = d_b = elong = zero
    return ThermalState(jnp.stack([q_b, q_n]), rise, th.ambient_c + rise, d_n + zero,
                        d_b + zero, elong + zero, conductance, capacity)


def build_system(params: BallScrewParams) -> System:
    """The coefficients of Eq. (31) for `params` (pure, differentiable, jit-friendly)."""
    n, b, m, c = params.nut, params.bearing, params.masses, params.damping
    thermal = thermal_state(params)
    cos_helix = jnp.cos(helix_angle(params))
    nut = physics.preloaded_pair(n.balls, n.ball_diameter, n.conformity_screw, n.conformity_nut,
                                 n.contact_angle, n.preload, nut_hertz_k(params), cos_helix,
                                 thermal.nut_offset)
    bearing = physics.preloaded_pair(b.balls, b.ball_diameter, b.conformity_inner,
                                     b.conformity_outer, b.contact_angle, b.preload,
                                     bearing_hertz_k(params), 1.0, thermal.bearing_offset)
    return System(jnp.stack([m.bearing, m.screw, m.nut]), jnp.stack([c.bearing, c.screw, c.nut]),
                  nut, bearing, screw_stiffness(params), thermal)


def warmup(params: BallScrewParams, times):
    """Temperature rises [K] of (bearing, screw, nut) at `times` [s] after a cold start.

    The transient of the same lumped network as `thermal_state`, with steel heat
    capacities of the three lumped masses; shape (len(times), 3).
    """
    th = thermal_state(params)
    heat = jnp.stack([th.heat_w[0], jnp.zeros_like(th.heat_w[0]), th.heat_w[1]])
    return physics.transient_temperature_rise(times, th.conductance, th.capacity, heat)
