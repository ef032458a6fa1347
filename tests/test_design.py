"""Design metrics, implicit sensitivities, optimisation and the design CLI.

Compiles are the cost here: each metric is compiled once (value and value-and-gradient
for one fixed tuple of parameter names) and reused with different arrays.
"""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax import ParameterError, build_system, physics, preset
from bsfs_jax.design import (
    DESIGN_PARAMETERS,
    METRICS,
    OperatingPoint,
    OrbitSettings,
    compiled,
    crosscheck_markdown,
    finite_difference_sensitivities,
    optimize,
    paper_crosscheck,
    sensitivities,
    verify_by_simulation,
)
from bsfs_jax.design.building import parameter_values

# A representative subset for the (expensive) orbit metrics: a count, an angle, the
# speed through the thermal chain, a mass, a damping and l_0.
ORBIT_NAMES = ("nut.balls", "bearing.contact_angle_deg", "thermal.speed_rpm",
               "masses.nut_kg", "damping.nut_n_s_per_m", "screw.length_to_nut_mm")
OP = dict(frequency_hz=400.0, force_n=100.0)
# At 100 N the linear-FRF guess is already close to the orbit: Newton needs no transient
# (and one diffeqsolve fewer is compiled). Harmonic balance: its orbit is a smooth function
# of the parameters, so central differences resolve even the tiny sensitivities (|d ln A /
# d ln c| ~ 5e-6); shooting's adaptive steps leave ~1e-10 of noise in A, too much for
# that. Shooting's own gradients are checked against these below.
FAST = OrbitSettings(transient_periods=0, method="hb", harmonics=16)
REL_TOL = 1e-3


@pytest.fixture(scope="module")
def params():
    return preset()


def _assert_matches_fd(ad, fd, *, floor=1e-6):
    """AD gradient within REL_TOL of central FD for every parameter that matters
    (|d ln m / d ln p| > floor); negligible ones must be negligible in both."""
    assert ad.names == fd.names
    assert ad.value == pytest.approx(fd.value, rel=1e-12)
    for name, g, f, s in zip(ad.names, ad.gradient, fd.gradient, fd.normalised, strict=True):
        if abs(s) > floor:
            assert g == pytest.approx(f, rel=REL_TOL), name
        else:
            assert abs(ad.normalised[ad.names.index(name)]) < 10 * floor, name


# -- static metrics: all design parameters -------------------------------------------------
@pytest.mark.parametrize("metric", ["natural_frequency", "static_stiffness", "thermal_error"])
def test_static_metric_gradients_match_finite_differences(params, metric):
    ad = sensitivities(metric, params)
    fd = finite_difference_sensitivities(metric, params)
    assert len(ad.names) >= 10 and ad.names == DESIGN_PARAMETERS
    _assert_matches_fd(ad, fd)


def test_static_stiffness_is_the_series_chain(params):
    """k = 1 / (1/k_b + 1/k_s + 1/k_n), joint tangents from the pair force law at u = 0."""
    system = build_system(params)
    k_b = jax.grad(physics.pair_force)(0.0, system.bearing)
    k_n = jax.grad(physics.pair_force)(0.0, system.nut)
    expected = 1.0 / (1.0 / k_b + 1.0 / system.screw_stiffness + 1.0 / k_n)
    res = sensitivities("static_stiffness", params)
    assert res.value == pytest.approx(float(expected) * 1e-6, rel=1e-9)
    # The series formula's own derivative in l_0: only k_s depends on it, k_s ~ 1/l_0.
    s_l0 = res.normalised[res.names.index("screw.length_to_nut_mm")]
    assert s_l0 == pytest.approx(-float(expected / system.screw_stiffness), rel=1e-6)


def test_frf_peak_gradient_and_peak_location(params):
    names = ("nut.balls", "masses.nut_kg", "damping.screw_n_s_per_m", "nut.preload_n")
    ad = sensitivities("frf_peak", params, names)
    fd = finite_difference_sensitivities("frf_peak", params, names)
    _assert_matches_fd(ad, fd)
    # Light damping: the peak compliance exceeds the static one by the resonant
    # amplification (about 1 / (2 zeta) ~ 20 for zeta ~ 0.02); check it is > 5x.
    k = sensitivities("static_stiffness", params).value  # N/um (compiled above)
    assert ad.value > 5.0 / k


