"""Jumps of a continued sweep located at their folds by the orbit engine's continuation.

A sweep sees a jump only as a large change between two grid points. The branch it leaves
ends at a fold (a saddle-node of periodic orbits) somewhere in between; continuing that
branch with shooting from the orbit before the jump finds the fold to the corrector's
tolerance (regula falsi on the fold's test function, `solvers.continue_orbits`).
"""

import equinox as eqx
import numpy as np

from ..solvers import Shooting, SolverError, continue_orbits


class ProblemFamily(eqx.Module):
    """p -> (args, period) of a `SweepProblem`: the sweep's parameter as a family for the
    continuation (its data are traced, so each new problem value does not recompile)."""

    problem: object

    @property
    def vector_field(self):
        return self.problem.vector_field

    def __call__(self, p):
        return self.problem.setup(self.problem.data, p)


def locate_fold(problem, y_before, value_before, value_after, *, method=None, ds=0.05,
                max_points: int = 120):
    """The fold bounding the branch through `y_before` (the state at phase 0 at
    `value_before`) between `value_before` and `value_after`.

    Returns a dict {"value", "amplitude", "located"} for the first fold found in the
    interval, or None (no orbit from `y_before`, or no fold in the interval).
    """
    try:
        branch = continue_orbits(ProblemFamily(problem), np.asarray(y_before, dtype=float),
                                 float(value_before), float(value_after),
                                 method=method or Shooting(), ds=ds, max_points=max_points,
                                 amplitude_index=problem.observe)
    except (SolverError, ValueError):
        return None
    lo, hi = sorted((float(value_before), float(value_after)))
    for b in branch.bifurcations:
        if b.kind == "fold" and lo <= b.p <= hi:
            return {"value": float(b.p), "amplitude": float(b.amplitude),
                    "located": bool(b.located)}
    return None


def locate_jump_folds(problem, result, jumps, **kwargs):
    """Attach the located fold to each jump of `result` (a continued `SweepResult`):
    sets `fold_value`, `fold_amplitude` and `fold_located` (None where none is found)."""
    for j in jumps:
        d = result.direction_index(j.direction)
        y = result.end_state[d, j.index_before]
        fold = None
        if np.all(np.isfinite(y)):
            fold = locate_fold(problem, y, j.value_before, j.value_after, **kwargs)
        j.fold_value = None if fold is None else fold["value"]
        j.fold_amplitude = None if fold is None else fold["amplitude"]
        j.fold_located = None if fold is None else fold["located"]
    return jumps
