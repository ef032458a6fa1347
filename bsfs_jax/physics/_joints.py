"""Restoring force of a preloaded pair of Hertz ball rows (double nut or bearing pair).

Paper Eqs. (5)-(16) (screw-nut joint) and (17)-(28) (bearing joint), as fixed by the
contract of physics.md section 1 (which corrects Eq. 20's sign and the thermal sign).
"""

import equinox as eqx
import jax.numpy as jnp

from ._safe import pos_pow


class PreloadedPair(eqx.Module):
    """Geometry of one preloaded pair, all SI, all differentiable arrays.

    Built from parameters by `preloaded_pair(...)`; fields:
    - `balls`: Z (nut, per half) or m (bearing, per row) [-], real-valued.
    - `hertz_k`: K [m/N^(2/3)].
    - `a0`: unloaded curvature-centre distance A0 = (f_1 + f_2 - 1) d [m].
    - `a`: preloaded distance A = A0 + K Q0^(2/3) [m].
    - `contact_angle`: free contact angle [rad].
    - `cos_helix`: cos(lambda) (1 for the bearing).
    - `offset`: signed thermal offset D [m]; positive reduces the contact deformation.
    """

    balls: jnp.ndarray
    hertz_k: jnp.ndarray
    a0: jnp.ndarray
    a: jnp.ndarray
    contact_angle: jnp.ndarray
    cos_helix: jnp.ndarray
    offset: jnp.ndarray


def preloaded_pair(balls, ball_diameter, conformity_1, conformity_2, contact_angle, preload,
                   hertz_k, cos_helix=1.0, offset=0.0):
    """Assemble a `PreloadedPair` (Eq. 5 / Eq. 17).

    Q0 = F_p / (Z sin(beta) cos(lambda)), delta0 = K Q0^(2/3), A = A0 + delta0.
    """
    f = lambda x: jnp.asarray(x, dtype=float)
    a0 = (f(conformity_1) + f(conformity_2) - 1.0) * f(ball_diameter)
    q0 = f(preload) / (f(balls) * jnp.sin(contact_angle) * cos_helix)
    delta0 = f(hertz_k) * q0 ** (2.0 / 3.0)
    return PreloadedPair(f(balls), f(hertz_k), a0, a0 + delta0, f(contact_angle),
                         f(cos_helix), f(offset))


def _side_geometry(u, pair: PreloadedPair, side):
    """(a_s, A_s, delta_s) for side s = +1 (left) or -1 (right) at axial displacement u."""
    a_s = pair.a * jnp.sin(pair.contact_angle) + side * u / pair.cos_helix
    b = pair.a * jnp.cos(pair.contact_angle)
    a_len = jnp.sqrt(a_s**2 + b**2)  # b > 0 for angles < 90 deg: no sqrt(0) here
    return a_s, a_len, a_len - pair.a0 - pair.offset


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


def side_forces(u, pair: PreloadedPair):
    """Axial forces (F_+, F_-) [N] carried by each half; each >= 0 (Eqs. 7, 9 / 19, 21)."""
    coeff = pair.balls * pair.hertz_k ** (-1.5) * pair.cos_helix
    out = []
    for side in (1.0, -1.0):
        a_s, a_len, delta = _side_geometry(u, pair, side)
        out.append(coeff * pos_pow(delta, 1.5) * a_s / a_len)
    return tuple(out)


def pair_force(u, pair: PreloadedPair):
    """Net restoring force F(u) = F_+ - F_- [N] of the pair; F(0) = 0 for equal offsets."""
    f_plus, f_minus = side_forces(u, pair)
    return f_plus - f_minus


def pair_potential(u, pair: PreloadedPair):
    """Elastic energy U(u) [J] with dU/du = F(u), exactly.

    Each half's force is s Z K^(-3/2) cos^2(lambda) delta_s^(3/2) d(delta_s)/du, so
    U = (2/5) Z K^(-3/2) cos^2(lambda) [delta_+^(5/2) + delta_-^(5/2)] (zero-point irrelevant).
    """
    d_plus, d_minus = contact_deformations(u, pair)
    coeff = 0.4 * pair.balls * pair.hertz_k ** (-1.5) * pair.cos_helix**2
    return coeff * (pos_pow(d_plus, 2.5) + pos_pow(d_minus, 2.5))
