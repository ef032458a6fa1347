"""Multi-start fit of a `Problem` (optimistix), with its own convergence evidence.

The optimiser (optimistix's dogleg, every start one lane of one compiled, vmapped solve:
`_solve.py`) stops on the remaining-step test below or on its own
tolerances; either way the test is made again at the returned point, and only that is taken
as convergence.
At the optimum the Gauss-Newton step that would remain is computed from the residual and
Jacobian: in the SVD J = U S V^T, the step's component along v_k is (U^T r)_k / s_k and
its standard error is 1 / s_k, so |(U^T r)_k| is the remaining step in units of its own
standard error. The fit is called converged when that is below `STEP_TOL` (1 %) in every
direction the data or prior determine and the starts that reached the lowest cost agree.
Without priors, directions with no usable information (standard error above
`_lm.NO_INFORMATION_STD`) have no meaningful step; they are left out of the test and their
parameters are reported as not determined by the uncertainty analysis.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

from ..measurement import MAX_ANCHOR_ROUNDS, anchored, masked_orbit_records, settle
from ._lm import NO_INFORMATION_STD, gn_step_sigma
from ._misfit import record_chi_squares
from ._modal import modal_estimate, modal_starts
from ._problem import Problem
from ._solve import SolveOptions, solve

STEP_TOL = 0.01  # remaining Gauss-Newton step / its standard error
SAME_COST_RTOL = 1e-6
MAX_REFITS = 3  # repeated fits after the model choice changed at the estimate


@dataclasses.dataclass
class FitResult:
    problem: Problem
    theta: np.ndarray
    values: np.ndarray
    cost: float  # 0.5 |r|^2 including the prior's entries
    residual: np.ndarray  # full residual (data rows, then prior rows)
    jacobian: np.ndarray
    starts: list  # dicts: start, cost, steps, optimizer_converged, same_minimum
    converged: bool  # remaining step < STEP_TOL and the starts agree
    optimizer_converged: bool
    remaining_step: float  # largest remaining GN step in units of its standard error
    steps: int
    seconds: float
    # How the models per record (and left-out chirp lines) were decided: "prior" (fixed by
    # the caller), "confirmed" (the choice at the estimate is the one fitted), "refitted"
    # (it differed; the fit was repeated with the choice at the estimate, then confirmed),
    # "unsettled" (it still changed after MAX_REFITS repeats: the fit is then not converged).
    model_choice: str = "prior"
    # A staged fit's first stage (`staged_starts`): what it fitted, its starts, how many
    # reached its best cost; None where the fit was not staged.
    stage1: dict | None = None
    # Why the model itself cannot be trusted at the estimate (a record without a model
    # orbit, a truncation error beyond `TRUNCATION_GATE`): each makes the fit not converged.
    model_issues: list = dataclasses.field(default_factory=list)
    model_issue_kinds: list = dataclasses.field(default_factory=list)  # one per issue
    # Model values per record at the estimate (`Problem.model_harmonics`), set by `fit`.
    model: list | None = None

    def add_model_issue(self, text: str, kind: str = "model") -> None:
        """Mark the fit not converged because of the model at the estimate; `kind` names
        the cause for programs ("no_steady_state", "truncation", "swept_orbit",
        "record_misfit")."""
        self.model_issues.append(text)
        self.model_issue_kinds.append(kind)
        self.converged = False

    @property
    def starts_agreeing(self) -> int:
        """Starts that reached the lowest cost, counted in quasi-random starts (a staged
        fit's full-fit start stands for the first-stage starts of its basin)."""
        return sum(s.get("starts_in_basin", 1) for s in self.starts if s["same_minimum"])

    @property
    def starts_total(self) -> int:
        return sum(s.get("starts_in_basin", 1) for s in self.starts)

    @property
    def convergence_text(self) -> str:
        agree, total = self.starts_agreeing, self.starts_total
        rescue = (self.stage1 or {}).get("rescue") or {}
        if rescue.get("taken"):
            via = (f" (the rescue's starts: the full fit from the first stage's optimum "
                   f"left {', '.join(rescue['records'])} outside their noise at "
                   f"{rescue['cost_before']:.6g})")
        elif self.stage1 and self.stage1.get("stage"):
            via = (f" (through {sum(s['same_minimum'] for s in self.starts)} of "
                   f"{len(self.starts)} first-stage optima)")
        else:
            via = ""
        if self.converged:
            return (f"converged: the remaining Gauss-Newton step is {self.remaining_step:.1e} "
                    f"of its standard error; {agree}/{total} starts reached the same "
                    f"minimum{via}")
        why = []
        if not self.remaining_step < STEP_TOL and not self.optimizer_converged:
            why.append(f"the optimiser stopped at its step limit ({self.steps} iterations)")
        if not self.remaining_step < STEP_TOL:
            why.append(f"the remaining Gauss-Newton step is {self.remaining_step:.2g} of its "
                       f"standard error (needs < {STEP_TOL:g})")
        if total > 1 and agree < 2:
            why.append(f"only {agree} of {total} starts reached the lowest cost{via}")
        why += self.model_issues
        if self.model_choice == "unsettled":
            why.append("the choice of model per record still changed at the estimate after a "
                       "repeated fit (a record near the limit of the linear model; choose one "
                       "with --model)")
        return "NOT converged: " + "; ".join(why or ["see the starts"])


def remaining_step(residual, jacobian, used=None, max_std=None) -> float:
    """Largest |(U^T r)_k| over the informative directions (see the module docstring)."""
    r, j = np.asarray(residual), np.asarray(jacobian)
    if used is not None:
        r, j = r[used], j[used]
    return gn_step_sigma(r, j, max_std)


def no_information_std(problem: Problem):
    """The standard error above which a direction counts as uninformative (None: priors)."""
    return NO_INFORMATION_STD if problem.prior_sigma is None else None


def solved_lanes(problem: Problem, out):
    """Per lane of `solve`'s output `out`: its residual and Jacobian (the rows `Problem.rj`
    returns) and the remaining Gauss-Newton step there, in standard errors (the fit's
    convergence test, `STEP_TOL`)."""
    keep = problem._residual_rows(out["residual"].shape[1])
    rows, max_std = full_used_mask(problem), no_information_std(problem)
    for r, j in zip(out["residual"], out["jacobian"]):
        r, j = r[keep], j[keep]
        yield r, j, remaining_step(r, j, rows, max_std)


def full_used_mask(problem: Problem) -> np.ndarray:
    """Rows of the full residual that carry information (data used + prior rows)."""
    used = problem.used_mask()
    if problem.prior_sigma is None:
        return used
    return np.concatenate([used, np.ones(problem.n_params, bool)])


def start_metric(problem: Problem, spread: float = 0.3) -> np.ndarray:
    """Scale of each fitted coordinate for spreading starts: its prior sigma (`spread`
    without priors)."""
    return (problem.prior_sigma if problem.prior_sigma is not None else
            np.full(problem.n_params, spread))


def _primes(d: int) -> list[int]:
    out, k = [], 2
    while len(out) < d:
        if all(k % p for p in out if p * p <= k):
            out.append(k)
        k += 1
    return out


def halton(d: int, n: int, seed: int) -> np.ndarray:
    """n points (n, d) of the scrambled Halton sequence in [0, 1)^d: dimension i the
    radical inverse in the i-th prime base, each digit through its own random permutation
    (Owen's scrambling, one permutation per digit down to 2^-54), drawn in order from
    `numpy.random.default_rng(seed)`. The same points as `scipy.stats.qmc.Halton(d,
    scramble=True, seed=seed).random(n)` to the bit (tested), without importing
    scipy.stats (about a quarter of a second of every identification's start)."""
    rng = np.random.default_rng(seed)
    bases = _primes(d)
    perms = []
    for base in bases:
        rows = np.repeat(np.arange(base)[None], math.ceil(54 / math.log2(base)) - 1, axis=0)
        for row in rows:
            rng.shuffle(row)
        perms.append(rows)
    out = np.zeros((n, d))
    for i, (base, rows) in enumerate(zip(bases, perms)):
        q, scale = np.arange(n), 1.0 / base
        for row in rows:
            out[:, i] += row[q % base] * scale
            q, scale = q // base, scale / base
    return out


def start_points(problem: Problem, starts: int, seed: int, spread: float = 0.3):
    """Start 0 is the prior; the others spread quasi-randomly (a scrambled Halton sequence,
    seeded) over the prior's central 95 % in every fitted coordinate: the normal quantiles
    of 0.025 + 0.95 u times each prior sigma (+-`spread`-sigma quantiles without priors)."""
    from scipy.special import ndtri  # the normal quantile (scipy.stats' norm.ppf)

    sigma = start_metric(problem, spread)
    out = [np.zeros(problem.n_params)]
    n = max(1, starts) - 1
    if n:
        u = halton(problem.n_params, n, seed)
        out += list(ndtri(0.025 + 0.95 * u) * sigma)
    return out


STAGE1_STARTS = 24  # quasi-random starts of a staged fit's first stage
FULL_STARTS = 8  # most distinct first-stage optima the full fit starts from
#: A staged fit's full fit is tried again from more starts (`rescue`) where a record's
#: mean squared weighted residual at its estimate exceeds this (a residual three times
#: its noise: with six entries, chi-square odds of about 1e-9; the model choice keeps the
#: models' own errors below 0.1 standard errors).
RESCUE_MEAN_Z2 = 9.0
#: The rescue's starts: the first stage's optimum moved this many of its standard
#: deviations either way along its two least determined directions.
RESCUE_SD = 2.0
_DISTINCT = 0.05  # scaled distance beyond which two optima are distinct


def first_estimate(problem: Problem, points):
    """The data-driven first estimate (`_modal.py`): the first resonance read off the
    records, and `points` (quasi-random starts, start 0 the prior) moved onto it, one
    program for all; the moved prior is theta_m. Where the problem chooses its models
    itself, they are chosen again at theta_m (`Problem.rechosen`): a record near the
    *measured* resonance is not on the linear model because the prior's resonance was
    elsewhere (measured on a default-set robustness drive whose resonance was 30 % above
    the prior's: the stage-1 records, chosen at the prior, cost 1.9e6 at the truth, and
    every stage-1 start stopped at its step limit).
    Returns (problem, points, summary dict for the report: the estimate or why none)."""
    estimate, why_not = modal_estimate(problem)
    if estimate is None:
        return problem, points, dict(estimate=None, why_not=why_not)
    moved, mismatch = modal_starts(problem, estimate, points, start_metric(problem))
    theta_m = np.asarray(moved[0], float)
    if problem.chooses_models and np.all(np.isfinite(theta_m)):
        problem = problem.rechosen(theta_m)
    return problem, moved, dict(estimate=estimate.as_dict(), summary=estimate.summary(),
                                mismatch_se=mismatch)


def staged_starts(problem: Problem, pts, starts: int, options: SolveOptions, modal: dict):
    """Starts for a fit with periodic-orbit records, from `pts` (`STAGE1_STARTS`, or
    `starts` if more, quasi-random starts moved onto the first resonance by
    `first_estimate`, whose summary `modal` is): each carried to the optimum of the records
    the cheaper models explain (the orbit records masked, `measurement.masked_orbit_records`),
    as one batched solve. Where no record is left on the cheaper models, there is no first
    stage: the full fit starts from the first max(`starts`, `FULL_STARTS`) of `pts`. The
    full fit starts from each distinct optimum (lowest cost first, at most max(`starts`,
    `FULL_STARTS`)); each carries the number of quasi-random starts that reached it (its
    basin), so agreement among starts is counted in the original starts.
    Returns (points, basin counts, summary dict for the report, the first stage's
    Jacobian at its best optimum, points[0]; None without a first stage)."""
    cheap = sum(m != "nonlinear" for m in problem.models)
    keep = max(1, starts, FULL_STARTS)
    if not cheap:
        # No record on the cheaper models: a first stage on linearised records would fit
        # the wrong model (measured on two records at a fold: its single optimum had 4x
        # the true damping, and the full fit from it stopped in a local minimum at 1.5e6
        # times the cost at the truth). The full fit starts from the quasi-random starts.
        return pts[:keep], [1] * keep, dict(stage=None, records=0, starts=keep,
                                            first_estimate=modal), None
    # The first stage is the full problem with the orbit records' rows masked
    # (`masked_orbit_records`): the same compiled program as the full fit.
    out = solve(np.stack(pts), True, masked_orbit_records(problem.fit_data),
                problem.structure, dataclasses.replace(options, step_tol=0.1))
    cost = np.where(np.isfinite(out["cost"]), out["cost"], np.inf)
    order = np.argsort(cost)
    best = cost[order[0]]
    same = np.abs(cost - best) <= 1e-3 * max(1.0, best)
    # Distinct optima (scaled distance > _DISTINCT from every chosen one), each with the
    # starts that reached it.
    distinct, basin = [], []
    for i in order[np.isfinite(cost[order])]:
        near = [k for k, j in enumerate(distinct)
                if np.max(np.abs(out["theta"][i] - out["theta"][j])) <= _DISTINCT]
        if near:
            basin[near[0]] += 1
        else:
            distinct.append(i)
            basin.append(1)
    if not distinct:  # every start failed: the prior
        distinct, basin = [order[0]], [1]
    summary = dict(stage="records on the linear and first-order models",
                   records=cheap, starts=len(pts),
                   reached_best=int(same.sum()), distinct_optima=len(distinct),
                   full_fit_starts=min(keep, len(distinct)), first_estimate=modal)
    jac = np.asarray(out["jacobian"][distinct[0]])[
        problem._residual_rows(out["residual"].shape[1])]
    return [out["theta"][i] for i in distinct[:keep]], basin[:keep], summary, jac


def fit(problem: Problem, *, starts: int = 3, seed: int = 0, max_steps: int = 100,
        theta0=None, warm_start: bool = True, check_models: bool = True,
        method: str = "dogleg", model_check: bool = True,
        on_models: Callable[[Problem], None] | None = None) -> FitResult:
    """Fit from several starts; the lowest cost wins and every start is reported.

    `theta0` replaces the prior as start 0 (e.g. a previous optimum). `warm_start`: where
    records use the periodic-orbit model, the fit is staged (`staged_starts`): tens of
    quasi-random starts fit the records the cheaper models explain, and the full fit starts
    from the best of their optima. `check_models`: where the
    problem chose its models itself (model "auto"), the choice is made again at the estimate
    (`Problem.rechosen`); if it differs, the fit is repeated with it from the starts' optima,
    up to `MAX_REFITS` times. `max_steps` bounds the optimiser's accepted steps (2 x
    `max_steps` steps with the rejected ones); `method` its descent (`_solve.make_solver`).
    `model_check`: compute the model at the estimate (`FitResult.model`) and mark the fit
    not converged where a record has none (`gate_steady_state`); `identify` does both from
    its branch check instead. `on_models(problem)` is called once the records' models are
    chosen, before the fit (`identify` starts compiling its check's programs there).
    """
    t0 = time.perf_counter()
    options = SolveOptions(method=method, max_steps=2 * max_steps, step_tol=0.1 * STEP_TOL)
    stage1, weights = None, None
    if warm_start:
        # The models per record chosen at the measured resonance (`first_estimate`), and
        # the staged fit's starts moved onto it.
        problem, pts, modal = first_estimate(
            problem, start_points(problem, max(starts, STAGE1_STARTS), seed))
    if on_models is not None:
        on_models(problem)
    if warm_start and "nonlinear" in problem.models:
        # A staged fit: the cheap records first, from many starts (`staged_starts`).
        points, weights, stage1, jac1 = staged_starts(problem, pts, starts, options, modal)
        theta1 = points[0]  # the first stage's best optimum (before theta0 replaces it)
    else:
        points = start_points(problem, starts, seed)
    if theta0 is not None:
        points[0] = np.asarray(theta0, float)
    result = _fit_from(problem, points, options, weights)
    if stage1 is not None and stage1.get("stage"):
        result, rescued = rescue(problem, result, theta1, jac1, options, stage1)
        if rescued:
            weights = None  # the rescue's starts stand for themselves
    if check_models and problem.chooses_models:
        for attempt in range(MAX_REFITS + 1):
            again = result.problem.rechosen(result.theta)
            if again.same_choice(result.problem):
                result.model_choice = "confirmed" if attempt == 0 else "refitted"
                break
            if attempt == MAX_REFITS:
                result.model_choice = "unsettled"
                result.converged = False
                break
            result = _fit_from(again, [np.asarray(r["theta"]) for r in result.starts],
                               options, weights)
    if model_check:
        result.model = result.problem.model_harmonics(result.theta)
        gate_steady_state(result)
    result.seconds = time.perf_counter() - t0
    result.stage1 = stage1
    return result


def misfit_records(problem: Problem, residual) -> list[str]:
    """Records whose mean squared weighted residual exceeds `RESCUE_MEAN_Z2`."""
    return [name for name, chi2, n in record_chi_squares(problem, residual)
            if chi2 / n > RESCUE_MEAN_Z2]


def rescue(problem: Problem, result: FitResult, theta1, jac1, options: SolveOptions,
           stage1: dict):
    """(result, taken): a staged fit whose estimate leaves a record far outside its noise
    (`misfit_records`) fitted again from more starts. Where every first-stage start
    reached one optimum, the full fit had one start, and the records the first stage
    leaves out (the periodic-orbit ones) can hold it in a local minimum: robustness drive
    906 (log-uniform default set) converged there with its 24 starts "agreeing", at 1.4
    times the truth's cost, nut_k 175 standard errors off, its two 3000 N records at 9-12
    times their noise. The new starts: the estimate, and the first stage's optimum
    `theta1` (its Jacobian there `jac1`, from the first stage's solve) moved `RESCUE_SD`
    of its standard deviations either way along the two directions its records determine
    least (those the left-out records decide; for drive
    906 the nut's Hertz coefficient against the thermal expansion). The lowest cost wins;
    convergence is then judged among these starts alone (two must agree), so a minimum
    that one start found says "not converged". `stage1["rescue"]` records it."""
    names = misfit_records(problem, result.residual)
    if not names:
        return result, False
    j = jac1[np.all(np.isfinite(jac1), axis=1)]
    var, vec = np.linalg.eigh(np.linalg.pinv(j.T @ j))
    sd = np.sqrt(np.clip(var, 0.0, None))
    pts = [np.asarray(result.theta, float)] + [
        np.asarray(theta1, float) + s * RESCUE_SD * sd[k] * vec[:, k]
        for k in (-1, -2) for s in (1.0, -1.0)]
    again = _fit_from(problem, pts, options)
    lower = again.cost < result.cost - SAME_COST_RTOL * max(1.0, result.cost)
    stage1["rescue"] = dict(records=names, starts=len(pts),
                            costs=[float(r["cost"]) for r in again.starts],
                            cost_before=float(result.cost), taken=bool(lower))
    return (again, True) if lower else (result, False)


def gate_steady_state(result: FitResult) -> None:
    """Not converged where a record's model at the estimate is not finite (`result.model`:
    its periodic orbit did not converge there)."""
    bad = [d.name for d, m in zip(result.problem.data, result.model)
           if not np.all(np.isfinite(m))]
    if bad:
        result.add_model_issue(
            "the model has no steady state at the estimate for record(s) "
            + ", ".join(f"'{n}'" for n in bad)
            + " (its periodic orbit did not converge), so the fit cannot match them",
            "no_steady_state")


def _fit_from(problem: Problem, points, options: SolveOptions, weights=None) -> FitResult:
    """Fit from `points`; `weights`: the quasi-random starts each point stands for (a staged
    fit's basin counts; 1 each by default)."""
    t0 = time.perf_counter()
    datas, settled = problem.fit_data, None
    if problem.structure.sweeps:
        # Swept records: each lane's sweep computed at its start, then again at its result
        # until the fitted orbit is the one the sweep reaches there (`measurement.anchored`,
        # `measurement.settle`).
        datas = [anchored(problem.fit_data, th, problem.structure) for th in points]
    out = solve(np.stack(points), True, datas, problem.structure, options)
    if problem.structure.sweeps:
        settled = settle(out, datas, problem.structure,
                         lambda th, ds: solve(th, True, ds, problem.structure, options))
    runs = []
    for k, (th0, (r, j, step)) in enumerate(zip(points, solved_lanes(problem, out))):
        runs.append(dict(start=problem.values(np.asarray(th0)).tolist(),
                         theta=out["theta"][k], residual=r, jacobian=j, step=step,
                         cost=float(out["cost"][k]), steps=int(out["steps"][k]),
                         evaluations=int(out["steps"][k]),
                         optimizer_converged=bool(step < options.step_tol),
                         stop=out["stop"][k],
                         starts_in_basin=1 if weights is None else int(weights[k])))
        if settled is not None:
            runs[-1]["on_swept_orbit"] = bool(settled[k])
    best = min(runs, key=lambda d: d["cost"] if np.isfinite(d["cost"]) else np.inf)
    for run in runs:
        run["same_minimum"] = bool(abs(run["cost"] - best["cost"])
                                   <= SAME_COST_RTOL * max(1.0, best["cost"]))
    theta, r, j, step = best["theta"], best["residual"], best["jacobian"], best["step"]
    best_k = next(k for k, run in enumerate(runs) if run is best)
    for run in runs:
        run["theta"] = np.asarray(run["theta"]).tolist()
        del run["residual"], run["jacobian"], run["step"]
    agree = sum(run["starts_in_basin"] for run in runs if run["same_minimum"])
    total = sum(run["starts_in_basin"] for run in runs)
    # The evidence at the returned point decides, not the optimiser's own stopping rule.
    converged = bool(step < STEP_TOL and (total == 1 or agree >= 2))
    if settled is not None:  # the best lane's anchors go with the result
        problem = problem.with_fit_data(datas[best_k])
    result = FitResult(problem, np.asarray(theta),
                       np.asarray(problem.values(np.asarray(theta))), float(best["cost"]), r,
                       j, runs, converged, bool(best["optimizer_converged"]), step,
                       best["steps"], time.perf_counter() - t0)
    if settled is not None and not settled[best_k]:
        result.add_model_issue(
            "a swept record's fitted orbit is not the one its sweep reaches at the estimate "
            f"after {MAX_ANCHOR_ROUNDS} re-anchored solves (the estimate sits at a fold)",
            "swept_orbit")
    return result
