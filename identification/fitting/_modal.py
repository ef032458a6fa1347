"""A data-driven first estimate: the first resonance read off the records, and starts on it.

A modal-test engineer starts a model update from the measured resonance, not from the
catalogue. So does the staged fit (`_fit.staged_starts`):

1. `modal_estimate(problem)` fits a single mode to the records' linear content near the
   first resonance: the lines of every FRF record and the fundamental ratio (acceleration
   over force) of every sine record that the linear or first-order model explains (those
   on the periodic-orbit model are left out), as receptance G = H / -(2 pi f)^2, in a band
   `BAND` around the largest significant peak. The mode is

       G(f) = A / (fn^2 - f^2 + 2 i zeta fn f) + B,   A, B complex

   (B: the higher modes' residual compliance; A complex: non-proportional damping). fn and
   zeta are found on a grid with A and B eliminated by weighted linear least squares
   (variable projection), then refined by optimistix's Levenberg-Marquardt (in coordinates
   scaled by the Jacobian's column norms); their standard errors come from its Jacobian,
   scaled up by the reduced chi-square where that exceeds 1 (measured on the bundled
   through-resonance records: with their 100 N sines near the peak included, the single
   mode settled 1.3 Hz below the truth at a reduced chi-square of 3.9 with a standard
   error of 0.02 Hz; which is why those records are left out).
2. `modal_starts(problem, estimate, points)` maps the estimate through the model's own
   linearisation: each quasi-random start moves to the nearest point (in the prior's
   metric) whose first natural frequency and modal damping ratio (`bsfs_jax.modes`'s
   definitions, linearised about the unforced equilibrium) match the estimate within its
   standard errors: a Levenberg-Marquardt iteration batched over the starts (numpy), on
   one compiled evaluation of the first mode and its Jacobian per fit structure. The starts
   keep their spread in the directions the resonance does not fix and all agree with the
   measured resonance in the two it does.

The estimate only places starts: every start is then fitted to all of the data, and the
fit's own convergence test and agreement among starts decide. A wrong first estimate can
cost iterations, never the answer.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import bsfs_jax
from bsfs_jax.machine import tangent_matrices

from ..measurement import FitData, Structure, is_frf, params_at

BAND = (0.75, 1.3)  # fraction of the peak frequency used by the single-mode fit
MIN_SNR = 5.0  # |G| / its standard error for a point to count as a peak candidate
MIN_POINTS = 4  # complex points in the band (two unknowns complex, two real: 6 numbers)
# Floors of the standard errors that the starts are held to: the single mode and the
# linearised model's undamped frequency and modal damping differ at about these levels.
FLOOR_LN_F, FLOOR_LN_ZETA = 1e-3, 0.05
# The single-mode fit's Levenberg-Marquardt: its Cauchy tolerances on the scaled coordinates
# and the residual, and its step limit (from the grid's best point it takes about ten).
SINGLE_MODE_TOL = 1e-10
SINGLE_MODE_STEPS = 200


@dataclasses.dataclass(frozen=True)
class ModalEstimate:
    """The first resonance read off the records (single-mode fit)."""

    frequency_hz: float
    zeta: float
    frequency_se_hz: float
    zeta_se: float
    speed_rpm: float
    points: int  # complex points in the band
    records: tuple  # names of the records that contributed
    reduced_chi2: float
    band_hz: tuple

    def as_dict(self) -> dict:
        return dict(frequency_hz=self.frequency_hz, frequency_se_hz=self.frequency_se_hz,
                    damping_ratio=self.zeta, damping_ratio_se=self.zeta_se,
                    speed_rpm=self.speed_rpm, points=self.points, records=list(self.records),
                    reduced_chi2=self.reduced_chi2, band_hz=list(self.band_hz))

    def summary(self) -> str:
        return (f"first resonance from the records: {self.frequency_hz:.1f} Hz (standard "
                f"error {self.frequency_se_hz:.2g} Hz), damping ratio {100 * self.zeta:.3g} % "
                f"({100 * self.zeta_se:.2g} %) (single mode fitted to {self.points} lines and "
                f"sines of {len(self.records)} record(s) at {self.speed_rpm:g} r/min, "
                f"{self.band_hz[0]:.0f}-{self.band_hz[1]:.0f} Hz; reduced chi-square "
                f"{self.reduced_chi2:.2g})")


def _points(problem):
    """{speed: (f [Hz], G [m/N] complex, std of G (per component), record index)} of the
    linear content of every record that the linear or first-order model explains (a record
    on the periodic-orbit model is left out: its fundamental ratio is not the linear FRF)."""
    out = {}
    for i, d in enumerate(problem.data):
        if problem.models[i] == "nonlinear":
            continue
        if is_frf(d):
            keep = ~np.asarray(problem.frf_left_out.get(i, np.zeros(d.frequency_hz.size,
                                                                     bool)))
            f = np.asarray(d.frequency_hz)[keep]
            w2 = (2 * np.pi * f) ** 2
            g = np.asarray(d.accelerance)[keep] / -w2
            s = np.sqrt(np.mean(np.asarray(d.variance)[keep], axis=1)) / w2
        else:
            fc, ac = complex(d.force[0]), complex(d.acceleration[0])
            if not abs(fc) > 0:
                continue
            f = np.asarray([d.frequency_hz])
            w2 = (2 * np.pi * f) ** 2
            h = ac / fc
            var = (np.mean(d.acceleration_var[0]) + abs(h) ** 2 * np.mean(d.force_var[0]))
            g = np.asarray([h]) / -w2
            s = np.sqrt(var) / abs(fc) / w2
        ok = np.isfinite(g) & np.isfinite(s) & (s > 0) & (f > 0)
        if np.any(ok):
            lst = out.setdefault(d.speed_rpm, [])
            lst.append((f[ok], g[ok], s[ok], np.full(int(ok.sum()), i)))
    return {k: tuple(np.concatenate(c) for c in zip(*v)) for k, v in out.items()}


def _projected(nu, g, w, r, zeta):
    """Variable projection on a grid: the weighted cost of the best (A, B) for every
    (r, zeta) pair (arrays of the same shape), and (A, B)."""
    phi = 1.0 / (r[..., None] ** 2 - nu ** 2 + 2j * zeta[..., None] * r[..., None] * nu)
    w2 = w ** 2
    # Normal equations of min sum w^2 |g - A phi - B|^2 (complex A, B).
    a11 = np.sum(w2 * np.abs(phi) ** 2, -1)
    a12 = np.sum(w2 * np.conj(phi), -1)
    a22 = np.sum(w2)
    b1 = np.sum(w2 * np.conj(phi) * g, -1)
    b2 = np.sum(w2 * g)
    det = a11 * a22 - np.abs(a12) ** 2
    a = (a22 * b1 - a12 * b2) / det
    b = (a11 * b2 - np.conj(a12) * b1) / det
    res = g - a[..., None] * phi - b[..., None]
    return np.sum(w2 * np.abs(res) ** 2, -1), a, b


def modal_estimate(problem):
    """(ModalEstimate, None) or (None, why not) for `problem`'s records."""
    pts = _points(problem)
    if not pts:
        return None, ("no record that the linear model explains has a usable fundamental "
                      "or FRF line")
    # The speed with the most points; a mode per speed would need its own thermal state.
    speed = max(pts, key=lambda s: pts[s][0].size)
    f, g, s, rec = pts[speed]
    strong = np.abs(g) / s > MIN_SNR
    if not np.any(strong):
        return None, f"no line or sine at {speed:g} r/min stands {MIN_SNR:g}x above its noise"
    fp = float(f[strong][np.argmax(np.abs(g[strong]))])
    lo, hi = BAND[0] * fp, BAND[1] * fp
    band = (f >= lo) & (f <= hi)
    below, above = np.sum(band & (f < 0.99 * fp)), np.sum(band & (f > 1.01 * fp))
    if band.sum() < MIN_POINTS or not below or not above:
        return None, (f"the records have {int(band.sum())} points within {lo:.0f}-{hi:.0f} "
                      f"Hz of the largest response ({fp:.0f} Hz), {int(below)} below and "
                      f"{int(above)} above it: the resonance is not bracketed (needs "
                      f"{MIN_POINTS}, with points on both sides)")
    nu, gb, w = f[band] / fp, g[band], 1.0 / s[band]
    scale = np.max(np.abs(gb))
    gb, w = gb / scale, w * scale
    r_grid, z_grid = np.meshgrid(1.0 + np.linspace(-0.06, 0.06, 61),
                                 np.geomspace(5e-4, 0.2, 30), indexing="ij")
    cost, a, b = _projected(nu, gb, w, r_grid, z_grid)
    k = np.unravel_index(np.nanargmin(cost), cost.shape)
    x0 = np.array([np.log(r_grid[k]), np.log(z_grid[k]), a[k].real, a[k].imag, b[k].real,
                   b[k].imag])

    x, r, jac, settled = _single_mode_fit(x0, nu, gb, w)
    dof = 2 * nu.size - x0.size
    chi2 = float(r @ r / dof) if dof > 0 else np.inf
    try:
        cov = np.linalg.inv(jac.T @ jac) * max(1.0, chi2)
    except np.linalg.LinAlgError:
        return None, "the single-mode fit near the peak is singular"
    se = np.sqrt(np.clip(np.diag(cov)[:2], 0.0, None))
    fn, zeta = fp * float(np.exp(x[0])), float(np.exp(x[1]))
    if not (settled and np.all(np.isfinite(se)) and lo < fn < hi and zeta < 0.5):
        return None, "the single-mode fit near the peak did not settle inside the band"
    names = tuple(dict.fromkeys(problem.data[i].name for i in rec[band]))
    return ModalEstimate(fn, zeta, fn * float(se[0]), zeta * float(se[1]), float(speed),
                         int(nu.size), names, chi2, (lo, hi)), None


