"""Helpers shared by the CLI commands: JAX set-up, parameter loading, atomic outputs."""

import json
import os
from pathlib import Path

from .._files import jsonable as jsonable
from .._files import write_bytes_atomic as write_bytes_atomic
from .._files import write_text_atomic as write_text_atomic


class CLIError(RuntimeError):
    """A user-facing error: printed as one line, exit status 1."""


def setup_jax() -> None:
    """64-bit floats, the persistent compilation cache (so repeated runs skip compiles), and
    one BLAS thread for jaxlib's CPU LAPACK (scipy's OpenBLAS, loaded at the first linear
    solve, after this): its threads oversubscribe small machines next to XLA's own (a
    199 x 199 LU took 120 ms instead of 1 ms on a loaded 2-core machine)."""
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


def add_params_args(parser) -> None:
    """--params FILE | --preset NAME (mutually exclusive), plus --set section.key=value."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--params", metavar="FILE", help="TOML parameter file")
    group.add_argument("--preset", metavar="NAME", help="bundled preset (see `bsfs params --list`)")
    parser.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                        help="override one parameter, e.g. --set nut.preload_n=2000 (repeatable)")


def load_params_from_args(args):
    from ..params import load_params, preset

    params = load_params(args.params) if getattr(args, "params", None) else preset(
        getattr(args, "preset", None) or "default")
    for item in getattr(args, "set", []) or []:
        if "=" not in item:
            raise CLIError(f"--set expects SECTION.KEY=VALUE, got '{item}'")
        name, value = item.split("=", 1)
        value = value.strip()
        if value.lower() in ("true", "false"):
            params = params.replace(name.strip(), value.lower() == "true")
            continue
        try:
            number = float(value)
        except ValueError:
            raise CLIError(f"--set {name}: '{value}' is not a number") from None
        params = params.replace(name.strip(), number)
    from ..params import validate

    return validate(params, source="--set")


def out_dir(path) -> Path:
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CLIError(f"--out '{path}' exists and is not a folder")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise CLIError(f"--out '{path}': '{parent}' is a file, not a folder; choose "
                               "another --out")
            break
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


def write_json(path, data) -> None:
    """Write JSON atomically (temp file in the same folder, then rename)."""
    write_bytes_atomic(path, (json.dumps(jsonable(data), indent=2) + "\n").encode())


def save_figure(fig, path) -> None:
    """Save a matplotlib figure atomically (PNG, 130 dpi)."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=130,
                bbox_inches="tight")
    write_bytes_atomic(path, buf.getvalue())


def progress_enabled(args) -> bool:
    """Progress bars only on a terminal, and never with --no-progress."""
    import sys

    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


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
    value (every value is validated before anything is computed)."""
    from ..params import validate

    for v in values:
        validate(params.replace(key, float(v)), source=f"{flag} {key} = {float(v):g}")
