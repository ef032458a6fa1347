"""Condition monitoring: trends, change points, time to a limit, and `bsfs monitor`.
numpy/scipy only (no JAX compilation); the CLI runs in-process."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bsfs_jax import monitoring as mon
from bsfs_jax.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location(
        "monitor_coverage_script", ROOT / "scripts" / "monitor_coverage.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_noise_free_linear_history_gives_the_exact_crossing():
    t = np.arange(0.0, 1001.0, 200.0)
    y = 1000.0 - 0.1 * t
    q = mon.monitor_quantity(t, mon.Series("preload", "N", y), mon.Level(value=600.0))
    ttl = q.time_to_limit_h
    assert q.change_points_h == []
    assert ttl.estimate == pytest.approx(4000.0, rel=1e-6)
    assert ttl.lower == pytest.approx(4000.0, rel=1e-6)
    assert ttl.upper == pytest.approx(4000.0, rel=1e-6)
    assert q.status == "ok" and ttl.p_before_next == 0.0


def test_percent_limit_is_of_the_baseline():
    t = np.arange(0.0, 1001.0, 200.0)
    y = 1000.0 - 0.1 * t
    q = mon.monitor_quantity(t, mon.Series("preload", "N", y), mon.Level(percent=60.0))
    assert q.limit == pytest.approx(600.0)
    assert q.time_to_limit_h.estimate == pytest.approx(4000.0, rel=1e-6)


def test_exponential_is_chosen_on_an_exponential_history():
    rng = np.random.default_rng(3)
    t = np.arange(20) * 200.0
    y = 1000.0 * np.exp(-t / 3000.0) + rng.normal(0, 2.0, t.size)
    q = mon.monitor_quantity(t, mon.Series("f", "Hz", y, np.full(t.size, 2.0)),
                             mon.Level(value=100.0))
    assert q.model == "exponential"
    truth = 3000.0 * math.log(10.0)
    assert q.time_to_limit_h.lower <= truth <= q.time_to_limit_h.upper


def test_a_step_is_found_at_its_test_and_the_trend_restarts():
    rng = np.random.default_rng(4)
    t = np.arange(20) * 200.0
    y = 1000.0 - 0.05 * t + rng.normal(0, 5.0, t.size)
    y[10:] += 150.0  # a repair between tests 10 and 11
    q = mon.monitor_quantity(t, mon.Series("nut_preload", "N", y, np.full(t.size, 5.0)),
                             mon.Level(value=600.0))
    assert q.change_points_h == [t[10]]
    assert q.baseline["hours"] == t[10]
    assert q.trend["t0_h"] == t[10]
    assert q.changes[10]["change"] == 0.0 and q.changes[12]["change"] < 0
    rate = q.trend["rate_per_h"] if q.model != "exponential" else None
    if rate is not None:
        assert rate == pytest.approx(-0.05, abs=0.03)


def test_a_late_repair_followed_by_faster_wear_is_found():
    """A repair 4 tests from the end after which the preload falls 4x faster: the level
    step alone is hidden by the new slope; the step with the trend restarting is not."""
    t = np.arange(24) * 200.0
    k = 20
    y = np.where(np.arange(24) < k, 1000.0 - 0.02 * t,
                 1000.0 - 0.4 * (t - 0.5 * (t[k - 1] + t[k])))
    y = y + np.random.default_rng(6).normal(0, 10.0, t.size)
    assert mon.change_points(t, y, np.full(t.size, 100.0)) == [k]


def test_no_step_is_reported_on_a_smooth_noisy_history():
    rng = np.random.default_rng(5)
    t = np.arange(30) * 200.0
    y = 1000.0 - 0.05 * t + rng.normal(0, 5.0, t.size)
    assert mon.change_points(t, y, np.full(t.size, 25.0)) == []


def test_wiener_diffusion_by_reml_is_less_biased_and_its_posterior_covers():
    """15 tests of a random walk (20 N per test, true diffusion 2 N^2/h) with 10 N test
    errors and 5 N scatter: maximum likelihood gives the diffusion far too little, REML
    less so, and the posterior behind the time-to-limit draws contains the truth."""
    rng = np.random.default_rng(8)
    ml, rl, hit = [], [], []
    for _ in range(60):
        t = np.arange(15) * 200.0
        x = 1000.0 - 0.05 * t + np.concatenate([[0.0], np.cumsum(rng.normal(0, 20.0, 14))])
        y = x + rng.normal(0, 10.0, 15) + rng.normal(0, 5.0, 15)
        b = np.full(15, 100.0)
        ml.append(mon._trends.fit_wiener(t, y, b, reml=False).scatter)
        f = mon._trends.fit_wiener(t, y, b)
        rl.append(f.scatter)
        s, p, cell = f.posterior[0], f.posterior[4], f.posterior[5][0]
        o = np.argsort(s)
        c = np.cumsum(p[o])
        lo, hi = s[o][np.searchsorted(c, 0.025)], s[o][np.searchsorted(c, 0.975)]
        hit.append(lo - cell / 2 <= 2.0 <= hi + cell / 2)
    assert np.mean(ml) < 0.6 * 2.0 and 1.3 * np.mean(ml) < np.mean(rl) <= 1.2 * 2.0
    assert np.mean(hit) >= 0.9


def test_time_to_limit_intervals_cover_on_synthetic_histories():
    script = _script()
    rows = [script.run_one(i, 11) for i in range(0, 80, 2)]  # 40 without a step
    cov = [r["covered"] for r in rows]
    assert 0.8 <= np.mean(cov) <= 1.0, np.mean(cov)
    assert np.mean([r["false_step"] for r in rows]) <= 0.15


def test_coverage_script_smoke(tmp_path):
    script = _script()
    assert script.main(["--histories", "6", "--out", str(tmp_path / "c")]) == 0
    rows = [json.loads(x) for x in (tmp_path / "c" / "rows.jsonl").read_text().splitlines()]
    assert len(rows) == 6 and {r["kind"] for r in rows} == set(script.KINDS)
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert summary["histories"] == 6 and "all" in summary
    assert "| all (6) |" in (tmp_path / "c" / "summary.md").read_text()


# ------------------------------------------------------------------------------ the CLI

def _history_csv(path, n=12, step=None):
    rng = np.random.default_rng(7)
    t = np.arange(n) * 200.0
    y = 1000.0 - 0.08 * t + rng.normal(0, 4.0, n)
    if step is not None:
        y[step:] += 200.0
    f = 50.0 + 0.001 * t + rng.normal(0, 0.05, n)
    lines = ["hours,nut_preload [N],nut_preload_std,friction [N m]"]
    lines += [f"{a:g},{b:.6g},4,{c:.6g}" for a, b, c in zip(t, y, f)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _check_schema(data, names):
    assert set(data["quantities"]) == set(names)
    for q in data["quantities"].values():
        for key in ("baseline", "model", "change_points_h", "time_to_limit_h", "status",
                    "changes"):
            assert key in q
        assert q["status"] in ("ok", "warning", "alarm")
        assert isinstance(q["change_points_h"], list)
        for c in q["changes"]:
            assert len(c["ci95"]) == 2
        ttl = q["time_to_limit_h"]
        if ttl is not None:
            assert ttl["lower"] <= ttl["estimate"] <= ttl["upper"]


def test_cli_monitors_a_history_csv(tmp_path, capsys):
    csv = _history_csv(tmp_path / "h.csv", step=6)
    out = tmp_path / "out"
    code = main(["monitor", "--history", str(csv), "--limit", "nut_preload=70%",
                 "--warn", "nut_preload=80%", "--limit", "friction=60", "--next-test",
                 "2600", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads((out / "monitor.json").read_text())
    _check_schema(data, ["nut_preload", "friction"])
    nut = data["quantities"]["nut_preload"]
    assert nut["change_points_h"] == [1200.0]
    assert nut["unit"] == "N" and nut["limit"] == pytest.approx(0.7 * nut["baseline"]["value"])
    assert data["quantities"]["friction"]["time_to_limit_h"]["upper"] == math.inf or \
        data["quantities"]["friction"]["time_to_limit_h"]["upper"] > 0
    assert "nut" in data["actions"] and "re-preload the nut" in data["actions"]["nut"]
    assert (out / "monitor.png").stat().st_size > 1000
    page = (out / "monitor.html").read_text()
    assert "data:image/png;base64," in page and "<table>" in page


def test_cli_tells_a_history_from_a_manifest_by_its_header(tmp_path, capsys):
    csv = _history_csv(tmp_path / "h.csv", step=6)
    code = main(["monitor", str(csv), "--limit", "nut_preload=70%", "--out",
                 str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().err
    data = json.loads((tmp_path / "out" / "monitor.json").read_text())
    assert data["quantities"]["nut_preload"]["change_points_h"] == [1200.0]
    capsys.readouterr()
    manifest = tmp_path / "m.csv"
    manifest.write_text("folder,hours\nnone_a,0\nnone_b,200\nnone_c,400\n")
    code = main(["monitor", str(manifest), "--out", str(tmp_path / "out2")])
    err = capsys.readouterr().err
    assert code != 0 and "none_a" in err and len(err.strip().splitlines()) == 1
    code = main(["monitor", str(csv), "--history", str(csv), "--out", str(tmp_path / "o3")])
    err = capsys.readouterr().err
    assert code != 0 and "give one history" in err


def _identify_folder(path, value, std, f1):
    path.mkdir(parents=True)
    report = {"parameters": {
        "nut_preload": {"key": "nut.preload_n", "unit": "N", "value": value, "std": std},
        "c_s": {"key": "damping.c_s", "unit": "N s/m", "value": 10.0, "std": None}}}
    (path / "report.json").write_text(json.dumps(report))
    pred = {"quantities": [{"name": "f1", "unit": "Hz", "value": f1,
                            "ci95": [f1 - 1.96, f1 + 1.96]}]}
    (path / "prediction.json").write_text(json.dumps(pred))


def test_cli_monitors_a_manifest_of_identify_folders(tmp_path, capsys):
    rows = ["folder,hours"]
    for i in range(6):
        h = 300.0 * i
        _identify_folder(tmp_path / f"t{i}", 1500.0 - 0.2 * h + (-1) ** i * 3, 5.0,
                         900.0 - 0.01 * h)
        rows.append(f"t{i},{h:g}")
    (tmp_path / "m.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    code = main(["monitor", "--manifest", str(tmp_path / "m.csv"), "--limit",
                 "nut_preload=900", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads((out / "monitor.json").read_text())
    _check_schema(data, ["nut_preload", "f1"])  # c_s has no standard error: left out
    ttl = data["quantities"]["nut_preload"]["time_to_limit_h"]
    assert ttl["lower"] < 3000.0 < ttl["upper"]
    assert data["quantities"]["f1"]["time_to_limit_h"] is None


@pytest.mark.parametrize("body, args, message", [
    ("hours,p\n0,1\n100,2\n", [], "2 test(s); a trend needs at least 3"),
    ("hours,p\n0,1\n200,2\n100,3\n", [], "hours not increasing"),
    ("time,p\n0,1\n100,2\n200,3\n", [], "first column must be 'hours'"),
    ("hours,p\n0,1\n100\n200,3\n", [], "1 values for 2 columns"),
    ("hours,p\n0,1\n100,2\n200,3\n", ["--limit", "q=5"], "--limit q: no such quantity"),
    ("hours,p,p_std\n0,1,0.1\n100,2,0\n200,3,0.1\n", [], "'p_std' must be a positive"),
    ("hours,p,q_std\n0,1,1\n100,2,1\n200,3,1\n", [], "column 'q_std' has no quantity"),
    ("hours,p\n0,1\n100,2\n200,3\n", ["--limit", "p=abc"], "is not a number"),
    ("hours,p\n0,1\n100,2\n200,3\n", ["--next-test", "100"], "must be after the last test"),
])
def test_cli_bad_histories_fail_in_one_line(tmp_path, capsys, body, args, message):
    (tmp_path / "h.csv").write_text(body)
    code = main(["monitor", "--history", str(tmp_path / "h.csv"), *args, "--out",
                 str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and message in err, err
    lines = err.splitlines()
    assert lines[-1].startswith("bsfs monitor: error") and message in lines[-1]
    assert sum(ln.startswith("bsfs monitor") for ln in lines) == 1
    assert not (tmp_path / "out").exists()


def test_cli_manifest_without_identify_output_fails(tmp_path, capsys):
    (tmp_path / "m.csv").write_text("folder,hours\na,0\nb,100\nc,200\n")
    code = main(["monitor", "--manifest", str(tmp_path / "m.csv"), "--out",
                 str(tmp_path / "out")])
    assert code == 1 and "no report.json" in capsys.readouterr().err


@pytest.mark.slow
def test_an_identified_drive_losing_nut_preload_is_monitored(tmp_path):
    """scripts/monitor_synthetic_drive.sh: six `bsfs synth` + `bsfs identify` tests of a
    drive whose nut preload falls by 0.25 N/h; the crossing of 900 N (2400 h) lies in the
    monitor's 95 % interval (about 2.5 minutes)."""
    import os
    import subprocess
    import sys

    bsfs = Path(sys.executable).with_name("bsfs")
    env = dict(os.environ, BSFS=str(bsfs), MPLBACKEND="Agg",
               PATH=f"{bsfs.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "monitor_synthetic_drive.sh"),
                           str(tmp_path / "drive")], env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    data = json.loads((tmp_path / "drive" / "monitor" / "monitor.json").read_text())
    nut = data["quantities"]["nut_preload"]
    assert nut["time_to_limit_h"]["lower"] <= 2400.0 <= nut["time_to_limit_h"]["upper"]
    assert nut["change_points_h"] == [] and nut["model"] in ("linear", "exponential")
    assert all(q["change_points_h"] == [] for q in data["quantities"].values())
