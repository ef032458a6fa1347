"""Property-based fuzzing (hypothesis) of the TOML parameter loader and the command line.

Properties:

- the loader either returns valid parameters or raises `ParameterError` with a one-line
  message that names the file (and the key or line); never another exception, never a hang;
- a command line that is wrong in at least one way (a non-finite, non-numeric or
  out-of-range number, an unknown flag or choice, a bad parameter file, preset or --set,
  an output path under a file, ...) ends with exit status 1 or 2 and one error line (after
  argparse's usage, for its own errors), writes nothing, and is refused *before* anything
  is computed: every computing entry point is replaced by a function that fails the test.

The strategies draw only invalid command lines (a valid one would start a simulation);
`identify`, `synth` and `plan-test` are left to their own tests.
"""

import contextlib
import io
import json
import math
import os
import signal
import warnings

import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from bsfs_jax.cli import main
from bsfs_jax.design import METRICS
from bsfs_jax.params import (
    KEYS,
    BallScrewParams,
    ParameterError,
    ParameterWarning,
    list_presets,
    load_params,
    validate,
)
from bsfs_jax.params._vocabulary import SECTIONS

# No example database: nothing is written into the work tree (the examples that found
# bugs are kept below as explicit @example cases instead).
FAST = settings(max_examples=150, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@contextlib.contextmanager
def _time_limit(seconds: float):
    """Fail (instead of hanging the suite) when the body runs longer than `seconds`."""

    def alarm(signum, frame):
        raise AssertionError(f"took more than {seconds} s: a hang?")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# -- the TOML loader ---------------------------------------------------------------------
KEY_NAMES = sorted({k.key for k in KEYS})
BARE = set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")
TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
               max_size=12)


def _key_text(name: str) -> str:
    """A TOML key: bare when it can be, else a basic string."""
    return name if name and set(name) <= BARE else json.dumps(name, ensure_ascii=False)


def _float_text(x: float) -> str:
    if math.isnan(x):
        return "nan"
    return ("inf" if x > 0 else "-inf") if math.isinf(x) else repr(x)


@st.composite
def _misspelt(draw, words):
    word = draw(st.sampled_from(words))
    i = draw(st.integers(0, len(word) - 1))
    how = draw(st.sampled_from(["drop", "double", "swap", "upper", "newline"]))
    if how == "drop":
        return word[:i] + word[i + 1:]
    if how == "double":
        return word[:i] + word[i] * 2 + word[i + 1:]
    if how == "swap" and i + 1 < len(word):
        return word[:i] + word[i + 1] + word[i] + word[i + 2:]
    if how == "newline":
        return word[:i] + "\n" + word[i:]
    return word.upper()


_toml_string = TEXT.map(lambda s: json.dumps(s, ensure_ascii=False).replace("\x7f", r"\u007f"))
NUMBER = st.one_of(
    st.floats().map(_float_text),  # nan, inf, huge, tiny, negative, zero
    st.integers(-10**30, 10**30).map(str),
    st.integers(10**300, 10**400).map(str),  # beyond float
    st.sampled_from(["0", "-0.0", "1e308", "-1e308", "1e-320", "1e400", "+inf", "-nan",
                     "0x7fffffff", "1_000", "9" * 5000]),
)
WRONG_TYPE = st.one_of(
    _toml_string,
    st.sampled_from(["true", "false", "[]", "[1, 2]", "{}", "{ a = 1 }", "1979-05-27",
                     "07:32:00", "'nan'", '"40"', "[[1]]", "[" * 3000 + "]" * 3000]),
)


def _valid(key):
    lo = key.low if key.low is not None else -1e3
    hi = key.high if key.high is not None else 1e4
    if key.kind == "bool":
        return st.sampled_from(["true", "false"])
    return st.floats(lo, hi, exclude_min=key.low_open, exclude_max=key.high_open,
                     allow_nan=False).map(_float_text)


def _value(key):
    return st.one_of(_valid(key), NUMBER, WRONG_TYPE) if key else st.one_of(NUMBER, WRONG_TYPE)


