"""Record loading: good CSV/UFF58 records load; every bad-record case is refused with the
file, the line and what to do (no JAX needed)."""

import numpy as np
import pytest
from _signals import F0, FS, META
from _signals import signals as _signals

from identification import (
    RecordError,
    load_record,
    load_records,
    write_record_csv,
    write_record_uff,
)
from identification.records._csv import format_record_csv


def _write(tmp_path, text, name="rec.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _csv(t=None, force=None, acc=None, meta=None):
    st, sf, sa = _signals()
    return format_record_csv(st if t is None else t, sf if force is None else force,
                             sa if acc is None else acc, META if meta is None else meta)


# Data lines start after the META header (5 lines) and the column line: sample i is on
# line 7 + i.
def _line(i, n_meta=len(META)):
    return n_meta + 2 + i


def test_good_csv_loads_exactly(tmp_path):
    t, force, acc = _signals()
    path = write_record_csv(tmp_path / "ok.csv", (t, force, acc), META)
    rec = load_record(path)
    assert rec.frequency_hz == F0 and rec.speed_rpm == 2000.0 and rec.sample_rate_hz == FS
    assert rec.time.size == t.size  # nothing dropped
    np.testing.assert_allclose(rec.force, force, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(rec.acceleration, acc, rtol=1e-5, atol=1e-9)
    assert rec.periods == pytest.approx(t.size / FS * F0)


def test_uff58_round_trip(tmp_path):
    t, force, acc = _signals()
    path = write_record_uff(tmp_path / "ok.uff", (t, force, acc), META)
    rec = load_record(path)
    assert rec.frequency_hz == F0 and rec.force_amplitude_n == 100.0
    np.testing.assert_allclose(rec.force, force, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(rec.acceleration, acc, rtol=1e-6, atol=1e-8)


def test_uff58_without_acceleration_is_refused(tmp_path):
    import pyuff

    t, force, _ = _signals()
    path = tmp_path / "force_only.uff"
    from identification.records._uff import uff58_set

    pyuff.UFF(str(path)).write_sets(uff58_set(t, force, 13, id4="frequency_hz=120"), mode="add")
    with pytest.raises(RecordError, match=r"force_only.uff.*acceleration \(type 12\) missing"):
        load_record(path)


def test_missing_column(tmp_path):
    text = _csv().replace("time_s,force_n,acceleration_m_s2", "time_s,force_n")
    path = _write(tmp_path, text)
    with pytest.raises(RecordError, match=rf"rec.csv:{_line(-1)}: missing column.*acceleration"):
        load_record(path)


def test_unknown_column(tmp_path):
    text = _csv().replace("time_s,force_n,acceleration_m_s2", "time_s,force_n,accel_g")
    path = _write(tmp_path, text)
    with pytest.raises(RecordError, match=r"unknown column\(s\) 'accel_g'.*must be exactly"):
        load_record(path)


def test_missing_header_key(tmp_path):
    meta = {k: v for k, v in META.items() if k != "speed_rpm"}
    path = _write(tmp_path, _csv(meta=meta))
    with pytest.raises(RecordError, match=r"rec.csv: header key\(s\) speed_rpm missing"):
        load_record(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_sample(tmp_path, bad):
    t, force, acc = _signals()
    acc[100] = bad
    path = _write(tmp_path, _csv(t, force, acc))
    with pytest.raises(RecordError, match=rf"rec.csv:{_line(100)}: acceleration_m_s2 is "
                                          rf"{bad}.*never drops"):
        load_record(path)


def test_non_numeric_value(tmp_path):
    text = _csv().splitlines()
    text[_line(5) - 1] = "0.00048828,abc,0.1"
    path = _write(tmp_path, "\n".join(text) + "\n")
    with pytest.raises(RecordError, match=rf"rec.csv:{_line(5)}: 'abc' is not a number"):
        load_record(path)


def test_time_not_increasing(tmp_path):
    t, force, acc = _signals()
    t[50] = t[49]
    path = _write(tmp_path, _csv(t, force, acc))
    with pytest.raises(RecordError, match=rf"rec.csv:{_line(50)}: time_s = .* does not increase"):
        load_record(path)


def test_time_non_uniform(tmp_path):
    t, force, acc = _signals()
    t[200:] += 0.5 / FS  # a half-sample jump: a dropped/duplicated stretch
    path = _write(tmp_path, _csv(t, force, acc))
    with pytest.raises(RecordError, match=rf"rec.csv:{_line(200)}: non-uniform time step"):
        load_record(path)


def test_sample_rate_mismatch(tmp_path):
    meta = dict(META, sample_rate_hz=10000.0)
    path = _write(tmp_path, _csv(meta=meta))
    with pytest.raises(RecordError, match=r"sample_rate_hz = 10000 but the time column gives "
                                          r"10240"):
        load_record(path)


def test_too_few_periods(tmp_path):
    t, force, acc = _signals(n=1200)  # 0.117 s = 14 periods at 120 Hz
    path = _write(tmp_path, _csv(t, force, acc))
    with pytest.raises(RecordError, match=r"only 14.1 excitation periods.*at least 20"):
        load_record(path)


def test_clipping_flat_top(tmp_path):
    t, force, acc = _signals()
    acc = np.minimum(acc, 0.3)  # a saturated accelerometer channel
    path = _write(tmp_path, _csv(t, force, acc))
    with pytest.raises(RecordError, match=r"acceleration_m_s2 stays at its extreme value 0.3 "
                                          r"for \d+ consecutive samples.*clipped"):
        load_record(path)


def test_clipping_full_scale(tmp_path):
    meta = dict(META, force_range_n=100.0)  # force peaks at ~104 N > 99.9 % of 100 N
    path = _write(tmp_path, _csv(meta=meta))
    with pytest.raises(RecordError, match=r"force_n = .* reaches the channel's full scale 100"):
        load_record(path)


def test_frequency_mismatch(tmp_path):
    meta = dict(META, frequency_hz=150.0)
    path = _write(tmp_path, _csv(meta=meta))
    with pytest.raises(RecordError, match=r"frequency_hz = 150 but the measured force's "
                                          r"dominant frequency is 120"):
        load_record(path)


def test_duplicate_and_missing_files(tmp_path):
    t, force, acc = _signals()
    path = write_record_csv(tmp_path / "ok.csv", (t, force, acc), META)
    with pytest.raises(RecordError, match="named twice"):
        load_records([path, path])
    with pytest.raises(RecordError, match="no such file"):
        load_record(tmp_path / "nope.csv")


def test_bundled_records_load():
    from identification import bundled_records

    for name, count in (("paper-test", 3), ("stepped-sine", 18)):
        recs = load_records(bundled_records(name))
        assert len(recs) == count
        assert all(r.periods >= 20 for r in recs)
        assert all(r.meta.get("synthetic") == "true" for r in recs)


# ----------------------------------------------------------------------------- broadband


def _chirp_signals(n=4096, lo=100.0, hi=2000.0):
    t = np.arange(n) / FS
    force = 50 * np.sin(2 * np.pi * (lo * t + 0.5 * (hi - lo) / t[-1] * t**2))
    acc = 0.01 * np.roll(force, 3) + np.random.default_rng(1).normal(0, 0.01, n)
    return t, force, acc


CHIRP_META = dict(excitation="chirp", start_hz=100.0, stop_hz=2000.0, force_amplitude_n=50.0,
                  sample_rate_hz=FS, speed_rpm=2000.0, ambient_c=20.0)


@pytest.mark.parametrize("suffix", [".csv", ".uff"])
def test_chirp_record_round_trip(tmp_path, suffix):
    write = write_record_csv if suffix == ".csv" else write_record_uff
    path = write(tmp_path / f"c{suffix}", _chirp_signals(), dict(CHIRP_META, seed=3.0))
    rec = load_record(path)
    assert rec.excitation == "chirp" and (rec.start_hz, rec.stop_hz) == (100.0, 2000.0)
    assert rec.force_amplitude_n == 50.0 and np.isnan(rec.frequency_hz)
    assert rec.meta["seed"] == 3.0 and "chirp 100-2000 Hz, 50 N" in rec.summary()


def test_random_record_needs_rms_force(tmp_path):
    meta = dict(excitation="random", force_amplitude_n=10.0, sample_rate_hz=FS,
                speed_rpm=0.0, ambient_c=20.0)
    path = _write(tmp_path, format_record_csv(*_chirp_signals(), meta))
    with pytest.raises(RecordError, match=r"rec.csv: header key\(s\) force_rms_n missing"):
        load_record(path)
    meta = dict(meta, force_rms_n=10.0)
    assert load_record(_write(tmp_path, format_record_csv(*_chirp_signals(), meta))).summary()


@pytest.mark.parametrize("change, message", [
    (dict(excitation="sweep"), r"'excitation = sweep' is not one of sine, chirp, random"),
    (dict(stop_hz=None), r"header key\(s\) stop_hz missing"),
    (dict(start_hz=2500.0, stop_hz=3000.0), r"only \d+ % of the force's power lies in the "
                                            r"header's band 2500-3000 Hz"),
    (dict(stop_hz=6000.0), r"stop_hz = 6000 is not below the Nyquist frequency"),
    (dict(start_hz=2000.0, stop_hz=100.0), r"start_hz = 2000 must be below stop_hz = 100"),
])
def test_bad_chirp_header(tmp_path, change, message):
    meta = {k: v for k, v in dict(CHIRP_META, **change).items() if v is not None}
    path = _write(tmp_path, format_record_csv(*_chirp_signals(), meta))
    with pytest.raises(RecordError, match=message):
        load_record(path)


def test_a_broken_tdms_file_is_refused_in_one_line(tmp_path):
    pytest.importorskip("nptdms")
    path = _write(tmp_path, "x", name="rec.tdms")
    with pytest.raises(RecordError, match=r"rec.tdms: the TDMS file has no group") as exc:
        load_record(path)
    assert "\n" not in str(exc.value)


# ----------------------------------------------------------------------------- FRF files


def _frf(n=50, coherence=True):
    from identification import FrfRecord

    f = np.linspace(100.0, 2000.0, n)
    h = 1.0 / (1.0 - (f / 1100.0) ** 2 + 0.02j * f / 1100.0) * (f / 1100.0) ** 2
    std = np.stack([0.01 + 0.001 * np.arange(n), 0.02 + 0.001 * np.arange(n)], axis=1)
    coh = np.linspace(0.6, 0.99, n) if coherence else None
    meta = {"force_level": "peak", "note": "bench test"}
    return FrfRecord(f, h, std**2, coh, 4, 1500.0, 21.5, meta, "bench.csv", "hammer", 250.0)


def _same_frf(a, b, rtol=1e-10):
    np.testing.assert_allclose(b.frequency_hz, a.frequency_hz, rtol=rtol)
    np.testing.assert_allclose(b.accelerance, a.accelerance, rtol=rtol)
    np.testing.assert_allclose(b.variance, a.variance, rtol=rtol)
    assert (b.excitation, b.n_averages, b.speed_rpm, b.ambient_c, b.force_amplitude_n) == (
        a.excitation, a.n_averages, a.speed_rpm, a.ambient_c, a.force_amplitude_n)


@pytest.mark.parametrize("coherence", [True, False])
def test_frf_csv_round_trip(tmp_path, coherence):
    from identification import FrfRecord, write_frf_csv

    frf = _frf(coherence=coherence)
    back = load_record(write_frf_csv(tmp_path / "f.csv", frf))
    assert isinstance(back, FrfRecord) and back.meta["note"] == "bench test"
    _same_frf(frf, back)
    assert (back.coherence is None) == (not coherence)
    assert "FRF (hammer, 250 N), 50 lines 100-2000 Hz, 4 average(s)" in back.summary()


@pytest.mark.parametrize("binary", [True, False])
def test_frf_uff_round_trip(tmp_path, binary):
    from identification import write_frf_uff

    frf = _frf()
    back = load_record(write_frf_uff(tmp_path / "f.uff", frf, binary=binary))
    _same_frf(frf, back, rtol=1e-10 if binary else 1e-5)  # ASCII: 6-digit abscissa
    np.testing.assert_allclose(back.coherence, frf.coherence, rtol=1e-10 if binary else 1e-5)


def _frf_csv(rows=None, meta=None, columns="frequency_hz,re,im,coherence"):
    meta = {"kind": "frf", "speed_rpm": 0.0, "ambient_c": 20.0, "n_averages": 10.0} \
        if meta is None else meta
    rows = rows or [(100.0 + 10 * i, 1.0 + 0.1 * i, -0.5, 0.9) for i in range(10)]
    head = [f"# {k} = {v}" for k, v in meta.items()]
    return "\n".join([*head, columns, *(",".join(str(x) for x in r) for r in rows)]) + "\n"


def test_frf_variance_from_coherence(tmp_path):
    from identification import frf_variance

    frf = load_record(_write(tmp_path, _frf_csv(), name="f.csv"))
    assert frf.excitation == "frf" and frf.n_averages == 10
    np.testing.assert_allclose(frf.variance, frf_variance(frf.accelerance, 0.9, 10))
    assert frf.force_amplitude_n is None


def _bad_rows(i, value, col=0):
    rows = [[100.0 + 10 * j, 1.0, -0.5, 0.9] for j in range(10)]
    rows[i][col] = value
    return rows


@pytest.mark.parametrize("text, message", [
    (_frf_csv(columns="frequency_hz,re,coherence", rows=[(100, 1, 0.9), (110, 1, 0.9)]),
     r"f.csv:5: missing column\(s\) 'im'"),
    (_frf_csv(columns="frequency_hz,re,im,std_re", rows=[(100, 1, 0, 1), (110, 1, 0, 1)]),
     r"f.csv:5: give both std_re and std_im"),
    (_frf_csv(columns="frequency_hz,re,im", rows=[(100, 1, 0), (110, 1, 0)]),
     r"f.csv: the FRF's uncertainty is missing. Add the standard errors \(std_re, std_im\), "
     r"or the coherence and the number of averages"),
    (_frf_csv(meta={"kind": "frf", "speed_rpm": 0.0, "ambient_c": 20.0}),
     r"uncertainty is missing"),
    (_frf_csv(meta={"kind": "frf", "ambient_c": 20.0, "n_averages": 4}),
     r"f.csv: header key\(s\) speed_rpm missing"),
    (_frf_csv(rows=_bad_rows(4, 125.0)), r"f.csv:10: frequency_hz = 125 is below the "
                                         r"previous line's 130.*increase strictly: sort"),
    (_frf_csv(rows=_bad_rows(3, 120.0)), r"f.csv:9: frequency_hz = 120 repeats the previous "
                                         r"line's 120"),
    (_frf_csv(rows=_bad_rows(5, "nan", col=2)), r"f.csv:11: re/im is not finite \(1 such "
                                                 r"line\(s\)\)"),
    (_frf_csv(rows=_bad_rows(0, 0.0)), r"f.csv:6: frequency_hz = 0 is not positive"),
    (_frf_csv(rows=_bad_rows(0, -10.0)), r"f.csv:6: frequency_hz = -10 is not positive"),
    (_frf_csv(rows=_bad_rows(2, 1.5, col=3)), r"f.csv:8: coherence = 1.5 is not in \(0, 1\]"),
    (_frf_csv(rows=_bad_rows(2, "x", col=1)), r"f.csv:8: 'x' is not a number"),
    (_frf_csv(meta={"kind": "frf", "excitation": "shaker", "speed_rpm": 0.0,
                    "ambient_c": 20.0}), r"'excitation = shaker' is not one of chirp, random, "
                                         r"hammer, frf"),
])
def test_bad_frf_csv(tmp_path, text, message):
    path = _write(tmp_path, text, name="f.csv")
    with pytest.raises(RecordError, match=message):
        load_record(path)


def _uff_frf(path, **change):
    import pyuff

    from identification.records._uff import uff58_set

    f = np.linspace(100.0, 1000.0, 10)
    s = uff58_set(f, (1.0 + 0.5j) * np.ones(10), 12, id4="speed_rpm=0; ambient_c=20",
                  id5="n_averages=5; excitation=hammer")
    s.update(func_type=4, ord_data_type=6, abscissa_spacing=0, abscissa_spec_data_type=18,
             orddenom_spec_data_type=13)
    s.update(change)
    coh = dict(uff58_set(f, np.full(10, 0.95), 0), func_type=6, abscissa_spacing=0,
               abscissa_spec_data_type=18, x=s["x"])
    pyuff.UFF(str(path)).write_sets([s, coh], mode="add")
    return path


def test_foreign_uff_frf_loads(tmp_path):
    from identification import frf_variance

    frf = load_record(_uff_frf(tmp_path / "h.uff"))
    assert frf.excitation == "hammer" and frf.n_averages == 5 and frf.frequency_hz.size == 10
    np.testing.assert_allclose(frf.variance, frf_variance(frf.accelerance, 0.95, 5))
    # a mobility (velocity / force) is converted to accelerance: times i w
    mob = load_record(_uff_frf(tmp_path / "m.uff", ordinate_spec_data_type=11))
    np.testing.assert_allclose(mob.accelerance, 2j * np.pi * mob.frequency_hz * (1 + 0.5j))
    assert mob.meta["converted_from"] == "mobility"


@pytest.mark.parametrize("change, message", [
    (dict(func_type=2), r"h.uff: UFF58 set 1 has function type 2 \(auto spectrum\)"),
    (dict(ordinate_spec_data_type=2), r"UFF58 set 1 \(FRF\): ordinate data type 2"),
    (dict(orddenom_spec_data_type=12), r"ordinate denominator data type 12"),
    (dict(abscissa_spec_data_type=17), r"abscissa data type 17.*frequency in Hz"),
    (dict(ord_data_type=4, data=np.ones(10)), r"the FRF data are real"),
    (dict(id4="ambient_c=20"), r"h.uff: header key\(s\) speed_rpm missing. Add lines like "
                               r"'# speed_rpm = ...' to an id line"),
    (dict(x=np.r_[100.0, 100.0, np.linspace(200, 1000, 8)]),
     r"h.uff: UFF58 set 1 \(FRF\), line 1 \(f = 100 Hz\): frequency_hz = 100 repeats"),
    (dict(x=np.r_[0.0, np.linspace(200, 1000, 9)]), r"line 0 \(f = 0 Hz\): frequency_hz = 0 "
                                                    r"is not positive"),
])
def test_bad_uff_frf(tmp_path, change, message):
    path = _uff_frf(tmp_path / "h.uff", **change)
    with pytest.raises(RecordError, match=message):
        load_record(path)


AA = dict(antialias_filter="butterworth", antialias_order=8.0, antialias_cutoff_hz=4096.0,
          antialias_design_rate_hz=40960.0)


@pytest.mark.parametrize("change, message", [
    (dict(antialias_filter="bessel"), r"'antialias_filter = bessel' is not one of "
                                      r"butterworth, none, linear-phase"),
    (dict(antialias_order=0.0), r"'antialias_order = 0.0' must be an integer 1-20"),
    (dict(antialias_order=2.5), r"'antialias_order = 2.5' must be an integer"),
    (dict(antialias_order=None), r"'antialias_order = None' must be an integer"),
    (dict(antialias_cutoff_hz=-5.0), r"'antialias_cutoff_hz = -5.0' must be a positive"),
    (dict(antialias_design_rate_hz=5000.0), r"'antialias_design_rate_hz = 5000.0' must be "
                                            r"above twice antialias_cutoff_hz \(8192 Hz\)"),
])
def test_bad_antialias_header(tmp_path, change, message):
    meta = {k: v for k, v in (META | AA | change).items() if v is not None}
    path = _write(tmp_path, _csv(meta=meta))
    with pytest.raises(RecordError, match="rec.csv: header " + message):
        load_record(path)


def test_antialias_header_round_trips_and_is_divided_out(tmp_path):
    """A stated filter survives CSV and UFF58, and the harmonics are divided by its response
    at k f (checked against filtering a known signal with the same digital filter)."""
    from scipy.signal import butter, sosfilt

    from identification import harmonic_analysis

    n, fs_hi = 8192, 4 * FS
    t_hi = np.arange(4 * n + 4096) / fs_hi
    clean = 100 * np.sin(2 * np.pi * 850.0 * t_hi + 0.3) + 5 * np.cos(6 * np.pi * 850.0 * t_hi)
    filtered = sosfilt(butter(8, 4096.0, fs=fs_hi, output="sos"), clean)[4096::4]
    t = np.arange(n) / FS
    meta = dict(META, frequency_hz=850.0, **AA)
    for writer, name in ((write_record_csv, "aa.csv"), (write_record_uff, "aa.uff")):
        rec = load_record(writer(tmp_path / name, (t, filtered, 0.01 * filtered), meta))
        assert {k: rec.meta[k] for k in AA} == AA
        h = harmonic_analysis(rec)
        shift = np.exp(1j * 2 * np.pi * 850.0 * h.harmonics * 4096 / fs_hi)  # the dropped start
        want = np.array([100 * np.exp(1j * (0.3 - np.pi / 2)), 0, 5]) * shift
        np.testing.assert_allclose(h.force, want, atol=1e-2)  # 1e-4 of the fundamental
        np.testing.assert_allclose(h.acceleration, 0.01 * want, atol=1e-4)
        raw = harmonic_analysis(load_record(writer(tmp_path / ("raw_" + name),
                                                   (t, filtered, 0.01 * filtered), META
                                                   | dict(frequency_hz=850.0))))
        assert abs(raw.force[2] - want[2]) > 2.0  # uncorrected: the filter's phase at 2550 Hz


@pytest.mark.parametrize("order", [1, 2, 5, 8])
def test_antialias_response_is_scipys_butterworth(order):
    """The closed-form response equals scipy.signal's digital and analog Butterworth."""
    from scipy.signal import butter, freqs, sosfreqz

    from identification.records._antialias import response

    f = np.linspace(1.0, 5000.0, 50)
    digital = dict(AA, antialias_order=float(order))
    want = sosfreqz(butter(order, 4096.0, fs=40960.0, output="sos"), worN=f, fs=40960.0)[1]
    np.testing.assert_allclose(response(digital, f), want, rtol=0, atol=1e-12)
    analog = {k: v for k, v in digital.items() if k != "antialias_design_rate_hz"}
    b, a = butter(order, 2 * np.pi * 4096.0, analog=True)
    np.testing.assert_allclose(response(analog, f), freqs(b, a, worN=2 * np.pi * f)[1],
                               rtol=0, atol=1e-12)
    assert response(dict(antialias_filter="linear-phase"), f) is None
    assert response({}, f) is None


def test_sine_noise_is_read_between_the_harmonic_lines():
    """Harmonics above the fitted three are signal, not noise: the noise is read between
    the lines (a record rich in them, as one whose joints open, was weighted as if its
    noise were those harmonics: 10-84x the true noise's RMS in the robustness study)."""
    from identification import harmonic_analysis
    from identification.measurement._harmonics import _fit
    from identification.measurement._sine_noise import noise_variance
    from identification.records._records import Record

    rng = np.random.default_rng(7)
    n, f, sigma = 8192, 150.0, 0.01
    t = np.arange(n) / FS
    acc = sum(10.0 / k * np.sin(2 * np.pi * k * f * t + 0.7 * k) for k in range(1, 21))
    acc = acc + rng.normal(0, sigma, n)
    force = 100 * np.sin(2 * np.pi * f * t) + rng.normal(0, 0.05, n)
    h = harmonic_analysis(Record(t, force, acc, f, 100.0, FS, 2000.0, 20.0, {}, "rich"))
    plain = np.sqrt(_fit(acc, t, h.frequency_hz, 3, 2)[2])
    assert plain > 50 * sigma  # the harmonics 4-20 in the residual
    assert h.acceleration_noise == pytest.approx(sigma, rel=0.1)
    assert h.force_noise == pytest.approx(0.05, rel=0.1)
    # The coefficients' variances follow: the fundamental's mean about 2 sigma^2 / n.
    assert h.acceleration_var[0, 0] == pytest.approx(2 * sigma**2 / n, rel=0.25)
    # Unbiased on white noise; too few bins between the lines: None (plain variance used).
    v = [noise_variance(rng.normal(0, 1, 5120), 146.0, FS, 4096.0) for _ in range(100)]
    assert np.mean(v) == pytest.approx(1.0, abs=0.02)
    assert noise_variance(rng.normal(0, 1, 5120), 3.0, FS, 4096.0) is None


# ---------------------------------------------------------------- records as software writes them


def _spreadsheet(text, *, bom=True, crlf=True, semicolon=False):
    """`text` as a spreadsheet's export writes it: UTF-8 BOM, Windows line ends, and in a
    European locale semicolons with decimal commas."""
    if semicolon:
        out = []
        for line in text.splitlines():
            if line.startswith("#"):
                key, _, value = line.partition("=")
                out.append(f"{key}={value.replace('.', ',')}")
            else:
                out.append(line.replace(",", ";").replace(".", ","))
        text = "\n".join(out) + "\n"
    if crlf:
        text = text.replace("\n", "\r\n")
    return (b"\xef\xbb\xbf" if bom else b"") + text.encode()


@pytest.mark.parametrize("semicolon", [False, True])
def test_spreadsheet_exports_load_as_the_plain_file(tmp_path, semicolon):
    t, force, acc = _signals()
    plain = load_record(write_record_csv(tmp_path / "plain.csv", (t, force, acc), META))
    path = tmp_path / "excel.csv"
    path.write_bytes(_spreadsheet(_csv(), semicolon=semicolon))
    rec = load_record(path)
    assert rec.frequency_hz == plain.frequency_hz and rec.sample_rate_hz == FS
    np.testing.assert_array_equal(rec.time, plain.time)
    np.testing.assert_array_equal(rec.force, plain.force)
    np.testing.assert_array_equal(rec.acceleration, plain.acceleration)


@pytest.mark.parametrize("column, factor", [("acceleration_g", 9.80665),
                                            ("acceleration_mm_s2", 1e-3)])
def test_acceleration_in_other_units_is_converted(tmp_path, column, factor):
    t, force, acc = _signals()
    text = format_record_csv(t, force, acc / factor, META).replace("acceleration_m_s2", column)
    rec = load_record(_write(tmp_path, text))
    np.testing.assert_allclose(rec.acceleration, acc, rtol=1e-5, atol=1e-9 * factor)


def test_two_acceleration_columns_are_refused(tmp_path):
    t, force, acc = _signals()
    text = format_record_csv(t, force, acc, META).replace(
        "acceleration_m_s2", "acceleration_g,acceleration_m_s2")
    with pytest.raises(RecordError, match="2 acceleration columns"):
        load_record(_write(tmp_path, text))


def test_messages_name_values_as_a_person_writes_them(tmp_path):
    t, force, acc = _signals()
    t = t.copy()
    t[5] = t[4]
    with pytest.raises(RecordError) as err:
        load_record(_write(tmp_path, _csv(t=t)))
    assert "np.float64" not in str(err.value) and "time_s = " in str(err.value)


def test_a_record_too_large_for_the_memory_is_refused_before_reading(tmp_path):
    from identification.records._load import check_memory

    path = write_record_csv(tmp_path / "big.csv", _signals(), META)
    check_memory([path], available=64e9)  # fits
    with pytest.raises(RecordError) as err:
        check_memory([path], available=1e9)
    text = str(err.value)
    assert "\n" not in text and str(path) in text
    assert "GB" in text and "Decimate" in text and "--max-lines" in text
