"""Randomised-maximum-likelihood refits: draws of the fitted coordinates for `bsfs predict`.

Each refit perturbs the fit's data by Gaussian noise at each line's stated standard error
(the sine harmonics' and FRF lines' real and imaginary parts) and the prior's centre by a
draw from the prior, then minimises the same cost from the estimate. For a model linear in
theta these are exact draws of the Gaussian posterior (Oliver, He & Reynolds 1996,
"Conditioning permeability fields to pressure data", ECMOR V; Bardsley et al. 2014,
"Randomize-then-optimize", SIAM J. Sci. Comput. 36); for this one they carry the estimate's
own skew through the model, which a Gaussian draw around the estimate does not.

Why `bsfs predict` wants them (docs/COVERAGE.md): where a quantity's second-order term is
large, its interval is the range of the quadratic model over draws. Over Gaussian draws the
model's median moves by half the curvature term tr(H C)/2 (+0.23 standard deviations for the
damping ratio over 200 replicates of the preload-loss test), while the estimate itself is
close to unbiased; over refits it moves as the exact refits do (-0.015 against -0.015 on the
bundled drive, one-off check `forecast_bootstrap_check.py`, in git at 9d7344c).

Where neighbouring FRF lines' errors are correlated (a Hann-windowed FRF, `_lines.py`),
the refits, which perturb every line independently, spread too little; each refit's
deviation from the estimate is then stretched by its parameter's widening factor, which
gives their spread the scale of the widened covariance while keeping their shape.

The refits run through `fit.solve`: batches of its lane class, so the fit's compiled
program serves them. A refit counts where the remaining Gauss-Newton step at its result is
below the fit's own `STEP_TOL`; the draws are offered to `bsfs predict` only where at least
`MIN_CONVERGED` of them did (dropping many failures would bias them).
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import numpy as np

from ..fitting import STEP_TOL, SolveOptions, solve, solved_lanes

REFITS = 200  # default number of refits (`bsfs identify --refits`)
AUTO_MAX_PARAMETERS = 5
MIN_CONVERGED = 0.95
BATCH = 4 * 8  # refits per call of `solve`: whole lane classes (4), one compiled program
METHOD = "randomised maximum likelihood (data and prior perturbed, refitted from the estimate)"


@dataclasses.dataclass(frozen=True)
class Refits:
    """Converged refits (file-unit values and fitted coordinates) and their account."""

    names: tuple
    values: np.ndarray  # (n, p) file units, converged refits only
    theta: np.ndarray  # (n, p)
    requested: int
    seed: int
    seconds: float
    # batches that failed on every attempt on a cluster: {batch, refits, cause} each
    failed: tuple = ()

    @property
    def converged(self) -> int:
        return len(self.values)

    @property
    def usable(self) -> bool:
        return self.requested > 0 and self.converged >= MIN_CONVERGED * self.requested

    def as_dict(self) -> dict:
        return dict(method=METHOD, requested=self.requested, converged=self.converged,
                    usable=self.usable, min_converged=MIN_CONVERGED, seed=self.seed,
                    seconds=round(self.seconds, 2), file="refits.npz",
                    **({"failed_batches": list(self.failed)} if self.failed else {}))


def refits_by_default(result) -> bool:
    """Whether `bsfs identify --refits auto` runs `REFITS` refits: where at most
    `AUTO_MAX_PARAMETERS` parameters are fitted and no record needs the periodic-orbit
    model. Measured (2-core machine, warm): 200 refits of the preload-loss test (5
    parameters) take 1.6-2.3 s and all converge; of the paper test's default fit (7
    parameters) 3.3-4.9 s, 189 of 200 converging (the rest crawl to the step limit, so
    `bsfs predict` would not use them) and its warm identify went from 2.8 s to 7.7 s; with
    periodic-orbit records about 0.1 s each. `--refits N` asks for them anywhere."""
    fit = getattr(result, "fit", result)
    problem = fit.problem
    return (problem.n_params <= AUTO_MAX_PARAMETERS
            and not any(m == "nonlinear" for m in problem.models))


def refits_for(result, n="auto", seed: int = 0, on_batch=None,
               runner=None) -> Refits | None:
    """What `bsfs identify --refits N|auto` saves: `refit(result, n)`, with "auto" read as
    `REFITS` where `refits_by_default`, else none; None where that is none or the fit did
    not converge (`bsfs predict` refuses an unconverged fit). `runner`: as `refit`'s."""
    if n == "auto":
        n = REFITS if refits_by_default(result) else 0
    if n == 0 or not getattr(result, "fit", result).converged:
        return None
    return refit(result, n, seed=seed, on_batch=on_batch, runner=runner)


