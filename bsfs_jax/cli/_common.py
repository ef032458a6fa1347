"""Helpers shared by the CLI commands: JAX set-up, parameter loading, atomic outputs."""

import json
import os
from pathlib import Path

from .._files import jsonable as jsonable
from .._files import save_figure as save_figure
from .._files import write_bytes_atomic as write_bytes_atomic
from .._files import write_text_atomic as write_text_atomic


class CLIError(RuntimeError):
    """A user-facing error: printed as one line, exit status 1."""


def setup_jax() -> None:
    """64-bit floats, the persistent compilation cache (so repeated runs skip compiles), and
    one BLAS thread for jaxlib's CPU LAPACK (scipy's OpenBLAS, loaded at the first linear
    solve, after this): its threads oversubscribe small machines next to XLA's own (a
    199 x 199 LU took 120 ms instead of 1 ms on a loaded 2-core machine). Also the CLI's
    EQX_ON_ERROR and XLA_FLAGS defaults (`cli.choose_process_settings`; `main` chooses them
    first, a script that calls this at its start gets them here), each where it still
    takes effect."""
    from .._host import apply

    apply()
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("BSFS_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "bsfs", "jax")
    try:
        os.makedirs(cache, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    except OSError:
        pass  # a read-only home: run without the cache
    if os.environ.get("BSFS_COMPILE_STATS"):
        _record_compiles(os.environ["BSFS_COMPILE_STATS"])


_EXIT_WORK: list = []


def at_exit(fn) -> None:
    """Run `fn()` when the process ends: by `atexit` for `main` called in a process, and
    by `cli.run` (the `bsfs` command) before its immediate exit, which skips `atexit`."""
    import atexit

    _EXIT_WORK.append(fn)
    atexit.register(fn)


def run_exit_work() -> None:
    """`cli.run`'s last step before `os._exit`: the `at_exit` work, latest first."""
    while _EXIT_WORK:
        _EXIT_WORK.pop()()


def _record_compiles(path: str) -> None:
    """For the benchmarks: count XLA compilations and their seconds (jax's compile events)
    and write them, with the peak memory, to `path` (JSON) when the process exits."""
    import json
    import resource

    import jax

    stats = {"compiles": 0, "compile_s": 0.0}

    def on_event(event, seconds, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            stats["compiles"] += 1
            stats["compile_s"] += seconds

    def write():
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(dict(stats, peak_rss_mb=peak), fh)

    jax.monitoring.register_event_duration_secs_listener(on_event)
    at_exit(write)


def add_params_args(parser) -> None:
    """--params FILE | --preset NAME (mutually exclusive), plus --set section.key=value."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--params", metavar="FILE", help="TOML parameter file")
    group.add_argument("--preset", metavar="NAME", help="bundled preset (see `bsfs params --list`)")
    parser.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                        help="override one parameter, e.g. --set nut.preload_n=2000 (repeatable)")


def load_params_from_args(args):
    """The parameters named by --params/--preset, with every --set applied; each --set is
    checked as a file's value is (a number in range, true/false for a switch)."""
    from ..params import check_value, load_params, one_line, preset, validate

    if getattr(args, "params", None) is not None:
        params = load_params(args.params)
    else:  # an empty --preset is refused like any unknown name, never taken as the default
        name = getattr(args, "preset", None)
        params = preset("default" if name is None else name)
    for item in getattr(args, "set", []) or []:
        if "=" not in item:
            raise CLIError(f"--set expects SECTION.KEY=VALUE, got '{one_line(item)}'")
        if any(ord(c) < 32 or ord(c) == 127 for c in item):
            raise CLIError(f"--set '{one_line(item)}' contains a control character (a line "
                           "break or tab); give SECTION.KEY=VALUE on one line")
        name, text = (part.strip() for part in item.split("=", 1))
        if text.lower() in ("true", "false"):
            value = text.lower() == "true"
        else:
            try:
                value = float(text)
            except ValueError:
                raise CLIError(f"--set {one_line(name)}: '{one_line(text)}' is not a number"
                               ) from None
        check_value(name, value, source="--set")
        params = params.replace(name, value)
    return validate(params, source="--set")


def out_dir(path, *, create: bool = True) -> Path:
    """The output folder `path`, created (with its parents) unless `create` is False; a
    CLIError when it, or a parent, is a file or cannot be created. Call it with
    `create=False` before a long computation to fail early without leaving a folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CLIError(f"--out '{path}' exists and is not a folder")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise CLIError(f"--out '{path}': '{parent}' is a file, not a folder; choose "
                               "another --out")
            break
    if not create:
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CLIError(f"--out '{path}': cannot create the folder ({exc.strerror})") from None
    return path


def finite_float(text: str) -> float:
    """argparse type: a finite number (nan and inf are refused in one line)."""
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got '{text}'")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    import argparse

    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got '{text}'")
    return value


def tolerance(text: str) -> float:
    """argparse type: a relative tolerance, 0 < value < 1."""
    import argparse

    value = finite_float(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"must lie between 0 and 1 (exclusive), got '{text}'")
    return value


def snr_db(text: str) -> float:
    """argparse type: a sensor signal-to-noise ratio in dB, 0 to 120 (below 0 the noise
    exceeds the signal; above 120 dB no real sensor chain reaches)."""
    import argparse

    value = finite_float(text)
    if not 0.0 <= value <= 120.0:
        raise argparse.ArgumentTypeError(f"a signal-to-noise ratio from 0 to 120 dB, got '{text}'")
    return value


def count(low: int, high: int):
    """argparse type: a whole number in [low, high] (the upper end keeps an absurd value
    from allocating or running for days before anything is written)."""
    import argparse

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
        if not low <= value <= high:
            shown = text if len(text) <= 20 else text[:17] + "..."
            raise argparse.ArgumentTypeError(f"must be a whole number from {low} to {high:,}, "
                                             f"got {shown}")
        return value

    parse.__name__ = "whole number"
    return parse


def write_json(path, data) -> None:
    """Write JSON atomically (temp file in the same folder, then rename)."""
    write_bytes_atomic(path, (json.dumps(jsonable(data), indent=2) + "\n").encode())


def progress_enabled(args) -> bool:
    """Progress bars on a terminal, or wherever `BSFS_PROGRESS=1` asks for them (a batch
    job's log); never with --no-progress or `BSFS_PROGRESS=0`."""
    import os
    import sys

    if getattr(args, "no_progress", False):
        return False
    wanted = os.environ.get("BSFS_PROGRESS", "").strip()
    return wanted == "1" if wanted in ("0", "1") else sys.stderr.isatty()


#: Plausible excitation of a machine-tool feed drive by a shaker or the cutting process.
PLAUSIBLE_FORCE_N = 1e5
PLAUSIBLE_FREQUENCY_HZ = 2e4


def warn_implausible_excitation(*, forces=(), frequencies=()) -> None:
    """One-line warnings for legal but implausible excitation values (a unit slip?)."""
    import warnings

    for f in forces:
        if f is not None and abs(float(f)) > PLAUSIBLE_FORCE_N:
            warnings.warn(f"force {float(f):g} N is above {PLAUSIBLE_FORCE_N:g} N, beyond any "
                          "shaker or cutting force on a feed drive; check the value and unit",
                          stacklevel=2)
            break
    for f in frequencies:
        if f is not None and float(f) > PLAUSIBLE_FREQUENCY_HZ:
            warnings.warn(f"frequency {float(f):g} Hz is above {PLAUSIBLE_FREQUENCY_HZ:g} Hz, "
                          "far beyond the drive's modes; check the value and unit",
                          stacklevel=2)
            break


def validate_sweep_values(params, key: str, values, flag: str):
    """Refuse up front a sweep or map range of a parameter key that crosses an invalid
    value: every value is validated (in one vectorised pass) before anything is computed."""
    import numpy as np

    from ..params import validate

    validate(params.replace(key, np.asarray(values, dtype=float)), source=f"{flag} {key}")


def add_engine_args(parser, chunk_help: str = "points per checkpoint chunk") -> None:
    """--engine and --chunk of the cold sweeps (`sweep`, `map`)."""
    parser.add_argument("--engine", choices=("auto", "kernel", "vmap", "queue"), default="auto",
                        help="how cold points are integrated: 'kernel' (one kernel, each "
                        "point its own adaptive loop; Triton on a GPU, interpret mode "
                        "elsewhere: slow, for testing), 'vmap' (lockstep batches of "
                        "--batch), 'queue' (a work queue of --batch lanes), 'auto' (default: "
                        "kernel on a GPU, vmap elsewhere)")
    parser.add_argument("--chunk", type=count(1, 10**6), default=None,
                        help=f"{chunk_help} (default 32; 8192 with the kernel engine)")
    parser.add_argument("--kernel-checks", action="store_true",
                        help="run the verification's orbit checks on the per-lane kernel "
                        "as well (needs the kernel engine: --engine kernel, or auto on a "
                        "GPU; not yet timed on a GPU, so off by default)")


def engine_settings(args) -> dict:
    """SweepConfig's `engine` and `chunk_size` from --engine, --chunk (and --lyapunov)."""
    import jax

    engine = {"vmap": "map"}.get(args.engine, args.engine)
    if engine == "kernel" and getattr(args, "lyapunov", False):
        raise CLIError("--engine kernel does not integrate the tangent dynamics: drop "
                       "--lyapunov or use --engine vmap")
    kernel = engine == "kernel" or (engine == "auto" and jax.default_backend() == "gpu"
                                    and not getattr(args, "lyapunov", False))
    if getattr(args, "kernel_checks", False) and not kernel:
        raise CLIError("--kernel-checks runs the orbit checks on the kernel engine's "
                       "kernel: add --engine kernel (or run on a GPU with --engine auto)")
    return {"engine": engine, "chunk_size": args.chunk or (8192 if kernel else 32)}


def say(message: str) -> None:
    """A one-line status message on stderr, at once (what a command is doing now)."""
    import sys

    print(message, file=sys.stderr, flush=True)


class Progress:
    """`progress(done, total)` for long steps: a line "LABEL: P % (S s)" on stderr at most
    every `every_s` seconds (and at the end), so that a terminal and a batch job's log both
    show the step advancing. Silent where `enabled` is false (--no-progress,
    BSFS_PROGRESS=0)."""

    def __init__(self, label: str, enabled: bool = True, every_s: float = 5.0):
        import time

        self.label, self.enabled, self.every_s = label, enabled, every_s
        self.start = self.last = time.monotonic()

    def __call__(self, done, total) -> None:
        import time

        now = time.monotonic()
        if not self.enabled or (now - self.last < self.every_s and done < total):
            return
        if done >= total and now - self.start < self.every_s:
            return  # a quick step needs no report
        self.last = now
        say(f"{self.label}: {100.0 * done / max(total, 1):.0f} % ({now - self.start:.0f} s)")


def progress_wanted(args) -> bool:
    """Plain progress lines unless --no-progress or BSFS_PROGRESS=0 turn them off."""
    import os

    return not getattr(args, "no_progress", False) and os.environ.get("BSFS_PROGRESS") != "0"
