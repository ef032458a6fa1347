"""Friction heat, convection and a lumped thermal network (paper Eqs. 1-4, 11, 23, 30).

Formulas and constants: physics.md section 4. Units: SI at every function boundary;
catalogue formulas that are stated in N mm and mm^2/s convert inside.

The network has three nodes: bearing pair (b), screw shaft (s) and nut (n).

    Q_b -> [b] --G_bs-- [s] --G_ns-- [n] <- Q_n
            |            |            |
          G_b0      h(n) pi d L     G_n0          (to ambient at T0)

Steady state: G (T - T0) = Q, a 3x3 linear solve. Transient: C dT/dt = Q - G (T - T0),
solved exactly through the eigenvectors of the symmetric pencil (G, C).
"""

import jax.numpy as jnp

from .._numerics import solve_3x3
from ._safe import pos_pow

STEEL_HEAT_CAPACITY_J_PER_KG_K = 460.0  # physics.md section 4
AIR_KINEMATIC_VISCOSITY_M2_S = 1.6e-5  # air near 30 C [K]
AIR_CONDUCTIVITY_W_PER_M_K = 0.026
AIR_PRANDTL = 0.71


def palmgren_torque(speed_rpm, viscosity_mm2_s, pitch_diameter, preload, static_rating, f0,
                    rows=2.0):
    """Bearing friction torque M = rows (M0 + M1) [N m] (Palmgren; physics.md section 4).

    M0 = 1e-7 f0 (nu n)^(2/3) d_m^3 [N mm] if nu n >= 2000, else 160e-7 f0 d_m^3;
    M1 = f1 P1 d_m with f1 = 0.001 (P0/C0)^0.33 and P0 = P1 = the axial preload per row.
    The two branches of M0 meet at nu n = 2000 (within 0.8 %), so the torque is continuous.
    """
    dm_mm = pitch_diameter * 1e3
    nu_n = viscosity_mm2_s * speed_rpm
    m0 = jnp.where(nu_n >= 2000.0, 1e-7 * f0 * pos_pow(nu_n, 2.0 / 3.0) * dm_mm**3,
                   160e-7 * f0 * dm_mm**3)
    f1 = 0.001 * (preload / static_rating) ** 0.33
    m1 = f1 * preload * dm_mm
    return rows * (m0 + m1) * 1e-3


def bearing_heat(speed_rpm, torque):
    """Q_b = 1.047e-4 n M [W] with M in N mm (Eq. 1), i.e. omega M with M in N m."""
    return 2.0 * jnp.pi * speed_rpm / 60.0 * torque


def nut_drag_torque(preload, lead, pitch_diameter):
    """Preload drag torque T_d = K_p F_p l / (2 pi) [N m], K_p = 0.05 / sqrt(tan(lambda)).

    HIWIN's form T_d = K_p F_p l[mm] / (2000 pi) in SI; about 0.24 N m for 25x5 at 1500 N.
    """
    tan_helix = lead / (jnp.pi * pitch_diameter)
    k_p = 0.05 / jnp.sqrt(tan_helix)
    return k_p * preload * lead / (2.0 * jnp.pi)


def nut_heat(speed_rpm, torque, calibration=1.0):
    """Q_n = (2 pi n / 60) T_d times the dimensionless f0 v0 factor of Eq. (2) [W].

    physics.md section 4: the paper's `0.12 pi n f0 v0 M2` is Tian & He's kJ/h formula; its
    f0 v0 factor is kept only as a calibration factor (default 1).
    """
    return calibration * 2.0 * jnp.pi * speed_rpm / 60.0 * torque


def shaft_convection_coefficient(speed_rpm, diameter, natural=5.0):
    """Film coefficient h [W/(m^2 K)] of a rotating shaft.

    Forced: Nu = 0.133 Re^(2/3) Pr^(1/3), Re = Omega d^2 / nu_air, h = Nu k_air / d (about
    32/51/67 for d = 25 mm at 1000/2000/3000 r/min). Blended with the natural-convection
    floor as sqrt(h_forced^2 + h_natural^2) so that h stays smooth and positive at rest.
    """
    omega = 2.0 * jnp.pi * speed_rpm / 60.0
    reynolds = omega * diameter**2 / AIR_KINEMATIC_VISCOSITY_M2_S
    nusselt = 0.133 * pos_pow(reynolds, 2.0 / 3.0) * AIR_PRANDTL ** (1.0 / 3.0)
    forced = nusselt * AIR_CONDUCTIVITY_W_PER_M_K / diameter
    return jnp.sqrt(forced**2 + natural**2)


def conductance_matrix(g_bearing_screw, g_nut_screw, g_bearing_ambient, g_screw_ambient,
                       g_nut_ambient):
    """Symmetric 3x3 conductance matrix [W/K] of the (bearing, screw, nut) network."""
    row_b = jnp.stack([g_bearing_screw + g_bearing_ambient, -g_bearing_screw,
                       jnp.zeros_like(g_bearing_screw)])
    row_s = jnp.stack([-g_bearing_screw, g_bearing_screw + g_nut_screw + g_screw_ambient,
                       -g_nut_screw])
    row_n = jnp.stack([jnp.zeros_like(g_nut_screw), -g_nut_screw, g_nut_screw + g_nut_ambient])
    return jnp.stack([row_b, row_s, row_n])


def steady_temperature_rise(conductance, heat):
    """Steady rises T - T0 [K] of (bearing, screw, nut) for heat inputs [W] (the 3 x 3
    network solved in closed form)."""
    return solve_3x3(conductance, heat)


def transient_temperature_rise(times, conductance, capacity, heat):
    """Rises [K] at `times` [s] from T = T0 at t = 0, shape (len(times), 3).

    Exact solution of C dT/dt = Q - G T: with C^(-1/2) G C^(-1/2) = V diag(lam) V^T,
    T(t) = T_ss - C^(-1/2) V diag(exp(-lam t)) V^T C^(1/2) T_ss.
    """
    c_half = jnp.sqrt(capacity)
    sym = conductance / c_half[:, None] / c_half[None, :]
    lam, vecs = jnp.linalg.eigh(sym)
    t_ss = steady_temperature_rise(conductance, heat)
    z0 = vecs.T @ (c_half * t_ss)
    decay = jnp.exp(-jnp.asarray(times)[:, None] * lam[None, :]) * z0[None, :]
    return t_ss[None, :] - (decay @ vecs.T) / c_half[None, :]


def ball_thermal_offset(expansion_per_k, ball_diameter, temperature_rise):
    """Signed thermal offset D = gamma d (T - T0) [m] (Eqs. 11 and 23; physics.md section 1)."""
    return expansion_per_k * ball_diameter * temperature_rise
