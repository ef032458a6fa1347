"""FRF estimation from chirp and random records: synthetic records of the full nonlinear
model at a small force agree with the linearised model within their own standard errors; the
variance formulas are calibrated; sine records are refused; `bsfs synth` writes chirps."""

import numpy as np
import pytest

import bsfs_jax
import identification as idn
from identification import RecordError, estimate_frf, frf_variance
from identification.records._records import Record

TRUTH = idn.DATA_DIR / "truth.toml"
FS = 10240.0
BAND = (50.0, 2000.0)
DURATION = 0.5  # shared by the fixtures and the CLI test: one compile per excitation


@pytest.fixture(scope="module")
def truth():
    return bsfs_jax.load_params(TRUTH)


@pytest.fixture(scope="module")
def chirp(truth):
    return idn.synthesize(truth, None, 5.0, duration_s=DURATION, sample_rate_hz=FS, seed=1,
                          excitation="chirp", start_hz=BAND[0], stop_hz=BAND[1])


@pytest.fixture(scope="module")
def random_record(truth):
    return idn.synthesize(truth, None, 5.0, duration_s=DURATION, sample_rate_hz=FS, seed=2,
                          excitation="random", start_hz=BAND[0], stop_hz=BAND[1])


def _z(frf, truth):
    """(L, 2) z-scores of (Re, Im) against the linearised model, and the model."""
    f = frf.frequency_hz
    padded = np.pad(f, (0, 1024 - f.size % 1024), mode="edge")  # one compile for all sizes
    model = -(2 * np.pi * f) ** 2 * np.asarray(bsfs_jax.linear_frf(truth, padded))[:f.size, 2]
    d = frf.accelerance - model
    return np.stack([d.real, d.imag], axis=1) / frf.std, model


def _check_agreement(frf, truth, max_peak_lines):
    z, model = _z(frf, truth)
    within = np.mean(np.abs(z).max(axis=1) < 3.0)
    assert within > 0.9, within
    assert 0.6 < np.mean(z**2) < 1.6  # honest standard errors, neither too small nor too big
    f = frf.frequency_hz
    df = np.median(np.diff(f))
    peak, true_peak = f[np.argmax(np.abs(frf.accelerance))], f[np.argmax(np.abs(model))]
    assert abs(peak - true_peak) <= max_peak_lines * df + 1e-9
    assert 1100 < peak < 1130  # the first mode (1114 Hz)


def test_chirp_frf_matches_linear_model(chirp, truth):
    assert chirp.excitation == "chirp" and np.isnan(chirp.frequency_hz)
    frf = estimate_frf(chirp)
    assert frf.excitation == "chirp" and frf.n_averages == 1 and frf.force_amplitude_n == 5.0
    assert frf.frequency_hz[0] >= BAND[0] and frf.frequency_hz[-1] <= BAND[1]
    lines = frf.frequency_hz * DURATION  # on the whole record's grid of 1/duration
    assert np.allclose(lines, np.round(lines)) and np.min(np.diff(frf.frequency_hz)) == 2.0
    assert frf.meta["dropped_lines"] > 0 and "dropped" in frf.summary()
    _check_agreement(frf, truth, max_peak_lines=1)


def test_random_frf_matches_linear_model(random_record, truth):
    frf = estimate_frf(random_record)
    assert frf.excitation == "random" and frf.n_averages == 9
    assert frf.meta["force_level"] == "rms" and "RMS" in frf.summary()
    assert frf.frequency_hz[-1] <= BAND[1]
    _check_agreement(frf, truth, max_peak_lines=2)


def test_welch_on_a_chirp_is_available(chirp):
    frf = estimate_frf(chirp, method="welch", band=(200, 1800))
    assert frf.n_averages == 9 and frf.frequency_hz[0] >= 200 and frf.frequency_hz[-1] <= 1800


