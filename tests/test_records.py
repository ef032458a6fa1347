"""Record loading: good CSV/UFF58 records load; every bad-record case is refused with the
file, the line and what to do (no JAX needed)."""

import numpy as np
import pytest

from identification import (
    RecordError,
    load_record,
    load_records,
    write_record_csv,
    write_record_uff,
)
from identification._records import format_record_csv

FS = 10240.0
F0 = 120.0
META = dict(frequency_hz=F0, force_amplitude_n=100.0, sample_rate_hz=FS, speed_rpm=2000.0,
            ambient_c=20.0)


def _signals(n=4096, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    force = 100 * np.sin(2 * np.pi * F0 * t + 0.3) + 4 * np.sin(4 * np.pi * F0 * t) \
        + rng.normal(0, 1, n)
    acc = 0.4 * np.sin(2 * np.pi * F0 * t + 0.31) + rng.normal(0, 0.005, n)
    return t, force, acc


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
    from identification._records import uff58_set

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
