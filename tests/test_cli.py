"""The `bsfs simulate`, `bsfs params` and `bsfs modes` commands, end to end (in-process)."""

import json
import tomllib

import numpy as np
import pytest

from bsfs_jax.cli import main


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    rc = main(["simulate", "--frequency", "500", "--force", "100", "--periods", "4",
               "--transient", "6", "--samples-per-period", "32", "--out", str(out)])
    assert rc == 0
    return out


def test_simulate_writes_self_describing_outputs(sim_dir):
    summary = json.loads((sim_dir / "summary.json").read_text())
    for key in ("frequency_hz", "force_n", "amplitude_um", "natural_frequencies_hz",
                "temperatures_c", "nut_offset_um", "bearing_offset_um", "screw_elongation_um"):
        assert key in summary
    assert summary["frequency_hz"] == 500.0 and summary["force_n"] == 100.0
    # 100 N far below resonance: close to the static compliance 100 N / k_static.
    static_um = 100.0 / summary["static_stiffness_n_per_um"]
    assert 0.9 * static_um < summary["amplitude_um"] < 1.5 * static_um
    f = summary["natural_frequencies_hz"]
    assert f == sorted(f) and 1000 < f[0] < 1300
    assert summary["temperatures_c"]["nut"] > summary["parameters"]["thermal.ambient_c"]
    lines = (sim_dir / "timeseries.csv").read_text().splitlines()
    header = [ln for ln in lines if ln.startswith("#")]
    assert any("frequency_hz = 500.0" in ln for ln in header)
    data = np.loadtxt(sim_dir / "timeseries.csv", delimiter=",", comments="#",
                      skiprows=len(header) + 1)
    assert data.shape == (4 * 32 + 1, 14)
    amp = 0.5 * np.ptp(data[:, 3]) * 1e6
    assert amp == pytest.approx(summary["amplitude_um"], rel=1e-9)
    assert (sim_dir / "response.png").stat().st_size > 10_000


def test_no_thermal_flag_zeroes_offsets(tmp_path):
    rc = main(["simulate", "--frequency", "500", "--force", "100", "--periods", "2",
               "--transient", "2", "--samples-per-period", "16", "--no-thermal",
               "--out", str(tmp_path)])
    assert rc == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["thermal_enabled"] is False and s["nut_offset_um"] == 0.0


def test_params_prints_loadable_complete_file(capsys, tmp_path):
    assert main(["params", "--preset", "nut-balls-60"]) == 0
    text = capsys.readouterr().out
    data = tomllib.loads(text)
    assert data["nut"]["balls"] == 60.0 and data["bearing"]["balls"] == 16.0
    path = tmp_path / "p.toml"
    path.write_text(text)
    assert main(["modes", "--params", str(path), "--json"]) == 0
    modes = json.loads(capsys.readouterr().out)
    assert len(modes["natural_frequencies_hz"]) == 3


