"""Where a swept record's periodic orbit starts in the fit: its anchor.

A record whose header gives a stepped sine's direction (`sweep = up` or `down`) is fitted on
the orbit that sweep reaches (`_orbit_model.swept_unknowns`: natural continuation in
frequency up to the record's, jumping where a branch ends at a fold, as the test itself
does). Until this module that continuation ran at every trial parameter set, inside the
residual: on a worn drive with the default fit set one residual and Jacobian then cost
0.555 s against 0.035 s without it, and one fit ran for more than 25 minutes.

Now the sweep is computed once per lane and round (`anchored`: the `sine_anchor` rows of
`FitData`, traced, so each lane of one compiled solve carries its own), and inside the
solve the record's orbit is Newton's from that anchor (`nonlinear_acceleration(start=)`):
the branch the sweep reached, followed as the parameters move, with the orbit's implicit
derivative as before. A step that leaves the branch (past its fold) has no orbit there:
its residual is not finite and the trust region rejects it.

After a solve the sweep is computed again at each lane's result (`settle`). Where the model
from the old anchor and the one from the new anchor agree (to `SAME_ORBIT_STD` standard
errors of every used harmonic), the lane's fit is on the orbit its sweep reaches at its
own result, as the old model demanded at every trial point. Where they differ, the lane
is solved again from its result with the new anchor, up to `MAX_ROUNDS` times; a lane
still unsettled after that is reported, and where it is the best one the fit is not
converged (`_fit._fit_from`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import bsfs_jax

from ._groups import FitData, Structure
from ._model import params_at, predictions
from ._orbit_model import swept_unknowns

MAX_ROUNDS = 3  # re-solves of a lane whose sweep reaches another orbit at its result
SAME_ORBIT_STD = 1e-3  # two models of a record agree within this many standard errors


@bsfs_jax.cached_jit
def _anchor_kernel(theta, data: FitData, structure: Structure):
    """Per group, (R, U): the HB unknowns of the orbit each swept record's sweep reaches at
    theta (zero for the other rows)."""
    out = []
    for gi, g in enumerate(data.groups):
        if not (g.sine_anchor.shape[1] and g.sweep_index.shape[0]):
            out.append(jnp.zeros_like(g.sine_anchor))
            continue
        system = bsfs_jax.build_system(params_at(theta, data, structure, gi))
        idx = g.sweep_index  # only the swept records: vmapped continuations run in lockstep
        z = jax.vmap(lambda f, fc, d: swept_unknowns(system, f, fc,
                                                     jnp.where(d < 0, -1.0, 1.0),
                                                     structure.orbit_harmonics))(
            g.sine_freq[idx, 0], g.sine_force[idx], g.sine_sweep[idx])
        out.append(jnp.zeros_like(g.sine_anchor).at[idx].set(z))
    return tuple(out)


def anchored(data: FitData, theta, structure: Structure) -> FitData:
    """`data` with every swept record's anchor computed at theta (unchanged where no record
    is swept)."""
    if not structure.sweeps:
        return data
    anchors = _anchor_kernel(jnp.asarray(theta, float), data, structure)
    groups = tuple(eqx.tree_at(lambda g: g.sine_anchor, g, np.asarray(a))
                   for g, a in zip(data.groups, anchors))
    return eqx.tree_at(lambda d: d.groups, data, groups)


def same_orbits(theta, a: FitData, b: FitData, structure: Structure) -> bool:
    """Whether the swept records' model at theta is the same from the anchors of `a` and
    of `b` (finite, and within `SAME_ORBIT_STD` standard errors of every used harmonic)."""
    th = jnp.asarray(theta, float)
    pa, pb = predictions(th, a, structure), predictions(th, b, structure)
    for (sa, *_), (sb, *_), g in zip(pa, pb, a.groups):
        swept = np.asarray(g.sine_orbit) & (np.asarray(g.sine_sweep) != 0)
        if not swept.any():
            continue
        x, y = np.asarray(sa)[swept], np.asarray(sb)[swept]
        scale = np.asarray(g.sine_scale)[swept]
        used = np.isfinite(scale)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            return False
        d = np.stack([(x - y).real, (x - y).imag], axis=-1)
        if np.any(np.abs(np.where(used, d / np.where(used, scale, 1.0), 0.0))
                  > SAME_ORBIT_STD):
            return False
    return True


def settle(out: dict, datas: list, structure: Structure, resolve) -> list:
    """Re-anchor each lane of a finished solve (`out`, `_solve.solve`'s dict; `datas`: the
    lanes' `FitData`, replaced in place) at its result, and solve again (`resolve(thetas,
    datas)` -> such a dict) the lanes whose sweep reaches another orbit there, up to
    `MAX_ROUNDS` times. Updates `out` in place (steps add up). Returns, per lane, whether
    its fitted orbit is the one its sweep reaches at its result (True for failed lanes:
    their cost is not finite and they cannot win)."""
    n = len(datas)
    settled = [not np.isfinite(out["cost"][k]) for k in range(n)]
    for round_ in range(MAX_ROUNDS + 1):
        todo = []
        for k in range(n):
            if settled[k]:
                continue
            new = anchored(datas[k], out["theta"][k], structure)
            if same_orbits(out["theta"][k], datas[k], new, structure):
                settled[k] = True
            elif round_ < MAX_ROUNDS:  # the last round only checks
                datas[k] = new
                todo.append(k)
        if not todo or round_ == MAX_ROUNDS:
            break
        again = resolve(np.stack([out["theta"][k] for k in todo]), [datas[k] for k in todo])
        for j, k in enumerate(todo):
            for key, value in again.items():
                if key == "steps":
                    out[key][k] = out[key][k] + value[j]
                else:
                    out[key][k] = value[j]
            settled[k] = not np.isfinite(out["cost"][k])
    return settled
