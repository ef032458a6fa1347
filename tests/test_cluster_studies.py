"""Identification's long jobs on a Dask cluster of two local worker processes: `bsfs
identify`'s bootstrap refits and `bsfs predict`'s draws give the local run's files to
1e-12, and the robustness and coverage studies write the local run's rows; a batch that
fails on every attempt is counted (refits) or computed in this process (predict); a
float64 jax array reaches a fresh worker as float64 (the worker's settings come before
any task's arguments); a chunk past `chunk_timeout` is reported and its worker restarted;
a cluster started by the `dask scheduler` / `dask worker` commands serves `bsfs sweep`
through BSFS_SCHEDULER."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from bsfs_jax.cluster import ChunkFailed, Cluster  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PRELOAD_FIT = "nut_preload,bearing_preload,c_b,c_s,c_n"
REFITS = "64"  # two batches of 32


class Box:
    """Not a pytree: its array travels as pickled, not as numpy (`Cluster.run`)."""

    def __init__(self, x):
        self.x = x


def dtype_and_error(box):
    import jax

    return str(box.x.dtype), float(box.x[0]) - 0.1, bool(jax.config.jax_enable_x64)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    cache = os.environ.get("BSFS_CACHE_DIR") or str(tmp_path_factory.mktemp("cache"))
    with Cluster(workers=2, cache=cache) as c:
        yield c


def _cli(argv, out, cluster=None):
    from bsfs_jax.cli import main

    extra = [] if cluster is None else ["--scheduler", cluster.client.scheduler.address]
    assert main([*argv, *extra, "--out", str(out)]) in (0, 4)
    return out


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """The bundled worn drive identified here, with 64 refits."""
    return _cli(["identify", "--data", "preload-loss", "--fit", PRELOAD_FIT, "--refits",
                 REFITS, "--no-progress"], tmp_path_factory.mktemp("identify") / "here")


def _worst(a, b, path="") -> float:
    """The largest relative difference between two JSON trees of the same shape (times,
    the cluster's account and the printed summary, which states times, left out);
    unequal strings fail."""
    if isinstance(a, dict):
        keys = [k for k in a if k not in ("cluster", "summary") and not k.endswith(
            ("seconds", "_s"))]
        assert set(keys) <= set(b), path
        return max([_worst(a[k], b[k], f"{path}/{k}") for k in keys], default=0.0)
    if isinstance(a, list):
        assert len(a) == len(b), path
        return max([_worst(x, y, f"{path}[{i}]") for i, (x, y) in enumerate(zip(a, b))],
                   default=0.0)
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) / max(abs(a), 1e-300)
    assert a == b, f"{path}: {a!r} != {b!r}"
    return 0.0


@pytest.mark.timeout(120)
def test_a_float64_jax_array_reaches_a_fresh_worker_as_float64(tmp_path):
    import jax.numpy as jnp
    from distributed import Client, LocalCluster

    with Cluster(workers=1, cache=str(tmp_path / "cache")) as fresh:
        ((_, got),) = list(fresh.run(dtype_and_error, [Box(jnp.asarray([0.1]))]))
    assert got == ("float64", 0.0, True)
    # a Dask client of the caller's own
    with (LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as local,
          Client(local) as client):
        ((_, got),) = list(Cluster(client=client, cache=str(tmp_path / "cache"))
                           .run(dtype_and_error, [Box(jnp.asarray([0.1]))]))
    assert got == ("float64", 0.0, True)


def sleep_then_pid(seconds):
    import time

    time.sleep(seconds)
    return os.getpid()


@pytest.mark.timeout(180)
def test_a_chunk_past_its_budget_is_reported_and_its_worker_restarted(tmp_path):
    import time

    with Cluster(workers=1, cache=str(tmp_path / "cache"), chunk_timeout=3) as c:
        t0 = time.perf_counter()
        got = dict(c.run(sleep_then_pid, [0.0, 3600.0, 0.0]))
        elapsed = time.perf_counter() - t0
        ((_, after),) = list(c.run(sleep_then_pid, [0.0]))
    assert elapsed < 60
    assert isinstance(got[0], int) and isinstance(got[2], int)
    assert isinstance(got[1], ChunkFailed) and got[1].attempts == 1
    assert "TimeoutError: ran past its budget of 3 s" in got[1].cause
    assert after != got[0]  # the worker was restarted: its overrunning thread is gone
    assert [f.position for f in c.failures] == [1]


def test_a_chunk_timeout_without_a_cluster_is_refused_in_one_line(tmp_path, capsys):
    from bsfs_jax.cli import main

    for argv in (["sweep", "--start", "100", "--stop", "200", "--num", "3"],
                 ["identify", "--data", "preload-loss", "--refits", "64"]):
        assert main([*argv, "--chunk-timeout", "60", "--out", str(tmp_path / "o")]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--chunk-timeout" in err[0], err
        assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit):
        main(["sweep", "--chunk-timeout", "-1", "--out", str(tmp_path / "o")])


@pytest.mark.timeout(300)
def test_identify_s_refits_on_two_workers_are_the_local_ones(cluster, identified, tmp_path):
    there = _cli(["identify", "--data", "preload-loss", "--fit", PRELOAD_FIT, "--refits",
                  REFITS, "--no-progress"], tmp_path / "there", cluster)
    a, b = np.load(identified / "refits.npz"), np.load(there / "refits.npz")
    assert a["samples"].shape == (int(REFITS), 5)
    np.testing.assert_allclose(b["samples"], a["samples"], rtol=1e-12, atol=0)
    report = json.loads((there / "report.json").read_text())
    assert report["refits"]["cluster"]["chunks_done"] == 2
    assert not report["refits"]["cluster"]["failed_chunks"]
    assert _worst(json.loads((identified / "report.json").read_text()), report) < 1e-12


@pytest.mark.timeout(600)
def test_predict_s_draws_on_two_workers_give_the_local_prediction(cluster, identified,
                                                                  tmp_path):
    argv = ["predict", "--from", str(identified), "--force", "100"]
    here = json.loads((_cli(argv, tmp_path / "here") / "prediction.json").read_text())
    there = json.loads((_cli(argv, tmp_path / "there", cluster) / "prediction.json")
                       .read_text())
    assert here["draws"] == there["draws"] and "refits" in here["draws"]
    # the draws decided some quantities (the lift-off force on the bundled drive)
    assert any(q["method"].startswith("model at each draw") for q in here["quantities"])
    # two batches per worker: not the local run's two (a lane does not depend on the cut)
    assert there["cluster"]["chunks_done"] >= 4 and not there["cluster"]["failed_chunks"]
    assert _worst(here, there) < 1e-12


class FailingSecond:
    """A stand-in cluster whose second chunk fails on every attempt."""

    n_workers = 2

    def __init__(self):
        self.failures = []

    def run(self, fn, items, name="x"):
        for k, item in enumerate(items):
            if k == 1:
                failed = ChunkFailed(k, item, "MemoryError: made up", 2)
                self.failures.append(failed)
                yield k, failed
            else:
                yield k, fn(item)


def test_a_batch_of_draws_that_fails_on_the_cluster_runs_here():
    from identification.forecasting._batches import run_batches

    stand_in = FailingSecond()
    out = run_batches(np.square, [(np.arange(3.0),), (np.arange(4.0),)], stand_in)
    np.testing.assert_array_equal(out[1], np.arange(4.0) ** 2)
    assert len(stand_in.failures) == 1


def _study(script, args, tmp_path, cluster=None):
    extra = [] if cluster is None else ["--scheduler", cluster.client.scheduler.address]
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / script), *args, *extra],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc.stdout


def _rows(path, key):
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    for r in rows:
        for k in ("synth_s", "fit_s", "host", "commit"):
            r.pop(k, None)
    return sorted(rows, key=lambda r: r[key])


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_the_studies_on_two_workers_write_the_local_rows(cluster, tmp_path):
    """Two drives of the robustness study and two replicates of the coverage study, a
    unit a chunk: the rows are the local ones (to 1e-12), and a rerun resumes."""
    for script, args, name, key in (
            ("robustness_study.py", ["--set", "preload", "--drives", "2"],
             "preload.jsonl", "drive"),
            ("coverage_study.py", ["--replicates", "2", "--batch", "1"], "bundled.jsonl",
             "replicate")):
        here, there = tmp_path / f"{key}_here", tmp_path / f"{key}_there"
        out = ["--out", str(here if key == "drive" else here / name)]
        _study(script, [*args, *out], tmp_path)
        out = ["--out", str(there if key == "drive" else there / name)]
        said = _study(script, [*args, *out], tmp_path, cluster)
        assert "units of work on" in said
        a, b = _rows(here / name, key), _rows(there / name, key)
        assert [r[key] for r in b] == [0, 1]
        assert _worst(a, b) < 1e-12
        again = _study(script, [*args, *out], tmp_path, cluster)
        assert len(_rows(there / name, key)) == 2, again


@pytest.mark.timeout(600)
def test_a_cluster_started_by_the_dask_commands_serves_bsfs_sweep(tmp_path):
    """The README's route: `dask scheduler`, then `dask worker` (processes that know
    nothing of bsfs, without the command's settings in their environment), and the
    command pointed at it by BSFS_SCHEDULER: the local run's sweep."""
    import time

    from distributed import Client

    from bsfs_jax.analysis import load_sweep
    from tests.test_cluster import assert_same_sweep

    dask = str(Path(sys.executable).parent / "dask")
    plain = {k: v for k, v in os.environ.items()
             if k not in ("XLA_FLAGS", "EQX_ON_ERROR", "BSFS_SCHEDULER")}
    file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(file)], cwd=tmp_path, env=plain,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(600):
            if file.exists() and file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(file.read_text())["address"]
        procs.append(subprocess.Popen(
            [dask, "worker", "--scheduler-file", str(file), "--nworkers", "2", "--nthreads",
             "1", "--no-dashboard"], cwd=tmp_path, env=plain, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL))
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
        swept = ["sweep", "--start", "3000", "--stop", "3500", "--num", "5", "--chunk", "2",
                 "--transient", "40", "--periods", "8", "--samples-per-period", "16"]
        cmd = [sys.executable, "-c", "from bsfs_jax.cli import run; run()", *swept]
        for out, extra in (("s0", {}), ("s1", {"BSFS_SCHEDULER": address})):
            proc = subprocess.run([*cmd, "--out", str(tmp_path / out)], cwd=tmp_path,
                                  env={**plain, **extra}, capture_output=True, text=True,
                                  timeout=400)
            assert proc.returncode == 0, proc.stdout[-1500:] + proc.stderr[-1500:]
        said = json.loads((tmp_path / "s1" / "summary.json").read_text())["cluster"]
        assert said["chunks_done"] == 3 + 1 and not said["failed_chunks"]
        assert_same_sweep(load_sweep(tmp_path / "s0" / "sweep.nc"),
                          load_sweep(tmp_path / "s1" / "sweep.nc"))
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs[::-1]:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_the_forecast_coverage_study_on_two_workers_writes_the_local_rows(cluster, tmp_path):
    """Three replicates of the forecast's coverage study (its modal part): the first in
    this process (the truth's values), the others a chunk each in fresh processes of the
    workers; the rows are the local run's."""
    args = ["--part", "modal", "--replicates", "3"]
    _study("forecast_coverage.py", [*args, "--out", str(tmp_path / "here")], tmp_path)
    said = _study("forecast_coverage.py", [*args, "--out", str(tmp_path / "there")], tmp_path,
                  cluster)
    assert "units of work on" in said

    def rows(folder):
        got = [json.loads(line) for f in sorted(folder.glob("100N*.jsonl"))
               for line in f.read_text().splitlines() if line.strip()]
        for r in got:
            r.pop("seconds", None)
        return sorted(got, key=lambda r: r["replicate"])

    a, b = rows(tmp_path / "here"), rows(tmp_path / "there")
    assert [r["replicate"] for r in b] == [0, 1, 2]
    assert _worst(a, b) < 1e-12
