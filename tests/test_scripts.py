"""Every study script that feeds a document runs, at the smallest size, by the command its
document gives (docs/COVERAGE.md, docs/ROBUSTNESS.md, docs/ROUTE_TO_CHAOS.md), writes its
rows and its summary where it is told, and touches nothing else. The studies' figures
come from full runs; these are smoke runs of the same code.

The pooled forecast table is recomputed from the committed rows (docs/data) and must be
the table docs/COVERAGE.md prints.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"


def _run(args, tmp_path, timeout=600):
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, *map(str, args)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc.stdout


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@pytest.mark.slow
def test_coverage_study_runs_one_replicate(tmp_path):
    out = tmp_path / "bundled.jsonl"
    _run([SCRIPTS / "coverage_study.py", "--replicates", "1", "--batch", "1", "--out", out],
         tmp_path)
    (row,) = _rows(out)
    assert row["replicate"] == 0 and row["params"]
    for p in row["params"].values():
        assert abs(p["z"]) < 10 and p["covers"] in (True, False)
    assert "|" in (tmp_path / "bundled_summary.md").read_text()
    # a rerun resumes: nothing left to run
    again = _run([SCRIPTS / "coverage_study.py", "--replicates", "1", "--out", out], tmp_path)
    assert "1 replicate(s) done, 0 to run" in again


@pytest.mark.slow
def test_robustness_study_runs_one_drive(tmp_path):
    _run([SCRIPTS / "robustness_study.py", "--set", "preload", "--drives", "1", "--out",
          tmp_path / "rob"], tmp_path)
    (row,) = _rows(tmp_path / "rob" / "preload.jsonl")
    assert row["drive"] == 0 and "converged" in row
    summary = json.loads((tmp_path / "rob" / "preload_summary.json").read_text())
    assert summary["drives"] == 1
    assert (tmp_path / "rob" / "preload_summary.md").exists()


@pytest.mark.slow
def test_forecast_coverage_runs_one_replicate(tmp_path):
    out = tmp_path / "fc"
    _run([SCRIPTS / "forecast_coverage.py", "--replicates", "1", "--out", out], tmp_path,
         timeout=900)
    rows = [r for f in sorted(out.glob("100N*.jsonl")) for r in _rows(f)]
    assert [r["replicate"] for r in rows] == [0]
    assert (out / "100N_truth.json").exists() and (out / "100N_summary.md").exists()


def test_pooled_forecast_table_is_the_one_in_coverage_md(tmp_path):
    """Every quantity of docs/COVERAGE.md's forecast table: its truth, replicates, coverage
    and the coverage's interval as the pooling script computes them from docs/data."""
    table = _run([SCRIPTS / "forecast_coverage_pool.py"], tmp_path)
    doc = (ROOT / "docs" / "COVERAGE.md").read_text()
    checked = 0
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) < 4 or "(" not in cells[2]:
            continue
        name, truth, cover, ci = cells[:4]
        pct, count = cover.split(" (")
        n = count.rstrip(")").split("/")[1]
        row = f"| {name} | {truth} | {n} | {pct} ({ci}) |"
        if f"| {name} |" in doc:
            assert row in doc, f"docs/COVERAGE.md: expected the row starting {row}"
            checked += 1
    assert checked >= 10


@pytest.mark.slow
def test_route_to_chaos_runs_one_small_atlas(tmp_path):
    docs = tmp_path / "docs"
    _run([SCRIPTS / "route_to_chaos.py", "--num", "3", "--only", "preload",
          "--no-bifurcations", "--out", tmp_path / "route", "--docs", docs], tmp_path)
    report = (docs / "ROUTE_TO_CHAOS.md").read_text()
    assert "route_to_chaos.py" in report
    assert sorted(p.name for p in (docs / "img").iterdir()) == [
        "route_preload_amplitude.png", "route_preload_motion.png"]
