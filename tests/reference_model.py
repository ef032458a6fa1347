"""An independent NumPy/SciPy implementation of the BSFS equations of motion (Eq. 31).

Written from physics.md section 1 alone, as a test oracle: it does not import bsfs_jax.
Inputs are the parameter file's values (a nested dict in file units, as `bsfs params`
prints them) plus the quantities this oracle deliberately does not recompute: the Hertz
coefficients K_n, K_b [m/N^(2/3)] and the signed thermal offsets D_n, D_b [m]. Its own
geometry (unit conversion, helix angle, A0, Q0, A, the screw spring of Eq. 29) is
computed here.
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass(frozen=True)
class Pair:
    """One preloaded pair of Hertz ball rows (SI)."""

    balls: float
    hertz_k: float  # K [m/N^(2/3)]
    a0: float  # unloaded curvature-centre distance [m]
    a: float  # preloaded distance [m]
    angle: float  # free contact angle [rad]
    cos_helix: float
    offset: float  # signed thermal offset [m]

    @classmethod
    def build(cls, balls, ball_diameter, conformity_1, conformity_2, angle, preload, hertz_k,
              cos_helix=1.0, offset=0.0):
        a0 = (conformity_1 + conformity_2 - 1.0) * ball_diameter
        q0 = preload / (balls * math.sin(angle) * cos_helix)
        a = a0 + hertz_k * q0 ** (2.0 / 3.0)
        return cls(balls, hertz_k, a0, a, angle, cos_helix, offset)

    def sides(self, u):
        """Axial forces carried by the left (+1) and right (-1) halves [N]."""
        u = np.asarray(u, dtype=float)
        out = []
        for s in (1.0, -1.0):
            a_s = self.a * math.sin(self.angle) + s * u / self.cos_helix
            b = self.a * math.cos(self.angle)
            length = np.hypot(a_s, b)
            delta = np.maximum(length - self.a0 - self.offset, 0.0)
            out.append(self.balls * self.hertz_k ** -1.5 * delta**1.5 * (a_s / length)
                       * self.cos_helix)
        return out[0], out[1]

    def force(self, u):
        f_plus, f_minus = self.sides(u)
        return f_plus - f_minus


class ReferenceBSFS:
    """Eq. 31 with NumPy: masses, dampers, nut pair, screw spring, bearing pair."""

    def __init__(self, file_values: dict, *, nut_k, bearing_k, nut_offset=0.0,
                 bearing_offset=0.0, screw_stiffness=None):
        mm, deg = 1e-3, math.pi / 180.0
        m, c, n, b, s = (file_values[k] for k in ("masses", "damping", "nut", "bearing",
                                                    "screw"))
        self.mass = np.array([m["bearing_kg"], m["screw_kg"], m["nut_kg"]], dtype=float)
        self.damping = np.array([c["bearing_n_s_per_m"], c["screw_n_s_per_m"],
                                 c["nut_n_s_per_m"]], dtype=float)
        beta = n["contact_angle_deg"] * deg
        helix = math.atan(n["lead_mm"] / (math.pi * n["pitch_diameter_mm"]))
        self.nut = Pair.build(n["balls"], n["ball_diameter_mm"] * mm, n["conformity_screw"],
                              n["conformity_nut"], beta, n["preload_n"], nut_k,
                              math.cos(helix), nut_offset)
        self.bearing = Pair.build(b["balls"], b["ball_diameter_mm"] * mm,
                                  b["conformity_inner"], b["conformity_outer"],
                                  b["contact_angle_deg"] * deg, b["preload_n"], bearing_k,
                                  1.0, bearing_offset)
        if screw_stiffness is None:
            root = (s["nominal_diameter_mm"] - n["ball_diameter_mm"] * math.cos(beta)) * mm
            screw_stiffness = (math.pi * s["youngs_modulus_gpa"] * 1e9 * root**2
                               / (4.0 * s["length_to_nut_mm"] * mm))
        self.k_s = float(screw_stiffness)

    def restoring(self, x, v):
        """Left-hand sides of Eq. 31 without inertia: internal forces on (m_b, m_s, m_n)."""
        x_b, x_s, x_n = x
        v_b, v_s, v_n = v
        c_b, c_s, c_n = self.damping
        f_b = self.bearing.force(x_b) + c_b * v_b
        f_s = self.k_s * (x_s - x_b) + c_s * (v_s - v_b)
        f_n = self.nut.force(x_n - x_s) + c_n * (v_n - v_s)
        return np.array([f_b - f_s, f_s - f_n, f_n])

    def rhs(self, t, y, amplitude, frequency):
        x, v = y[:3], y[3:]
        p = amplitude * math.sin(2.0 * math.pi * frequency * t)
        acc = (np.array([0.0, 0.0, p]) - self.restoring(x, v)) / self.mass
        return np.concatenate([v, acc])

    def simulate(self, y0, t_eval, amplitude, frequency, *, rtol=1e-11, atol=1e-16,
                 method="DOP853"):
        sol = solve_ivp(self.rhs, (0.0, float(t_eval[-1])), np.asarray(y0, dtype=float),
                        method=method, t_eval=np.asarray(t_eval, dtype=float), rtol=rtol,
                        atol=atol, args=(amplitude, frequency))
        if not sol.success:
            raise RuntimeError(f"reference solve_ivp failed: {sol.message}")
        return sol.y.T

    def stiffness_matrix(self, x0=None, h=1e-10):
        """Tangent stiffness d(restoring)/dx [N/m] by central differences at x0."""
        x0 = np.zeros(3) if x0 is None else np.asarray(x0, dtype=float)
        k = np.empty((3, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            k[:, j] = (self.restoring(x0 + e, np.zeros(3))
                       - self.restoring(x0 - e, np.zeros(3))) / (2 * h)
        return k

    def damping_matrix(self):
        c_b, c_s, c_n = self.damping
        return np.array([[c_b + c_s, -c_s, 0.0], [-c_s, c_s + c_n, -c_n], [0.0, -c_n, c_n]])

    def linear_frf(self, frequencies_hz, x0=None):
        """Receptance x / P [m/N] of the linearised system (force on the nut), (n_f, 3)."""
        k, c, m = self.stiffness_matrix(x0), self.damping_matrix(), np.diag(self.mass)
        out = []
        for f in np.atleast_1d(frequencies_hz):
            w = 2 * math.pi * f
            out.append(np.linalg.solve(k - w**2 * m + 1j * w * c, np.array([0.0, 0.0, 1.0])))
        return np.array(out)
