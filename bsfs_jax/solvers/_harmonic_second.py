"""Harmonic balance in the positions only (`HarmonicBalance(second_order=True)`).

For a mechanical system whose state is y = (x, v) with x' = v exactly (the ball screw's
three masses: positions, then velocities), the velocity's Fourier coefficients follow from
the position's: with tau = Omega t and scaled states z_x = x / s_x, z_v = v / s_v,

    z_v = rho Omega dz_x/dtau,   rho = s_x / s_v,
    a^v_k = rho Omega k b^x_k,   b^v_k = -rho Omega k a^x_k,   c^v_0 = 0.

So the unknowns are the positions' coefficients alone, d/2 (2H + 1) numbers instead of
d (2H + 1), and the residual is the first-order residual's velocity rows at the expanded
coefficients: its position rows vanish identically there (the AFT of the linear field
x' = v is exact for N > 2H samples). The solutions are the first-order method's, to
rounding; Newton's matrix is half the size, so its LU costs an eighth (at 64 harmonics on
the ball screw 1.0 ms instead of 5.2 ms; the LU was most of a continuation step).

Everything else (error estimate, monodromy, samples) runs on the expanded coefficients.
The functions here work on arrays; `HarmonicBalance` calls them where `second_order`.
"""

import jax.numpy as jnp
import numpy as np


def _rho(scale, m):
    return scale[:m] / scale[m:]


def expand(z, h: int, d: int, omega, scale):
    """First-order coefficients (c_0, a_1..a_H, b_1..b_H over the d states) from the
    positions' (over d / 2)."""
    m = d // 2
    c0 = z[:m]
    a = z[m:m + h * m].reshape(h, m)
    b = z[m + h * m:].reshape(h, m)
    w = _rho(scale, m)[None, :] * omega * jnp.arange(1, h + 1, dtype=z.dtype)[:, None]
    full_a = jnp.concatenate([a, w * b], axis=1)
    full_b = jnp.concatenate([b, -w * a], axis=1)
    return jnp.concatenate([c0, jnp.zeros(m, z.dtype), full_a.reshape(-1),
                            full_b.reshape(-1)])


def positions(z_full, h: int, d: int):
    """The positions' coefficients of first-order coefficients (the inverse of `expand`
    on its image; numpy or jax arrays)."""
    return z_full.reshape(2 * h + 1, d)[:, :d // 2].reshape(-1)


def velocity_rows(r_full, h: int, d: int):
    """The velocity equations' rows of a first-order residual."""
    return r_full.reshape(2 * h + 1, d)[:, d // 2:].reshape(-1)


def chord_blocks(jacobian, h: int, d: int, omega, scale):
    """(B_0, B_k) of the linear field z' = `jacobian` z in the positions: the velocity
    rows on harmonic k act on X_k = a^x_k - i b^x_k as
    B_k = -k^2 rho Omega - J_vx / Omega - i k J_vv rho (B_0 = -J_vx / Omega)."""
    m = d // 2
    a_s = jnp.asarray(jacobian) / omega
    rho = _rho(scale, m)
    k = jnp.arange(1, h + 1, dtype=a_s.dtype)[:, None, None]
    b0 = -a_s[m:, :m]
    bk = (-(k ** 2) * (omega * jnp.diag(rho))[None] + b0[None]
          - 1j * k * (a_s[m:, m:] * omega * rho[None, :])[None])
    return b0, bk


def assemble(table, layout, chained, h: int, d: int, omega, scale):
    """d(velocity rows)/d(positions' coefficients) from the AFT table of the velocity
    rows of the field's Jacobian (`HarmonicBalance.residual_and_jacobian`: `table`
    (2N, d/2, d), `layout` its (w1, w2, c1, c2), `chained` its columns permuted,
    `_aft_layout.chained_layout`).
    The velocity coefficients are linear in the positions' (`expand`), so the chain rule
    permutes columns: the column of a^x_k gains -rho Omega k times the one of b^v_k,
    b^x_k gains rho Omega k times a^v_k; the derivative term +-k between a^v_k and b^v_k
    becomes -k^2 rho Omega on the diagonal."""
    m = d // 2
    s = 2 * h + 1
    w1, w2, c1, c2 = layout
    p1, p2, q1, q2 = chained
    tx, tv = table[..., :m], table[..., m:]
    kk = np.concatenate([[0.0], np.arange(1, h + 1), np.arange(1, h + 1)])  # k of column c
    w = (omega * kk)[:, None] * _rho(scale, m)[None, :]  # rho_j Omega k(c), (s, m)
    bx = c1[..., None, None] * tx[w1] + c2[..., None, None] * tx[w2]  # (s, s, m, m)
    bv = q1[..., None, None] * tv[p1] + q2[..., None, None] * tv[p2]
    mat = jnp.transpose(bx + bv * w[None, :, None, :], (0, 2, 1, 3)).reshape(s * m, s * m)
    return jnp.diag((-kk[:, None] * w).reshape(-1)) - mat / omega