# -- orbit metrics --------------------------------------------------------------------
@pytest.fixture(scope="module")
def amplitude_sens(params):
    return (sensitivities("amplitude", params, ORBIT_NAMES, settings=FAST, **OP),
            finite_difference_sensitivities("amplitude", params, ORBIT_NAMES, settings=FAST,
                                            **OP))


def test_amplitude_gradient_by_shooting_equals_harmonic_balance(params, amplitude_sens):
    """The same exact gradient from the other orbit method (the default, shooting), over
    every design parameter (one reverse pass: the program of the design-study notebook,
    which the suite's compilation cache then shares), compared on the subset."""
    shoot = sensitivities("amplitude", params, DESIGN_PARAMETERS,
                          settings=OrbitSettings(transient_periods=0), **OP)
    hb = amplitude_sens[0]
    assert shoot.value == pytest.approx(hb.value, rel=1e-9)
    subset = shoot.gradient[[DESIGN_PARAMETERS.index(n) for n in ORBIT_NAMES]]
    np.testing.assert_allclose(subset, hb.gradient, rtol=1e-6,
                               atol=1e-6 * np.max(np.abs(hb.gradient)))


def test_amplitude_gradient_matches_finite_differences(amplitude_sens):
    ad, fd = amplitude_sens
    _assert_matches_fd(ad, fd)


def test_amplitude_agrees_with_linear_response_at_small_force(params, amplitude_sens):
    """100 N is nearly linear (physics.md): the orbit amplitude ~ P |H_nn(f)|."""
    from bsfs_jax import linear_frf

    ad, _ = amplitude_sens
    h = abs(complex(linear_frf(params, OP["frequency_hz"])[0, 2]))
    assert ad.value == pytest.approx(OP["force_n"] * h * 1e6, rel=0.02)


def test_amplitude_scales_with_force_in_linear_regime(params):
    value_fn, _ = compiled("amplitude", ORBIT_NAMES, FAST)
    theta = jnp.asarray(parameter_values(params, ORBIT_NAMES))
    a1 = float(value_fn(theta, params, OperatingPoint(OP["frequency_hz"], 50.0)))
    a2 = float(value_fn(theta, params, OperatingPoint(OP["frequency_hz"], 100.0)))
    assert a2 / a1 == pytest.approx(2.0, rel=0.01)


@pytest.fixture(scope="module")
def floquet_sens(params):
    names = ORBIT_NAMES[:4]
    return (sensitivities("floquet", params, names, settings=FAST, **OP),
            finite_difference_sensitivities("floquet", params, names, settings=FAST, **OP))


def test_floquet_gradient_matches_finite_differences(floquet_sens):
    ad, fd = floquet_sens
    _assert_matches_fd(ad, fd)


def test_floquet_modulus_matches_linear_eigenvalues(params, floquet_sens):
    """Small force: multipliers ~ exp(lambda T), lambda the linearised state eigenvalues."""
    from bsfs_jax.machine import linearise

    k, c, m, _ = linearise(params)
    a = jnp.block([[jnp.zeros((3, 3)), jnp.eye(3)], [-k / m[:, None], -c / m[:, None]]])
    lam = np.linalg.eigvals(np.asarray(a))
    expected = np.max(np.abs(np.exp(lam / OP["frequency_hz"])))
    ad, _ = floquet_sens
    assert 0.0 < ad.value < 1.0
    assert ad.value == pytest.approx(expected, rel=0.02)


# -- cross-check rows, optimisation and verification ----------------------------------------
def test_paper_crosscheck_rows(amplitude_sens, floquet_sens):
    rows = paper_crosscheck({"amplitude": amplitude_sens[0], "floquet": floquet_sens[0]})
    covered = {(r["parameter"], r["metric"]) for r in rows}
    assert ("thermal.speed_rpm", "amplitude") in covered
    assert ("nut.balls", "floquet") in covered
    for r in rows:
        s = r["normalised"]
        if r["expected"] != 0 and abs(s) >= 1e-3:
            assert r["agrees"] == (np.sign(s) == r["expected"])
    table = crosscheck_markdown(rows)
    assert table.count("\n") == len(rows) + 1


