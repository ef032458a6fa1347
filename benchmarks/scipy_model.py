"""The BSFS vector field (paper Eq. 31, physics.md section 1) in plain numpy, for the
reference integrators of the benchmarks (scipy solve_ivp and the numba Dormand-Prince).

`bsfs_coefficients(params)` flattens the coefficients that `bsfs_jax.build_system`
computes (masses, damping, screw stiffness, the two preloaded Hertz pairs) into one float
array, so the references integrate exactly the same equations as the JAX model.
"""

import numpy as np

# Layout of the coefficient vector.
M, C, KS = slice(0, 3), slice(3, 6), 6
NUT, BEAR = 7, 12  # each pair: coeff, axial, radial_sq, reach, cos_helix
N_COEFFS = 17


def bsfs_coefficients(params) -> np.ndarray:
    """Coefficients of Eq. 31 for `params` (BallScrewParams), via bsfs_jax.build_system."""
    from bsfs_jax import build_system

    s = build_system(params)
    out = np.zeros(N_COEFFS)
    out[M] = np.asarray(s.mass)
    out[C] = np.asarray(s.damping)
    out[KS] = float(s.screw_stiffness)
    for base, pair in ((NUT, s.nut), (BEAR, s.bearing)):
        out[base:base + 5] = [float(pair.coeff), float(pair.axial), float(pair.radial_sq),
                              float(pair.reach), float(pair.cos_helix)]
    return out


def pair_force(u, c, base):
    """Net force of a preloaded Hertz pair at axial displacement u (scalar)."""
    coeff, axial, radial_sq, reach, cos_h = c[base:base + 5]
    f = 0.0
    for side in (1.0, -1.0):
        a_s = axial + side * u / cos_h
        a_len = np.sqrt(a_s * a_s + radial_sq)
        d = a_len - reach
        if d > 0.0:
            f += side * coeff * d * np.sqrt(d) * a_s / a_len
    return f


def rhs(t, y, c, frequency, force):
    """dy/dt of the BSFS, y = (x_b, x_s, x_n, v_b, v_s, v_n)."""
    xb, xs, xn, vb, vs, vn = y
    fb = pair_force(xb, c, BEAR)
    fs = c[KS] * (xs - xb)
    fn = pair_force(xn - xs, c, NUT)
    db, ds, dn = c[3] * vb, c[4] * (vs - vb), c[5] * (vn - vs)
    p = force * np.sin(2.0 * np.pi * frequency * t)
    return np.array([
        vb, vs, vn,
        -(fb + db - fs - ds) / c[0],
        -(fs + ds - fn - dn) / c[1],
        (p - fn - dn) / c[2],
    ])


def solve_ivp_strobe(c, frequency, force, transient_periods, samples, rtol, atol,
                     y0=None):
    """scipy RK45 from rest to (transient + samples) periods, sampled at t = kT.

    Returns (strobe (samples + 1, 6), number of RK steps (nfev / 6), status)."""
    from scipy.integrate import solve_ivp

    period = 1.0 / frequency
    t_end = (transient_periods + samples) * period
    t_eval = period * np.arange(transient_periods, transient_periods + samples + 1)
    t_eval[-1] = t_end
    sol = solve_ivp(rhs, (0.0, t_end), np.zeros(6) if y0 is None else y0, method="RK45",
                    t_eval=t_eval, rtol=rtol, atol=atol, args=(c, frequency, force))
    return sol.y.T, sol.nfev / 6.0, sol.status
