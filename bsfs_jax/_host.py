"""Process-wide settings that a program may choose for itself, and a library must not.

Importing bsfs (`bsfs_jax`, its subpackages, `identification`) changes no environment
variable, no `jax.config` value and no XLA flag. The `bsfs` command chooses the settings
below for its own process (`bsfs_jax.cli`); a program that uses the library gets the same
ones by calling `bsfs_jax.use_fast_compilation()` at its start.
"""

from __future__ import annotations

import os
import sys
import warnings

#: XLA's CPU compiler with its earlier fusion emitters: compilation about a quarter shorter
#: (measured on a 2-core machine: the test suite's XLA seconds 1750 -> 1307, a cold
#: `bsfs sensitivity` 29.5 -> 24.6 s), the results the same to rounding. The few programs
#: that run long enough for the newer emitters' faster code to pay ask for them themselves
#: (`cached_jit(..., runs_long=True)`).
XLA_FAST_FLAG = "--xla_cpu_use_fusion_emitters=false"
_XLA_OPTION = "xla_cpu_use_fusion_emitters"


def _backend_started() -> bool:
    """Whether jax has started a backend in this process (XLA has then read XLA_FLAGS).
    Never imports jax."""
    bridge = sys.modules.get("jax._src.xla_bridge")
    started = getattr(bridge, "backends_are_initialized", None)
    return bool(started()) if started is not None else False


def apply(*, eqx_on_error: bool = True, xla_flags: bool = True
          ) -> tuple[dict[str, str], list[str]]:
    """(what was changed: environment variable -> its new value, why each other setting
    could not be made any more); no warning. `use_fast_compilation` documents the rules."""
    changed: dict[str, str] = {}
    late: list[str] = []
    if eqx_on_error and "EQX_ON_ERROR" not in os.environ:
        if "equinox" in sys.modules:
            late.append("EQX_ON_ERROR=nan not set: equinox is imported already and reads "
                        "EQX_ON_ERROR only at its import")
        else:
            os.environ["EQX_ON_ERROR"] = changed["EQX_ON_ERROR"] = "nan"
    flags = os.environ.get("XLA_FLAGS", "")
    if (xla_flags and os.environ.get("BSFS_XLA_DEFAULTS", "1") != "0"
            and _XLA_OPTION not in flags):
        if _backend_started():
            late.append(f"{XLA_FAST_FLAG} not added to XLA_FLAGS: jax has started its "
                        "backend already and reads XLA_FLAGS only then")
        else:
            os.environ["XLA_FLAGS"] = changed["XLA_FLAGS"] = f"{flags} {XLA_FAST_FLAG}".strip()
    return changed, late


def use_fast_compilation(*, eqx_on_error: bool = True, xla_flags: bool = True
                         ) -> dict[str, str]:
    """Choose, for this process, the settings the `bsfs` command uses: shorter XLA
    compilations, and programs that jax's persistent compilation cache can keep. Call it at
    the start of your program, before importing equinox (or anything that imports it:
    diffrax, optimistix, most of bsfs) and before the first computation with jax.

    It changes two environment variables of this process (`os.environ`, which child
    processes inherit), and nothing else (no `jax.config` value):

    - `EQX_ON_ERROR=nan` (`eqx_on_error`), only where EQX_ON_ERROR is unset and equinox is
      not imported yet (equinox reads it once, at its import). Equinox's runtime checks
      (in diffrax, lineax, optimistix) then give NaN instead of raising through a host
      callback: a program with a host callback is never written to jax's persistent
      compilation cache, nor kept by `bsfs_jax.cached_jit`, so without this setting such
      programs are compiled again in every process. bsfs works either way: its solvers
      report failures through their `result` codes (`RESULTS`), not through equinox's
      raises; with equinox's default a failed check raises instead of giving NaN.
    - `XLA_FLAGS` gains `--xla_cpu_use_fusion_emitters=false` (`xla_flags`): XLA's CPU
      compiler with its earlier fusion emitters (compilations about a quarter shorter,
      the results the same to rounding), unless XLA_FLAGS already names that option or
      BSFS_XLA_DEFAULTS=0 is set. XLA reads XLA_FLAGS once, when jax starts its backend
      (the first computation, or `jax.devices()`): after that the flag would have no
      effect, and it is not added.

    A setting that comes too late is left unchanged and named in a `RuntimeWarning`.

    **Returns:** a dict of the environment variables it changed and their new values
    (empty if it changed nothing). Setting the variables in the shell before Python starts
    has the same effect.
    """
    changed, late = apply(eqx_on_error=eqx_on_error, xla_flags=xla_flags)
    for why in late:
        warnings.warn(f"bsfs_jax.use_fast_compilation: {why}; call it at the start of the "
                      "program, or set the variable before starting Python", RuntimeWarning,
                      stacklevel=2)
    return changed
