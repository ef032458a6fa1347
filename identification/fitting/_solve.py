"""The fit's least-squares solve: optimistix, one compiled program for every lane.

`solve(theta0, free, data, structure)` minimises 0.5 |r(theta)|^2 for a batch of lanes, each
with its own start, free/held mask and data (`FitData`, see `measurement._groups`), as one vmapped
`optimistix.least_squares` inside one `jit`. Everything that varies between starts,
held-parameter variants (the profile likelihood), model-choice iterations and replicates is
a traced array of a fixed layout, and lanes run in batches of `LANE_CLASSES` (4: a single
start is padded to 4 lanes that hold every parameter and stop at once, more are cut into
calls of 4). So a layout compiles once. On a CPU the lanes of a batch run one after the
other inside the program (`lax.map`); vmapped lanes run in lockstep, and one slow start (124
steps against 8-21 for the others on the preload-loss set) made the whole batch cost 4 x
124 steps.

Held parameters enter as theta = where(free, z, theta0), and rows z - theta0 (zero at the
start, and they stay so) pin them: the Jacobian keeps full column rank for every descent.

The solver is optimistix's dogleg (`DoglegDescent` and `ClassicalTrustRegion`, as
`optimistix.Dogleg`) whose Gauss-Newton point comes from a truncated SVD: singular
directions below the information floor (`FitData.info_floor`, a maximum-likelihood fit's
directions without information) are left out. The alternatives (`SolveOptions.method`)
were measured on the paper test: `benchmarks/bench_fit_solver.py`. It stops on the
project's own convergence test rather than on small changes of y and f
(which the ODE solver's noise may never give): the remaining Gauss-Newton step, in units of
its own standard error, below `step_tol` in every informative direction (`_fit.py`
explains the test). Its Cauchy test (rtol, atol on theta and the residual) is kept as a
second way out; the fit's evidence is computed again at the returned point in any case.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

import bsfs_jax

from ..measurement import Structure, residual_with_jacobian
from ._lm import NULL_RTOL

LANE_CLASSES = (4,)
# Longest dogleg step in scaled parameters (an e^2 factor on a log-parameter). Measured on 6
# replicates of the preload-loss set x 8 starts: 1491 steps in all and one start stuck at the
# step limit without a cap, 1186 steps and none stuck with it (1: 1443 and one stuck).
MAX_STEP = 2.0


def gn_step(r, j, floor):
    """Largest |(U^T r)_k| over informative singular directions of J: the traced twin of
    `_lm.gn_step_sigma`, for the solver's own stopping test."""
    u, s, _ = jnp.linalg.svd(j, full_matrices=False)
    keep = s > jnp.maximum(s[0] * NULL_RTOL, floor)
    proj = jnp.abs(u.T @ r)
    return jnp.where(jnp.any(keep) & jnp.all(jnp.isfinite(r)),
                     jnp.max(jnp.where(keep, proj, 0.0)), jnp.inf)


class StepTestGaussNewton(optx.AbstractGaussNewton):
    """A Gauss-Newton-family solver (descent and search as given) that also stops once the
    remaining Gauss-Newton step is below `step_tol` standard errors."""

    rtol: float
    atol: float
    norm: Callable
    descent: optx.AbstractDescent
    search: optx.AbstractSearch
    verbose: Callable
    step_tol: float

    def terminate(self, fn, y, args, options, state, tags):
        cauchy, result = super().terminate(fn, y, args, options, state, tags)
        j = jnp.where(args[1][None, :], state.f_info.jac.as_matrix(), 0.0)  # no pinning rows
        step = gn_step(state.f_info.residual, j, args[2].info_floor)
        done = (~state.first_step) & (step < self.step_tol)
        return cauchy | done, result


class TruncatedDoglegDescent(optx.DoglegDescent):
    """optimistix's dogleg descent whose Gauss-Newton point leaves out the singular
    directions of the current Jacobian below `floor` (lineax's SVD with rcond = floor / the
    largest singular value; at least round-off), and whose steps are at most `max_step`
    long."""

    floor: jax.Array = 0.0
    max_step: float = 2.0  # longest step (scaled parameters: log-values, offsets in um)

    def query(self, y, f_info, state):
        # The reduced SVD, not compute_uv=False: on jaxlib's CPU backend (0.10) the latter
        # reserves an m x m workspace for an m x n matrix (34 GB for a 65 536-row residual).
        s0 = jnp.linalg.svd(f_info.jac.as_matrix(), full_matrices=False)[1][0]
        rcond = jnp.clip(self.floor / jnp.maximum(s0, 1e-300), 1e-13, 0.5)
        inner = optx.DoglegDescent(linear_solver=lx.SVD(rcond=rcond),
                                   root_finder=self.root_finder,
                                   trust_region_norm=self.trust_region_norm)
        return inner.query(y, f_info, state)

    def step(self, step_size, state):
        # optimistix's trust region is relative (1 = the full Gauss-Newton step); far from
        # the optimum that step can be e^6 in a damping, from where the dogleg crawled back
        # along the valley for 100+ steps. An absolute cap keeps each step local.
        y, result = super().step(step_size, state)
        n = jnp.sqrt(jnp.sum(y**2))
        return y * jnp.minimum(1.0, self.max_step / jnp.maximum(n, 1e-300)), result


def _quiet(**kwargs):
    return None