def _single_mode_residual(x, args):
    """Weighted residual (2 n,) of the single mode x = (ln r, ln zeta, Re A, Im A, Re B,
    Im B) at the frequency ratios nu = f / f_peak (padded points: weight 0)."""
    nu, g, w = args
    r, z = jnp.exp(x[0]), jnp.exp(x[1])
    model = (x[2] + 1j * x[3]) / (r ** 2 - nu ** 2 + 2j * z * r * nu) + x[4] + 1j * x[5]
    d = w * (g - model)
    return jnp.concatenate([d.real, d.imag])


@bsfs_jax.cached_jit
def _single_mode_solve(x0, nu, g, w):
    """Levenberg-Marquardt (optimistix) from x0 in coordinates scaled by the Jacobian's
    column norms at x0 (every coordinate of unit effect on the residual, as MINPACK's
    scaling by the Jacobian does). Returns (x, residual, Jacobian, converged)."""
    args = (nu, g, w)
    jac0 = jax.jacfwd(_single_mode_residual)(x0, args)
    d = jnp.sqrt(jnp.sum(jac0 ** 2, axis=0))
    d = jnp.where(jnp.isfinite(d) & (d > 0), d, 1.0)
    scaled = lambda u, a: _single_mode_residual(x0 + u / d, a)
    solver = optx.LevenbergMarquardt(rtol=SINGLE_MODE_TOL, atol=SINGLE_MODE_TOL)
    sol = optx.least_squares(scaled, solver, jnp.zeros_like(x0), args=args,
                             max_steps=SINGLE_MODE_STEPS, throw=False)
    x = x0 + sol.value / d
    return (x, _single_mode_residual(x, args), jax.jacfwd(_single_mode_residual)(x, args),
            sol.result == optx.RESULTS.successful)


