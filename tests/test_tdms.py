"""TDMS records (npTDMS): the written layout round-trips through `load_record`, LabVIEW-style
files (other names, unit_string, wf_increment, g) load, and every bad file is refused in one
line naming the file (no JAX needed)."""

import sys

import numpy as np
import pytest

nptdms = pytest.importorskip("nptdms")

from _signals import F0, FS, META  # noqa: E402
from _signals import signals as _signals  # noqa: E402

from identification import Record, RecordError, load_record, load_tdms, write_record_tdms

G = 9.80665


def _write(path, channels, group="Untitled", group_props=None, file_props=None, groups=()):
    """A TDMS file: `channels` = [(name, data, properties)] in `group`; `groups`: extra
    (name, channels) groups written first."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    objects = [RootObject(properties=file_props or {})]
    for gname, chans, props in [*groups, (group, channels, group_props or {})]:
        objects.append(GroupObject(gname, properties=props))
        objects += [ChannelObject(gname, n, np.asarray(d), properties=p) for n, d, p in chans]
    with TdmsWriter(str(path)) as writer:
        writer.write_segment(objects)
    return path


def _labview(force=None, acc=None, force_props=None, acc_props=None, names=("Force", "Accel")):
    _, f, a = _signals()
    timing = {"wf_increment": 1.0 / FS, "wf_start_offset": 0.0}
    return [(names[0], f if force is None else force,
             {"unit_string": "N", **timing, **(force_props or {})}),
            (names[1], a if acc is None else acc,
             {"unit_string": "m/s^2", **timing, **(acc_props or {})})]


def _refused(path, match):
    with pytest.raises(RecordError, match=match) as info:
        load_record(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text
    return text


# ----------------------------------------------------------------------------- good files


def test_round_trip_sine(tmp_path):
    t, force, acc = _signals()
    meta = dict(META, source="bench 3", seed=7.0, force_range_n=5000.0)
    path = write_record_tdms(tmp_path / "rec.tdms", (t, force, acc), meta)
    rec = load_record(path)
    assert isinstance(rec, Record) and rec.source == str(path)
    np.testing.assert_array_equal(rec.time, t)
    np.testing.assert_array_equal(rec.force, force)
    np.testing.assert_array_equal(rec.acceleration, acc)
    assert rec.meta == meta
    assert (rec.frequency_hz, rec.sample_rate_hz, rec.speed_rpm) == (F0, FS, 2000.0)
    # a loaded Record writes back the same
    again = load_tdms(write_record_tdms(tmp_path / "again.tdms", rec))
    np.testing.assert_array_equal(again.force, rec.force)
    assert again.meta == rec.meta


def test_round_trip_random(tmp_path):
    rng = np.random.default_rng(3)
    n = 4096
    t = np.arange(n) / FS
    force = rng.normal(0, 10, n)
    acc = 0.01 * force + rng.normal(0, 0.01, n)
    meta = dict(excitation="random", force_rms_n=10.0, sample_rate_hz=FS, speed_rpm=0.0,
                ambient_c=21.5)
    rec = load_record(write_record_tdms(tmp_path / "rnd.tdms", (t, force, acc), meta))
    assert rec.excitation == "random" and np.isnan(rec.frequency_hz)
    assert rec.force_amplitude_n == 10.0 and rec.meta == meta
    np.testing.assert_array_equal(rec.acceleration, acc)


def test_labview_layout_by_unit_string_and_g(tmp_path):
    """No time channel, other channel names, acceleration in g, metadata in the file's
    properties (numbers as text and ints too), waveform timing with an offset."""
    _, f, a = _signals()
    chans = _labview(acc=a / G, acc_props={"unit_string": "g"},
                     force_props={"wf_start_offset": 1.5})
    chans[1][2]["wf_start_offset"] = 1.5
    file_props = {"frequency_hz": "120", "force_amplitude_n": 100, "speed_rpm": 2000.0,
                  "ambient_c": 20.0, "author": "rig 2"}
    path = _write(tmp_path / "lv.tdms", chans, file_props=file_props)
    rec = load_record(path)
    np.testing.assert_allclose(rec.acceleration, a, rtol=1e-12)
    np.testing.assert_array_equal(rec.force, f)
    np.testing.assert_allclose(rec.time, 1.5 + np.arange(f.size) / FS, rtol=1e-12)
    assert rec.sample_rate_hz == pytest.approx(FS, rel=1e-12)
    assert rec.frequency_hz == 120.0 and rec.force_amplitude_n == 100.0
    assert rec.meta["author"] == "rig 2" and rec.meta["acceleration_converted_from"] == "g"


def test_group_named_bsfs_and_group_properties_win(tmp_path):
    _, f, a = _signals()
    other = ("first", [("force_n", f[:100], {}), ("acceleration_m_s2", a[:100], {})], {})
    chans = [("FORCE_N", f, {}), ("Acceleration_M_S2", a, {})]  # names case-insensitive
    path = _write(tmp_path / "two.tdms", chans, group="BSFS", groups=[other],
                  group_props=dict(META, ambient_c=23.0), file_props={"ambient_c": 99.0})
    rec = load_record(path)  # no wf_increment, no time channel: sample_rate_hz property
    assert rec.time.size == f.size and rec.ambient_c == 23.0
    np.testing.assert_allclose(rec.time, np.arange(f.size) / FS)


def test_time_channel_gives_the_sample_rate(tmp_path):
    t, f, a = _signals()
    meta = {k: v for k, v in META.items() if k != "sample_rate_hz"}
    chans = [("time_s", t, {"unit_string": "s"}), ("force_n", f, {}),
             ("acceleration_m_s2", a, {})]
    rec = load_record(_write(tmp_path / "t.tdms", chans, group_props=meta))
    assert rec.sample_rate_hz == pytest.approx(FS, rel=1e-12)
    np.testing.assert_array_equal(rec.time, t)


# ----------------------------------------------------------------------------- bad files


def test_not_tdms(tmp_path):
    path = tmp_path / "bad.tdms"
    path.write_text("time_s,force_n,acceleration_m_s2\n" * 20)
    _refused(path, r"bad.tdms: not a readable TDMS file \(.*\)\. Save the record")


def test_no_group(tmp_path):
    path = tmp_path / "empty.tdms"
    path.write_bytes(b"")
    _refused(path, r"empty.tdms: the TDMS file has no group")


def test_missing_channel(tmp_path):
    chans = _labview(acc_props={"unit_string": "V"}, names=("Force", "Volts"))
    path = _write(tmp_path / "nochan.tdms", chans, group_props=META)
    _refused(path, r"group 'Untitled' has no acceleration_m_s2 channel \(channels: 'Force' "
                   r"\(N\), 'Volts' \(V\)\)\. Name the channels")


def test_two_force_channels_by_unit(tmp_path):
    chans = [*_labview(), ("Force 2", _signals()[1], {"unit_string": "N"})]
    path = _write(tmp_path / "two.tdms", chans, group_props=META)
    _refused(path, r"several force channels by unit_string.*name the one to use 'force_n'")


def test_unknown_unit(tmp_path):
    chans = _labview(force_props={"unit_string": "kN"}, names=("force_n", "Accel"))
    path = _write(tmp_path / "kn.tdms", chans, group_props=META)
    _refused(path, r"channel 'force_n' \(force\) has unit_string 'kN', not one of 'N'")


def test_different_lengths(tmp_path):
    _, _, a = _signals()
    path = _write(tmp_path / "len.tdms", _labview(acc=a[:-1]), group_props=META)
    _refused(path, r"'Force' has 4096 samples, 'Accel' 4095; both must cover the same")


def test_no_sample_rate(tmp_path):
    _, f, a = _signals()
    meta = {k: v for k, v in META.items() if k != "sample_rate_hz"}
    path = _write(tmp_path / "nofs.tdms", [("force_n", f, {}), ("acceleration_m_s2", a, {})],
                  group_props=meta)
    _refused(path, r"nofs.tdms: no sample rate: .*no wf_increment property")


def test_rates_disagree(tmp_path):
    chans = _labview(acc_props={"wf_increment": 1.0 / 5120.0})
    path = _write(tmp_path / "rates.tdms", chans, group_props=META)
    _refused(path, r"sampled at different rates")
    t, f, a = _signals()
    chans = [*_labview(), ("time_s", 2 * t, {"unit_string": "s"})]
    path = _write(tmp_path / "time.tdms", chans, group_props=META)
    _refused(path, r"wf_increment .* but channel 'time_s' gives 5120 Hz")


def test_nan_sample(tmp_path):
    _, f, _ = _signals()
    f[100] = np.nan
    path = _write(tmp_path / "nan.tdms", _labview(force=f), group_props=META)
    _refused(path, r"nan.tdms: sample 100: force_n is nan \(non-finite")


def test_missing_property(tmp_path):
    meta = {k: v for k, v in META.items() if k not in ("speed_rpm", "frequency_hz")}
    path = _write(tmp_path / "meta.tdms", _labview(), group_props=meta)
    _refused(path, r"property\(ies\) frequency_hz, speed_rpm missing\. Add them as properties "
                   r"of group 'Untitled'")


def test_header_checks_shared(tmp_path):
    """The format-independent checks (`_records.finish`) run on TDMS records too."""
    path = _write(tmp_path / "f0.tdms", _labview(), group_props=dict(META, frequency_hz=300.0))
    _refused(path, r"frequency_hz = 300 but the measured force's dominant frequency")


def test_without_nptdms(tmp_path, monkeypatch):
    path = write_record_tdms(tmp_path / "rec.tdms", _signals(), META)
    monkeypatch.setitem(sys.modules, "nptdms", None)
    _refused(path, r"rec.tdms: reading TDMS needs npTDMS.*pip install npTDMS.*bsfs\[tdms\]")
