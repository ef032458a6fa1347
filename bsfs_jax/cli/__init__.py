"""The `bsfs` command line. Each command lives in its own module with `register(sub)`.

Only this layer chooses process-wide settings: `jax.config` (64-bit floats, the persistent
compilation cache), and the environment of its own process (`EQX_ON_ERROR=nan` and XLA's
earlier CPU fusion emitters, `choose_process_settings`), and only when `main` runs, never
at an import. It also parses arguments and writes files.
"""

import argparse
import importlib
import os
import sys

# Command modules, in the order they appear in `bsfs --help`. Each defines
# `register(subparsers)` which adds its sub-command(s) with `set_defaults(func=...)`.
_COMMAND_MODULES = [
    "bsfs_jax.cli._simulate_cmd",
    "bsfs_jax.cli._analysis_cmd",
    "bsfs_jax.cli._map_cmd",
    "bsfs_jax.cli._continue_cmd",
    "bsfs_jax.cli._identify_cmd",
    "bsfs_jax.cli._predict_cmd",
    "bsfs_jax.cli._monitor_cmd",
    "bsfs_jax.cli._synth_cmd",
    "bsfs_jax.cli._design_cmd",
    "bsfs_jax.cli._reproduce_cmd",
]


#: Commands whose long runs checkpoint under --out and resume when rerun.
_RESUMABLE = ("sweep", "map", "reproduce")


class _Parser(argparse.ArgumentParser):
    """argparse, with its error (usage + one line) kept to one line whatever the user
    typed: control characters in the message are escaped, long values cut."""

    def error(self, message):
        from ..params import one_line

        super().error(one_line(message, 400))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="bsfs",
        description="Simulate, analyse and identify the nonlinear vibration of a ball screw "
        "feed system under thermal deformation (Yang et al. 2022 model, JAX).",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"bsfs {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # command group not built yet
            raise
        module.register(sub)
    return parser


def _one_line_warnings(command) -> None:
    """Our warnings (implausible values, ...) as one line each, once per message."""
    import warnings

    from ..params import ParameterWarning

    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ParameterWarning) or category is UserWarning:
            text = str(message)
            what = text.split(": ", 1)[-1]  # the same value checked twice, from two sources
            if what not in shown:
                shown.add(what)
                print(f"bsfs {command}: warning: {text}", file=sys.stderr)
        else:
            warnings._showwarning_orig(message, category, filename, lineno, file, line)

    warnings._showwarning_orig = getattr(warnings, "_showwarning_orig", warnings.showwarning)
    warnings.showwarning = show


def setup_jax() -> None:
    """The command's own process settings, for a script that runs like the command: 64-bit
    floats, the persistent compilation cache (`BSFS_CACHE_DIR`, else ~/.cache/bsfs/jax),
    one BLAS thread, and `choose_process_settings`' defaults where they still take effect.
    A library user calls nothing of this (see `bsfs_jax.use_fast_compilation`)."""
    from ._common import setup_jax as _setup_jax

    _setup_jax()


def choose_process_settings() -> dict[str, str]:
    """The `bsfs` command's own settings for its process, chosen before equinox is imported
    and before jax starts its backend: `bsfs_jax.use_fast_compilation()`'s (EQX_ON_ERROR=nan
    unless EQX_ON_ERROR is set; `--xla_cpu_use_fusion_emitters=false` in XLA_FLAGS unless
    XLA_FLAGS names that option or BSFS_XLA_DEFAULTS=0), without its warnings: where `main`
    is called in a process that has used equinox or jax already, a setting that comes too
    late is skipped. Returns the environment variables it changed."""
    from .._host import apply

    return apply()[0]


def main(argv=None) -> int:
    choose_process_settings()  # first: before the command modules import jax's users
    from ._common import CLIError, setup_jax

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    setup_jax()
    _one_line_warnings(args.command)
    from ..params import ParameterError, one_line

    def user_errors():
        # A SolverError can only come from a loaded `solvers`: a command that never loads
        # it (`bsfs modes`, `bsfs params`) does not import it for this clause.
        solvers = sys.modules.get("bsfs_jax.solvers")
        return (CLIError, ParameterError, FileExistsError, FileNotFoundError,
                *((solvers.SolverError,) if solvers is not None else ()))

    try:
        return int(args.func(args) or 0)
    except user_errors() as exc:
        print(f"bsfs {args.command}: error: {one_line(exc, 2000)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # e.g. `bsfs params | head`
        return 0
    except KeyboardInterrupt:
        resume = ("; rerun the same command with the same --out to resume from its checkpoint"
                  if args.command in _RESUMABLE else "")
        print(f"bsfs {args.command}: interrupted{resume}", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the safety net, not the fix: one line + a log
        log = _write_crash_log(args)
        print(f"bsfs {args.command}: internal error: {type(exc).__name__}: "
              f"{one_line(str(exc).splitlines()[0], 300) if str(exc) else ''} (the traceback "
              f"is in {log}; "
              "please report it with the command line)", file=sys.stderr)
        return 3


def _write_crash_log(args) -> str:
    """Write the current exception's traceback to OUT/bsfs-error.log (or the cache
    folder when there is no output folder) and return the path."""
    import os
    import tempfile
    import traceback
    from pathlib import Path

    text = f"bsfs {' '.join(sys.argv[1:])}\n\n{traceback.format_exc()}"
    out = getattr(args, "out", None)
    folders = [Path(out)] if out and Path(out).is_dir() else []
    folders.append(Path(os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")))
                   / "bsfs")
    folders.append(Path(tempfile.gettempdir()))
    for folder in folders:
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / "bsfs-error.log"
            path.write_text(text)
            return str(path)
        except OSError:
            continue
    return "(no writable folder for the log)"


def run() -> None:
    """The `bsfs` console command: `main`, then an immediate exit (`os._exit`) once every
    effect of jax has finished, the logs and output streams are flushed and the CLI's own
    exit work is done (`_common.at_exit`). The interpreter's usual teardown (freeing jax's
    compiled programs and arrays, module by module) took about half a second of a warm
    `bsfs identify` and writes nothing: every file is written and closed (atomically)
    before `main` returns. `BSFS_FAST_EXIT=0` keeps the usual exit (for a profiler or a
    coverage tool, which write their results at exit)."""
    code = main()
    if os.environ.get("BSFS_FAST_EXIT", "1") == "0":
        sys.exit(code)
    import logging

    from ._common import run_exit_work

    if "jax" in sys.modules:
        sys.modules["jax"].effects_barrier()
    run_exit_work()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (`bsfs params | head`)
            pass
    os._exit(code)
