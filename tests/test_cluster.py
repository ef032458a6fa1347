"""Studies on a Dask cluster (`bsfs_jax.cluster`), on a local cluster of two worker
processes: an atlas's rows and a sweep's chunks give the local run's answers (to 1e-12) and
its checkpoint files, so either run resumes from the other's; a worker killed with SIGKILL
loses only its chunk, which runs again; a chunk that always fails is reported with its
cause while the rest completes, and a rerun computes only it; a worker's second chunk of a
kind compiles nothing; `bsfs map` and `bsfs sweep --scheduler` write the local run's files;
bad options end in one line."""

import functools
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("distributed")

from bsfs_jax.analysis import (  # noqa: E402
    SweepConfig,
    VerifySettings,
    atlas,
    sweep,
)
from bsfs_jax.cluster import Cluster, cpu_key, host_cache_dir, open_cluster  # noqa: E402
from tests.test_atlas import row_problem  # noqa: E402  (the same Duffing rows)

GAMMAS = np.array([0.20, 0.28])
OMEGAS = np.array([1.20, 1.22, 1.25, 1.27])
CFG = SweepConfig(transient_periods=60, periods=16, samples_per_period=16, lyapunov=False,
                  batch_size=2, chunk_size=2)
VERIFY = VerifySettings(max_period=8, block_periods=64, max_blocks=2, min_blocks=1,
                        align_periods=8, batch=4)
# A sweep of 18 points in chunks of 4: 5 integration chunks, 2 verification chunks (16 + 2).
SWEEP_GAMMAS = np.linspace(0.1, 0.4, 18)
SWEEP_CFG = SweepConfig(transient_periods=60, periods=16, samples_per_period=16,
                        lyapunov=False, batch_size=2, chunk_size=4)


def fake_bifurcations(omega):
    return [{"x": 0.24 + 0.05 * (omega - 1.2), "kind": "fold", "amplitude": 1.0}]


def _on_worker() -> bool:
    try:
        from distributed import get_worker

        get_worker()
        return True
    except ValueError:
        return False


