"""bsfs leaves its host alone: importing any of its modules changes no environment
variable, no `jax.config` value and no XLA flag, and starts no jax backend. The `bsfs`
command chooses its own settings for its own process, and a library user gets the same ones
by calling `bsfs_jax.use_fast_compilation()`. Each check runs in a fresh process."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FLAG = "--xla_cpu_use_fusion_emitters=false"
# What the host chooses, which bsfs must not touch.
_HOST_VARS = ("EQX_ON_ERROR", "XLA_FLAGS", "BSFS_XLA_DEFAULTS")


def _run(code: str, **env) -> dict:
    """Run `code` in a fresh interpreter whose environment has none of `_HOST_VARS` but
    those in `env`; the JSON object it prints on its last line."""
    base = {k: v for k, v in os.environ.items() if k not in _HOST_VARS}
    base["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT)] + ([base["PYTHONPATH"]] if base.get("PYTHONPATH") else []))
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT,
                         env={**base, **env}, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


_IMPORT_EVERYTHING = """
    import importlib, json, os, pkgutil, sys
    import jax  # jax's own import sets variables of its own (TF_CPP_MIN_LOG_LEVEL, ...)
    KEYS = ("jax_enable_x64", "jax_compilation_cache_dir", "jax_numpy_rank_promotion",
            "jax_default_matmul_precision")
    env0 = dict(os.environ)
    config0 = {k: getattr(jax.config, k) for k in KEYS}
    import bsfs_jax, identification
    names = ["bsfs_jax", "identification"]
    for pkg in (bsfs_jax, identification):
        names += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")]
    for name in names:
        importlib.import_module(name)
    bsfs_jax.use_fast_compilation  # a lazy name: loads its module, changes nothing
    env1 = dict(os.environ)
    from jax._src import xla_bridge
    import equinox._config
    print(json.dumps(dict(
        modules=names,
        env_changed=sorted(k for k in {*env0, *env1} if env0.get(k) != env1.get(k)),
        config0=config0, config1={k: getattr(jax.config, k) for k in KEYS},
        backend_started=xla_bridge.backends_are_initialized(),
        eqx_on_error=equinox._config.EQX_ON_ERROR)))
"""


@pytest.mark.parametrize("env", [
    {}, {"EQX_ON_ERROR": "raise", "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}],
    ids=["unset", "set"])
def test_importing_bsfs_changes_nothing_of_its_host(env):
    got = _run(_IMPORT_EVERYTHING, **env)
    subpackages = {p.parent.name for p in (ROOT / "bsfs_jax").glob("*/__init__.py")}
    assert {f"bsfs_jax.{name}" for name in subpackages} <= set(got["modules"])
    assert "identification.fitting._fit" in got["modules"] and len(got["modules"]) > 100
    assert got["env_changed"] == []
    assert got["config1"] == got["config0"]
    assert got["backend_started"] is False  # a host can still choose XLA_FLAGS after it
    assert got["eqx_on_error"] == "raise"  # equinox's default, or the host's choice


_USE = """
    import json, os, sys, warnings
    import bsfs_jax
    {before}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        changed = bsfs_jax.use_fast_compilation()
    import equinox._config
    import jax.numpy as jnp
    total = float(jnp.sum(jnp.arange(4.0)))  # XLA accepts the flags it got
    print(json.dumps(dict(changed=changed, total=total,
                          eqx=os.environ.get("EQX_ON_ERROR"),
                          xla=os.environ.get("XLA_FLAGS"),
                          equinox_mode=equinox._config.EQX_ON_ERROR,
                          warnings=[str(w.message) for w in caught
                                    if w.category is RuntimeWarning])))
"""


def test_use_fast_compilation_sets_what_its_docstring_says():
    got = _run(_USE.format(before=""))
    assert got["changed"] == {"EQX_ON_ERROR": "nan", "XLA_FLAGS": FLAG}
    assert (got["eqx"], got["xla"], got["equinox_mode"]) == ("nan", FLAG, "nan")
    assert got["total"] == 6.0 and got["warnings"] == []


@pytest.mark.parametrize("env, changed", [
    ({"XLA_FLAGS": "--xla_force_host_platform_device_count=2"},
     {"EQX_ON_ERROR": "nan", "XLA_FLAGS": f"--xla_force_host_platform_device_count=2 {FLAG}"}),
    ({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}, {"EQX_ON_ERROR": "nan"}),
    ({"BSFS_XLA_DEFAULTS": "0"}, {"EQX_ON_ERROR": "nan"}),
    ({"EQX_ON_ERROR": "raise"}, {"XLA_FLAGS": FLAG}),
], ids=["adds-to-flags", "option-named", "xla-defaults-off", "eqx-set"])
def test_use_fast_compilation_leaves_the_hosts_own_choices(env, changed):
    got = _run(_USE.format(before=""), **env)
    assert got["changed"] == changed and got["warnings"] == []
    assert got["eqx"] == env.get("EQX_ON_ERROR", "nan") == got["equinox_mode"]
    assert got["xla"] == changed.get("XLA_FLAGS", env.get("XLA_FLAGS"))


def test_use_fast_compilation_too_late_changes_nothing_and_says_so():
    """After equinox's import and jax's first computation neither setting would take
    effect: neither is made, and each is named in a warning."""
    got = _run(_USE.format(before="import equinox, jax; jax.devices()"))
    assert got["changed"] == {} and got["eqx"] is None and got["xla"] is None
    assert got["equinox_mode"] == "raise"
    assert len(got["warnings"]) == 2
    assert "EQX_ON_ERROR" in got["warnings"][0] and "XLA_FLAGS" in got["warnings"][1]


_CLI = """
    import json, os, sys
    from bsfs_jax.cli import main
    code = main(["modes", "--json"])
    import equinox._config
    print(json.dumps(dict(code=code, eqx=os.environ.get("EQX_ON_ERROR"),
                          xla=os.environ.get("XLA_FLAGS"),
                          equinox_mode=equinox._config.EQX_ON_ERROR)))
"""


@pytest.mark.parametrize("env, eqx, xla", [
    ({}, "nan", FLAG),
    ({"EQX_ON_ERROR": "raise", "BSFS_XLA_DEFAULTS": "0"}, "raise", None),
    ({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}, "nan",
     "--xla_cpu_use_fusion_emitters=true"),
], ids=["defaults", "told-not-to", "option-named"])
def test_the_bsfs_command_chooses_its_own_settings(tmp_path, env, eqx, xla):
    got = _run(_CLI, BSFS_CACHE_DIR=str(tmp_path / "cache"), **env)
    assert got == dict(code=0, eqx=eqx, xla=xla, equinox_mode=eqx)
