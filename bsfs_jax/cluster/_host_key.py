"""The host's CPU as a folder name: compiled code is kept per CPU on a shared cache.

XLA compiles for the CPU features of the host it runs on, and refuses (or, worse, runs
badly) an executable compiled for other features. On a cluster of mixed nodes that share
one persistent compilation cache (`BSFS_CACHE_DIR` on shared storage), each kind of CPU
therefore gets a folder of its own: `<cache>/cpu-<model>-<digest>`, the digest taken of
the CPU model and its feature flags. Nodes of one kind share their compiled programs.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import re
from pathlib import Path


def _cpuinfo() -> tuple[str, str]:
    """(model name, feature flags) from /proc/cpuinfo (Linux), else from `platform`."""
    model, flags = "", ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                key = key.strip().lower()
                if not model and key in ("model name", "cpu model", "hardware"):
                    model = value.strip()
                elif not flags and key in ("flags", "features"):
                    flags = " ".join(sorted(value.split()))
                if model and flags:
                    break
    except OSError:
        pass
    return model or platform.processor() or platform.machine(), flags


@functools.cache
def cpu_key() -> str:
    """A short name of this host's CPU kind, safe as a folder name: the model in words
    (at most 40 characters) and 12 hex digits of the model, machine and feature flags,
    e.g. `cpu-intel-xeon-processor-icelake-3f2a9c41d0b7`."""
    model, flags = _cpuinfo()
    digest = hashlib.sha256(f"{platform.machine()}\0{model}\0{flags}".encode()).hexdigest()
    words = re.sub(r"\(r\)|\(tm\)|cpu|@.*$", " ", model.lower())
    words = re.sub(r"[^a-z0-9]+", "-", words).strip("-")[:40].strip("-") or "unknown"
    return f"cpu-{words}-{digest[:12]}"


def cache_root() -> Path:
    """The persistent compilation cache's root: `$BSFS_CACHE_DIR`, else
    `~/.cache/bsfs/jax` (as the `bsfs` command)."""
    root = os.environ.get("BSFS_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "bsfs", "jax")
    return Path(root)


def host_cache_dir(root=None) -> Path:
    """This host's folder of the shared cache: `root` (default `cache_root()`) / `cpu_key()`."""
    return Path(cache_root() if root is None else root) / cpu_key()