def test_optimize_respects_the_stiffness_constraint(params):
    """Lower nut preload cuts the heat (thermal error) but also the stiffness: with a
    minimum stiffness just below the start the optimum sits on the constraint."""
    k0 = sensitivities("static_stiffness", params, ("nut.preload_n",)).value
    k_min = 0.99 * k0
    res = optimize("thermal_error", params, ("nut.preload_n",),
                   {"nut.preload_n": (500.0, 2500.0)}, min_stiffness_n_per_um=k_min)
    assert res.direction == "min"
    assert res.constraint_satisfied
    assert res.optimum[0] < res.start[0]
    assert res.optimum_value < res.start_value and res.improvement_percent > 0
    # Active constraint: the optimum stiffness is k_min to the penalty's tolerance.
    assert res.optimum_stiffness_n_per_um == pytest.approx(k_min, rel=2e-3)
    # Without the constraint the preload runs to its lower bound.
    free = optimize("thermal_error", params, ("nut.preload_n",),
                    {"nut.preload_n": (500.0, 2500.0)})
    assert free.optimum[0] == pytest.approx(500.0, rel=2e-3)
    assert "nut.preload_n" in free.at_bound


def test_optimize_maximises_natural_frequency_within_bounds(params):
    res = optimize("natural_frequency", params,
                   ("bearing.contact_angle_deg", "masses.nut_kg"),
                   {"bearing.contact_angle_deg": (30.0, 50.0), "masses.nut_kg": (1.0, 2.0)})
    assert res.direction == "max"
    assert res.optimum[0] == pytest.approx(50.0, rel=2e-3)  # stiffer bearing
    assert res.optimum[1] == pytest.approx(1.0, rel=2e-3)  # lighter nut
    assert res.optimum_value > res.start_value and res.improvement_percent > 0


def test_static_stiffness_verified_by_simulation(params):
    check = verify_by_simulation("static_stiffness", params, force_n=100.0)
    assert check["checked"]
    assert check["relative_difference"] < 0.01  # 0.05 f1: dynamic amplification 0.25 %


# -- errors and the CLI -------------------------------------------------------------------
def test_errors_name_the_bad_value(params):
    with pytest.raises(ValueError, match="unknown metric 'amplitud'.*amplitude"):
        sensitivities("amplitud", params)
    with pytest.raises(ParameterError, match="nut.bals"):
        sensitivities("static_stiffness", params, ("nut.bals",))
    with pytest.raises(ValueError, match="frequency must be positive"):
        sensitivities("amplitude", params, ORBIT_NAMES, frequency_hz=-1.0, settings=FAST)
    with pytest.raises(ValueError, match="not in --vary"):
        optimize("natural_frequency", params, ("nut.balls",), {"bearing.balls": (10, 20)})


def test_cli_sensitivity_writes_json_png_and_report(tmp_path):
    from bsfs_jax.cli import main

    out = tmp_path / "sens"
    rc = main(["sensitivity", "--metric", "static_stiffness", "--out", str(out)])
    assert rc == 0
    data = json.loads((out / "sensitivity.json").read_text())
    assert data["metric"] == "static_stiffness" and data["unit"] == "N/um"
    assert len(data["parameters"]) == len(DESIGN_PARAMETERS)
    assert (out / "sensitivity.png").stat().st_size > 10_000
    assert "Comparison with the paper" in (out / "sensitivity.md").read_text()
    # The exact gradient is probed by central differences by default, on its two largest
    # entries, and the verdict is reported.
    check = data["gradient_check"]
    assert len(check["checked"]) == 2 and check["passed"] is True
    assert max(check["relative_difference"]) < 1e-2
    assert "agrees with central differences" in (out / "sensitivity.md").read_text()
    rc = main(["sensitivity", "--metric", "static_stiffness", "--no-fd-probe",
               "--out", str(tmp_path / "s2")])
    unchecked = json.loads((tmp_path / "s2" / "sensitivity.json").read_text())
    assert rc == 0 and unchecked["gradient_check"]["passed"] is None