def test_sine_record_refused():
    t = np.arange(2048) / FS
    rec = Record(t, np.sin(2 * np.pi * 200 * t), 0.1 * np.sin(2 * np.pi * 200 * t), 200.0, 1.0,
                 FS, 0.0, 20.0, {}, "sine.csv")
    with pytest.raises(RecordError, match=r"sine.csv: a sine record has no broadband FRF; use "
                                          r"harmonic_analysis"):
        estimate_frf(rec)


def test_frf_variance_formula():
    h = np.array([2.0 + 1.0j, -1.0j])
    g2 = np.array([0.9, 0.5])
    v = frf_variance(h, g2, 10)
    expected = np.abs(h) ** 2 * (1 - g2) / (2 * 10 * g2)
    assert v.shape == (2, 2) and np.allclose(v[:, 0], expected) and np.allclose(v[:, 1], expected)


def _fir_records(kind, n_rep, n=4096, seed=0):
    """Records of a known FIR system y = h * f + output noise (pure numpy)."""
    rng = np.random.default_rng(seed)
    taps = np.array([1.0, 0.6, -0.4, 0.2])
    t = np.arange(n) / FS
    if kind == "chirp":  # a burst chirp 200-4000 Hz with tapered ends
        w = np.sin(0.5 * np.pi * np.clip(np.minimum(t, t[-1] - t) / 0.01, 0, 1)) ** 2
        force = w * np.sin(2 * np.pi * (200 * t + 0.5 * 3800 / t[-1] * t**2))
        meta = dict(excitation="chirp", start_hz=200.0, stop_hz=4000.0)
    for _ in range(n_rep):
        if kind == "random":
            force = rng.standard_normal(n)
            meta = dict(excitation="random")
        acc = np.convolve(force, taps)[:n] + 0.3 * rng.standard_normal(n)
        yield Record(t, force, acc, np.nan, 1.0, FS, 0.0, 20.0, meta, f"{kind}.csv"), taps


@pytest.mark.parametrize("kind", ["random", "chirp"])
def test_variances_are_calibrated(kind):
    """Over replicates the z-scores against the exact FRF have unit variance (within 15 %):
    Welch's overlap correction and the coherence's lost degree of freedom (random), and the
    difference-based noise estimate (chirp single frame)."""
    z2 = []
    for rec, taps in _fir_records(kind, 40 if kind == "random" else 20):
        frf = estimate_frf(rec, min_coherence=0.0)
        w = 2 * np.pi * frf.frequency_hz / FS
        exact = np.polyval(taps[::-1], np.exp(-1j * w))
        d = frf.accelerance - exact
        z2.append(np.concatenate([d.real, d.imag]) / np.concatenate(frf.std.T))
    z2 = np.concatenate(z2) ** 2
    assert 0.85 < np.mean(z2) < 1.15, np.mean(z2)


