"""Analyses: spectra, Lyapunov exponents (tangent dynamics), motion classification."""

import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.analysis import (
    SweepConfig,
    SweepProblem,
    amplitude_spectrum,
    classify_motion,
    detect_jumps,
    largest_lyapunov,
    strobe_period,
    stroboscopic,
    sweep,
)
from bsfs_jax.solvers import RESULTS, SolverSettings, result_ok
from tests.textbook import LORENZ_CLASSIC, LORENZ_LYAPUNOV, duffing, linear_oscillator, lorenz

# ---------------------------------------------------------------------------------------
# Spectra and sections


@pytest.mark.parametrize("window", ["hann", "rect"])
def test_amplitude_spectrum_recovers_sinusoids(window):
    dt, n = 1e-4, 4000  # 0.4 s: 2.5 Hz bins
    t = np.arange(n) * dt
    x = 3e-6 + 2e-6 * np.sin(2 * np.pi * 500.0 * t) + 0.5e-6 * np.cos(2 * np.pi * 1500.0 * t)
    f, a = amplitude_spectrum(x, dt, window=window)
    assert f.shape == a.shape == (n // 2 + 1,)
    assert f[1] == pytest.approx(2.5)
    assert a[np.argmin(abs(f - 500.0))] == pytest.approx(2e-6, rel=1e-9)
    assert a[np.argmin(abs(f - 1500.0))] == pytest.approx(0.5e-6, rel=1e-9)
    assert a[0] == pytest.approx(3e-6)
    # jnp input gives the same numbers (the sweep computes spectra inside jit)
    _, aj = amplitude_spectrum(jnp.asarray(x), dt, window=window)
    np.testing.assert_allclose(np.asarray(aj), a, rtol=1e-10, atol=1e-18)


def test_stroboscopic_takes_one_sample_per_period():
    samples = np.arange(40.0).reshape(20, 2)  # 5 periods of 4 samples
    s = stroboscopic(samples, 4)
    np.testing.assert_array_equal(s[:, 0], [0.0, 8.0, 16.0, 24.0, 32.0])
    with pytest.raises(ValueError, match="samples_per_period"):
        stroboscopic(samples, 0)


# ---------------------------------------------------------------------------------------
# Classification of constructed signals


def _logistic(n, r=4.0, x0=0.3123):
    x = np.empty(n)
    x[0] = x0
    for k in range(1, n):
        x[k] = r * x[k - 1] * (1 - x[k - 1])
    return x


def _henon(n, a=1.4, b=0.3):
    z = np.zeros((n + 100, 2))
    for k in range(1, n + 100):
        x, y = z[k - 1]
        z[k] = (1 - a * x * x + y, b * x)
    return z[100:]


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7, 11, 16])
def test_period_n_detected(n):
    rng = np.random.default_rng(n)
    pattern = rng.normal(size=(n, 3))
    strobe = np.tile(pattern, (65 // n + 2, 1))[:65] + 1e-7 * rng.normal(size=(65, 3))
    m = classify_motion(strobe, lyapunov_per_period=-0.3)
    assert (m.kind, m.period, m.label) == ("periodic", n, f"period-{n}")
    assert strobe_period(strobe, max_period=16) == n


def test_period_17_is_not_reported_as_lower_period():
    rng = np.random.default_rng(0)
    strobe = np.tile(rng.normal(size=(17, 2)), (5, 1))[:80]
    assert strobe_period(strobe, max_period=16) == 0
    assert strobe_period(strobe, max_period=20) == 17


def test_quasi_periodic_torus():
    # Irrational rotation on a circle (the stroboscopic image of a 2-torus).
    k = np.arange(400)
    rho = (np.sqrt(5) - 1) / 2
    strobe = np.stack([np.cos(2 * np.pi * rho * k), np.sin(2 * np.pi * rho * k)], axis=1)
    with_lyap = classify_motion(strobe, lyapunov_per_period=0.002)
    spectral_only = classify_motion(strobe)
    assert with_lyap.kind == spectral_only.kind == "quasi-periodic"
    assert with_lyap.consistent is True
    assert spectral_only.line_fraction > 0.99


@pytest.mark.parametrize("system", ["logistic", "henon"])
def test_chaotic_maps(system):
    if system == "logistic":
        strobe = _logistic(512)
        # Exponent of the logistic map at r = 4 is ln 2 per iterate.
        lam = np.mean(np.log(np.abs(4.0 * (1 - 2 * strobe[:-1]))))
        assert lam == pytest.approx(np.log(2), abs=0.08)
    else:
        strobe = _henon(512)
        lam = 0.42  # Henon map's largest exponent (a = 1.4, b = 0.3)
    with_lyap = classify_motion(strobe, lyapunov_per_period=lam)
    spectral_only = classify_motion(strobe)
    assert with_lyap.kind == spectral_only.kind == "chaotic"
    assert with_lyap.consistent is True
    assert spectral_only.line_fraction < 0.9


def test_failed_run_classified_failed():
    strobe = np.full((10, 2), np.nan)
    assert classify_motion(strobe).kind == "failed"
    assert classify_motion(np.zeros((10, 2)), result=RESULTS.max_steps_reached).kind == "failed"
    assert classify_motion(np.zeros((10, 2)), result=RESULTS.successful).kind == "periodic"


def test_detect_jumps_finds_the_jump_and_not_the_smooth_flank():
    v = np.linspace(0.0, 10.0, 41)
    a = 1.0 + 0.1 * v  # smooth rise ...
    a[25:] = 0.2  # ... then a drop
    (j,) = detect_jumps(v, a)
    assert (j.index_before, j.index_after) == (24, 25)
    assert j.value_before == pytest.approx(6.0) and j.value_after == pytest.approx(6.25)
    assert j.amplitude_before == pytest.approx(1.6) and j.amplitude_after == pytest.approx(0.2)
    assert j.kind == "jump-down"
    assert detect_jumps(v, 1.0 + 0.1 * v) == []


# ---------------------------------------------------------------------------------------
# Lyapunov exponents from the tangent dynamics


def test_lorenz_largest_lyapunov_exponent():
    res = largest_lyapunov(lorenz, jnp.array([1.0, 1.0, 1.0]), jnp.array(LORENZ_CLASSIC),
                           interval=1.0, n_intervals=2000, transient_intervals=20,
                           settings=SolverSettings(rtol=1e-8, atol=1e-10))
    assert bool(res.result == RESULTS.successful) and bool(res.ok)
    assert float(res.exponent) == pytest.approx(LORENZ_LYAPUNOV, rel=0.03)


def test_linear_oscillator_exponent_is_minus_zeta_omega():
    zeta, w0 = 0.05, 2.0
    args = jnp.array([zeta, w0, 1.0, 1.3])
    res = largest_lyapunov(linear_oscillator, jnp.array([0.1, 0.0]), args,
                           interval=2 * np.pi / 1.3, n_intervals=200,
                           settings=SolverSettings(rtol=1e-10, atol=1e-12))
    assert float(res.exponent) == pytest.approx(-zeta * w0, rel=0.02)


# ---------------------------------------------------------------------------------------
# The period-doubling route of the forced double-well Duffing oscillator


def _duffing_gamma(data, gamma):
    delta, alpha, beta, omega = data[0], data[1], data[2], data[3]
    return (delta, alpha, beta, gamma, omega), 2.0 * jnp.pi / omega


def test_duffing_period_doubling_route():
    """x'' + 0.3 x' - x + x^3 = g cos(1.2 t): period 1, 2, 4 then chaos as g grows
    (the classic route, e.g. Thompson & Stewart; Guckenheimer & Holmes section 2.2)."""
    problem = SweepProblem(duffing, _duffing_gamma, jnp.array([0.3, -1.0, 1.0, 1.2]),
                           jnp.array([1.0, 0.0]), "gamma", observe=0,
                           state_names=("x", "v"), state_units=("1", "1"), time_unit="1")
    cfg = SweepConfig(transient_periods=300, periods=64, samples_per_period=16, batch_size=4,
                      chunk_size=4, settings=SolverSettings(rtol=1e-9, atol=1e-11))
    res = sweep(problem, [0.20, 0.28, 0.29, 0.50], config=cfg, progress=False)
    motions = res.motions()[0]
    assert [m.label for m in motions] == ["period-1", "period-2", "period-4", "chaotic"]
    lam = res.lyapunov_per_period()[0]
    assert np.all(lam[:3] < 0) and lam[3] > 0.05
    assert np.all(result_ok(res.result))
    # Period-2 shows a subharmonic line at half the forcing frequency; period-1 does not.
    half = np.argmin(abs(res.spectrum_order - 0.5))
    one = np.argmin(abs(res.spectrum_order - 1.0))
    spec = res.spectrum[0]
    assert spec[1, half] > 1e-3 * spec[1, one]
    assert spec[0, half] < 1e-6 * spec[0, one]


def test_contracting_but_unsettled_response_is_not_quasi_periodic():
    # A period-1 orbit approached slowly: strobe = fixed point + a residual mode rotating
    # by the golden angle per period (repeats for no n <= 16 within tol = 1e-3, but
    # within 10 tol from one period to the next). A negative exponent says the attractor
    # is periodic, not a torus.
    k = np.arange(65)
    theta = 2 * np.pi * (3 - np.sqrt(5)) / 2
    for amp, kind, label, n in ((0.0052, "periodic", "period-1 (settling)", 1),
                                (0.05, "settling", "periodic (settling)", 0)):
        strobe = np.stack([1.0 + amp * np.cos(theta * k), 0.5 + amp * np.sin(theta * k)], 1)
        m = classify_motion(strobe, lyapunov_per_period=-0.03, scale=np.array([1.0, 1.0]))
        assert (m.kind, m.label, m.period, m.converged) == (kind, label, n, False)
        # Without the exponent the same samples are not declared periodic.
        assert classify_motion(strobe, scale=np.array([1.0, 1.0])).kind == "quasi-periodic"