def row_problem_killing(marker, omega):
    """The row at OMEGAS[1] kills its worker (SIGKILL) the first time it runs there."""
    if _on_worker() and omega == OMEGAS[1] and not os.path.exists(marker):
        open(marker, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return row_problem(omega)


def row_problem_failing(omega):
    """The row at OMEGAS[2] always fails on a worker."""
    if _on_worker() and omega == OMEGAS[2]:
        raise FloatingPointError(f"made-up failure at omega = {omega}")
    return row_problem(omega)


def failing_chunk(bad, fn, item):
    """`fn(item)`, except that integration chunk `bad` (an int item) always fails."""
    if isinstance(item, int) and item == bad:
        raise MemoryError(f"made-up loss of chunk {item}")
    return fn(item)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    cache = os.environ.get("BSFS_CACHE_DIR") or str(tmp_path_factory.mktemp("cache"))
    with Cluster(workers=2, cache=cache) as c:
        yield c


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    return _atlas(row_problem, tmp_path_factory.mktemp("local"))


def _atlas(rows, folder, runner=None):
    return atlas(rows, GAMMAS, OMEGAS, y_name="omega", config=CFG, verify=VERIFY,
                 checkpoint_dir=folder, progress=False, row_bifurcations=fake_bifurcations,
                 runner=runner)


def _sweep(folder, runner=None):
    return sweep(row_problem(1.22), SWEEP_GAMMAS, config=SWEEP_CFG, verify=VERIFY,
                 checkpoint_dir=folder, progress=False, runner=runner)


def assert_same_verdicts(a, b, rows=None):
    rows = slice(None) if rows is None else rows
    for name, v in a.verdicts.items():
        w = b.verdicts[name]
        if np.asarray(v).dtype.kind in "fc":
            np.testing.assert_allclose(np.asarray(w)[rows], np.asarray(v)[rows], rtol=0,
                                       atol=1e-12, err_msg=name)
        else:
            assert (np.asarray(w)[rows] == np.asarray(v)[rows]).all(), name


def assert_same_sweep(a, b, points=slice(None)):
    """The same sweep (arrays (directions, points, ...); period (points,)) at `points`."""
    np.testing.assert_allclose(b.period[points], a.period[points], rtol=0, atol=1e-12)
    for name in ("amplitude", "strobe", "spectrum", "end_state"):
        np.testing.assert_allclose(np.asarray(getattr(b, name))[:, points],
                                   np.asarray(getattr(a, name))[:, points], rtol=0,
                                   atol=1e-12, err_msg=name)
    assert_same_verdicts(a, b, rows=(slice(None), points))


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


@pytest.mark.timeout(60)
def test_the_cache_folder_is_keyed_by_the_cpu_and_bad_options_are_refused(tmp_path, capsys):
    key = cpu_key()
    assert key.startswith("cpu-") and "/" not in key and len(key) <= 60
    assert host_cache_dir(tmp_path) == tmp_path / key
    with pytest.raises(ValueError, match="either"):
        open_cluster("tcp://127.0.0.1:1", 2)
    with pytest.raises(ValueError, match=">= 1"):
        Cluster(workers=0)
    with pytest.raises(ConnectionError, match=r"no Dask scheduler answered at "
                       r"tcp://127\.0\.0\.1:1 within 2 s.*--scheduler"):
        Cluster(scheduler="tcp://127.0.0.1:1", timeout=2)
    from bsfs_jax.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["map", "--workers", "0", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "a number of workers from 1 to 4096, got '0'" in err
    assert err.strip().splitlines()[-1] == ("bsfs map: error: argument --workers: a number "
                                            "of workers from 1 to 4096, got '0'")
    assert not (tmp_path / "x").exists()


@pytest.mark.timeout(120)
def test_dask_is_imported_only_when_a_cluster_opens():
    code = ("import sys, bsfs_jax.cluster, bsfs_jax.analysis; from bsfs_jax.cli import "
            "build_parser; build_parser().parse_args(['map', '--workers', '2', '--x-start', "
            "'1', '--x-stop', '2', '--x-num', '2', '--y-start', '1', '--y-stop', '2', "
            "'--y-num', '2', '--out', 'x']); print(sorted(m for m in ('dask', 'distributed') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=100, cwd=os.path.dirname(os.path.dirname(__file__)))
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr[-2000:]


@pytest.mark.timeout(240)
def test_an_atlas_on_two_workers_gives_the_local_answers_and_files(cluster, local, tmp_path):
    before = len(cluster.records)
    a = _atlas(row_problem, tmp_path / "c", cluster.run)
    assert a.metadata["rows_computed_this_run"] == OMEGAS.size and "failed_rows" not in a.metadata
    assert_same_verdicts(local, a)
    assert a.bifurcations == local.bifurcations
    mine = cluster.records[before:]
    assert len({r["pid"] for r in mine}) == 2, mine  # both worker processes took rows
    assert os.getpid() not in {r["pid"] for r in mine}
    assert all(r["cache"].endswith(cpu_key()) for r in mine)
    # The client wrote each row's checkpoint, under the local run's names; a rerun on the
    # cluster, and a local run, load every row.
    assert _files(tmp_path / "c") == [*(f"atlas_row_{j:05d}.npz" for j in range(OMEGAS.size)),
                                      "manifest.json"]
    again = _atlas(row_problem, tmp_path / "c", cluster.run)
    assert again.metadata["rows_computed_this_run"] == 0
    assert _atlas(row_problem, tmp_path / "c").metadata["rows_computed_this_run"] == 0
    assert_same_verdicts(local, again)


@pytest.mark.timeout(240)
def test_a_sweep_s_chunks_on_two_workers_give_the_local_answers_and_checkpoints(
        cluster, tmp_path):
    here = _sweep(tmp_path / "here")
    before = len(cluster.records)
    there = _sweep(tmp_path / "there", cluster.run)
    assert there.metadata["chunks_computed_this_run"] == 5 == here.metadata["chunks"]
    assert "failed_chunks" not in there.metadata
    assert_same_sweep(here, there)
    kinds = [r["kind"] for r in cluster.records[before:]]
    assert kinds.count("_cold_part") == 5 and kinds.count("_verify_part") == 2, kinds
    # The same checkpoint files: a local run resumes from the cluster's and vice versa.
    assert _files(tmp_path / "here") == _files(tmp_path / "there")
    assert _sweep(tmp_path / "there").metadata["chunks_computed_this_run"] == 0
    n = len(cluster.records)
    again = _sweep(tmp_path / "here", cluster.run)
    assert again.metadata["chunks_computed_this_run"] == 0 and len(cluster.records) == n
    assert_same_sweep(here, again)


@pytest.mark.timeout(240)
def test_a_worker_s_second_chunk_compiles_nothing(cluster, tmp_path):
    """Every chunk after a worker's first of its kind (the same layout, other values)
    neither compiles a program nor reads one from the persistent cache: an atlas's rows
    and a sweep's integration chunks (run by the earlier tests, else here)."""
    def kinds():
        return {r["kind"] for r in cluster.records if r["chunk_of_worker"] > 1}

    if "_row_task" not in kinds():
        _atlas(row_problem, tmp_path / "atlas", cluster.run)
    if "_cold_part" not in kinds():
        _sweep(tmp_path / "sweep", cluster.run)
    later = [r for r in cluster.records if r["chunk_of_worker"] > 1
             and r["kind"] in ("_row_task", "_cold_part")]
    assert {r["kind"] for r in later} == {"_row_task", "_cold_part"}, cluster.records
    for r in later:
        assert r["programs"] == 0 and r["compiled"] == 0, r
    first = [r for r in cluster.records if r["chunk_of_worker"] == 1]
    assert any(r["programs"] > 0 for r in first)  # (the counting sees programs at all)


@pytest.mark.timeout(240)
def test_a_worker_killed_mid_run_loses_only_its_row(cluster, local, tmp_path):
    marker = tmp_path / "killed"
    a = _atlas(functools.partial(row_problem_killing, str(marker)), tmp_path / "ckpt",
               cluster.run)
    assert marker.exists()  # a worker was killed ...
    assert "failed_rows" not in a.metadata and a.metadata["rows_computed_this_run"] == 4
    assert_same_verdicts(local, a)  # ... and its row ran again: the same answers
    assert a.bifurcations == local.bifurcations
    cluster.client.wait_for_workers(2, timeout=60)  # its nanny started a new one


@pytest.mark.timeout(240)
def test_a_failing_row_is_reported_and_a_rerun_resumes(cluster, local, tmp_path):
    a = _atlas(row_problem_failing, tmp_path, cluster.run)
    (f,) = a.metadata["failed_rows"]
    assert f["chunk"] == 2 and f["values"] == [OMEGAS[2]] * 2 and f["attempts"] == 2
    assert f["cause"].startswith("FloatingPointError: made-up failure"), f
    assert (a.motion[2] == "unresolved").all() and "made-up failure" in a.reason[2, 0]
    assert_same_verdicts(local, a, rows=[0, 1, 3])  # the rest completed
    assert cluster.failures[-1].attempts == 2 and "made-up" in cluster.failures[-1].cause
    # The failed row was not saved: a rerun computes it alone, the others are loaded.
    again = _atlas(row_problem, tmp_path, cluster.run)
    assert again.metadata["rows_computed_this_run"] == 1
    assert_same_verdicts(local, again)


@pytest.mark.timeout(240)
def test_a_failing_sweep_chunk_is_reported_and_a_rerun_resumes(cluster, tmp_path):
    here = _sweep(tmp_path / "here")

    def runner(fn, items):
        return cluster.run(functools.partial(failing_chunk, 2, fn), items)

    there = _sweep(tmp_path / "there", runner)
    (f,) = there.metadata["failed_chunks"]
    assert f["stage"] == "integration" and f["chunk"] == 2 and f["attempts"] == 2
    assert f["values"] == [SWEEP_GAMMAS[8], SWEEP_GAMMAS[11]] and f["points"] == 4
    assert f["cause"] == "MemoryError: made-up loss of chunk 2", f
    lost = slice(8, 12)
    assert np.isnan(there.amplitude[0, lost]).all()
    assert (there.verdicts["motion"][0, lost] == "failed").all()
    assert "failed on every attempt on the cluster" in there.verdicts["reason"][0, 8]
    kept = np.r_[0:8, 12:18]
    assert_same_sweep(here, there, kept)  # the rest completed, with the local answers
    again = _sweep(tmp_path / "there", cluster.run)  # computes chunk 2 (and re-verifies)
    assert again.metadata["chunks_computed_this_run"] == 1
    assert "failed_chunks" not in again.metadata
    assert_same_sweep(here, again)


def _cli(argv, out, cluster=None):
    from bsfs_jax.cli import main

    extra = [] if cluster is None else ["--scheduler", cluster.client.scheduler.address]
    assert main([*argv, *extra, "--no-progress", "--out", str(out)]) == 0
    return json.loads((out / "summary.json").read_text())


@pytest.mark.timeout(300)
def test_bsfs_map_and_sweep_on_the_cluster_write_the_local_files(cluster, tmp_path):
    from bsfs_jax.analysis import load_atlas, load_sweep

    small = ["--transient", "40", "--periods", "8", "--samples-per-period", "16"]
    mapped = ["map", "--x", "frequency_hz", "--x-start", "3000", "--x-stop", "3500",
              "--x-num", "2", "--y", "force_n", "--y-start", "4000", "--y-stop", "5000",
              "--y-num", "2", "--no-bifurcations", "--max-blocks", "1", "--block-periods",
              "64", *small]
    here, there = _cli(mapped, tmp_path / "m0"), _cli(mapped, tmp_path / "m1", cluster)
    assert there["cluster"]["chunks_done"] == 2 and not there["cluster"]["failed_chunks"]
    assert [p["motion"] for p in here["points"]] == [p["motion"] for p in there["points"]]
    assert_same_verdicts(load_atlas(tmp_path / "m0" / "atlas.nc"),
                         load_atlas(tmp_path / "m1" / "atlas.nc"))
    # The same files, less the local rows' own sweep checkpoints (a worker's row is one
    # chunk: the client checkpoints it whole, as the local run does after each row).
    assert [f for f in _files(tmp_path / "m0") if "/row_" not in f] == _files(tmp_path / "m1")
    swept = ["sweep", "--start", "3000", "--stop", "3500", "--num", "5", "--chunk", "2",
             *small]
    _cli(swept, tmp_path / "s0")
    there = _cli(swept, tmp_path / "s1", cluster)
    assert there["cluster"]["chunks_done"] == 3 + 1  # integration chunks + verification
    a, b = load_sweep(tmp_path / "s0" / "sweep.nc"), load_sweep(tmp_path / "s1" / "sweep.nc")
    assert_same_sweep(a, b)
    assert _files(tmp_path / "s0") == _files(tmp_path / "s1")


@pytest.mark.timeout(420)
def test_bsfs_map_s_bifurcation_points_on_the_cluster_are_the_local_ones(cluster, tmp_path):
    """Each row's continuation runs on the worker beside its sweep: the folds of the
    100 N resonance (two rows) come back as the local run finds them."""
    from bsfs_jax.analysis import load_atlas

    mapped = ["map", "--x", "frequency_hz", "--x-start", "1000", "--x-stop", "1250",
              "--x-num", "3", "--y", "force_n", "--y-start", "90", "--y-stop", "100",
              "--y-num", "2", "--max-blocks", "1", "--block-periods", "64", "--transient",
              "40", "--periods", "8", "--samples-per-period", "16"]
    here, there = _cli(mapped, tmp_path / "m0"), _cli(mapped, tmp_path / "m1", cluster)
    assert there["cluster"]["chunks_done"] == 2 and not there["cluster"]["failed_chunks"]
    a, b = load_atlas(tmp_path / "m0" / "atlas.nc"), load_atlas(tmp_path / "m1" / "atlas.nc")
    assert_same_verdicts(a, b)
    assert any(p["kind"] == "fold" for p in a.bifurcations), a.bifurcations
    assert len(b.bifurcations) == len(a.bifurcations)
    for p, q in zip(a.bifurcations, b.bifurcations, strict=True):
        assert p["kind"] == q["kind"] and p["y"] == q["y"]
        np.testing.assert_allclose([q["x"], q["amplitude"]], [p["x"], p["amplitude"]],
                                   rtol=0, atol=1e-12)
    assert here["notes"] == there["notes"]