def test_chirp_variances_are_calibrated_through_a_resonance():
    """Noise on both channels through a sharp resonance (a two-pole filter at 1000 Hz, 1 %
    damping, 20 lines per half-power bandwidth): the force sensor's noise enters H1
    through |H|^2, so the error is largest at the peak. The stated variances hold there
    and on the flanks separately (mean z^2 within 15 % of 1); the output-noise-only
    estimate it replaced gave mean z^2 of 1.4 at the peak and 0.75 on the flanks."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(5)
    n, f0, zeta = 10240, 1000.0, 0.01
    t = np.arange(n) / FS
    rad = np.exp(-zeta * 2 * np.pi * f0 / FS)
    den = [1.0, -2 * rad * np.cos(2 * np.pi * f0 / FS), rad**2]
    w = np.sin(0.5 * np.pi * np.clip(np.minimum(t, t[-1] - t) / (0.03 * t[-1]), 0, 1)) ** 2
    force = w * np.sin(2 * np.pi * (200 * t + 0.5 * 3800 / t[-1] * t**2))
    acc = lfilter([1.0], den, force)
    rms = lambda x: np.sqrt(np.mean(x**2))  # noqa: E731
    bins = {"peak": [], "flanks": []}
    for _ in range(30):
        f_meas = force + rng.normal(0, 0.01 * rms(force), n)  # 40 dB on both channels
        a_meas = acc + rng.normal(0, 0.01 * rms(acc), n)
        rec = Record(t, f_meas, a_meas, np.nan, 1.0, FS, 0.0, 20.0,
                     dict(excitation="chirp", start_hz=200.0, stop_hz=4000.0), "chirp.csv")
        frf = estimate_frf(rec, min_coherence=0.0)
        zf = np.exp(-2j * np.pi * frf.frequency_hz / FS)
        exact = 1.0 / (1.0 + den[1] * zf + den[2] * zf**2)
        d = (frf.accelerance - exact)[:, None]
        z2 = (np.concatenate([d.real, d.imag], 1) / frf.std) ** 2
        dist = np.abs(frf.frequency_hz - f0) / (2 * zeta * f0)  # in half-power bandwidths
        bins["peak"].append(z2[dist < 1])
        bins["flanks"].append(z2[(dist >= 1) & (dist < 3)])
    for name, z2 in bins.items():
        assert 0.85 < np.mean(np.concatenate(z2)) < 1.15, (name, np.mean(np.concatenate(z2)))


def test_single_frame_needs_a_burst(chirp):
    cut = Record(chirp.time[1000:4000], chirp.force[1000:4000], chirp.acceleration[1000:4000],
                 np.nan, 5.0, FS, chirp.speed_rpm, chirp.ambient_c, chirp.meta, "cut.csv")
    with pytest.raises(RecordError, match=r"cut.csv: the force does not start and end at rest"
                                          r".*method='welch'"):
        estimate_frf(cut)


def test_estimated_frf_round_trips(tmp_path, random_record):
    frf = estimate_frf(random_record)
    for path in (idn.write_frf_uff(tmp_path / "r.uff", frf),
                 idn.write_frf_csv(tmp_path / "r.csv", frf)):
        back = idn.load_record(path)
        assert isinstance(back, idn.FrfRecord) and back.excitation == "random"
        np.testing.assert_allclose(back.frequency_hz, frf.frequency_hz, rtol=1e-12)
        np.testing.assert_allclose(back.accelerance, frf.accelerance, rtol=1e-10)
        np.testing.assert_allclose(back.variance, frf.variance, rtol=1e-10)
        np.testing.assert_allclose(back.coherence, frf.coherence, rtol=1e-10)
        assert back.n_averages == 9 and back.force_amplitude_n == 5.0
        assert back.meta["force_level"] == "rms" and back.speed_rpm == frf.speed_rpm


def test_synth_cli_chirp(tmp_path, chirp):
    from bsfs_jax.cli import main

    path = tmp_path / "chirp.csv"
    argv = ["synth", "--params", str(TRUTH), "--excitation", "chirp", "--force", "5",
            "--duration", str(DURATION), "--seed", "1"]
    assert main([*argv, "--start", "50", "--stop", "2000", "--frf", "--out", str(path)]) == 0
    rec = idn.load_record(path)
    assert rec.excitation == "chirp" and (rec.start_hz, rec.stop_hz) == BAND
    assert rec.force_amplitude_n == 5.0 and rec.meta["parameters"] == str(TRUTH)
    np.testing.assert_allclose(rec.force, chirp.force, rtol=1e-5, atol=1e-5)  # same seed
    frf = idn.load_record(tmp_path / "chirp_frf.csv")
    assert isinstance(frf, idn.FrfRecord) and frf.excitation == "chirp"
    # Refused in one line, before any simulation.
    for bad in (["--start", "50"], ["--start", "2000", "--stop", "50"],
                ["--start", "50", "--stop", "4500"], ["--start", "-5", "--stop", "50"],
                ["--frequency", "100", "--start", "50", "--stop", "100"]):
        assert main([*argv, *bad, "--out", str(tmp_path / "x.csv")]) == 1
    assert main(["synth", "--params", str(TRUTH), "--force", "5",
                 "--out", str(tmp_path / "x.csv")]) == 1  # a sine needs --frequency
    assert not (tmp_path / "x.csv").exists()
