"""The model at the estimate, checked: which branch each periodic-orbit record is on, the
orbit model's truncation error, and the gates that keep a fit from calling itself
converged where the model, not the data, would set the answer."""

from __future__ import annotations

import numpy as np

from ..measurement import (
    branches,
    compliance_and_gradient,
    error_in_std,
    predictions,
    prefetch_branches,
    sine_variance,
    sweep_direction,
)
from ._fit import gate_steady_state
from ._misfit import gate_record_misfit
from ._problem import Problem

# An orbit record whose model truncation error (H against 2H harmonics) exceeds this many
# standard errors makes the fit not converged: the model, not the data, would set the answer.
TRUNCATION_GATE = 1.0


def check_model(result):
    """The model at the estimate, checked (`record_branches`): each orbit record's branch,
    its model (`FitResult.model`, from the same program) and the gates (no steady state,
    truncation error, one record carrying the misfit: `_misfit.py`). Returns (result,
    branches).

    Where the truncation gate fails, more harmonics are not the cure: on the one gated
    drive of the preload robustness study (an upper orbit at 1134 Hz, 6.5 km/s^2, the
    joints out of contact for part of each period) the fit repeated at 32 harmonics was
    26 standard errors off 64 (at 16 it was 1.6 off 32): harmonic balance does not
    converge there, and the fit says so."""
    problem = result.problem
    orbit_model = {}
    branch = record_branches(problem, result.theta, orbit_model)
    result.model = problem.model_harmonics(result.theta, orbit_model)
    gate_steady_state(result)
    gate_truncation(result, branch, [d.name for d in problem.data],
                    problem.structure.orbit_harmonics)
    gate_record_misfit(result)
    return result, branch


def gate_truncation(result, branch: dict, names, harmonics: int = 16) -> None:
    """Mark `result` (a `FitResult`) not converged where a record's orbit model is not
    accurate to `TRUNCATION_GATE` standard errors at the estimate (or its check failed)."""
    bad = {names[i]: b["orbit_truncation_error_std"] for i, b in branch.items()
           if not b["orbit_truncation_error_std"] <= TRUNCATION_GATE}
    if bad:
        result.add_model_issue(
            "the periodic-orbit model's truncation error at the estimate exceeds "
            f"{TRUNCATION_GATE:g} standard error(s) for "
            + ", ".join(f"'{n}' ({z:.2g})" for n, z in bad.items())
            + f" ({harmonics} against {2 * harmonics} harmonics; nan: the "
              f"{2 * harmonics}-harmonic orbit failed)", "truncation")


def _branch_groups(problem: Problem, theta):
    """Per speed with periodic-orbit records: (their indices, the arguments of
    `measurement.branches`: system at `theta`, frequencies, forces, accelerations, sweep
    directions)."""
    for s in problem.speeds:
        idx = [i for i, d in enumerate(problem.data)
               if d.speed_rpm == s and problem.models[i] == "nonlinear"]
        if idx:
            recs = [problem.data[i] for i in idx]
            yield idx, (problem.system_at(theta, s), [d.frequency_hz for d in recs],
                        np.stack([d.force for d in recs]),
                        np.stack([d.acceleration for d in recs]),
                        [sweep_direction(d) for d in recs])


def prefetch_check(problem: Problem) -> None:
    """Start compiling the programs of `check_model` and `uncertainty` (the branch check,
    the model at the estimate, the static compliance) in the background while the fit
    runs (`bsfs_jax.cached_jit`'s `prefetch`), with the layout of `problem`'s records and
    models. Where the fit's estimate re-chooses the models, a program of another layout
    is compiled when it is called, as without the prefetch."""
    theta = np.zeros(problem.n_params)  # numpy: no compiled program to fill it
    for _, args in _branch_groups(problem, theta):
        prefetch_branches(*args, harmonics=problem.structure.orbit_harmonics)
    predictions.prefetch(theta, problem.fit_data, problem.structure, False)
    compliance_and_gradient.prefetch(theta, problem.fit_data, problem.structure)


def record_branches(problem: Problem, theta, models: dict | None = None) -> dict:
    """For each record on the periodic-orbit model, at `theta`: which branch its orbit is
    ("single", "upper", "lower" or "unresolved"; `measurement.branches`), the evidence, the
    sweep direction that reaches it, and the model's truncation error in standard errors
    (16 against 32 harmonics, largest over the usable harmonics). `models` (a dict, filled
    in): {record index: the fitted orbit's acceleration harmonics (nan: no orbit)}."""
    out = {}
    for idx, args in _branch_groups(problem, theta):
        labels, evidence, trunc, fitted = branches(
            *args, harmonics=problem.structure.orbit_harmonics)
        recs = [problem.data[i] for i in idx]
        for j, i in enumerate(idx):
            if models is not None:
                models[i] = fitted[j]
            d = recs[j]
            var = sine_variance(problem, i, d)
            usable = d.frequency_hz * d.harmonics <= problem.max_harmonic_hz
            z = float(np.max(np.where(usable, error_in_std(trunc[j], var), 0.0)))
            out[i] = dict(branch=labels[j], orbit_truncation_error_std=z, **evidence[j])
    return out
