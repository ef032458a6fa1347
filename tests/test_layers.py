"""The map of the house holds (docs/ARCHITECTURE.md, "Layers"): every package imports only
the packages its layer may use, no module imports another package's private module, and
no two modules import each other, directly or round a loop. Read from the source with
`ast` (imports inside functions and under TYPE_CHECKING count too); no JAX needed."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("bsfs_jax", "identification")

# What each layer may import: ARCHITECTURE.md's table, top to bottom. "_files",
# "_programs", "_numerics", "_lazy" and "_host" are bsfs_jax's own utility modules (files,
# programs and the host settings are public as bsfs_jax.files, bsfs_jax.cached_jit and
# bsfs_jax.use_fast_compilation); "bsfs_jax" is its top-level API.
_UTIL = {"_files", "_numerics"}
ALLOWED = {
    "_files": set(),
    "files": {"_files"},
    "_numerics": set(),
    "_lazy": set(),
    "_host": set(),
    "_prefetch": set(),
    "_programs": {"_files", "_prefetch"},
    "params": {"_files", "_numerics"},
    "physics": {"_numerics"},
    "model": {"params", "physics", "_numerics"},
    "solvers": {"_programs"} | _UTIL,
    "machine": {"params", "model", "solvers", "_programs", "_lazy"} | _UTIL,
    "analysis": {"machine", "model", "solvers", "params", "files", "_programs"} | _UTIL,
    "design": {"machine", "model", "solvers", "params", "_programs", "_lazy"} | _UTIL,
    # identification sits on bsfs_jax's public API only (no private module of it)
    "identification": {"bsfs_jax", "files", "params", "physics", "model", "solvers",
                       "machine", "analysis", "design"},
    "plotting": {"analysis", "_files"},
    "monitoring": {"_files", "_numerics", "files"},
    "reproduce": {"_files", "_numerics", "params", "physics", "model", "solvers", "machine",
                  "analysis", "design", "plotting"},
    "cli": {"_files", "_numerics", "_programs", "_host", "bsfs_jax", "files", "params", "physics",
            "model", "solvers", "machine", "analysis", "design", "identification",
            "plotting", "reproduce", "monitoring"},
    "bsfs_jax": {"_programs", "_lazy", "_host", "params", "physics", "model", "solvers", "machine"},
}


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
    assert "identification._csv" in EDGES["identification._load"]  # from ._csv import
    assert "bsfs_jax.solvers" in EDGES["bsfs_jax.analysis._orbit_trials"]  # from ..solvers
    assert "identification._load" in EDGES["identification._report"]  # inside a function
    EDGES["identification._records"].add("identification._load")  # a loop, made up
    try:
        assert any({"identification._load", "identification._records"} <= set(c)
                   for c in _cycles())
    finally:
        EDGES["identification._records"].discard("identification._load")