def test_bad_input_is_one_clear_line(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('base = "default"\n[nut]\nbals = 40\n')
    assert main(["modes", "--params", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "bals" in err and "did you mean 'balls'" in err.lower() and "Traceback" not in err
    assert main(["modes", "--set", "masses.nut_kg=-1"]) == 1
    err = capsys.readouterr().err
    assert "masses.nut_kg" in err and "(0, inf)" in err
    assert main(["simulate", "--frequency", "-5", "--force", "1", "--out", str(tmp_path)]) == 1
    assert "--frequency must be positive" in capsys.readouterr().err


def test_solver_failure_is_reported_with_settings(capsys, tmp_path):
    rc = main(["simulate", "--frequency", "500", "--force", "100", "--periods", "2",
               "--transient", "2", "--max-steps", "20", "--out", str(tmp_path)])
    assert rc == 1
    err = capsys.readouterr().err
    assert "maximum number of solver steps" in err and "max_steps=20" in err
    assert not (tmp_path / "summary.json").exists()


def test_version(capsys):
    import bsfs_jax

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"bsfs {bsfs_jax.__version__}"


def test_simulate_verify_reports_the_orbit_not_the_transient(tmp_path):
    # 20 periods at 3500 Hz leave the first mode's free vibration dominant (the samples
    # give ~9 um); the verified orbit's amplitude equals that of a 2 s run (0.669307 um,
    # computed once with a 7000-period sweep), and the summary says it was verified.
    out = tmp_path / "sim"
    assert main(["simulate", "--frequency", "3500", "--force", "5000", "--transient", "20",
                 "--periods", "10", "--verify", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    st = summary["steady_state"]
    assert st["verified"] and st["motion"] == "period-1"
    assert st["amplitude_um"] == pytest.approx(0.669307, rel=1e-4)
    assert summary["amplitude_um"] > 2 * st["amplitude_um"]
    assert st["evidence"]["orbit_residual"] < 1e-6 and st["evidence"]["max_multiplier"] < 1
    # Without --verify the summary says the steady state was not checked.
    out2 = tmp_path / "sim2"
    assert main(["simulate", "--frequency", "3500", "--force", "5000", "--transient", "20",
                 "--periods", "10", "--out", str(out2)]) == 0
    st2 = json.loads((out2 / "summary.json").read_text())["steady_state"]
    assert st2["verified"] is False and "--verify" in st2["reason"]


def _cases(tmp_path):
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00\x81 not text")
    empty = tmp_path / "empty.toml"
    empty.write_text("# nothing set\n")
    a_file = tmp_path / "a_file"
    a_file.write_text("user data\n")
    sim = ["simulate", "--frequency", "500", "--force", "100"]
    return {
        # name: (argv, exit status, text the one line must hold)
        "nan force": (sim[:-1] + ["nan", "--out", str(tmp_path / "o1")], 2,
                      "must be a finite number"),
        "inf frequency": (["simulate", "--frequency", "inf", "--force", "1", "--out",
                           str(tmp_path / "o2")], 2, "must be a finite number"),
        "unknown solver": (sim + ["--solver", "rk99", "--out", str(tmp_path / "o3")], 2,
                           "invalid choice: 'rk99'"),
        "binary parameter file": (["modes", "--params", str(binary)], 1, "not a text (UTF-8)"),
        "empty parameter file": (["modes", "--params", str(empty)], 1, "sets no parameters"),
        "output under a file": (sim + ["--out", str(a_file / "sub")], 1,
                                "is a file, not a folder"),
        "frequency for a static metric": (
            ["sensitivity", "--metric", "static_stiffness", "--frequency", "120", "--out",
             str(tmp_path / "o5")], 1, "--frequency means nothing for --metric static"),
        "sweep range through zero balls": (
            ["sweep", "--param", "nut.balls", "--start", "0", "--stop", "40", "--num", "5",
             "--frequency", "1000", "--out", str(tmp_path / "o4")], 1,
            "'nut.balls' = 0 is outside the allowed range"),
        "sweep kernel checks without the kernel": (
            ["sweep", "--start", "500", "--stop", "600", "--num", "2", "--force", "100",
             "--engine", "vmap", "--kernel-checks", "--out", str(tmp_path / "o14")], 1,
            "--kernel-checks runs the orbit checks on the kernel engine's kernel"),
        "sweep kernel checks without verification": (
            ["sweep", "--start", "500", "--stop", "600", "--num", "2", "--force", "100",
             "--engine", "kernel", "--kernel-checks", "--no-verify", "--out",
             str(tmp_path / "o15")], 1, "drop --no-verify"),
        "synth noise below 0 dB": (["synth", "--frequency", "100", "--force", "10",
                                    "--noise-db", "-1000", "--out", str(tmp_path / "r.csv")],
                                   2, "signal-to-noise ratio from 0 to 120 dB"),
        "identify zero starts": (["identify", "--starts", "0", "--out", str(tmp_path / "o6")],
                                 2, "must be a whole number from 1"),
        "identify unknown prior": (["identify", "--prior", "c_q=1", "--out",
                                    str(tmp_path / "o7")], 1, "is not a fitted parameter"),
        "identify preload and hertz together": (
            ["identify", "--fit", "nut_k,nut_preload", "--out", str(tmp_path / "o8")], 1,
            "set the same joint stiffness"),
        "identify compare without report": (
            ["identify", "--compare", str(tmp_path / "nothing"), "--out",
             str(tmp_path / "o9")], 1, "cannot read"),
        "identify record above the band": (
            ["identify", str(tmp_path / "hf.csv"), "--out", str(tmp_path / "o10")], 1,
            "above the usable band"),
        "identify posterior with too few draws": (
            ["identify", "--posterior", "50", "--out", str(tmp_path / "o12")], 1,
            "at least 100 draws"),
        "identify posterior without priors": (
            ["identify", "--posterior", "200", "--no-priors", "--out", str(tmp_path / "o13")],
            1, "needs priors"),
        "plan-test noise above 120 dB": (["plan-test", "--noise-db", "500", "--out",
                                         str(tmp_path / "o11")], 2, "from 0 to 120 dB"),
    }


def _high_frequency_record(path):
    """A 4000 Hz sine record at 10240 Hz: above the usable band (0.25 x sample rate)."""
    import numpy as np

    import identification as idn

    fs, f = 10240.0, 4000.0
    t = np.arange(4096) / fs
    rng = np.random.default_rng(0)
    meta = dict(frequency_hz=f, force_amplitude_n=100.0, sample_rate_hz=fs, speed_rpm=2000.0,
                ambient_c=20.0)
    idn.write_record_csv(path, (t, 100 * np.sin(2 * np.pi * f * t) + rng.normal(0, 1, t.size),
                                np.sin(2 * np.pi * f * t + 1) + rng.normal(0, .01, t.size)),
                         meta)


@pytest.mark.parametrize("name", ["nan force", "inf frequency", "unknown solver",
                                  "binary parameter file", "empty parameter file",
                                  "output under a file", "sweep range through zero balls",
                                  "sweep kernel checks without the kernel",
                                  "sweep kernel checks without verification",
                                  "frequency for a static metric", "synth noise below 0 dB",
                                  "identify zero starts", "identify unknown prior",
                                  "identify preload and hertz together",
                                  "identify compare without report",
                                  "identify record above the band",
                                  "plan-test noise above 120 dB"])
def test_named_bad_inputs_end_in_one_line(capsys, tmp_path, name):
    if name == "identify record above the band":
        _high_frequency_record(tmp_path / "hf.csv")
    argv, status, text = _cases(tmp_path)[name]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own errors: usage line + one error line
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == status, err
    assert text in err and "Traceback" not in err
    assert len([line for line in err.splitlines() if "error" in line]) == 1
    assert (tmp_path / "a_file").read_text() == "user data\n"  # never overwritten


def test_no_progress_is_accepted_by_every_long_command():
    from bsfs_jax.cli import build_parser

    parser = build_parser()
    for argv in (["sensitivity", "--metric", "amplitude", "--out", "x"],
                 ["optimize", "--metric", "amplitude", "--vary", "nut.preload_n", "--out", "x"],
                 ["identify", "--out", "x"], ["simulate", "--frequency", "1", "--force", "1",
                                              "--out", "x"]):
        assert parser.parse_args([*argv, "--no-progress"]).no_progress


def test_progress_shows_off_a_terminal_only_where_asked(monkeypatch):
    """Progress bars follow the terminal, unless `BSFS_PROGRESS` says 1 (a batch job's
    log) or 0; `--no-progress` always hides them."""
    import io
    import sys
    from types import SimpleNamespace

    from bsfs_jax.cli._common import progress_enabled

    monkeypatch.setattr(sys, "stderr", io.StringIO())  # not a terminal
    quiet, plain = SimpleNamespace(no_progress=True), SimpleNamespace(no_progress=False)
    monkeypatch.delenv("BSFS_PROGRESS", raising=False)
    assert not progress_enabled(plain)
    monkeypatch.setenv("BSFS_PROGRESS", "1")
    assert progress_enabled(plain) and not progress_enabled(quiet)
    monkeypatch.setenv("BSFS_PROGRESS", "0")
    assert not progress_enabled(plain)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert not progress_enabled(plain)
    monkeypatch.setenv("BSFS_PROGRESS", "yes please")  # not 0 or 1: the terminal decides
    assert progress_enabled(plain) and not progress_enabled(quiet)


def test_implausible_values_warn_in_one_line_and_still_run(capsys):
    assert main(["modes", "--set", "nut.preload_n=1e30"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "warning" in line]
    assert len(lines) == 1 and "'nut.preload_n' = 1e+30" in lines[0]
    assert "plausible range [10, 50000]" in lines[0] and "Traceback" not in err
    # The bundled presets are all plausible.
    import warnings

    from bsfs_jax.params import list_presets, preset, validate

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in list_presets():
            validate(preset(name), source=name)


def test_unexpected_errors_are_one_line_with_a_log(capsys, tmp_path, monkeypatch):
    import bsfs_jax.cli._simulate_cmd as sim

    def boom(args):
        raise RuntimeError("something nobody expected\nsecond line")

    monkeypatch.setattr(sim, "run_modes", boom)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert main(["modes"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error: RuntimeError: something nobody" in err
    log = tmp_path / "bsfs" / "bsfs-error.log"
    assert "Traceback" in log.read_text() and "second line" in log.read_text()


def test_readme_lists_every_preset_and_command():
    from pathlib import Path

    from bsfs_jax.cli import build_parser
    from bsfs_jax.params import list_presets

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert [p for p in list_presets() if f"`{p}`" not in readme] == []
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert [c for c in sub.choices if f"`bsfs {c}" not in readme] == []


def test_modes_and_argument_errors_do_not_load_the_solvers(tmp_path):
    """`bsfs modes` and a mistyped command answer without importing the solvers (diffrax,
    optimistix): the packages load their public names on first use."""
    import subprocess
    import sys

    code = ("import sys\nfrom bsfs_jax.cli import main\n"
            "codes = [main(['modes', '--json']), main(['modes', '--speed', '-5'])]\n"
            "heavy = sorted(m for m in ('diffrax', 'optimistix', 'lineax', 'bsfs_jax.solvers') "
            "if m in sys.modules)\n"
            "print('CODES', codes, 'HEAVY', heavy)\n")
    env = {**__import__("os").environ, "BSFS_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300)
    line = [x for x in out.stdout.splitlines() if x.startswith("CODES")]
    assert line == ["CODES [0, 1] HEAVY []"], out.stdout[-2000:] + out.stderr[-2000:]


def test_bsfs_command_exits_at_once_with_its_output_and_exit_work_done(tmp_path):
    """The console command (`cli.run`) ends the process without the interpreter's teardown:
    its output arrives whole, the exit code is main's, and the CLI's exit work (the
    benchmarks' compile statistics) is written; a user error exits 1 with its one line."""
    import json
    import subprocess
    import sys

    env = {**__import__("os").environ, "BSFS_CACHE_DIR": str(tmp_path / "cache"),
           "BSFS_COMPILE_STATS": str(tmp_path / "stats.json")}
    cmd = [sys.executable, "-c", "from bsfs_jax.cli import run; run()"]
    ok = subprocess.run(cmd + ["modes", "--json"], capture_output=True, text=True, env=env,
                        timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert json.loads(ok.stdout)  # the whole JSON document, flushed before the exit
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert set(stats) == {"compiles", "compile_s", "peak_rss_mb"} and stats["peak_rss_mb"] > 0
    bad = subprocess.run(cmd + ["modes", "--speed", "-5"], capture_output=True, text=True,
                         env=env, timeout=300)
    assert bad.returncode == 1 and bad.stderr.count("\n") == 1 and "error" in bad.stderr


def test_continue_starts_harmonic_balance_high_where_a_joint_opens():
    # Where the force opens a joint inside the interval (the linearised lift-off test of
    # the design metrics), hb starts at 64 harmonics; elsewhere, or when given, as asked.
    from bsfs_jax import preset
    from bsfs_jax.cli._continue_cmd import CONTACT_HARMONICS, HARMONICS, starting_harmonics
    from bsfs_jax.design import opens_joint

    p = preset()
    assert opens_joint(p, 100.0, 1000.0, 1250.0) and not opens_joint(p, 10.0, 1000.0, 1250.0)
    h, note = starting_harmonics(p, 100.0, 1250.0, 1000.0, "auto", None)
    assert h == CONTACT_HARMONICS and "loses contact" in note
    assert starting_harmonics(p, 100.0, 1000.0, 1250.0, "hb", None)[0] == CONTACT_HARMONICS
    assert starting_harmonics(p, 10.0, 1000.0, 1250.0, "auto", None) == (HARMONICS, None)
    assert starting_harmonics(p, 100.0, 1000.0, 1250.0, "auto", 16) == (16, None)
    assert starting_harmonics(p, 100.0, 1000.0, 1250.0, "shooting", None) == (HARMONICS, None)
    # a looser tolerance needs half as many near the peak
    assert starting_harmonics(p, 100.0, 1000.0, 1250.0, "auto", None, 1e-4)[0] == \
        CONTACT_HARMONICS // 2


def test_kernel_checks_reach_the_verification(capsys, tmp_path, monkeypatch):
    """`--kernel-checks` asks the verification for its orbit checks on the kernel
    (`VerifySettings.kernel_checks`), for `sweep` and `map`; without it they stay vmapped."""
    import bsfs_jax.analysis as analysis
    from bsfs_jax.cli._common import CLIError

    seen = []

    def capture(*args, verify=None, **kwargs):
        seen.append(verify.kernel_checks)
        raise CLIError("captured")

    monkeypatch.setattr(analysis, "sweep", capture)
    monkeypatch.setattr(analysis, "atlas", capture)
    base = ["sweep", "--start", "500", "--stop", "600", "--num", "2", "--force", "100",
            "--engine", "kernel"]
    for k, extra in enumerate(([], ["--kernel-checks"])):
        assert main(base + extra + ["--out", str(tmp_path / f"s{k}")]) == 1
    grid = ["map", "--x-start", "500", "--x-stop", "600", "--x-num", "2", "--y-start", "100",
            "--y-stop", "200", "--y-num", "2", "--engine", "kernel", "--no-bifurcations"]
    for k, extra in enumerate(([], ["--kernel-checks"])):
        assert main(grid + extra + ["--out", str(tmp_path / f"m{k}")]) == 1
    assert "captured" in capsys.readouterr().err
    assert seen == [False, True, False, True]
