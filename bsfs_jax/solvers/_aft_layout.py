"""Static index layouts of harmonic balance's assembled Jacobian (numpy, cached per
harmonic count and grid): the AFT convolution's gather (`aft_jacobian_layout`), its
columns permuted for the positions-only method (`chained_layout`), and the derivative
term's blocks (`derivative_blocks`). Used by `_harmonic.py`."""

import functools

import numpy as np


@functools.lru_cache(maxsize=16)
def aft_jacobian_layout(h: int, n: int):
    """Static gather layout of the AFT Jacobian (`HarmonicBalance.residual_and_jacobian`).

    Blocks (r, c) over r, c in [c_0, a_1..a_H, b_1..b_H]; each block is
    c1 * table[w1] + c2 * table[w2], table = [alpha_0..alpha_(N-1), beta_0..beta_(N-1)]
    (Ahat_m = alpha_m + i beta_m). From dP_k/dc_0 = Ahat_k,
    dP_k/da_l = (Ahat_(k-l) + Ahat_(k+l)) / 2, dP_k/db_l = i (Ahat_(k+l) - Ahat_(k-l)) / 2
    and the real rows Re P_0, 2 Re P_k (a_k), -2 Im P_k (b_k)."""
    size = 2 * h + 1
    w1 = np.zeros((size, size), np.int32)
    w2 = np.zeros((size, size), np.int32)
    c1 = np.zeros((size, size))
    c2 = np.zeros((size, size))
    alpha = lambda m: m % n  # noqa: E731
    beta = lambda m: n + m % n  # noqa: E731
    for r in range(size):
        k = 0 if r == 0 else (r - 1) % h + 1
        kind = "c" if r == 0 else ("a" if r <= h else "b")
        # Re P_k (times 1 for c_0, 2 for a_k) or Im P_k (times -2 for b_k)
        f = 1.0 if kind == "c" else (2.0 if kind == "a" else -2.0)
        re = kind != "b"
        for c in range(size):
            l_ = 0 if c == 0 else (c - 1) % h + 1
            ckind = "c" if c == 0 else ("a" if c <= h else "b")
            if ckind == "c":  # Ahat_k
                w1[r, c], c1[r, c] = (alpha(k), f) if re else (beta(k), f)
            elif ckind == "a":  # (Ahat_(k-l) + Ahat_(k+l)) / 2
                w1[r, c], w2[r, c] = (alpha(k - l_), alpha(k + l_)) if re else \
                    (beta(k - l_), beta(k + l_))
                c1[r, c] = c2[r, c] = 0.5 * f
            else:  # i (Ahat_(k+l) - Ahat_(k-l)) / 2: Re = -(beta_+ - beta_-) / 2,
                # Im = (alpha_+ - alpha_-) / 2
                w1[r, c], w2[r, c] = (beta(k + l_), beta(k - l_)) if re else \
                    (alpha(k + l_), alpha(k - l_))
                c1[r, c], c2[r, c] = (-0.5 * f, 0.5 * f) if re else (0.5 * f, -0.5 * f)
    return w1, w2, c1, c2


@functools.lru_cache(maxsize=16)
def chained_layout(h: int, n: int):
    """`aft_jacobian_layout` with its columns permuted for the chain rule of harmonic
    balance in the positions (`_harmonic_second.assemble`): the column of a^x_k takes
    b^v_k's entries (factor -1), that of b^x_k takes a^v_k's (+1); c_0 takes none."""
    w1, w2, c1, c2 = aft_jacobian_layout(h, n)
    s = 2 * h + 1
    src = np.zeros(s, np.int64)
    sign = np.zeros(s)
    src[1:h + 1], sign[1:h + 1] = np.arange(h + 1, s), -1.0
    src[h + 1:], sign[h + 1:] = np.arange(1, h + 1), 1.0
    return w1[:, src], w2[:, src], c1[:, src] * sign, c2[:, src] * sign


@functools.lru_cache(maxsize=16)
def derivative_blocks(h: int):
    """(2H+1) x (2H+1): +k at (a_k, b_k), -k at (b_k, a_k): d/d(Omega t) in the residual."""
    out = np.zeros((2 * h + 1, 2 * h + 1))
    for k in range(1, h + 1):
        out[k, h + k] = k
        out[h + k, k] = -k
    return out