@st.composite
def toml_documents(draw):
    """TOML built from the real vocabulary: real, misspelt or foreign sections and keys
    (also keys of another section), with valid, extreme or wrongly typed values."""
    lines = []
    if draw(st.booleans()):
        base = draw(st.one_of(st.sampled_from(list_presets()), _misspelt(list_presets()),
                              TEXT))
        lines.append(f"base = {draw(st.one_of(st.just(json.dumps(base)), NUMBER))}")
    sections = draw(st.lists(st.one_of(st.sampled_from(SECTIONS), _misspelt(SECTIONS),
                                       st.just("nut.balls"), TEXT), max_size=4, unique=True))
    for section in sections:
        lines.append(f"[{_key_text(section)}]" if "." not in section else f"[{section}]")
        own = [k for k in KEYS if k.section == section]
        names = draw(st.lists(st.one_of(st.sampled_from(own) if own else st.nothing(),
                                        st.sampled_from(KEYS),
                                        _misspelt(KEY_NAMES).map(lambda n: (n,)),
                                        TEXT.map(lambda n: (n,))),
                              max_size=5))
        for entry in names:
            key = entry if not isinstance(entry, tuple) else None
            name = key.key if key else entry[0]
            lines.append(f"{_key_text(name)} = {draw(_value(key))}")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def toml_path(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_toml") / "params.toml"


def _check_loader(path):
    """The property: valid parameters, or one ParameterError line naming the file."""
    with _time_limit(10), warnings.catch_warnings():
        warnings.simplefilter("ignore", ParameterWarning)
        try:
            params = load_params(path)
        except ParameterError as exc:
            message = str(exc)
            assert message and message.isprintable(), repr(message)  # one line, no escapes
            assert str(path) in message, message
            return
        assert isinstance(params, BallScrewParams)
        validate(params)


@given(doc=toml_documents())
@example(doc="[nut]\nballs = " + "9" * 400 + "\n")  # beyond float: was an OverflowError
@example(doc='[nut]\n"bal\\nls" = 40\n')  # a newline in a key: was a two-line message
@example(doc="a = " + "[" * 5000 + "]" * 5000 + "\n")  # was a RecursionError
@example(doc="a = " + "1" * 5000 + "\n")  # > 4300 digits: was a bare ValueError
@example(doc="[screw]\nyoungs_modulus_gpa = 1e300\n")  # overflows in SI units
@example(doc='base = "nope"\n')  # an unknown base: the message now names the file
@FAST
def test_loader_on_vocabulary_documents(toml_path, doc):
    toml_path.write_text(doc, encoding="utf-8")
    _check_loader(toml_path)


@given(text=st.text(max_size=300))
@settings(max_examples=100, deadline=None, database=None)
def test_loader_on_random_text(toml_path, text):
    toml_path.write_bytes(text.encode("utf-8", "surrogatepass"))
    _check_loader(toml_path)


@given(data=st.binary(max_size=300))
@example(data=b"\xff\xfe\x00\x81 not text")
@example(data=b"\xef\xbb\xbf[nut]\nballs = 40\n")  # a byte-order mark
@settings(max_examples=100, deadline=None, database=None)
def test_loader_on_random_bytes(toml_path, data):
    toml_path.write_bytes(data)
    _check_loader(toml_path)


# -- the command line --------------------------------------------------------------------
class ReachedComputation(BaseException):
    """Raised by every computing entry point: the command line was not refused up front.
    A BaseException, so the CLI's safety net (`except Exception`) cannot swallow it."""


_COMPUTING = [
    "bsfs_jax.cli._simulate_cmd._report_fn", "bsfs_jax.machine.simulate",
    "bsfs_jax.machine.bsfs_family", "bsfs_jax.analysis.sweep", "bsfs_jax.analysis.atlas",
    "bsfs_jax.solvers.continue_orbits", "bsfs_jax.design.sensitivities",
    "bsfs_jax.design.finite_difference_sensitivities", "bsfs_jax.design.check_gradient",
    "bsfs_jax.design.optimize", "bsfs_jax.design.verify_by_simulation",
    "bsfs_jax.reproduce.reproduce",
]


@pytest.fixture(scope="module")
def no_computing():
    def refuse(*args, **kwargs):
        raise ReachedComputation(f"called with {args!r:.200}")

    with pytest.MonkeyPatch.context() as mp:
        for target in _COMPUTING:
            mp.setattr(target, refuse)
        # Warm up outside the time limit: the first call imports every command module and
        # starts JAX (seconds on a loaded machine).
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            main(["params", "--preset", "cold"])
        yield


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Bad parameter files, a good one, and a plain file that must never be touched."""
    root = tmp_path_factory.mktemp("fuzz_cli")
    bad = {
        "missing": "",
        "binary": b"\xff\xfe\x00\x81 not text",
        "empty": "# nothing set\n",
        "not toml": "[nut\nballs = = 3\n",
        "misspelt key": "[nut]\nbals = 40\n",
        "out of range": "[masses]\nnut_kg = -1\n",
        "huge integer": "[nut]\nballs = " + "9" * 400 + "\n",
        "wrong type": "[nut]\nballs = 'forty'\n",
        "unknown base": 'base = "nope"\n',
        "deep": "a = " + "[" * 5000 + "]" * 5000 + "\n",
    }
    paths = {}
    for i, (name, content) in enumerate(bad.items()):
        path = root / f"bad{i}.toml"
        if name != "missing":
            (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
        paths[name] = path
    paths["directory"] = root
    good = root / "good.toml"
    good.write_text("[nut]\npreload_n = 1200\n")
    plain = root / "user_file"
    plain.write_text("user data\n")
    return {"bad": paths, "good": good, "plain": plain, "root": root}


# Flag domains: (kind, low, low included, high, high included); None: unbounded.
def F(low=None, low_in=True, high=None, high_in=True):
    return ("float", low, low_in, high, high_in)


def I(low, high):  # noqa: E743 - reads as the integer domain [low, high]
    return ("int", low, True, high, True)


POS, TOL = F(0.0, False), F(0.0, False, 1.0, False)
SOLVERS = ["dopri5-fused", "tsit5", "dopri5", "dopri8", "kvaerno5"]
PARAMS_FLAGS = ("--params", "--preset", "--set")

COMMANDS = {
    "simulate": dict(
        base={"--frequency": "500", "--force": "100"}, out=True,
        numbers={"--frequency": POS, "--force": F(0.0), "--speed": F(0.0, True, 20000.0),
                 "--rtol": TOL, "--atol": POS, "--periods": I(2, 10**6),
                 "--transient": I(0, 10**7), "--samples-per-period": I(8, 10**4),
                 "--max-steps": I(1, 10**10)},
        choices={"--solver": SOLVERS}, switches=["--no-thermal", "--verify", "--no-progress"],
        extra=[]),
    "params": dict(base={}, out=False, numbers={}, choices={}, switches=[], extra=[]),
    "modes": dict(base={}, out=False, numbers={"--speed": F(0.0, True, 20000.0),
                                               "--static-force": F()},
                  choices={}, switches=["--no-thermal", "--json"], extra=[]),
    "sweep": dict(
        base={"--start": "400", "--stop": "600", "--num": "3"}, out=True,
        numbers={"--start": POS, "--stop": POS, "--num": I(1, 10**5), "--frequency": POS,
                 "--force": F(0.0), "--continued-transient": I(1, 10**7),
                 "--periods": I(1, 10**5), "--samples-per-period": I(8, 10**4),
                 "--rtol": TOL, "--atol": POS, "--max-steps": I(1, 10**10),
                 "--batch": I(0, 10**4), "--chunk": I(1, 10**5)},
        choices={"--solver": SOLVERS, "--mode": ["cold", "continued"],
                 "--direction": ["up", "down", "both"]},
        switches=["--no-verify", "--log-waterfall", "--no-folds", "--lyapunov", "--shard",
                  "--no-progress"],
        extra=[{"--param": "nut.bals", "--frequency": "500"},
               {"--param": "thermal.enabled", "--frequency": "500"},
               {"--param": "nut.balls", "--start": "0", "--stop": "40", "--frequency": "500"},
               {"--param": "nut.contact_angle_deg", "--start": "95", "--stop": "30",
                "--frequency": "500"},
               {"--param": "nut.preload_n"},  # no --frequency
               {"--transient": "abc"}, {"--transient": "-3"}, {"--transient": "0"},
               {"--num": "100000", "--periods": "100000"},
               {"--param": "force_n", "--start": "-10", "--stop": "10",
                "--frequency": "500"}]),
    "map": dict(
        base={"--x-start": "400", "--x-stop": "600", "--x-num": "3", "--y-start": "10",
              "--y-stop": "100", "--y-num": "2"}, out=True,
        numbers={"--x-start": POS, "--x-stop": POS, "--x-num": I(1, 10**4),
                 "--y-start": F(0.0), "--y-stop": F(0.0), "--y-num": I(1, 10**4),
                 "--frequency": POS, "--force": POS, "--transient": I(1, 10**7),
                 "--periods": I(1, 10**5), "--samples-per-period": I(8, 10**4),
                 "--rtol": TOL, "--atol": POS, "--max-steps": I(1, 10**10),
                 "--batch": I(0, 10**4), "--chunk": I(1, 10**5), "--max-period": I(1, 1000),
                 "--max-blocks": I(1, 1000), "--block-periods": I(32, 10**6), "--ds": POS,
                 "--max-points": I(2, 10**6)},
        choices={"--solver": SOLVERS}, switches=["--lyapunov", "--no-bifurcations", "--shard",
                                                 "--no-progress"],
        extra=[{"--x": "force_n", "--y": "force_n"},
               {"--x": "damping_scale"}, {"--x": "nut.bals"}, {"--y": "thermal.enabled"},
               {"--x-start": "700", "--x-stop": "600"},
               {"--y": "nut.balls", "--y-start": "0", "--y-stop": "40"},
               {"--y": "damping_scale", "--y-start": "-1", "--y-stop": "2"},
               {"--x": "nut.preload_n", "--x-start": "100", "--x-stop": "200"},  # no --freq
               {"--band": ["900", "800"]}, {"--band": ["-5", "800"]},
               {"--x-num": "10000", "--y-num": "10000"}]),
    "continue": dict(
        base={"--start": "400", "--stop": "600"}, out=True,
        numbers={"--start": POS, "--stop": POS, "--force": POS, "--harmonics": I(1, 1024),
                 "--hb-tol": POS, "--ds": POS, "--ds-max": POS, "--max-points": I(2, 10**6),
                 "--transient-periods": I(0, 10**7), "--rtol": TOL, "--atol": POS},
        choices={"--method": ["auto", "hb", "shooting"], "--dof": ["bearing", "screw", "nut"],
                 "--solver": ["dopri8", "dopri5", "tsit5", "kvaerno5"]},
        switches=["--no-cross-check", "--no-progress"],
        extra=[{"--start": "500", "--stop": "500"}, {"--ds": "0.1", "--ds-max": "0.01"}]),
    "sensitivity": dict(
        base={"--metric": "static_stiffness"}, out=True,
        numbers={"--force": POS},
        choices={"--metric": ["static_stiffness", "natural_frequency", "thermal_error"]},
        switches=["--check-fd", "--no-fd-probe", "--no-progress"],
        extra=[{"--frequency": "120"}, {"--vary": ","}, {"--vary": "nut.bals"},
               {"--vary": "thermal.enabled"}, {"--vary": "nut.balls,nut.balls"},
               {"--vary": "nut.hertz_k_m_per_n23"},
               {"--metric": "amplitude", "--frequency": "-120"},
               {"--metric": "floquet", "--frequency": "0"}]),
    "optimize": dict(
        base={"--metric": "natural_frequency", "--vary": "nut.balls"}, out=True,
        numbers={"--min-stiffness": POS, "--max-steps": I(1, 10**5), "--force": POS},
        choices={"--metric": ["natural_frequency", "static_stiffness", "thermal_error"]},
        switches=["--no-verify", "--no-fd-probe", "--no-progress"],
        extra=[{"--bounds": "nut.balls=60:40"}, {"--bounds": "nut.balls=nan:60"},
               {"--bounds": "nut.balls=40:inf"}, {"--bounds": "nut.balls"},
               {"--bounds": "nut.balls=a:b"}, {"--bounds": "bearing.balls=10:20"},
               {"--bounds": "nut.balls=0:60"}, {"--metric": "frc_peak"},
               {"--vary": "nut.bals"}, {"--vary": ""}, {"--frequency": "120"},
               {"--metric": "amplitude", "--force": "-5"}]),
    "reproduce": dict(
        base={"--quick": None}, out=True, numbers={"--thermal-frequency": POS}, choices={},
        switches=["--no-progress"],
        extra=[{"--preset": "nope"}, {"--preset": "defualt"}]),
}


ALL_CHOICES = {c for spec in COMMANDS.values() for cs in spec["choices"].values() for c in cs
               } | set(METRICS)


def _valid_number(domain):
    kind, low, low_in, high, high_in = domain
    if kind == "int":
        return st.integers(low, min(high, low + 50)).map(str)
    lo = 1e-3 if low is None else low
    return st.floats(lo, min(high if high is not None else lo + 1e4, lo + 1e4),
                     exclude_min=not low_in, exclude_max=high is not None and not high_in
                     ).map(repr)


def _bad_number(domain):
    """Text that the flag must refuse: non-finite, not a number, or out of its domain."""
    kind, low, low_in, high, high_in = domain
    parses = (lambda t: int(t)) if kind == "int" else (lambda t: float(t))

    def not_parsed(t):
        try:
            parses(t)
        except (ValueError, OverflowError):
            return True
        return False

    options = [st.sampled_from(["nan", "inf", "-inf", "NaN", "Infinity", "1e999", "-1e999",
                                ""]),
               TEXT.filter(not_parsed)]
    if kind == "float" and low is not None:
        below = st.floats(1e-9, 1e12).map(lambda d: low - d)
        options.append(below.map(repr) if low_in else st.one_of(below.map(repr),
                                                                   st.just(repr(low))))
    if kind == "float" and high is not None:
        above = st.floats(1e-9, 1e12).map(lambda d: high + max(d, 1e-9 * high))
        options.append(above.map(repr) if high_in else st.one_of(above.map(repr),
                                                                   st.just(repr(high))))
    if kind == "int":
        options += [st.integers(1, 10**6).map(lambda d: str(low - d)),
                    st.integers(1, 10**30).map(lambda d: str(high + d)),
                    st.just("1.5"), st.just("9" * 400)]
    return st.one_of(options)


def _bad_set():
    return st.one_of(
        st.sampled_from(["nut.preload_n", "masses", "=5", "nut.bals=40", "nut.balls=nan",
                         "nut.balls=inf", "nut.balls=-inf", "nut.balls=forty", "nut.balls=",
                         "nut.balls=true", "thermal.enabled=3", "thermal.enabled=yes",
                         "masses.nut_kg=-1", "screw.youngs_modulus_gpa=1e300",
                         "nut.contact_angle_deg=90", "nut.balls=1e999", "thermal.speed_rpm=1e5",
                         "nut.ball_diameter_mm=30", "nut.ba\nlls=4"]),
        st.tuples(_misspelt([k.name for k in KEYS]), st.floats(1, 10)).map(
            lambda t: f"{t[0]}={t[1]!r}").filter(lambda s: s.split("=")[0] not in
                                                 {k.name for k in KEYS}),
        TEXT.filter(lambda s: "=" not in s),
    )


@st.composite
def bad_command_lines(draw, files):
    """(argv, out folder or None): a command line wrong in at least one way."""
    name = draw(st.sampled_from(sorted(COMMANDS)))
    spec = COMMANDS[name]
    flags = dict(spec["base"])
    # A few valid options first (so the refusal is checked amid real settings) ...
    for _ in range(draw(st.integers(0, 3))):
        what = draw(st.sampled_from(["number", "choice", "switch"]))
        if what == "number" and spec["numbers"]:
            flag = draw(st.sampled_from(sorted(spec["numbers"])))
            flags[flag] = draw(_valid_number(spec["numbers"][flag]))
        elif what == "choice" and spec["choices"]:
            flag = draw(st.sampled_from(sorted(spec["choices"])))
            flags[flag] = draw(st.sampled_from(spec["choices"][flag]))
        elif spec["switches"]:
            flags[draw(st.sampled_from(spec["switches"]))] = None
    # ... then one to three faults.
    kinds = ["unknown flag"] + (["number"] if spec["numbers"] else []) + \
        (["choice"] if spec["choices"] else []) + (["extra"] if spec["extra"] else []) + \
        (["params", "preset", "set", "both"] if name != "reproduce" else []) + \
        (["out"] if spec["out"] else [])
    sets = []
    chosen = draw(st.lists(st.sampled_from(kinds), min_size=1, max_size=3))
    # An "extra" is a combination of flags that is wrong as a whole: a second one, or one
    # drawn after another fault, could overwrite its flags into a valid command line (two
    # extras gave `sweep --param nut.preload_n --frequency 500`). So at most one, first.
    if "extra" in chosen:
        chosen = ["extra"] + [k for k in chosen if k != "extra"]
    for kind in chosen:
        if kind == "unknown flag":
            flags["--zz-" + draw(st.text("abcdefghij", min_size=1, max_size=6))] = \
                draw(st.one_of(st.none(), st.just("1")))
        elif kind == "number":
            flag = draw(st.sampled_from(sorted(spec["numbers"])))
            flags[flag] = draw(_bad_number(spec["numbers"][flag]))
        elif kind == "choice":
            flag = draw(st.sampled_from(sorted(spec["choices"])))
            flags[flag] = draw(TEXT.filter(lambda t: t not in ALL_CHOICES))
        elif kind == "extra":
            flags.update(draw(st.sampled_from(spec["extra"])))
        elif kind == "params":
            flags.pop("--preset", None)
            flags["--params"] = str(draw(st.sampled_from(sorted(files["bad"].items())))[1])
        elif kind == "preset":
            flags.pop("--params", None)
            flags["--preset"] = draw(TEXT.filter(lambda t: t not in list_presets()))
        elif kind == "set":
            sets.append(draw(_bad_set()))
        elif kind == "both":
            flags["--params"], flags["--preset"] = str(files["good"]), "default"
        elif kind == "out":
            plain = files["plain"]
            flags["--out"] = str(draw(st.sampled_from([plain, plain / "sub", plain / "a" / "b"])))
    out = None
    if spec["out"] and "--out" not in flags:
        out = files["root"] / f"out{draw(st.integers(0, 10**9))}"
        flags["--out"] = str(out)
    argv = [name]
    items = list(flags.items()) + [("--set", s) for s in sets]
    for flag, value in draw(st.permutations(items)):
        if value is None:
            argv.append(flag)
        elif isinstance(value, list):
            argv += [flag, *value]
        elif draw(st.booleans()) or value.startswith("-") or not value:
            argv.append(f"{flag}={value}")
        else:
            argv += [flag, value]
    return argv, out


def _run(argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), \
            _time_limit(20), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # numpy overflow etc.: never silent
        try:
            rc = main(argv)
        except SystemExit as exc:  # argparse: usage + one error line, status 2
            rc = exc.code
        except ReachedComputation:
            pytest.fail(f"computing started for a bad command line: {argv!r}")
    return rc, err.getvalue()


def _check_refused(argv, rc, err):
    assert rc in (1, 2), (argv, rc, err)
    lines = err.splitlines()
    errors = [line for line in lines if ": error: " in line]
    assert len(errors) == 1 and lines[-1] == errors[0], (argv, err)
    for line in lines[:-1]:  # argparse's usage (indented continuation lines) or warnings
        assert line.startswith(("usage: ", " ")) or ": warning: " in line, (argv, err)
    assert "Traceback" not in err


# Derandomised (the same 600 command lines every run) so that CI is reproducible; set
# BSFS_FUZZ_EXPLORE=1 to draw new ones. Random runs found `map --block-periods 16` and
# `--set` with a line break (both fixed in the CLI), and two cases that were the generator's
# own: two drawn "extra" combinations merged into a valid command line, which then reached
# computation (`sweep --param nut.preload_n --frequency 500`); the other finding, files
# in the out folder of `reproduce --preset nope`, came from such an example run earlier
# in the same shrinking (the examples share one fixture folder, so out0 is reused). 12 000
# newly drawn command lines pass since (20 runs of BSFS_FUZZ_EXPLORE=1).
@given(data=st.data())
@settings(max_examples=600, deadline=None, database=None,
          derandomize=not os.environ.get("BSFS_FUZZ_EXPLORE"),
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
def test_bad_command_lines_are_refused_in_one_line(no_computing, files, data):
    argv, out = data.draw(bad_command_lines(files))
    rc, err = _run(argv)
    _check_refused(argv, rc, err)
    event(f"{argv[0]}: exit {rc}")  # --hypothesis-show-statistics: how each was refused
    if out is not None:  # nothing written, not even half
        assert not out.exists() or not any(p.is_file() for p in out.rglob("*")), argv
    assert files["plain"].read_text() == "user data\n"


@pytest.mark.parametrize("argv", [
    ["simulate", "--frequency", "5\n0", "--force", "1", "--out", "o"],
    ["modes", "--set", "nut.ba\nlls=40"],
    ["modes", "--params", "no\nfile.toml"],
    ["sweep", "--param", "nut.balls", "--start", "0", "--stop", "40", "--num", "100000",
     "--frequency", "500", "--out", "o"],
])
def test_named_odd_inputs_are_one_line(no_computing, files, argv):
    """Newlines typed into values, and a 100000-point range through an invalid value (each
    point was validated in turn, 6 minutes, before the first was refused)."""
    argv = [a if a != "o" else str(files["root"] / "named") for a in argv]
    rc, err = _run(argv)
    _check_refused(argv, rc, err)
