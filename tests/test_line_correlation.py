"""Correlated errors of neighbouring FRF lines (Hann-windowed Welch FRFs) widen the
identified intervals, and only there (identification/intervals/_lines.py)."""

import numpy as np
import pytest

import bsfs_jax
import identification as idn
from identification.intervals._lines import SIGNIFICANCE, lag_correlations

NAMES = ["nut_preload", "bearing_preload", "c_b", "c_s", "c_n"]


def test_lag_correlations_of_a_moving_average_and_of_white_noise():
    rng = np.random.default_rng(0)
    n, a = 20000, 0.8
    e = rng.standard_normal((n + 1, 2))
    z = (e[1:] + a * e[:-1]) / np.sqrt(1 + a * a)  # MA(1): lag-1 correlation a / (1 + a^2)
    ok = np.ones(n, bool)
    R = lag_correlations(z, ok)
    assert R[0, 0, 0] == pytest.approx(a / (1 + a * a), abs=0.03)
    assert R[0, 1, 1] == pytest.approx(a / (1 + a * a), abs=0.03)
    assert np.all(R[1:] == 0.0) and R[0, 0, 1] == 0.0  # below SIGNIFICANCE: exactly zero
    white = lag_correlations(rng.standard_normal((n, 2)), ok)
    assert np.count_nonzero(white) <= 1  # a 4-sigma false positive is rare
    assert SIGNIFICANCE >= 3.0


@pytest.fixture(scope="module")
def truth():
    return bsfs_jax.preset()


def test_a_random_record_is_widened_and_a_chirp_is_not(truth):
    rnd = idn.synthesize(truth, None, 2.0, duration_s=2.0, sample_rate_hz=10240.0, seed=5,
                         excitation="random", start_hz=50.0, stop_hz=2500.0)
    res = idn.identify([rnd], fit_names=NAMES)
    f = np.asarray(res.uncertainty.noise["line_widening"])
    # Hann, 50 % overlap: about 1 + 2 (0.43) in variance, ~1.35 on the standard error
    assert np.all(f > 1.2) and np.all(f < 1.6)
    assert "correlated" in res.uncertainty.noise["text"]
    chirp = idn.synthesize(truth, None, 5.0, duration_s=1.0, sample_rate_hz=10240.0, seed=5,
                           excitation="chirp", start_hz=50.0, stop_hz=2500.0)
    res = idn.identify([chirp], fit_names=NAMES)
    assert np.all(np.asarray(res.uncertainty.noise["line_widening"]) == 1.0)
    assert "correlated" not in res.uncertainty.noise["text"]


@pytest.mark.slow
def test_random_record_intervals_cover(truth):
    """24 random records (2 N RMS, 2 s at 10.24 kHz): the widened intervals' z scores have
    about unit spread and the reported 95 % intervals cover the truth; without the widening
    the spread is about 1.3."""
    recs = idn.synthesize_many(truth, None, 2.0, [200 + i for i in range(24)], duration_s=2.0,
                               sample_rate_hz=10240.0, excitation="random", start_hz=50.0,
                               stop_hz=2500.0)
    z, z_plain, covered = [], [], []
    for rec in recs:
        res = idn.identify([rec], fit_names=NAMES)
        u = res.uncertainty
        f = np.asarray(u.noise["line_widening"])
        for j in range(len(NAMES)):
            t = truth.get(res.problem.keys[j])
            z.append(np.log(u.values[j] / t) / u.scaled_std[j])
            z_plain.append(z[-1] * f[j])
            covered.append(u.ci95[j][0] <= t <= u.ci95[j][1])
    z, z_plain = np.asarray(z), np.asarray(z_plain)
    assert 0.75 < z.std() < 1.25, z.std()
    assert z_plain.std() > 1.15, z_plain.std()
    assert np.mean(covered) >= 0.88, np.mean(covered)