def test_cli_optimize_rejects_bad_bounds(tmp_path, capsys):
    from bsfs_jax.cli import main

    rc = main(["optimize", "--metric", "natural_frequency", "--vary", "nut.balls",
               "--bounds", "nut.balls=60:40", "--out", str(tmp_path / "o")])
    assert rc == 1
    assert "lower 60.0 must be below upper 40.0" in capsys.readouterr().err


def test_metric_table_is_complete():
    for name in ("frc_peak", "amplitude", "natural_frequency", "static_stiffness", "floquet",
                 "thermal_error"):
        assert name in METRICS
    assert METRICS["natural_frequency"].direction == "max"
    assert METRICS["amplitude"].direction == "min"


# -- the FRC peak on a folded curve (100 N: the joints lose contact at the resonance) ------
# The default (auto): harmonic balance cannot meet its 1e-6 estimate with 64 harmonics at
# this contact-loss peak, so the search falls back to shooting.
FRC_100N = OrbitSettings(frc_band=(0.975, 0.99))
FRC_NAMES = ("masses.nut_kg", "screw.length_to_nut_mm")


@pytest.fixture(scope="module")
def frc_100n(params):
    ad = sensitivities("frc_peak", params, FRC_NAMES, force_n=100.0, settings=FRC_100N)
    fd = finite_difference_sensitivities("frc_peak", params, FRC_NAMES, force_n=100.0,
                                         settings=FRC_100N)
    return ad, fd


def test_frc_peak_gradient_matches_continuation_peaks_on_a_folded_curve(frc_100n):
    """The issue's case: default preset, 100 N, a fold between 1118.7 and 1120.2 Hz. The
    finite differences re-run the continuation and locate the peak each time."""
    ad, fd = frc_100n
    assert ad.value == pytest.approx(31.672, rel=2e-4)  # um, as `bsfs continue` finds
    np.testing.assert_allclose(ad.gradient, fd.gradient, rtol=1e-4)
    # Heavier nut, longer screw: the peak rises (the sign the linear model predicts).
    assert np.all(ad.normalised > 0)


def test_probe_takes_its_values_from_the_gradient_program(params, frc_100n):
    """`bsfs sensitivity`'s probe (`probe_gradient`) differences the peak with the values of
    the gradient's own program (its searches on two threads): the same quotients as the
    value program's (`finite_difference_sensitivities` above) to the searches' accuracy."""
    from bsfs_jax.design import probe_gradient

    ad, fd = frc_100n
    out = probe_gradient("frc_peak", params, ad, k=2, force_n=100.0, settings=FRC_100N)
    assert out["passed"]
    probed = finite_difference_sensitivities(
        "frc_peak", params, FRC_NAMES, force_n=100.0, settings=FRC_100N, only=FRC_NAMES,
        gradient_program=True)
    np.testing.assert_allclose(probed.gradient, fd.gradient, rtol=1e-6)
    # The two programs locate one peak, each to the peak search's tolerance (1e-10,
    # `design._orbit`); they round differently: 1.1e-12 and 2.3e-12 apart (relative) with
    # the CPU compiler's earlier fusion emitters, bsfs's default, under 1e-12 with the
    # newer ones.
    assert probed.value == pytest.approx(fd.value, rel=1e-10)