def perturbed(data, rng, prior: bool = True):
    """The fit data with Gaussian noise at each line's stated standard error and, where
    `prior`, the prior's centre drawn from the prior (`FitData.prior_shift`)."""
    groups = []
    for g in data.groups:
        s, acc = np.asarray(g.sine_scale), np.asarray(g.sine_acc)
        n = np.where(np.isfinite(s), s, 0.0) * rng.standard_normal(s.shape)
        fs, fa = np.asarray(g.frf_scale), np.asarray(g.frf_acc)
        nf = np.where(np.isfinite(fs), fs, 0.0) * rng.standard_normal(fs.shape)
        groups.append(eqx.tree_at(lambda g: (g.sine_acc, g.frf_acc), g,
                                  (acc + n[..., 0] + 1j * n[..., 1],
                                   fa + nf[..., 0] + 1j * nf[..., 1])))
    inv = np.asarray(data.inv_sigma, float)
    sigma = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), 0.0)
    shift = sigma * rng.standard_normal(inv.shape) if prior else np.zeros_like(inv)
    return eqx.tree_at(lambda d: (d.groups, d.prior_shift), data, (tuple(groups), shift))


def refit(result, n: int = REFITS, seed: int = 0, options: SolveOptions | None = None,
          on_batch=None, runner=None) -> Refits:
    """`n` randomised-maximum-likelihood refits of `result` (an `IdentificationResult` or
    a `FitResult`), seeded. `on_batch(done, n)` reports progress.

    `runner`: where the batches of `BATCH` refits run; None: here, one after another;
    `bsfs_jax.cluster.Cluster.run`: on a Dask cluster's workers, a batch a chunk. Each
    batch carries the random generator's state at its start, so the draws, and the
    refits, are the same wherever it runs. A batch that fails on every attempt counts
    its refits as not converged (`Refits.failed` says why)."""
    import functools

    fit = getattr(result, "fit", result)
    problem = fit.problem
    theta = np.asarray(fit.theta, float)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    options = SolveOptions() if options is None else options
    items = []
    for lo in range(0, n, BATCH):
        m = min(BATCH, n - lo)
        items.append((m, rng.bit_generator.state))
        for _ in range(m):  # on to the next batch's state: the same draws as `_batch`'s
            perturbed(problem.fit_data, rng)
    job = functools.partial(refit_batch, problem, theta, options)
    results: list = [None] * len(items)
    failed, done = [], 0
    for k, value in (enumerate(map(job, items)) if runner is None else runner(job, items)):
        if isinstance(value, Exception):  # a chunk that failed on every attempt
            failed.append(dict(batch=k, refits=items[k][0], cause=getattr(value, "cause",
                                                                          str(value))))
            value = np.zeros((0, theta.size))
        results[k] = value
        done += items[k][0]
        if on_batch is not None:
            on_batch(done, n)
    th = np.concatenate([np.zeros((0, theta.size)), *results])
    unc = getattr(result, "uncertainty", None)
    if unc is not None and len(th):
        f = np.asarray(unc.noise.get("line_widening", np.ones(theta.size)), float)
        th = theta + (th - theta) * f  # correlated FRF lines (module docstring)
    values = np.asarray(problem.values(th)) if len(th) else th
    return Refits(tuple(problem.names), values, th, int(n), int(seed),
                  time.perf_counter() - t0, tuple(failed))


def refit_batch(problem, theta, options, item) -> np.ndarray:
    """(k, p): the converged refits of one batch, `item` = (m, the random generator's
    state at its start): m perturbed copies of the fit data (`perturbed`), refitted from
    `theta` in one call of `fit.solve`; a refit counts where its remaining Gauss-Newton
    step is below `STEP_TOL` and its coordinates are finite."""
    m, state = item
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    datas = [perturbed(problem.fit_data, rng) for _ in range(m)]
    out = solve(np.tile(theta, (m, 1)), True, datas, problem.structure, options)
    keep = [th for th, (_, _, step) in zip(out["theta"], solved_lanes(problem, out))
            if step < STEP_TOL and np.all(np.isfinite(th))]
    return np.asarray(keep, float).reshape(-1, theta.size)


def save_refits(refits: Refits, folder, estimate) -> object:
    """Write `folder`/refits.npz atomically (names, samples: the converged refits' file-unit
    values, estimate: the fit's values they belong to, so that `bsfs predict` can tell a
    stale file); returns its path."""
    from pathlib import Path

    from bsfs_jax.files import save_npz_atomic

    return save_npz_atomic(Path(folder) / "refits.npz", names=np.asarray(refits.names),
                           samples=refits.values, estimate=np.asarray(estimate, float))