def make_solver(method: str, step_tol, floor=0.0) -> StepTestGaussNewton:
    """The descent and search of optimistix's solvers, with the step test. `floor`: the
    dogleg's Gauss-Newton point leaves out singular directions below it."""
    if method == "lm":  # optx.LevenbergMarquardt
        descent, search = optx.DampedNewtonDescent(), optx.ClassicalTrustRegion()
    elif method == "indirect-lm":  # optx.IndirectLevenbergMarquardt (Moré's lambda search)
        descent, search = optx.IndirectDampedNewtonDescent(), optx.ClassicalTrustRegion()
    elif method == "dogleg":  # optx.Dogleg
        descent = TruncatedDoglegDescent(floor=floor, max_step=MAX_STEP)
        search = optx.ClassicalTrustRegion()
    elif method == "gauss-newton":  # optx.GaussNewton with a backtracking line search
        descent, search = optx.NewtonDescent(), optx.BacktrackingArmijo()
    else:
        raise ValueError(f"unknown method '{method}' (lm, indirect-lm, dogleg, gauss-newton)")
    return StepTestGaussNewton(rtol=1e-12, atol=1e-12, norm=optx.max_norm, descent=descent,
                               search=search, verbose=_quiet, step_tol=step_tol)


@dataclasses.dataclass(frozen=True)
class SolveOptions:
    """`method` and `max_steps` are static (part of the program); `step_tol` is traced."""

    method: str = "dogleg"
    max_steps: int = 200
    step_tol: float = 1e-3
    # "map": lanes one after the other (CPU: the batch costs the sum of the lanes' steps);
    # "vmap": in lockstep (accelerators: the slowest lane's steps, all lanes in parallel).
    lanes: str = dataclasses.field(
        default_factory=lambda: "map" if jax.default_backend() == "cpu" else "vmap")


def _solve_lane(theta0, free, data, step_tol, structure, options):
    def fn(z, args):
        theta0, free, data = args
        theta = jnp.where(free, z, theta0)
        pin = jnp.where(free, 0.0, z - theta0)  # held parameters (module docstring)
        return jnp.concatenate([residual_with_jacobian(theta, data, structure), pin]), None

    solver = make_solver(options.method, step_tol, data.info_floor)
    sol = optx.least_squares(fn, solver, theta0, args=(theta0, free, data), has_aux=True,
                             max_steps=options.max_steps, throw=False, options=dict(jac="fwd"))
    theta = jnp.where(free, sol.value, theta0)
    f_info = sol.state.f_info
    n = f_info.residual.shape[0] - theta0.shape[0]  # without the pinning rows
    r = f_info.residual[:n]
    j = jnp.where(free[None, :], f_info.jac.as_matrix()[:n], 0.0)
    codes = jnp.stack([sol.result == optx.RESULTS.successful,
                       sol.result == optx.RESULTS.nonlinear_max_steps_reached])
    return dict(theta=theta, residual=r, jacobian=j, cost=0.5 * jnp.sum(r**2),
                steps=sol.stats["num_steps"], codes=codes)


@bsfs_jax.cached_jit(fast_compile=True)
def _solve_lanes(theta0, free, data, step_tol, structure, options):
    lane = lambda t, f, d: _solve_lane(t, f, d, step_tol, structure, options)
    if options.lanes == "vmap":
        return jax.vmap(lane)(theta0, free, data)
    # One lane after the other inside the program: each lane's loop stops at its own step
    # count (vmapped lanes run in lockstep until the slowest one stops).
    return jax.lax.map(lambda a: lane(*a), (theta0, free, data))


def lane_class(n: int) -> int:
    for c in LANE_CLASSES:
        if n <= c:
            return c
    return LANE_CLASSES[-1]


def _stack(items):
    # numpy on the host: no small compiled programs per leaf shape
    return jax.tree_util.tree_map(lambda *xs: np.stack(xs), *items)


def solve(theta0, free, data, structure: Structure, options: SolveOptions | None = None):
    """Solve lanes: `theta0` (n, p), `free` (n, p) bool, `data` one `FitData` for every lane
    or a list of n (same layout). Returns a dict of numpy arrays with a leading axis n:
    theta, residual, jacobian, cost, steps, and `stop` (list of n texts)."""
    options = SolveOptions() if options is None else options
    theta0 = np.atleast_2d(np.asarray(theta0, float))
    n = theta0.shape[0]
    free = np.broadcast_to(np.asarray(free, bool), theta0.shape)
    datas = list(data) if isinstance(data, list | tuple) else [data] * n
    if len(datas) != n:
        raise ValueError(f"{len(datas)} data sets for {n} lanes")
    out = []
    size = lane_class(n)
    for lo in range(0, n, size):
        idx = list(range(lo, min(lo + size, n)))
        pad = idx + [idx[0]] * (size - len(idx))
        lane_free = free[pad].copy()
        lane_free[len(idx):] = False  # padding lanes hold everything: they stop at once
        res = _solve_lanes(jnp.asarray(theta0[pad]), jnp.asarray(lane_free),
                           _stack([datas[i] for i in pad]), jnp.asarray(options.step_tol),
                           structure, dataclasses.replace(options, step_tol=None))
        res = jax.tree_util.tree_map(np.asarray, res)
        out.append(jax.tree_util.tree_map(lambda x: x[:len(idx)], res))
    res = {k: np.concatenate([o[k] for o in out]) for k in out[0]}
    res["stop"] = [("stopped (remaining Gauss-Newton step or Cauchy test)" if ok else
                    f"optimistix stopped at its step limit ({options.max_steps} steps)"
                    if at_max else "optimistix reported a failed solve")
                   for ok, at_max in res.pop("codes")]
    return res
