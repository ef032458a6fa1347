"""The forecast's modal quantities (`natural_frequency_1_hz`, `damping_ratio_1`,
`static_stiffness_n_per_um`): exact gradients and Hessians in one program, and the model
itself at the identification's draws where the delta method is doubtful."""

from __future__ import annotations

import functools

import numpy as np

import bsfs_jax

from ._batches import draw_batches
from ._intervals import Identified, from_hessian, value_jac_hess


def _modal_values(coords, theta):
    """[f1, zeta1, static stiffness] of the model at theta (traceable)."""
    import jax.numpy as jnp

    m = bsfs_jax.modes(bsfs_jax.build_system(coords.at(theta)))
    return jnp.stack([m.frequencies_hz[0], m.damping_ratios[0], m.static_stiffness])


@bsfs_jax.cached_jit
def _modal_program(coords, theta):
    """(value, Jacobian, Hessian) of `_modal_values`."""
    return value_jac_hess(functools.partial(_modal_values, coords), theta)


@bsfs_jax.cached_jit
def _modal_at_draws(coords, thetas):
    """(n, 3): `_modal_values` at each row of `thetas`."""
    import jax

    return jax.vmap(functools.partial(_modal_values, coords))(thetas)


def _modal_draws(ident: Identified) -> np.ndarray:
    """`_modal_at_draws` at the identification's draws, in batches of `DRAW_BATCH` (the
    last padded with the estimate): one program for any count of refits or draws."""
    import jax.numpy as jnp

    return np.concatenate([np.asarray(_modal_at_draws(ident.coordinates,
                                                      jnp.asarray(thetas, float)))
                           for thetas in draw_batches(ident)])[:len(ident.draws)]


def _modal(ident: Identified):
    """natural_frequency_1_hz, damping_ratio_1, static_stiffness_n_per_um: exact gradients
    and Hessians (`from_hessian`); where the second-order check finds the delta method
    doubtful and the identification saved draws (refits or posterior), the model itself
    at each draw, in one vmapped batch (`_modal_at_draws`)."""
    import jax.numpy as jnp

    value, jac, hess = (np.asarray(a) for a in _modal_program(
        ident.coordinates, jnp.asarray(ident.theta, float)))
    at_draws = functools.cache(lambda: _modal_draws(ident))
    out = []
    for k, (name, unit, scale) in enumerate((("natural_frequency_1_hz", "Hz", 1.0),
                                             ("damping_ratio_1", "-", 1.0),
                                             ("static_stiffness_n_per_um", "N/um", 1e-6))):
        exact = None if ident.draws is None else (lambda k=k: at_draws()[:, k])
        out.append(from_hessian(name, unit, value[k], jac[k], hess[k], ident,
                                scale=scale, exact=exact))
    return out, float(value[0])
