"""Restoring force of a preloaded pair of Hertz ball rows (double nut or bearing pair).

Paper Eqs. (5)-(16) (screw-nut joint) and (17)-(28) (bearing joint), as fixed by the
contract of physics.md section 1 (which corrects Eq. 20's sign and the thermal sign):

    a_s = A sin(beta) + s u / cos(lambda),  b = A cos(beta),  A_s = sqrt(a_s^2 + b^2)
    delta_s = A_s - A0 - D                  (no contact when <= 0)
    F_side,s = Z K^(-3/2) max(delta_s, 0)^(3/2) (a_s / A_s) cos(lambda)
    F(u) = F_side,+1 - F_side,-1
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._numerics import float_array
from ._safe import pos_pow


class PreloadedPair(eqx.Module):
    """One preloaded pair, SI units, all differentiable arrays. Build with `preloaded_pair`.

    Physical fields (reported, and used by the potential):
    - `balls`: Z (nut, per half) or m (bearing, per row), real-valued;
    - `hertz_k`: K [m/N^(2/3)]; `a0`: A0 = (f_1 + f_2 - 1) d [m];
    - `a`: preloaded centre distance A = A0 + K Q0^(2/3) [m];
    - `contact_angle` [rad]; `cos_helix`: cos(lambda) (1 for the bearing);
    - `offset`: signed thermal offset D [m] (positive reduces the contact deformation).

    Derived once here so the force law (evaluated at every solver stage) stays cheap:
    - `coeff` = Z K^(-3/2) cos(lambda) [N/m^(3/2)]; `axial` = A sin(beta) [m];
    - `radial_sq` = (A cos(beta))^2 [m^2]; `reach` = A0 + D [m].

    Because of these derived fields, change a pair by rebuilding it with `preloaded_pair`
    (or change the parameters and call `build_system`), not with `eqx.tree_at` on a field.
    """

    balls: jnp.ndarray
    hertz_k: jnp.ndarray
    a0: jnp.ndarray
    a: jnp.ndarray
    contact_angle: jnp.ndarray
    cos_helix: jnp.ndarray
    offset: jnp.ndarray
    coeff: jnp.ndarray
    axial: jnp.ndarray
    radial_sq: jnp.ndarray
    reach: jnp.ndarray


def preloaded_pair(balls, ball_diameter, conformity_1, conformity_2, contact_angle, preload,
                   hertz_k, cos_helix=1.0, offset=0.0):
    """Assemble a `PreloadedPair` (Eq. 5 / Eq. 17).

    Q0 = F_p / (Z sin(beta) cos(lambda)), delta0 = K Q0^(2/3), A = A0 + delta0.
    """
    f = float_array
    balls, hertz_k, angle, cos_helix, offset = map(f, (balls, hertz_k, contact_angle,
                                                      cos_helix, offset))
    a0 = (f(conformity_1) + f(conformity_2) - 1.0) * f(ball_diameter)
    q0 = f(preload) / (balls * jnp.sin(angle) * cos_helix)
    a = a0 + hertz_k * q0 ** (2.0 / 3.0)
    return PreloadedPair(
        balls, hertz_k, a0, a, angle, cos_helix, offset,
        coeff=balls * hertz_k ** (-1.5) * cos_helix,
        axial=a * jnp.sin(angle),
        radial_sq=(a * jnp.cos(angle)) ** 2,
        reach=a0 + offset,
    )


def _side_geometry(u, pair: PreloadedPair, side):
    """(a_s, A_s, delta_s) for side s = +1 (left) or -1 (right) at axial displacement u."""
    a_s = pair.axial + side * u / pair.cos_helix
    a_len = jnp.sqrt(a_s * a_s + pair.radial_sq)  # radial_sq > 0 below 90 deg: no sqrt(0)
    return a_s, a_len, a_len - pair.reach


def _fast_side_force(u, pair: PreloadedPair, side):
    """F_side,s without a division or a square root: products by reciprocals of the run's
    constants (computed once, outside any time loop) and reciprocal square roots."""
    a_s = pair.axial + (side / pair.cos_helix) * u
    a_sq = a_s * a_s + pair.radial_sq
    inv_len = jax.lax.rsqrt(a_sq)
    delta = a_sq * inv_len - pair.reach
    return pair.coeff * pos_pow(delta, 1.5, fast=True) * (a_s * inv_len)


def contact_deformations(u, pair: PreloadedPair):
    """Normal contact deformations (delta_+, delta_-) [m]; a side is unloaded when <= 0."""
    return _side_geometry(u, pair, 1.0)[2], _side_geometry(u, pair, -1.0)[2]


def contact_angles(u, pair: PreloadedPair):
    """Load-dependent contact angles (beta_+, beta_-) [rad] (Eqs. 6, 8)."""
    out = []
    for side in (1.0, -1.0):
        a_s, a_len, _ = _side_geometry(u, pair, side)
        out.append(jnp.arcsin(a_s / a_len))
    return tuple(out)


def side_forces(u, pair: PreloadedPair, fast=False):
    """Axial forces (F_+, F_-) [N] carried by each half; each >= 0 (Eqs. 7, 9 / 19, 21).

    `fast`: see `pair_force`."""
    if fast:
        return _fast_side_force(u, pair, 1.0), _fast_side_force(u, pair, -1.0)
    out = []
    for side in (1.0, -1.0):
        a_s, a_len, delta = _side_geometry(u, pair, side)
        out.append(pair.coeff * pos_pow(delta, 1.5) * a_s / a_len)
    return tuple(out)


def pair_force(u, pair: PreloadedPair, fast=False):
    """Net restoring force F(u) = F_+ - F_- [N] of the pair; F(0) = 0 for equal offsets.

    `fast=True`: the same law with no division and no square root (reciprocal square
    roots, products by reciprocals), a few ulp from the correctly rounded default. The
    per-lane GPU kernel runs it: there a float64 division or square root is a branching
    software sequence that serialises the step (about 1.7x the time per step on an H100).
    Elsewhere the default keeps every operation correctly rounded, so that differently
    fused programs (vmap, the fused loop, forward and reverse derivatives) agree to the
    bit."""
    f_plus, f_minus = side_forces(u, pair, fast)
    return f_plus - f_minus


def pair_potential(u, pair: PreloadedPair):
    """Elastic energy U(u) [J] with dU/du = F(u), exactly.

    Each half's force is s Z K^(-3/2) cos^2(lambda) delta_s^(3/2) d(delta_s)/du, so
    U = (2/5) Z K^(-3/2) cos^2(lambda) [delta_+^(5/2) + delta_-^(5/2)] (zero-point irrelevant).
    """
    d_plus, d_minus = contact_deformations(u, pair)
    return 0.4 * pair.coeff * pair.cos_helix * (pos_pow(d_plus, 2.5) + pos_pow(d_minus, 2.5))
