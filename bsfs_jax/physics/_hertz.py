"""Hertz point-contact deformation coefficient of a ball between two grooves.

physics.md section 3; paper Eqs. (5), (17) use `delta = K Q^(2/3)` with K from here.
"""

import jax.numpy as jnp


def _reduced_modulus(youngs_modulus, poisson_ratio):
    """E' = E / (1 - nu^2) for steel on steel [Pa] (Hamrock-Brewe convention)."""
    return youngs_modulus / (1.0 - poisson_ratio**2)


def contact_radii(ball_diameter, conformity, pitch_diameter, contact_angle, inner):
    """Effective radii (R_x, R_y) [m] of one ball-groove contact (physics.md section 3).

    **Arguments:**
    - `ball_diameter`: D [m].
    - `conformity`: groove radius / D, > 0.5.
    - `pitch_diameter`: ball-centre diameter d_m [m].
    - `contact_angle`: [rad].
    - `inner`: True for the inner ring / screw groove (convex), False for the outer ring /
      nut groove (concave). A Python bool: it selects the formula.
    """
    g = ball_diameter * jnp.cos(contact_angle) / pitch_diameter
    sign = -1.0 if inner else 1.0
    r_x = ball_diameter * (1.0 + sign * g) / 2.0
    r_y = conformity * ball_diameter / (2.0 * conformity - 1.0)
    return r_x, r_y


def curvature_sum_and_difference(ball_diameter, conformity, pitch_diameter, contact_angle, inner):
    """Harris's curvature sum Sum(rho) [1/m] and curvature difference F(rho) [-].

    Sum(rho) = (1/D) [4 - 1/f +- 2g/(1 -+ g)] (upper signs inner). Used by the exact
    (elliptic-integral) Hertz solution; Harris's 209 bearing gives 0.2018 1/mm, 0.9400.
    """
    g = ball_diameter * jnp.cos(contact_angle) / pitch_diameter
    term = 2.0 * g / (1.0 - g) if inner else -2.0 * g / (1.0 + g)
    total = (4.0 - 1.0 / conformity + term) / ball_diameter
    diff = (1.0 / conformity + term) / (4.0 - 1.0 / conformity + term)
    return total, diff


def contact_coefficient(ball_diameter, conformity, pitch_diameter, contact_angle,
                        youngs_modulus, poisson_ratio, inner):
    """K [m/N^(2/3)] of one contact, delta = K Q^(2/3), Hamrock-Brewe closed form.

    k = 1.0339 (R_y/R_x)^0.6360, Ebar = 1.0003 + 0.5968 R_x/R_y,
    Fbar = 1.5277 + 0.6023 ln(R_y/R_x), delta = Fbar [9/(2 Ebar R) (Q/(pi k E'))^2]^(1/3).
    """
    r_x, r_y = contact_radii(ball_diameter, conformity, pitch_diameter, contact_angle, inner)
    ratio = r_y / r_x
    k = 1.0339 * ratio**0.6360
    e_bar = 1.0003 + 0.5968 / ratio
    f_bar = 1.5277 + 0.6023 * jnp.log(ratio)
    r_eff = 1.0 / (1.0 / r_x + 1.0 / r_y)
    e_prime = _reduced_modulus(youngs_modulus, poisson_ratio)
    # delta / Q^(2/3): Q enters only as Q^(2/3), so it factors out exactly.
    return f_bar * (9.0 / (2.0 * e_bar * r_eff) / (jnp.pi * k * e_prime) ** 2) ** (1.0 / 3.0)


def hertz_coefficient(ball_diameter, conformity_inner, conformity_outer, pitch_diameter,
                      contact_angle, youngs_modulus, poisson_ratio):
    """Per-ball K = K_inner + K_outer [m/N^(2/3)] (contacts in series; physics.md section 3).

    For the screw-nut joint, "inner" is the screw groove (f_s) and "outer" the nut groove
    (f_n); for the bearing, the inner (f_i) and outer (f_o) rings.
    """
    k_in = contact_coefficient(ball_diameter, conformity_inner, pitch_diameter, contact_angle,
                               youngs_modulus, poisson_ratio, inner=True)
    k_out = contact_coefficient(ball_diameter, conformity_outer, pitch_diameter, contact_angle,
                                youngs_modulus, poisson_ratio, inner=False)
    return k_in + k_out