def test_peak_search_near_a_branch_finds_the_whole_band_peak(params):
    """The finite differences' search (`locate_frc_peak_near`: a short continuation of the
    perturbed drive from the nominal branch's stretch around its peak) finds the peak the
    whole-band search finds, in fewer points; the folded 100 N curve, the
    nut preload 1 % up."""
    from bsfs_jax.design import locate_frc_peak, with_values
    from bsfs_jax.design.building import locate_frc_peak_near

    settings = dataclasses.replace(FRC_100N, frc_method="shooting")
    _, nominal = locate_frc_peak(params, 100.0, settings)
    moved = with_values(params, ("nut.preload_n",),
                        jnp.asarray(parameter_values(params, ("nut.preload_n",))) * 1.01)
    _, whole = locate_frc_peak(moved, 100.0, settings)
    _, near = locate_frc_peak_near(moved, 100.0, settings, nominal)
    assert abs(whole.peak.amplitude / nominal.peak.amplitude - 1) > 1e-4  # it did move
    assert near.peak.amplitude == pytest.approx(whole.peak.amplitude, rel=1e-7)
    assert near.peak.p == pytest.approx(whole.peak.p, abs=1e-3)
    assert len(near) < len(whole)  # 13 against 19 here; 6 against 184 over 0.8-1.2 f1


def test_auto_frc_goes_to_shooting_where_a_joint_opens(params):
    """"auto" skips harmonic balance where the working force opens a joint near the peak
    (there HB misses its 1e-6 estimate even at 64 harmonics, see FRC_100N): the linearised
    lift-off force over the band lies between 10 N and 100 N on the default drive, and
    each joint's equals the force at which its linear joint displacement reaches the
    contact window (the relative displacement the preload deformation allows)."""
    from bsfs_jax.design import opens_joint
    from bsfs_jax.design.building import OPENS_FRACTION
    from bsfs_jax.machine import joint_windows, linear_frf, linear_liftoff_force, linearise, modes

    f1 = float(modes(params).frequencies_hz[0])
    lo, hi = FRC_100N.frc_band[0] * f1, FRC_100N.frc_band[1] * f1
    assert opens_joint(params, 100.0, lo, hi) and not opens_joint(params, 10.0, lo, hi)
    grid = jnp.linspace(lo, hi, 257)
    system = build_system(params)
    lift = np.asarray(linear_liftoff_force(system, grid))
    assert 10.0 < OPENS_FRACTION * lift.min() < 100.0
    # At that force the linear response's joint amplitudes touch the windows exactly.
    win = joint_windows(system, linearise(system)[3])
    h = np.asarray(linear_frf(system, grid))
    amp = {"bearing": np.abs(h[:, 0]).max(), "nut": np.abs(h[:, 2] - h[:, 1]).max()}
    for k, joint in enumerate(("bearing", "nut")):
        assert lift[k] * amp[joint] == pytest.approx(float(win[joint]), rel=1e-12)
        # and the window is the preload deformation scale: micrometres, not metres
        assert 1e-7 < float(win[joint]) < 1e-4


