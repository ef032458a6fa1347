"""A whole atlas as one sweep: the rows' problems stacked into one problem over grid points.

Row by row, an atlas of Ny rows is Ny sweeps, each waiting for its own slowest point (on a
GPU, the kernel engine's time is the slowest point's loop whatever the number of points).
Stacked, the grid is one sweep of Ny x Nx points: one batch, sharded over the devices like
any sweep, verified point by point by the same verifier. Point k of the grid is row
j = k // Nx at x[k % Nx]; its setup is the row problem's own setup on row j's data.
"""

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._sweep_problem import SweepProblem


class GridSetup(eqx.Module):
    """setup(data, k) of grid point k: the row setup on row k // nx's data at x[k % nx]."""

    row_setup: Callable = eqx.field(static=True)
    row_static: Any = eqx.field(static=True)
    nx: int = eqx.field(static=True)

    def __call__(self, data, value):
        rows, x = data
        k = jnp.round(value).astype(jnp.int32)
        j, i = k // self.nx, k % self.nx
        row = eqx.combine(jax.tree_util.tree_map(lambda a: a[j], rows), self.row_static)
        return self.row_setup(row, x[i])


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except Exception:  # noqa: BLE001 - an incomparable static part is a different one
        return False


def grid_problem(problems, x) -> SweepProblem | None:
    """One `SweepProblem` over the grid points of `problems` (one per row) x `x`, or None
    where the rows differ in more than their arrays (then the atlas runs row by row)."""
    p0 = problems[0]
    dyn0, static0 = eqx.partition(p0.data, eqx.is_array)
    tree0 = jax.tree_util.tree_structure(dyn0)
    dyns = []
    for p in problems:
        dyn, static = eqx.partition(p.data, eqx.is_array)
        if (p.vector_field is not p0.vector_field or not _same(p.setup, p0.setup)
                or jax.tree_util.tree_structure(dyn) != tree0 or not _same(static, static0)
                or not np.array_equal(np.asarray(p.y0), np.asarray(p0.y0))
                or p.component_field is not p0.component_field):
            return None
        dyns.append(dyn)
    if any(jnp.shape(a) != jnp.shape(b) for d in dyns[1:]
           for a, b in zip(jax.tree_util.tree_leaves(d), jax.tree_util.tree_leaves(dyn0))):
        return None
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *dyns)
    x = jnp.asarray(x, dtype=float)
    return SweepProblem(p0.vector_field, GridSetup(p0.setup, static0, int(x.shape[0])),
                        (stacked, x), p0.y0, "grid point", "", p0.observe, p0.state_names,
                        p0.state_units, p0.time_unit, component_field=p0.component_field)
