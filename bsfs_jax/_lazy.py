"""Public names that load their module on first use (PEP 562), for the packages' `__init__`.

`bsfs modes`, `bsfs params` and every argument error then run without importing the
solvers, diffrax or optimistix (about 0.35 s of a cold start on the 2-core machine).
"""

import sys
from collections.abc import Callable
from importlib import import_module


def lazy_names(package: str, names: dict[str, str],
               computed: dict[str, Callable[[], object]] | None = None):
    """(__getattr__, __dir__) for `package`, whose public `names` (name -> module, relative
    to the package) are imported on first access and then kept in its namespace;
    `computed`: names whose value a function gives (also on first access)."""
    namespace = sys.modules[package].__dict__
    computed = computed or {}

    def __getattr__(name: str):
        if name in computed:
            value = computed[name]()
        elif name in names:
            value = getattr(import_module(names[name], package), name)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value
        return value

    def __dir__():
        return sorted({*namespace, *names, *computed})

    return __getattr__, __dir__