def test_frc_peak_equals_the_continue_peak(params, frc_100n, tmp_path):
    from bsfs_jax.cli import main
    from bsfs_jax.design import frc_peak_location
    from bsfs_jax.machine import modes

    f1 = float(modes(params).frequencies_hz[0])
    start, stop = (FRC_100N.frc_band[0] * f1, FRC_100N.frc_band[1] * f1)
    out = tmp_path / "cont"
    assert main(["continue", "--start", f"{start!r}", "--stop", f"{stop!r}", "--force", "100",
                 "--method", "auto", "--hb-tol", "1e-4", "--no-progress",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    # At --hb-tol 1e-4 harmonic balance passes (32 harmonics); the peak it locates agrees
    # with the metric's (shooting) to the HB truncation.
    assert summary["method"] == "harmonic balance" and summary["harmonics"] == 32
    assert summary["peak_amplitude_um"] == pytest.approx(frc_100n[0].value, rel=1e-5)
    op = OperatingPoint(1.0, 100.0)
    f_peak, a_peak = frc_peak_location(params, op, FRC_100N)
    # The metric at the same parameters: the same located point, its amplitude from the
    # differentiable program (not the continuation's), equal to round-off.
    from bsfs_jax.design._metrics import frc_peak
    assert a_peak == pytest.approx(float(frc_peak(params, op, FRC_100N)), rel=1e-12)
    # The sensitivity's value comes from parameters rebuilt from their file units (last-bit
    # differences), for which the peak is located again: the same peak to far below the
    # corrector's tolerance (1e-8), not bit for bit (measured 1.1e-12 after the Newton of
    # 2026-11-27 took its step from an LU factorisation).
    assert a_peak * 1e6 == pytest.approx(frc_100n[0].value, rel=1e-10)
    # The peak is flat (dA/ds = 0), so its frequency is fixed less sharply than its value.
    assert summary["peak_frequency_hz"] == pytest.approx(f_peak, rel=1e-4)
    folds = [b for b in json.loads((out / "bifurcations.json").read_text())
             if b["type"] == "fold"]
    assert len(folds) == 2
    for b in folds:  # cross-checked by shooting to 1e-4 (relative)
        assert b["cross_check"]["other_method"] == "shooting"
        assert b["cross_check"]["relative_difference"] < 1e-4


@pytest.mark.slow
def test_frc_peak_gradient_at_5000n():
    """Cold preset, 5000 N, 900-1500 Hz: strongly nonlinear (contact loss)."""
    cold = preset("cold")
    settings = OrbitSettings(frc_band=(900.0 / 1165.0, 1500.0 / 1165.0))
    names = ("masses.nut_kg", "nut.preload_n")
    ad = sensitivities("frc_peak", cold, names, force_n=5000.0, settings=settings)
    fd = finite_difference_sensitivities("frc_peak", cold, names[:1], force_n=5000.0,
                                         settings=settings)
    assert ad.gradient[0] == pytest.approx(fd.gradient[0], rel=1e-4)
    # The preload moves the 961 um peak by only 2.5e-4 um per 1e-4 relative step, near the
    # ~1e-7 um noise of the shooting solves (a quotient's noise ~4e-4 relative there); a
    # 1e-3 step has ten times the signal and a truncation error below 1e-4 relative (the
    # quotients at 3e-4 and 1e-3 differ by 3e-5): the exact gradient must agree with it to
    # 1e-4, as the mass's does with its 1e-4 quotient.
    coarse = finite_difference_sensitivities("frc_peak", cold, names[1:], force_n=5000.0,
                                             settings=settings, rel_step=1e-3)
    assert ad.gradient[1] == pytest.approx(coarse.gradient[0], rel=1e-4)


def _result(names, normalised, value=2.0):
    from bsfs_jax.design import SensitivityResult

    theta = np.ones(len(names))
    grad = np.asarray(normalised, float) * value / theta
    return SensitivityResult("m", "u", value, None, None, tuple(names), theta, grad,
                             np.asarray(normalised, float), "test")


def test_a_wrong_gradient_is_flagged_never_passed():
    from bsfs_jax.design import compare_gradients
    from bsfs_jax.design.building import gradient_not_checked, largest_entries

    exact = _result(["a", "b", "c"], [0.8, -0.3, 1e-6])
    assert largest_entries(exact) == ("a", "b")
    wrong = _result(["a", "b"], [0.8, 0.3])  # the sign of the second is wrong
    check = compare_gradients(exact, wrong)
    assert check["passed"] is False and "DISAGREES" in check["summary"]
    assert check["relative_difference"][1] == pytest.approx(2.0)
    assert compare_gradients(exact, _result(["a", "b"], [0.8, -0.3 * (1 + 1e-4)]))["passed"]
    # A negligible entry is compared absolutely (difference noise), a real one is not.
    assert compare_gradients(exact, _result(["c"], [3e-6]))["passed"]
    assert not compare_gradients(exact, _result(["c"], [0.01]))["passed"]
    assert gradient_not_checked()["passed"] is None


@jax.custom_jvp
def _tripled_derivative(x):
    return x


@_tripled_derivative.defjvp
def _tripled_jvp(primals, tangents):
    return primals[0], 3.0 * tangents[0]


@pytest.fixture
def wrong_metric(monkeypatch):
    """static_stiffness with a deliberately wrong (tripled) derivative, registered as a
    metric (its description, which the CLI offers, and its functions)."""
    from bsfs_jax.design import METRIC_INFO, Metric
    from bsfs_jax.design._metrics import static_stiffness

    def wrong(params, op=None, settings=None, hint=None):
        return _tripled_derivative(static_stiffness(params))

    metric = Metric("wrong_stiffness", "stiffness, wrong derivative", "N/um", 1e-6, "max",
                    False, False, "static stiffness with a tripled derivative", wrong)
    monkeypatch.setitem(METRICS, metric.name, metric)
    monkeypatch.setitem(METRIC_INFO, metric.name, metric)
    return metric.name


def test_gradient_probe_catches_a_wrong_derivative(params, wrong_metric, tmp_path, capsys):
    from bsfs_jax.cli import main
    from bsfs_jax.design import check_gradient

    names = ("nut.preload_n",)
    good = check_gradient("static_stiffness", params, names)
    assert good["passed"] and good["checked"] == list(names)
    bad = check_gradient(wrong_metric, params, names)
    assert bad["passed"] is False and bad["relative_difference"][0] == pytest.approx(2.0, 1e-3)
    # `bsfs optimize` refuses to follow it: one line, exit 1, nothing written.
    out = tmp_path / "opt"
    assert main(["optimize", "--metric", wrong_metric, "--vary", "nut.preload_n",
                 "--no-verify", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "DISAGREES with central differences" in err
    assert not out.exists()
    # `bsfs sensitivity` writes its outputs flagged, and exits 3.
    assert main(["sensitivity", "--metric", wrong_metric, "--vary", "nut.preload_n",
                 "--out", str(tmp_path / "sens")]) == 3
    data = json.loads((tmp_path / "sens" / "sensitivity.json").read_text())
    assert data["gradient_check"]["passed"] is False
    assert "DISAGREES" in (tmp_path / "sens" / "sensitivity.md").read_text()


def test_cli_optimize_records_the_gradient_check(tmp_path):
    from bsfs_jax.cli import main

    out = tmp_path / "opt"
    assert main(["optimize", "--metric", "thermal_error", "--vary", "nut.preload_n",
                 "--bounds", "nut.preload_n=500:2500", "--no-verify", "--out", str(out)]) == 0
    check = json.loads((out / "optimize.json").read_text())["gradient_check"]
    assert check["passed"] is True
    for where in ("start", "optimum"):
        assert check[where]["checked"] == ["nut.preload_n"] and check[where]["passed"]
    assert check["optimum"]["value"] < check["start"]["value"]  # thermal error, minimised
    assert "start: agrees with central differences" in (out / "optimize.md").read_text()
    assert main(["optimize", "--metric", "thermal_error", "--vary", "nut.preload_n",
                 "--bounds", "nut.preload_n=500:2500", "--no-verify", "--no-fd-probe",
                 "--out", str(tmp_path / "o2")]) == 0
    unchecked = json.loads((tmp_path / "o2" / "optimize.json").read_text())["gradient_check"]
    assert unchecked["passed"] is None and "not checked" in unchecked["summary"]


def test_peak_hint_layout_is_the_located_hints(params, frc_100n):
    # `prefetch_programs` compiles the FRC peak's programs during the search from a hint
    # laid out in advance; it serves only if that layout is the located hint's exactly
    # (tree, static method, shapes, dtypes, weak types). At 100 N a joint opens (shooting).
    import jax

    from bsfs_jax.design import get_metric
    from bsfs_jax.design._sensitivity import locate_hint
    from bsfs_jax.design.building import peak_hint_layout

    op = OperatingPoint(1.0, 100.0)
    layout = peak_hint_layout(params, 100.0, FRC_100N)
    hint = locate_hint(get_metric("frc_peak"), params, op, FRC_100N)  # the fixture's search
    (la, ta), (lb, tb) = (jax.tree_util.tree_flatten(h) for h in (layout, hint))
    assert ta == tb
    def layout_of(leaves):
        return [(np.shape(x), np.dtype(x.dtype), bool(getattr(x, "weak_type", False)))
                for x in leaves]

    assert layout_of(la) == layout_of(lb)
    # No joint opens at 10 N: harmonic balance, whose harmonic count the search finds.
    assert peak_hint_layout(params, 10.0, FRC_100N) is None
    assert peak_hint_layout(params, 100.0, dataclasses.replace(FRC_100N,
                                                               frc_method="hb")) is None
