"""The force sensor's noise seen through the model: the weights of periodic-orbit records.

The model is driven by the measured force harmonics, so their noise reaches the residual
A - model(F). For the linearised model that is G F, whose variance is |G|^2 var(F) per
harmonic (`_groups._sine_arrays`). A periodic orbit of the nonlinear joints responds to
its force otherwise: near the first resonance its amplitude grows faster than the force,
and at a high force (contact loss) the fundamental's noise reaches the second and third
harmonics, which |G_k|^2 var(F_k) leaves out. Replicating the sensor noise on such
records (one-off check `robustness_noise_mc.py`, in git at 9d7344c) gave residual
variances up to 10x the stated ones along the directions that inform the dampers.

Here the orbit records' weights take the model's own derivatives instead: var(A_kc) +
sum_md (d model_kc / d F_md)^2 var(F_md) over the Re and Im parts c, d of every harmonic
k, m, the derivatives by central differences of the fit's own prediction program
(`_model.predictions` with its orbits: one compiled program per layout, about 2 s to
compile for the bundled through-resonance test) at the point where the models are chosen
(the prior, the first estimate, the estimate). Six force directions are perturbed in
every record at once: records do not couple. A diagonal weight: the residual's
correlations between its entries are not carried, so a near-resonance record whose
amplified direction lies between Re and Im keeps part of its anisotropy.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from . import _model

# Central-difference step relative to each record's largest force harmonic: about the
# noise's own scale (40 dB SNR gives 1e-4 per coefficient), far above the orbit solver's
# tolerance.
REL_STEP = 1e-5


def force_gains(problem, theta) -> dict:
    """{record index: (H, 2, H, 2) squared derivatives of its model acceleration's (Re,
    Im) per harmonic with respect to its force harmonics' (Re, Im)} for the records on
    the periodic-orbit model; a record whose orbit is not found at theta is left out (it
    keeps the linearised weight)."""
    orbit = [i for i, m in enumerate(problem.models) if m == "nonlinear"]
    if not orbit:
        return {}
    fd, st = problem.fit_data, problem.structure
    th = jnp.asarray(theta, float)
    forces = [np.asarray(g.sine_force) for g in fd.groups]
    steps = [REL_STEP * np.maximum(np.max(np.abs(f), axis=1, initial=0.0), 1e-12)
             for f in forces]
    n_h = forces[0].shape[1] if forces else 0

    def predicted(k, unit, sign):
        groups = []
        for g, f, h in zip(fd.groups, forces, steps):
            moved = f.copy()
            if f.shape[0]:
                moved[:, k] = moved[:, k] + sign * unit * h
            groups.append(eqx.tree_at(lambda q: q.sine_force, g, moved))
        data = eqx.tree_at(lambda q: q.groups, fd, type(fd.groups)(groups))
        return [np.asarray(p[0]) for p in _model.predictions(th, data, st)]

    cols = {}
    for k in range(n_h):
        for c, unit in ((0, 1.0), (1, 1j)):
            plus, minus = predicted(k, unit, 1.0), predicted(k, unit, -1.0)
            with np.errstate(invalid="ignore", divide="ignore"):  # no orbit: inf, left out
                cols[k, c] = [(p - m) / (2.0 * h[:, None])
                              for p, m, h in zip(plus, minus, steps)]
    out = {}
    for i in orbit:
        gi, _, _, j = problem.layout[i]
        jac = np.zeros((n_h, 2, n_h, 2))
        for (k, c), per_group in cols.items():
            col = per_group[gi][j]
            jac[:, 0, k, c], jac[:, 1, k, c] = col.real, col.imag
        if np.all(np.isfinite(jac)):
            out[i] = jac ** 2
    return out

