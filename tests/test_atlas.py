"""Two-parameter atlases: a double-well Duffing atlas (verified labels, NetCDF round trip,
resume from the checkpoint folder, bifurcation curves, plots) and the `bsfs map` command."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from bsfs_jax.analysis import (
    VERDICT_FIELDS,
    Atlas,
    SweepConfig,
    SweepProblem,
    VerifySettings,
    atlas,
    load_atlas,
)
from bsfs_jax.plotting import plot_atlas_amplitude, plot_atlas_motion
from tests.textbook import duffing

# Double-well Duffing x'' + 0.3 x' - x + x^3 = gamma cos(omega t): x = gamma, y = omega.
GAMMAS = np.array([0.20, 0.28])
OMEGAS = np.array([1.20, 1.25])
CFG = SweepConfig(transient_periods=60, periods=16, samples_per_period=16, lyapunov=False,
                  batch_size=2, chunk_size=2)
VERIFY = VerifySettings(max_period=8, block_periods=64, max_blocks=2, min_blocks=1,
                        align_periods=8, batch=4)


def gamma_setup(data, gamma):
    delta, alpha, beta, omega = data
    return (delta, alpha, beta, gamma, omega), 2.0 * jnp.pi / omega


def row_problem(omega):
    return SweepProblem(duffing, gamma_setup, jnp.array([0.3, -1.0, 1.0, omega]),
                        jnp.array([1.0, 0.0]), "gamma", unit="1", observe=0,
                        state_names=("x", "v"), state_units=("1", "1"), time_unit="1")


CALLS = []


def fake_bifurcations(omega):
    """A fold in every row (drifting by less than a grid step) and a period doubling in
    the first row only: two curves, kinds never mixed."""
    import threading

    CALLS.append((omega, threading.current_thread().name))
    out = [{"x": 0.24 + 0.05 * (omega - 1.2), "kind": "fold", "amplitude": 1.0}]
    if omega < 1.22:
        out.append({"x": 0.245, "kind": "period-doubling", "amplitude": 1.1})
    return out


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("atlas")


@pytest.fixture(scope="module")
def duffing_atlas(folder):
    return atlas(row_problem, GAMMAS, OMEGAS, y_name="omega", y_unit="rad/s", config=CFG,
                 verify=VERIFY, checkpoint_dir=folder / "ckpt", progress=False,
                 row_bifurcations=fake_bifurcations, x_label="Forcing amplitude gamma",
                 y_label="Forcing frequency omega", metadata={"test": True})


def test_atlas_shapes_and_verified_period_one(duffing_atlas):
    a = duffing_atlas
    assert a.shape == (2, 2) and a.x_name == "gamma" and a.y_name == "omega"
    assert set(a.verdicts) == set(VERDICT_FIELDS)
    for name in VERDICT_FIELDS:
        assert np.shape(a.verdicts[name]) == (2, 2), name
    assert a.motion.dtype.kind == "U" and a.verified.dtype == bool
    # gamma = 0.20: the small period-1 orbit in one well, verified in both rows.
    for j in range(2):
        assert a.motion[j, 0] == "period-1", a.reason[j, 0]
        assert a.verified[j, 0] and a.period_n[j, 0] == 1
        assert a.orbit_residual[j, 0] < 1e-6 and a.max_multiplier[j, 0] < 1
    assert a.metadata["rows_computed_this_run"] == 2 and a.metadata["test"] is True
    assert [b["y"] for b in a.bifurcations] == [1.2, 1.2, 1.25]
    # The rows' bifurcation runs went to worker threads beside the sweeps, once per row.
    assert sorted(w for w, _ in CALLS[:2]) == sorted(OMEGAS.tolist())
    assert all(name.startswith("bsfs-row") for _, name in CALLS[:2])


def test_atlas_netcdf_round_trip(duffing_atlas, folder):
    path = folder / "atlas.nc"
    duffing_atlas.save(path)
    b = load_atlas(path)
    assert b.x_name == "gamma" and b.y_unit == "rad/s" and b.y_label.startswith("Forcing")
    np.testing.assert_array_equal(b.x, GAMMAS)
    np.testing.assert_array_equal(b.y, OMEGAS)
    for name, v in duffing_atlas.verdicts.items():
        if v.dtype.kind in "fc":
            np.testing.assert_array_equal(b.verdicts[name], v, err_msg=name)
        else:
            assert b.verdicts[name].dtype == v.dtype or v.dtype.kind == "U", name
            assert (b.verdicts[name] == v).all(), name
    assert b.bifurcations == duffing_atlas.bifurcations
    ds = duffing_atlas.to_xarray()
    assert ds["motion"].dims == ("omega", "gamma")
    assert ds["gamma"].attrs["units"] == "1" and ds["omega"].attrs["units"] == "rad/s"
    assert json.loads(ds.attrs["config"])["periods"] == 16


def test_atlas_rerun_loads_finished_rows(duffing_atlas, folder):
    calls = len(CALLS)
    again = atlas(row_problem, GAMMAS, OMEGAS, y_name="omega", y_unit="rad/s", config=CFG,
                  verify=VERIFY, checkpoint_dir=folder / "ckpt", progress=False,
                  row_bifurcations=fake_bifurcations)
    assert again.metadata["rows_computed_this_run"] == 0 and len(CALLS) == calls
    assert (again.motion == duffing_atlas.motion).all()
    np.testing.assert_array_equal(again.amplitude, duffing_atlas.amplitude)
    assert again.bifurcations == duffing_atlas.bifurcations
    # Another grid in the same folder is refused, not mixed in.
    with pytest.raises(ValueError, match="different"):
        atlas(row_problem, GAMMAS, OMEGAS + 0.01, y_name="omega", config=CFG,
              verify=VERIFY, checkpoint_dir=folder / "ckpt", progress=False)


def _synthetic(points):
    shape = (3, 5)
    verdicts = {"motion": np.full(shape, "period-1"), "verified": np.ones(shape, bool),
                "amplitude": np.ones(shape), "reason": np.full(shape, "ok")}
    return Atlas("f", "Hz", "P", "N", np.linspace(0, 4, 5), np.array([0.0, 1.0, 2.0]),
                 verdicts, bifurcations=points)


def test_curves_join_same_kind_in_adjacent_rows():
    pts = [{"x": 1.0, "y": 0.0, "kind": "fold", "amplitude": 1.0},
           {"x": 2.5, "y": 1.0, "kind": "fold", "amplitude": 2.0},       # 1.5 steps away
           {"x": 1.2, "y": 1.0, "kind": "period-doubling", "amplitude": 1.0},
           {"x": 3.0, "y": 2.0, "kind": "neimark-sacker", "amplitude": 1.0}]
    curves = _synthetic(pts).curves()
    fold = [c for c in curves if c["kind"] == "fold"]
    assert len(fold) == 1 and fold[0]["x"] == [1.0, 2.5] and fold[0]["y"] == [0.0, 1.0]
    assert sorted(c["kind"] for c in curves) == ["fold", "neimark-sacker", "period-doubling"]
    assert all(len(c["x"]) == 1 for c in curves if c["kind"] != "fold")
    # Beyond 3 grid steps, or two rows apart: not joined.
    far = [{"x": 0.0, "y": 0.0, "kind": "fold", "amplitude": 1.0},
           {"x": 3.5, "y": 1.0, "kind": "fold", "amplitude": 1.0}]
    assert len(_synthetic(far).curves()) == 2
    skip = [far[0], {"x": 0.1, "y": 2.0, "kind": "fold", "amplitude": 1.0}]
    assert len(_synthetic(skip).curves()) == 2
    # Two folds drifting together by more than their distance: joined without crossing
    # (nearest-first would join 2.0 to 1.0 and 2.3 to 0.0).
    pair = [{"x": x, "y": y, "kind": "fold", "amplitude": 1.0}
            for x, y in ((2.0, 0.0), (2.3, 0.0), (0.0, 1.0), (1.0, 1.0))]
    assert sorted(c["x"] for c in _synthetic(pair).curves()) == [[2.0, 0.0], [2.3, 1.0]]


def test_atlas_curves_summary_and_plots(duffing_atlas):
    curves = duffing_atlas.curves()
    fold = [c for c in curves if c["kind"] == "fold"]
    assert len(fold) == 1 and fold[0]["y"] == [1.2, 1.25]
    s = duffing_atlas.summary()
    json.dumps(s, allow_nan=False)
    assert sum(s["motion_counts"].values()) == 4 and 0.25 <= s["verified_fraction"] <= 1
    p = s["points"][0]
    assert p["gamma"] == 0.2 and p["omega"] == 1.2 and p["motion"] == "period-1"
    assert set(p["evidence"]) == {"orbit_residual", "max_multiplier", "lyapunov_per_period",
                                  "lyapunov_per_period_95", "transient"}
    fig = plot_atlas_motion(duffing_atlas)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "Forcing amplitude gamma [1]"
    assert ax.get_ylabel() == "Forcing frequency omega [rad/s]"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "period-1" in labels and "fold" in labels and "period doubling" in labels
    fig = plot_atlas_amplitude(duffing_atlas, unit_scale=1.0, unit="1")
    assert fig.axes[0].get_xlabel().startswith("Forcing amplitude")
    assert fig.axes[1].get_ylabel() == "Amplitude (half peak-to-peak) [1]"


def test_cli_map_writes_outputs(tmp_path):
    from bsfs_jax.cli import main

    out = tmp_path / "map"
    argv = ["map", "--x", "frequency_hz", "--x-start", "3000", "--x-stop", "3500",
            "--x-num", "2", "--y", "force_n", "--y-start", "4000", "--y-stop", "5000",
            "--y-num", "2", "--no-bifurcations", "--transient", "40", "--periods", "8",
            "--samples-per-period", "16", "--max-blocks", "1",
            "--block-periods", "64", "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    for name in ("atlas.nc", "summary.json", "motion.png", "amplitude.png"):
        assert (out / name).stat().st_size > 0, name
    s = json.loads((out / "summary.json").read_text())
    assert len(s["points"]) == 4 and s["x_name"] == "frequency_hz" and s["y_name"] == "force_n"
    p = s["points"][0]
    assert {"frequency_hz", "force_n", "amplitude", "motion", "verified", "evidence",
            "reason"} <= set(p)
    assert p["frequency_hz"] == 3000.0 and p["force_n"] == 4000.0
    assert load_atlas(out / "atlas.nc").shape == (2, 2)


def test_cli_map_bad_input_is_one_line(tmp_path, capsys):
    from bsfs_jax.cli import main

    base = ["map", "--x-start", "3000", "--x-stop", "3500", "--x-num", "2",
            "--y-start", "4000", "--y-stop", "5000", "--y-num", "2", "--out", str(tmp_path)]
    for extra, word in ((["--y", "nut.preloadn"], "unknown parameter"),
                        (["--y", "force_n", "--x-num", "0"], "--x-num"),
                        (["--y", "force_n", "--y-stop", "4000"], "--y-start"),
                        (["--y", "force_n", "--x-start", "-1"], "positive"),
                      (["--y", "force_n", "--engine", "vmap", "--kernel-checks"],
                       "--kernel-checks")):
        capsys.readouterr()
        assert main(base + extra) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err, err


def _duffing_components(t, y, args):
    delta, alpha, beta, gamma, omega = args
    return y[1], gamma * jnp.cos(omega * t) - delta * y[1] - alpha * y[0] - beta * y[0] ** 3


def test_atlas_as_one_grid_gives_the_rows_answers(duffing_atlas, tmp_path):
    """`batch="grid"`: both rows as one sweep of four points (the map engine, and the
    kernel engine in interpret mode) give the row-by-row verdicts; a rerun loads them."""
    import dataclasses

    def kernel_row(omega):
        return dataclasses.replace(row_problem(omega), component_field=_duffing_components)

    runs = {
        "map": atlas(row_problem, GAMMAS, OMEGAS, y_name="omega", config=CFG, verify=VERIFY,
                     checkpoint_dir=tmp_path / "g", progress=False, batch="grid"),
        "kernel": atlas(kernel_row, GAMMAS, OMEGAS, y_name="omega", verify=VERIFY,
                        config=dataclasses.replace(CFG, engine="kernel", kernel_block=4),
                        progress=False, batch="grid"),
    }
    for name, grid in runs.items():
        assert grid.metadata["rows_batched_as_one_grid"] == 2, name
        for k in ("motion", "period_n", "verified"):
            np.testing.assert_array_equal(grid.verdicts[k], duffing_atlas.verdicts[k])
        np.testing.assert_allclose(grid.verdicts["amplitude"],
                                   duffing_atlas.verdicts["amplitude"], rtol=1e-5)
    again = atlas(row_problem, GAMMAS, OMEGAS, y_name="omega", config=CFG, verify=VERIFY,
                  checkpoint_dir=tmp_path / "g", progress=False, batch="grid")
    assert again.metadata["rows_computed_this_run"] == 0
    np.testing.assert_array_equal(again.verdicts["motion"], runs["map"].verdicts["motion"])
    with pytest.raises(ValueError, match="batch must be"):
        atlas(row_problem, GAMMAS, OMEGAS, y_name="omega", batch="columns")


def test_cli_map_row_continuation_by_harmonic_balance_finds_the_shooting_folds(tmp_path):
    """`bsfs map --method hb` (what auto picks where its error estimate passes) locates the
    row's folds where `--method shooting` does (the 100 N branch over 1050-1150 Hz, whose
    folds near 1088 and 1090 Hz the forecast's coverage study uses)."""
    from bsfs_jax.cli import main

    found = {}
    for method in ("hb", "shooting"):
        out = tmp_path / method
        argv = ["map", "--x", "frequency_hz", "--x-start", "1050", "--x-stop", "1150",
                "--x-num", "2", "--y", "force_n", "--y-start", "100", "--y-stop", "101",
                "--y-num", "1", "--method", method, "--transient", "40", "--periods", "8",
                "--samples-per-period", "16", "--max-blocks", "1", "--block-periods", "64",
                "--no-progress", "--out", str(out)]
        assert main(argv) == 0
        s = json.loads((out / "summary.json").read_text())
        assert not s["notes"], s["notes"]
        found[method] = sorted(b["x"] for b in s["bifurcations"] if b["kind"] == "fold")
    assert len(found["shooting"]) >= 2, found
    assert len(found["hb"]) == len(found["shooting"]), found
    np.testing.assert_allclose(found["hb"], found["shooting"], rtol=1e-5)
