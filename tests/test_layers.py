"""The map of the house holds (docs/ARCHITECTURE.md, "Layers"): every package imports only
the packages its layer may use, no module imports another package's private module, and
no two modules import each other, directly or round a loop. Read from the source with
`ast` (imports inside functions and under TYPE_CHECKING count too); no JAX needed."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("bsfs_jax", "identification")

# What each layer may import: docs/ARCHITECTURE.md's table ("Layers"), read from the
# document, which is the one statement of the rule. "_files", "_programs", "_numerics",
# "_lazy" and "_host" are bsfs_jax's own utility modules (files, programs and the host
# settings are public as bsfs_jax.files, bsfs_jax.cached_jit and
# bsfs_jax.use_fast_compilation); "bsfs_jax" is its top-level API.


def read_layer_table(text: str) -> dict[str, set[str]]:
    """{layer: the layers it may import} from ARCHITECTURE.md's "Layers" table."""
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    table = {}
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        table[cells[0].strip("`")] = set(re.findall(r"`([\w.]+)`", cells[-1]))
    return table


ALLOWED = read_layer_table((ROOT / "docs" / "ARCHITECTURE.md").read_text())
# identification's sub-packages: each a job; they use one another through their
# `__init__` only (the private-module test below), and only the top-level API and the
# forecast itself use the forecast.
FORECAST = "identification.forecasting"


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The project modules that `name` imports (a `from X import y` counts as X.y where y
    is a module, else as X)."""
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base if is_pkg else base[:-1]
                base = base[:len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            targets = [f"{module}.{a.name}" if f"{module}.{a.name}" in MODULES else module
                       for a in node.names]
        else:
            continue
        found |= {t for t in targets if t.split(".")[0] in PACKAGES}
    return found


EDGES = {name: _imports(name, path) for name, path in MODULES.items()}


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] == "identification":
        return "identification"
    return parts[1] if len(parts) > 1 else "bsfs_jax"


def _package(module: str) -> str:
    """The package a module belongs to (its folder)."""
    path = MODULES[module]
    parts = path.relative_to(ROOT).parent.parts
    return ".".join(parts)


def test_the_layers_table_names_every_package():
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    for layer in ALLOWED:
        if layer in ("files", "bsfs_jax", "_numerics"):
            continue
        assert f"`bsfs_jax/{layer}" in doc or f"`{layer}/`" in doc, layer
    assert "tests/test_layers.py" in doc


def test_each_package_imports_only_the_layers_above_it():
    wrong = []
    for module, targets in EDGES.items():
        src = _layer(module)
        for t in targets:
            dst = _layer(t)
            if dst != src and dst not in ALLOWED[src]:
                wrong.append(f"{module} imports {t} ({src} may not use {dst})")
    assert not wrong, "\n".join(wrong)


def test_no_module_imports_another_package_s_private_module():
    wrong = []
    for module, targets in EDGES.items():
        for t in targets:
            private = any(p.startswith("_") for p in t.split(".")[1:])
            if not private or t not in MODULES:
                continue
            owner = _package(t)
            mine = _package(module)
            # bsfs_jax's own utility modules serve every package of bsfs_jax
            if owner == "bsfs_jax" and mine.startswith("bsfs_jax"):
                continue
            if owner != mine:
                wrong.append(f"{module} imports {t}, private to {owner}")
    assert not wrong, "\n".join(wrong)


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in EDGES[v]:
            if w not in MODULES:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in MODULES:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    assert _cycles() == []


def test_the_import_reader_sees_relative_and_function_level_imports():
    """The checks above would pass vacuously if these were missed."""
    assert "identification.records._csv" in EDGES["identification.records._load"]  # ._csv
    assert "bsfs_jax.solvers" in EDGES["bsfs_jax.analysis._orbit_trials"]  # from ..solvers
    # inside a function (identification/report/_report.py, `identify`)
    assert "identification.records" in EDGES["identification.report._report"]
    EDGES["identification.records._records"].add("identification.records._load")  # made up
    try:
        assert any({"identification.records._load", "identification.records._records"}
                   <= set(c) for c in _cycles())
    finally:
        EDGES["identification.records._records"].discard("identification.records._load")


def test_only_the_api_and_the_forecast_use_the_forecast():
    """The forecast sits on the identification's result: no other job of identification
    imports it (identification/__init__ re-exports its public names)."""
    wrong = [f"{m} imports {t}" for m, targets in EDGES.items() for t in targets
             if t.startswith(FORECAST) and not m.startswith(FORECAST)
             and m != "identification"]
    assert not wrong, "\n".join(wrong)


def test_a_residual_evaluation_walks_the_measurement_package_only():
    """The measurement model (identification/measurement) imports no other job of
    identification but the records it reads: one residual evaluation never leaves it."""
    own = ("identification.measurement", "identification.records")
    wrong = [f"{m} imports {t}" for m, targets in EDGES.items()
             if m.startswith(own[0]) for t in targets
             if t.startswith("identification") and not t.startswith(own)]
    assert not wrong, "\n".join(wrong)