def _single_mode_fit(x0, nu, g, w):
    """`_single_mode_solve` on the points padded to a power of two (at least 16; weight
    0), so that one compiled program serves every band of that size class; numpy out."""
    n = nu.size
    size = max(16, 1 << (n - 1).bit_length())
    pad = lambda a: np.concatenate([a, np.zeros(size - n, a.dtype)])
    x, r, jac, ok = _single_mode_solve(jnp.asarray(x0, float), jnp.asarray(pad(nu)),
                                       jnp.asarray(pad(g)), jnp.asarray(pad(w)))
    keep = np.concatenate([np.arange(n), size + np.arange(n)])
    return np.asarray(x), np.asarray(r)[keep], np.asarray(jac)[keep], bool(ok)


def first_mode(theta, data: FitData, structure: Structure, group: int):
    """(f1 [Hz], modal damping ratio of mode 1) of the model at theta, linearised about the
    unforced equilibrium of speed group `group` (as `bsfs_jax.modes`)."""
    k, c, m = tangent_matrices(bsfs_jax.build_system(params_at(theta, data, structure, group)))
    modes = bsfs_jax.Modes.from_matrices(k, c, m, jnp.zeros(3))
    return modes.frequencies_hz[0], modes.damping_ratios[0]


@bsfs_jax.cached_jit
def _mode_and_jacobian(thetas, data, structure, group):
    """ln(f1, zeta1) (B, 2) and its Jacobian (B, 2, p) at a batch of thetas."""
    def fn(th):
        f, z = first_mode(th, data, structure, group)
        return jnp.log(jnp.maximum(jnp.stack([f, z]), jnp.finfo(float).tiny))

    both = lambda th: (fn(th),) * 2
    return jax.vmap(lambda th: jax.jacfwd(both, has_aux=True)(th)[::-1])(thetas)


