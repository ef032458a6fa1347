"""The data-driven first estimate: the first resonance read off the records by a
single-mode fit, and the fit's starts moved onto it through the model's linearisation.

Checked against the bundled through-resonance drive's truth (data/resonance.toml): its
first natural frequency and modal damping ratio from `bsfs_jax.modes`, an eigenanalysis
independent of the curve fit.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
import identification as idn
from identification.fitting._fit import start_metric, start_points
from identification.fitting._modal import (
    FLOOR_LN_F,
    FLOOR_LN_ZETA,
    first_mode,
    modal_estimate,
    modal_starts,
)


@pytest.fixture(scope="module")
def resonance():
    data = [idn.measurement_data(r) for r in idn.load_records(idn.bundled_records("resonance"))]
    prior = bsfs_jax.preset().replace("thermal.speed_rpm", data[0].speed_rpm)
    problem = idn.Problem(data, prior, idn.PRELOAD_FIT)
    truth = bsfs_jax.modes(bsfs_jax.build_system(
        bsfs_jax.load_params(idn.DATA_DIR / "resonance.toml")))
    return problem, float(truth.frequencies_hz[0]), float(truth.damping_ratios[0])


def test_the_resonance_is_read_off_the_linear_records(resonance):
    problem, f1, zeta = resonance
    linear = problem.without_orbit_records()  # the staged fit's first stage
    est, why = modal_estimate(linear)
    assert why is None
    assert abs(est.frequency_hz - f1) < 3 * est.frequency_se_hz
    assert abs(est.zeta - zeta) < 3 * est.zeta_se
    assert est.frequency_se_hz < 1e-3 * f1 and est.zeta_se < 0.05 * zeta
    assert 0.5 < est.reduced_chi2 < 2.0
    assert "first resonance from the records" in est.summary()


def test_records_on_the_orbit_model_are_left_out(resonance):
    # Their fundamental ratio is not the linear FRF: with the bundled 100 N sines near the
    # peak the single mode settled 1.3 Hz (80 standard errors) below the truth.
    problem, _, _ = resonance
    assert "nonlinear" in problem.models
    est, _ = modal_estimate(problem)
    linear_est, _ = modal_estimate(problem.without_orbit_records())
    assert est == linear_est
    names = {problem.data[i].name for i, m in enumerate(problem.models) if m == "nonlinear"}
    assert not names & set(est.records)


def test_records_that_do_not_bracket_the_resonance_give_no_estimate():
    data = [idn.measurement_data(r) for r in idn.load_records(idn.bundled_records("paper-test"))]
    est, why = modal_estimate(idn.Problem(data, bsfs_jax.preset(), idn.PRELOAD_FIT))
    assert est is None
    assert "not bracketed" in why or "stands" in why


def test_starts_move_onto_the_measured_resonance_and_keep_their_spread(resonance):
    problem, _, _ = resonance
    first = problem.without_orbit_records()
    est, _ = modal_estimate(first)
    pts = start_points(first, 12, 0)
    moved, mismatch = modal_starts(first, est, pts, start_metric(first))
    modes = np.asarray([[float(v) for v in first_mode(jnp.asarray(m), first.fit_data,
                                                      first.structure, 0)] for m in moved])
    before = np.asarray([[float(v) for v in first_mode(jnp.asarray(p), first.fit_data,
                                                       first.structure, 0)] for p in pts])
    # Before: spread over tens of Hz; after: within the floors of the estimate.
    assert np.ptp(before[:, 0]) > 20.0
    assert np.all(np.abs(np.log(modes[:, 0] / est.frequency_hz)) < 3 * FLOOR_LN_F)
    assert np.all(np.abs(np.log(modes[:, 1] / est.zeta)) < 3 * FLOOR_LN_ZETA)
    assert mismatch < 3.0
    # The two conditions fix two directions of five: the starts stay distinct.
    moved = np.asarray(moved)
    d = np.max(np.abs(moved[:, None] - moved[None]), axis=-1)
    assert np.min(d + np.eye(len(moved)) * 1e9) > 0.05


def test_plan_test_weighs_a_plan_through_the_resonance():
    """`plan-test`'s through-resonance candidate: sines within +-10 % of the prior's first
    resonance, weighed with the model a fit would use there (the periodic orbit)."""
    prior = bsfs_jax.preset()
    f1 = float(bsfs_jax.modes(bsfs_jax.build_system(
        prior.replace("thermal.speed_rpm", 2000.0))).frequencies_hz[0])
    plans = idn.candidate_plans(resonance_hz=f1)
    plan = plans[-1]
    assert plan.name.startswith("through the resonance")
    sines = [r.frequency_hz for r in plan.records if r.excitation == "sine"]
    assert sum(abs(f / f1 - 1.0) <= 0.1 for f in sines) == 2
    names, std, _, problem = idn.fisher_std(plan, prior, idn.PRELOAD_FIT)
    near = [i for i, d in enumerate(problem.data)
            if not hasattr(d, "accelerance") and abs(d.frequency_hz / f1 - 1.0) <= 0.1]
    assert [problem.models[i] for i in near] == ["nonlinear", "nonlinear"]
    assert np.all(np.isfinite(std)) and np.all(std < 1.0)
    assert len(idn.candidate_plans()) == len(plans) - 1  # only on request


def test_plan_test_cli_lists_the_resonance_plan(tmp_path):
    import json

    from bsfs_jax.cli import main

    fit = ",".join(idn.PRELOAD_FIT)
    assert main(["plan-test", "--fit", fit, "--out", str(tmp_path / "a")]) == 0
    plans = json.loads((tmp_path / "a" / "plan.json").read_text())["plans"]
    res = [p for p in plans if p["name"].startswith("through the resonance")]
    assert len(res) == 1 and all(np.isfinite(v) for v in res[0]["expected_std"].values())
    assert main(["plan-test", "--fit", fit, "--no-resonance", "--out",
                 str(tmp_path / "b")]) == 0
    plans = json.loads((tmp_path / "b" / "plan.json").read_text())["plans"]
    assert not any(p["name"].startswith("through the resonance") for p in plans)
