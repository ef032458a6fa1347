"""The fit's model and residual as pure functions of (theta, `FitData`, `Structure`).

Nothing here closes over a problem object: the data are traced arguments and the structure
is the only static one, so the compiled programs (`residual_and_jacobian`, `predictions`
and the solve in `_solve.py`) are cached per structure and array shapes, not per problem.

Per speed group the sine records' model is the linearised FRF, plus the first-order
harmonic-balance correction where `sine_first`, replaced by the periodic orbit (harmonic balance)
where `sine_orbit` (computed only for the `orbit_index` slots); FRF lines use the
linearised accelerance.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

import bsfs_jax

from ._groups import FitData, Structure
from ._linear import drift_terms, linear_acceleration, linearisation_error, receptance
from ._orbit_model import ORBIT_HARMONICS, nonlinear_acceleration

# A trial point whose model is not finite (a joint without preload) costs this per entry.
BAD_RESIDUAL = 1e6


def values(theta, data: FitData, structure: Structure):
    """File-unit values: prior * exp(theta) (log-parameters) or prior + theta [um]."""
    log = jnp.asarray(structure.log, bool)
    v0 = data.prior_values
    return jnp.where(log, v0 * jnp.exp(jnp.where(log, theta, 0.0)), v0 + theta)


def params_at(theta, data: FitData, structure: Structure, group: int):
    """Full `BallScrewParams` of speed group `group` (a Python int) at theta."""
    v = values(theta, data, structure)
    p = data.base.replace("thermal.speed_rpm", data.speeds[group])
    for i, (key, g) in enumerate(zip(structure.keys, structure.groups)):
        if g < 0 or g == group:
            p = p.replace(key, v[i])
    return p


def _sine_model(system, g, first_order: bool, sweeps: bool = False, orbits: bool = True,
                orbits_on=True, harmonics: int = ORBIT_HARMONICS):
    lin = linear_acceleration(system, g.sine_freq, g.sine_force)
    if first_order:
        corr = jax.vmap(linearisation_error, in_axes=(None, 0, 0))(
            system, g.sine_freq[:, 0], g.sine_force)
        lin = lin + jnp.where(g.sine_first[:, None], corr, 0.0)
    if not (orbits and g.orbit_index.shape[0]):
        return lin
    idx = g.orbit_index

    def solve_orbits():
        if sweeps:  # swept records start from their anchors (`_anchors.py`)
            fn = lambda f, fc, am, z: nonlinear_acceleration(system, f, fc, am, harmonics,
                                                             start=z)
            return jax.vmap(fn)(g.sine_freq[idx, 0], g.sine_force[idx], g.sine_acc[idx],
                                g.sine_anchor[idx])
        fn = lambda f, fc, am: nonlinear_acceleration(system, f, fc, am, harmonics)
        return jax.vmap(fn)(g.sine_freq[idx, 0], g.sine_force[idx], g.sine_acc[idx])

    def skip():  # a first stage: the orbit records' rows carry no data
        return lin[idx], jnp.ones(idx.shape, bool)

    # A branch, not a select, where the flag is not batched (the lanes of a CPU solve
    # run one after the other): a first stage costs what a program without orbits does.
    nl, ok = jax.lax.cond(orbits_on, solve_orbits, skip)
    nl = jnp.where(ok[:, None], nl, jnp.inf)
    # Padded slots repeat a real slot (the same value twice) or point at a record that is
    # not on the orbit model (masked below).
    full = jnp.zeros_like(lin).at[idx].set(nl)
    return jnp.where(g.sine_orbit[:, None], full, lin)


def predict(theta, data: FitData, structure: Structure, orbits: bool = True):
    """Model per group: [(sine harmonics (R, H), FRF accelerance (L,), the sine harmonics'
    drifting-force terms (R, H))] (complex; the first includes the third, `drift_terms`).
    `orbits=False`: the periodic-orbit records get their linearised model instead (a
    caller that has their orbits already, `Problem.model_harmonics`, which adds the
    drift terms to them)."""
    out = []
    for gi, g in enumerate(data.groups):
        system = bsfs_jax.build_system(params_at(theta, data, structure, gi))
        if g.sine_freq.shape[0]:
            terms = drift_terms(system, g.sine_freq, g.sine_rate, g.sine_rate2)
            sine = _sine_model(system, g, structure.first_order, structure.sweeps, orbits,
                               data.orbits_on, structure.orbit_harmonics) + terms
        else:
            sine = terms = jnp.zeros(g.sine_freq.shape, complex)
        frf = (linear_acceleration(system, g.frf_freq, jnp.ones(g.frf_freq.shape, complex))
               if g.frf_freq.shape[0] else jnp.zeros(0, complex))
        out.append((sine, frf, terms))
    return out


def residual(theta, data: FitData, structure: Structure):
    """Noise-weighted data residual (about N(0, 1) at the truth), then the prior's entries
    (theta - shift) / sigma (zero where a parameter has no prior; the shift is zero but in a
    randomised-maximum-likelihood refit)."""
    parts = []
    for (sine, frf, _), g in zip(predict(theta, data, structure), data.groups):
        for model, meas, scale in ((sine, g.sine_acc, g.sine_scale),
                                   (frf, g.frf_acc, g.frf_scale)):
            d = meas - model
            d = jnp.where(jnp.isfinite(d), d, BAD_RESIDUAL)
            parts.append((jnp.real(d) / scale[..., 0]).reshape(-1))
            parts.append((jnp.imag(d) / scale[..., 1]).reshape(-1))
    parts.append((theta - data.prior_shift) * data.inv_sigma)
    return jnp.concatenate(parts)


def traced_residual_and_jacobian(theta, data, structure):
    """(`residual` (m,), its forward-mode Jacobian (m, p), non-finite entries zeroed), traced:
    for callers that batch or compile it themselves (`residual_and_jacobian` is compiled)."""
    both = lambda th: (residual(th, data, structure),) * 2
    j, r = jax.jacfwd(both, has_aux=True)(theta)
    return r, jnp.where(jnp.isfinite(j), j, 0.0)


@functools.partial(jax.custom_jvp, nondiff_argnums=(2,))
def residual_with_jacobian(theta, data, structure):
    """`residual` whose derivative is the forward-mode Jacobian computed once (one pass with
    p tangents) and applied as a matrix: under `jax.linearize` (optimistix's `jac="fwd"`)
    the model, with its periodic orbits, then runs once per step, not once per column."""
    return residual(theta, data, structure)


@residual_with_jacobian.defjvp
def _residual_jvp(structure, primals, tangents):
    theta, data = primals
    r, j = traced_residual_and_jacobian(theta, data, structure)
    return r, j @ tangents[0]  # the data are never differentiated


@bsfs_jax.cached_jit
def residual_and_jacobian(theta, data: FitData, structure: Structure):
    """(residual, Jacobian): one compiled program per structure and layout."""
    return traced_residual_and_jacobian(theta, data, structure)


@bsfs_jax.cached_jit
def predictions(theta, data: FitData, structure: Structure, orbits: bool = True):
    """`predict`, compiled: one program per structure and layout."""
    return predict(theta, data, structure, orbits)


def static_compliance(theta, data: FitData, structure: Structure, group: int):
    """Static compliance at the nut x_n / P [m/N] of speed group `group`."""
    system = bsfs_jax.build_system(params_at(theta, data, structure, group))
    return jnp.real(receptance(system, jnp.zeros(1))[0, 2])


@bsfs_jax.cached_jit
def compliance_and_gradient(theta, data: FitData, structure: Structure):
    """(compliance (G,), its gradient (G, p)) at every speed group. Forward mode: the
    program is half the size of reverse mode's (0.5 s to compile instead of 1.1 s)."""
    def both(th):
        c = jnp.stack([static_compliance(th, data, structure, g)
                       for g in range(structure.n_groups)])
        return c, c

    grads, values = jax.jacfwd(both, has_aux=True)(theta)
    return values, grads
