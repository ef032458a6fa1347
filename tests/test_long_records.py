"""Records of the sizes users bring: no hang, no program that grows with the record.

The line screening of a chirp's FRF once ran two batched LAPACK solves side by side over
every line; above about 2000 lines jaxlib's CPU thread pool deadlocked on them (a 4 s chirp
at 0.25 Hz resolution has 7600). The per-test timeout (pyproject.toml) turns a hang into a
failure.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bsfs_jax
from bsfs_jax._numerics import solve_small


def test_solve_small_equals_lapack_with_pivoting():
    rng = np.random.default_rng(3)
    for n in (1, 3, 6, 12):
        a = rng.normal(size=(40, n, n)) + 1j * rng.normal(size=(40, n, n))
        if n > 1:
            a[:, 0, 0] = 0.0  # the first pivot must come from another row
        b = rng.normal(size=(40, n, 2)) + 1j * rng.normal(size=(40, n, 2))
        x = np.asarray(solve_small(a, b))
        ref = np.linalg.solve(a, b)
        assert np.max(np.abs(x - ref)) <= 1e-12 * np.max(np.abs(ref))
        # the residual, independent of numpy's answer
        assert np.max(np.abs(a @ x - b)) <= 1e-12 * np.max(np.abs(b))


def test_solve_small_gradient_matches_finite_differences():
    def f(s):
        a = jnp.array([[s, 1.0, 0.5], [2.0, 3.0, 1.0], [0.1, -1.0, 4.0]])
        return jnp.sum(solve_small(a, jnp.ones((3, 1))) ** 2)

    eps = 1e-6
    fd = (f(0.5 + eps) - f(0.5 - eps)) / (2 * eps)
    assert abs(float(jax.grad(f)(0.5)) - float(fd)) < 1e-7 * max(1.0, abs(float(fd)))


@pytest.mark.timeout(120)
def test_chirp_line_screening_of_a_long_record_returns():
    """The vmapped linearisation error over 8192 lines (a 4 s chirp at 10 kHz has 7600)
    returns, and equals the per-line values computed in small batches."""
    from identification.measurement._linear import linearisation_error

    system = bsfs_jax.build_system(bsfs_jax.preset("default"))
    f = jax.jit(jax.vmap(linearisation_error, in_axes=(None, 0, 0)))
    n = 8192
    freq = jnp.linspace(100.0, 2000.0, n)
    force = jnp.full((n, 1), 5.0 + 0.0j)
    big = np.asarray(f(system, freq, force))
    assert np.all(np.isfinite(big))
    idx = np.array([0, 1000, 4000, 8191])
    small = np.asarray(f(system, freq[idx], force[idx]))
    np.testing.assert_allclose(big[idx], small, rtol=1e-10, atol=0)


# ------------------------------------------------------------- records of the sizes users bring
# Each record kind at a realistic size, made here (seeded, not committed), read and
# identified by the library; the per-test timeout turns a hang into a failure.

_FIT = ("nut_preload", "bearing_preload", "c_b", "c_s", "c_n")


def _identify(paths, fit=_FIT, **kw):
    import identification as idn

    said = []
    res = idn.identify([str(p) for p in paths], None, fit, starts=1, profile=False,
                       say=said.append, **kw)
    values = dict(zip(res.problem.names, np.asarray(res.fit.values, float)))
    return res, values, said


def _check(res, values, said):
    assert res.fit.converged
    # The drive the records were made from (the default preset): both preloads within 5 %.
    # (A sanity bound, not an interval check: the coverage studies measure the intervals.)
    for name in ("nut_preload", "bearing_preload"):
        if name in values:
            assert abs(values[name] / 1500.0 - 1.0) < 0.05
    assert said and said[0].startswith("reading")  # it says what it does from the start


def _synth(tmp_path, name, writer="csv", **kw):
    import identification as idn

    rec = idn.synthesize(bsfs_jax.preset("default"), kw.pop("frequency_hz", None),
                         kw.pop("force_n"), **kw)
    if writer == "tdms":
        return idn.write_record_tdms(tmp_path / f"{name}.tdms", rec)
    return idn.write_record_csv(tmp_path / f"{name}.csv", rec)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_10_s_sine_at_25_6_khz(tmp_path):
    path = _synth(tmp_path, "sine", frequency_hz=150.0, force_n=100.0, duration_s=10.0,
                  sample_rate_hz=25600.0, seed=5)
    # one sine determines one combination (the static compliance): the nut's preload alone
    _check(*_identify([path], fit=("nut_preload",)))


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_30_s_chirp_at_25_6_khz_is_merged_and_screened(tmp_path):
    path = _synth(tmp_path, "chirp", force_n=5.0, duration_s=30.0, sample_rate_hz=25600.0,
                  excitation="chirp", start_hz=100.0, stop_hz=2500.0, seed=6)
    res, values, said = _identify([path])
    _check(res, values, said)
    assert any("merged in runs of" in s for s in said)  # 72 000 lines -> at most 32 768
    assert res.data[0].frequency_hz.size <= 32768


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_20_s_random_record_in_tdms(tmp_path):
    path = _synth(tmp_path, "random", writer="tdms", force_n=20.0, duration_s=20.0,
                  sample_rate_hz=25600.0, excitation="random", start_hz=50.0, stop_hz=2500.0,
                  seed=7)
    _check(*_identify([path]))


def _model_frf(n_lines, seed):
    """An FRF of `n_lines` lines, 50-2500 Hz, of the default drive's linear model with 1 %
    Gaussian noise on Re and Im (as a random test's Welch estimate states them)."""
    from identification import FrfRecord
    from identification.measurement._linear import receptance

    f = np.linspace(50.0, 2500.0, n_lines)
    system = bsfs_jax.build_system(bsfs_jax.preset("default"))
    acc = -((2 * np.pi * f) ** 2) * np.asarray(receptance(system, f))[:, 2]
    std = 0.01 * np.abs(acc)
    rng = np.random.default_rng(seed)
    noisy = acc + std * (rng.standard_normal(n_lines) + 1j * rng.standard_normal(n_lines))
    return FrfRecord(f, noisy, np.stack([std**2, std**2], axis=1), None, 10, 2000.0, 20.0,
                     {"force_level": "rms"}, "model_frf", "random", 20.0)


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("suffix", ["csv", "uff"])
def test_an_frf_file_of_65536_lines(tmp_path, suffix):
    import identification as idn

    frf = _model_frf(65536, seed=8)
    write = idn.write_frf_csv if suffix == "csv" else idn.write_frf_uff
    path = write(tmp_path / f"frf.{suffix}", frf)
    assert idn.load_record(path).frequency_hz.size == 65536
    res, values, said = _identify([path])
    _check(res, values, said)
    assert res.data[0].frequency_hz.size == 32768  # runs of 2 (--max-lines default)
