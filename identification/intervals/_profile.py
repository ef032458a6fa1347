"""Profile-likelihood intervals where the linearised covariance is doubtful.

Check. If the cost were quadratic, moving parameter i by t of its standard errors while the
others follow their conditional optimum (the path theta_hat + t C e_i / sigma_i) would
raise 2 x cost by exactly t^2. The cost is evaluated on that path at t = +-1.96; where it
rises by less than 3.84 (1 - `LINEAR_TOL`) or more than 3.84 (1 + `LINEAR_TOL`), the
linearised interval is doubtful on that side. (The path is only the first-order guess of
the conditional optimum: where the valley curves, the path's cost rises faster than the
profile's.) So a doubtful side is checked with the profile itself at t = 1.96 (below), and
only where that too is off by more than `LINEAR_TOL` is the interval's end searched.

Profile. For a doubtful parameter the others are re-optimised with theta_i held (the fit's
own compiled optimistix solve, the held parameter masked: `fit.solve`), and the end of the
95 % interval is where the profile's 2 x cost exceeds the optimum's by 3.84 (chi-square, 1
degree of freedom), found by a secant search in t. The searches of every doubtful side of
every parameter advance together: each round's profile points are one vmapped solve. A profile that
stays below 3.84 out to `MAX_T` standard errors leaves that side open: the parameter is
then not determined.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..fitting import SolveOptions, solve
from ._uncertainty import Z95, Uncertainty

LINEAR_TOL = 0.1
LEVEL = Z95**2  # 3.84
MAX_T = 8.0


def levels(unc: Uncertainty) -> np.ndarray:
    """(p,) rise of 2 x cost that ends each parameter's 95 % interval: 3.84 times the
    variance inflation its standard error carries (the noise scale's s^2 where the
    residuals show model error, and the correlated FRF lines' widening squared), so that a
    quadratic cost gives the linearised interval back."""
    f = np.asarray(unc.noise.get("line_widening", np.ones(len(unc.names))), float)
    return LEVEL * float(unc.noise.get("scaled_by", 1.0)) * f**2


def path_step(unc: Uncertainty, i: int) -> np.ndarray:
    """(p,) the conditional path of parameter i per standard error: theta moves by this
    times t when theta_i moves by t of its standard errors and the others follow their
    conditional optimum (the direction of the fit's own information, not of the widened
    covariance)."""
    f = np.asarray(unc.noise.get("line_widening", np.ones(len(unc.names))), float)
    c0 = unc.covariance / np.outer(f, f)
    return unc.scaled_std[i] * c0[:, i] / c0[i, i]


def held_costs(problem, starts, held_index, held_values):
    """2 x cost with theta_i held at a value and the others re-optimised, for many (start,
    i, value) requests at once: one batched optimistix solve (`fit.solve`) of the fit's own
    compiled program. Returns (optima (n, p), 2 x costs (n,), inf where not finite)."""
    starts = np.array(starts, float, ndmin=2)
    lanes = np.arange(starts.shape[0])
    starts[lanes, held_index] = held_values
    free = np.ones(starts.shape, bool)
    free[lanes, held_index] = False
    out = solve(starts, free, problem.fit_data, problem.structure,
                SolveOptions(step_tol=1e-3))
    cost = 2.0 * out["cost"]
    return out["theta"], np.where(np.isfinite(cost), cost, np.inf)


def linearity_check(result, unc: Uncertainty) -> np.ndarray:
    """(p, 2) rise of 2 x cost at t = -1.96 and +1.96 along each parameter's path, / its
    level (`levels`: 3.84 where nothing widens the interval)."""
    pb = result.problem
    base = 2.0 * result.cost  # the fit's own 2 x cost at the optimum (no re-evaluation)
    out = np.full((pb.n_params, 2), np.nan)
    cov = unc.covariance
    level = levels(unc)
    points, where = [], []
    for i in range(pb.n_params):
        s = np.sqrt(cov[i, i])
        if not (np.isfinite(s) and s > 0 and np.isfinite(unc.scaled_std[i])):
            continue
        for k, t in enumerate((-Z95, Z95)):
            points.append(result.theta + t * path_step(unc, i))
            where.append((i, k))
    if points:
        # The cost at each point: the fit's own compiled solve with nothing free (it stops
        # at its start), so the check compiles nothing of its own.
        at = solve(np.stack(points), False, pb.fit_data, pb.structure)
        two = np.where(np.isfinite(at["cost"]), 2.0 * at["cost"], np.inf)
        for (i, k), c in zip(where, two):
            out[i, k] = (c - base) / level[i]
    return out


def _rises(result, unc, requests):
    """Rise of the profile's 2 x cost over the optimum's at each (i, sign, t): theta_i held
    at theta_hat_i + sign t sigma_i, the others started on the conditional path. One
    batched solve for all requests."""
    if not requests:
        return []
    base = 2.0 * result.cost  # the fit's own 2 x cost at the optimum (no re-evaluation)
    s = unc.scaled_std
    idx = np.asarray([i for i, _, _ in requests])
    starts = np.stack([result.theta + sign * t * path_step(unc, i) for i, sign, t in requests])
    held = np.asarray([result.theta[i] + sign * t * s[i] for i, sign, t in requests])
    _, costs = held_costs(result.problem, starts, idx, held)
    return [c - base for c in costs]


def _end_search(r1, level: float = LEVEL):
    """Generator of the t > 0 where the profile's rise reaches `level` (r1 = rise at 1.96):
    yields the next t to evaluate, is sent its rise, returns t (inf: never, by MAX_T)."""
    t0, r0 = 0.0, 0.0
    t1 = Z95
    for _ in range(12):
        if abs(r1 - level) < 1e-3 * level:
            return t1
        if r1 < level:  # not there yet: extrapolate outwards (rise ~ t^2)
            t_new = t1 * np.sqrt(level / max(r1, 1e-12)) if r1 > 0 else 2 * t1
            t_new = min(t_new, 2.0 * t1)
            if t1 >= MAX_T:
                return np.inf
            t0, r0, t1 = t1, r1, min(t_new, MAX_T)
        else:  # bracketed between t0 and t1: secant on sqrt(rise)
            a, b = np.sqrt(max(r0, 0.0)), np.sqrt(r1)
            t_new = t0 + (t1 - t0) * (np.sqrt(level) - a) / max(b - a, 1e-12)
            t_new = min(max(t_new, t0 + 0.05 * (t1 - t0)), t1 - 0.05 * (t1 - t0))
            r_new = yield t_new
            if r_new < level:
                t0, r0 = t_new, r_new
                continue
            t1, r1 = t_new, r_new
            continue
        r1 = yield t1
    return t1


def _profile_ends(result, unc, first, level):
    """{(i, k): t_end} for every side in `first` ({(i, k): rise at 1.96}); the searches of
    all sides advance together, each round one batched solve."""
    ends, live = {}, {}
    for key, r1 in first.items():
        gen = _end_search(r1, level[key[0]])
        try:
            live[key] = (gen, next(gen))
        except StopIteration as stop:
            ends[key] = stop.value
    while live:
        keys = list(live)
        rises = _rises(result, unc, [(i, (-1.0, 1.0)[k], live[(i, k)][1]) for i, k in keys])
        for key, rise in zip(keys, rises):
            gen = live[key][0]
            try:
                live[key] = (gen, gen.send(rise))
            except StopIteration as stop:
                ends[key] = stop.value
                del live[key]
    return ends


def profile_intervals(result, unc: Uncertainty, *, force: bool = False) -> tuple:
    """(updated `Uncertainty`, table (p, 2) of the profile's rise at -+1.96 sigma / 3.84).

    Sides whose conditional-path rise is within `LINEAR_TOL` of 3.84 keep the linearised
    end (table: the path's rise); the others get the held profile at 1.96 sigma, and where
    that is off by more than `LINEAR_TOL` too, the profile end replaces the linearised one.
    `force`: profile every side.
    """
    pb = result.problem
    table = linearity_check(result, unc)
    finite = np.isfinite(unc.scaled_std)
    if not unc.noise["estimable"]:
        return unc, table
    ci = unc.ci95.copy()
    method = list(unc.ci_method)
    determined = unc.determined.copy()
    log = pb.is_log
    sides = [(i, k) for i in np.nonzero(finite)[0] for k in (0, 1)
             if force or abs(table[i, k] - 1.0) > LINEAR_TOL]
    level = levels(unc)
    rises = _rises(result, unc, [(i, (-1.0, 1.0)[k], Z95) for i, k in sides])
    first = {}
    for (i, k), r1 in zip(sides, rises):
        table[i, k] = r1 / level[i]
        if force or abs(table[i, k] - 1.0) > LINEAR_TOL:
            first[(i, k)] = r1
    for (i, k), t in sorted(_profile_ends(result, unc, first, level).items()):
        sign = (-1.0, 1.0)[k]
        method[i] = "profile"
        if not np.isfinite(t):
            ci[i, k] = 0.0 if log[i] and sign < 0 else sign * np.inf
            determined[i] = False
            continue
        th = result.theta[i] + sign * t * unc.scaled_std[i]
        ci[i, k] = (pb.prior_values[i] * np.exp(th) if log[i] else pb.prior_values[i] + th)
    return dataclasses.replace(unc, ci95=ci, ci_method=method, determined=determined), table