def _project(starts, target, scale, inv_sigma, data, structure, group, steps=30):
    """Levenberg-Marquardt, batched over the starts (numpy; one compiled evaluation of the
    first mode and its Jacobian per iteration): min |(m(th) - target) / scale|^2 +
    |(th - th0) inv_sigma|^2 for each start th0. Returns (theta, mode rows)."""
    def rows(th):
        m, j = (np.asarray(a) for a in _mode_and_jacobian(jnp.asarray(th), data, structure,
                                                           group))
        r = np.concatenate([(m - target) / scale, (th - starts) * inv_sigma], axis=1)
        pin = np.broadcast_to(np.diag(inv_sigma), (len(th),) + (inv_sigma.size,) * 2)
        jac = np.concatenate([j / scale[None, :, None], pin], axis=1)
        return r, jac

    th = np.array(starts, float)
    r, jac = rows(th)
    cost = np.sum(r ** 2, axis=1)
    lam = np.full(len(th), 1e-3)
    for _ in range(steps):
        jtj = np.einsum("bki,bkj->bij", jac, jac)
        g = np.einsum("bki,bk->bi", jac, r)
        a = jtj + lam[:, None, None] * np.einsum("bii->bi", jtj)[:, :, None] * np.eye(
            th.shape[1])
        trial = th - np.linalg.solve(a, g[..., None])[..., 0]
        r_t, jac_t = rows(trial)
        cost_t = np.sum(r_t ** 2, axis=1)
        better = np.isfinite(cost_t) & (cost_t < cost)
        th = np.where(better[:, None], trial, th)
        r = np.where(better[:, None], r_t, r)
        jac = np.where(better[:, None, None], jac_t, jac)
        done = better & (cost - cost_t < 1e-10 * (1.0 + cost))
        cost = np.where(better, cost_t, cost)
        lam = np.where(better, lam / 10.0, lam * 10.0)
        if np.all(done | (lam > 1e8)):
            break
    return th, r


def modal_starts(problem, estimate: ModalEstimate, points, sigma):
    """`points` (quasi-random starts, theta) each moved to the nearest point in the metric
    1 / `sigma` whose model resonance matches `estimate` (module docstring). Returns the
    moved starts (a start whose solve failed stays where it was) and the largest remaining
    mismatch of the moved starts in units of the estimate's standard errors."""
    group = problem.speeds.index(estimate.speed_rpm)
    # Only the parameter set enters: the records' arrays are left out, so the program does
    # not depend on the test's layout.
    light = eqx.tree_at(lambda d: d.groups, problem.fit_data, ())
    target = np.log([estimate.frequency_hz, estimate.zeta])
    scale = np.maximum([estimate.frequency_se_hz / estimate.frequency_hz,
                        estimate.zeta_se / estimate.zeta], [FLOOR_LN_F, FLOOR_LN_ZETA])
    th, r = _project(np.stack(points).astype(float), target, scale,
                     1.0 / np.asarray(sigma, float), light, problem.structure, group)
    ok = np.all(np.isfinite(th), axis=1) & np.all(np.isfinite(r), axis=1)
    moved = [th[i] if ok[i] else np.asarray(p, float) for i, p in enumerate(points)]
    mismatch = float(np.max(np.abs(r[ok, :2]))) if np.any(ok) else np.inf
    return moved, mismatch
