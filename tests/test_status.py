"""The documents the project generates match their generators, and they read as a manual.

README's status table is scripts/status.py's output from docs/status.toml and the
committed outputs; BENCHMARKS.md is benchmarks/run_all.py's assembly of
benchmarks/results/*.md. A hand edit of either, or an output changed without regenerating
them, fails here: run `make status` or `python benchmarks/run_all.py --assemble-only`.
The documents' links resolve, the status table's cells are short, ARCHITECTURE.md's layer
table is the one tests/test_layers.py enforces, and no document reads as a diary.
Files only, no JAX compilation.
"""

import importlib.util
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests import run_each

ROOT = Path(__file__).resolve().parents[1]


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


status = _load("bsfs_status_script", ROOT / "scripts" / "status.py")
run_all = _load("bsfs_run_all_script", ROOT / "benchmarks" / "run_all.py")


def _git(*args):
    try:
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True,
                              text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None


def _record_candidates():
    """tests/last_run.json as on disk, and as committed when a local `make test` has
    rewritten it since (the README then legitimately still shows the committed run)."""
    out = [status.FROM_DISK]
    if _git("rev-parse", "--git-dir") is None or _git("rev-parse", "--git-dir").returncode:
        return out
    shown = _git("show", f"HEAD:{status.RECORD}")
    if shown is not None and shown.returncode == 0:
        try:
            out.append(json.loads(shown.stdout))
        except json.JSONDecodeError:
            pass
    else:
        out.append(None)  # not committed: the README may show "no recorded run"
    return out


def _table_rows(block: str) -> list[list[str]]:
    """The cells of the status table's body rows."""
    rows = []
    for ln in block.splitlines():
        if ln.startswith("| ") and not ln.startswith("| area |"):
            rows.append([c.strip() for c in re.split(r"(?<!\\)\|", ln)[1:-1]])
    return rows


def _rows_by_area(block):
    return {r[0]: dict(zip(status.COLUMNS, r, strict=True)) for r in _table_rows(block)}


def _copy_tree(tmp_path):
    for rel in ["README.md", "BENCHMARKS.md", status.TEMPLATES, "docs/REPRODUCTION.md",
                "docs/ROUTE_TO_CHAOS.md", status.RECORD, "bsfs_jax/design/_catalogue.py"]:
        if (ROOT / rel).exists():
            (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(ROOT / rel, tmp_path / rel)
    shutil.copytree(ROOT / "benchmarks" / "results", tmp_path / "benchmarks" / "results")
    shutil.copytree(ROOT / "bsfs_jax" / "params" / "presets",
                    tmp_path / "bsfs_jax" / "params" / "presets")
    return tmp_path


# ------------------------------------------------------------------- generated documents


def test_readme_status_block_is_the_generators_output():
    before, block, after = status.split_readme((ROOT / "README.md").read_text(encoding="utf-8"))
    rendered = [status.render(ROOT, test_record=rec)[0] for rec in _record_candidates()]
    if block not in rendered:
        pytest.fail("README.md's status table is not scripts/status.py's output: "
                    f"{status.diff_summary(block, rendered[0])}; run `make status` "
                    "(`python scripts/status.py`), and edit docs/status.toml, not README.md")


def test_the_status_table_has_one_short_line_per_area():
    _, block, _ = status.split_readme((ROOT / "README.md").read_text(encoding="utf-8"))
    rows = _table_rows(block)
    areas = [r["area"] for r in status.load_templates(ROOT)["row"]]
    assert [r[0] for r in rows] == areas  # one line per area, in the templates' order
    for row in rows:
        assert len(row) == len(status.COLUMNS), row[0]
        for cell in row:
            assert len(cell) <= status.MAX_CELL, (row[0], len(cell), cell[:60])


def test_the_generator_refuses_a_long_cell(tmp_path):
    root = _copy_tree(tmp_path)
    toml = root / status.TEMPLATES
    text = toml.read_text()
    marker = "Done. Validated on textbook systems"
    assert marker in text
    toml.write_text(text.replace(marker, "Very long. " * 30 + marker, 1))
    with pytest.raises(SystemExit, match="Sweeps and analysis.*at most 300"):
        status.render(root)


def test_benchmarks_md_is_the_assembly_of_the_results():
    text = (ROOT / "BENCHMARKS.md").read_text()
    expected = run_all.assemble() + "\n"
    assert text == expected, (
        f"BENCHMARKS.md: {run_all.diff_summary(text, expected)}; run "
        "`python benchmarks/run_all.py --assemble-only` (edit benchmarks/results/*.md)")


def test_each_benchmark_section_names_its_command_machine_and_date():
    for path in run_all._results():
        text = path.read_text()
        assert re.search(r"^## [A-Z]\d ", text, re.M), f"{path.name}: no '## X1 Title' heading"
        for word in ("Command:", "Machine", "Date"):
            assert word in text, f"{path.name} does not say its {word.rstrip(':')}"
        assert re.search(r"^\|.*\|$", text, re.M), f"{path.name} has no table"


def test_the_generator_reads_no_ignored_file():
    """Every file it reads is one a fresh clone can have (nothing under out/, .venv/...)."""
    if _git("rev-parse", "--git-dir") is None or _git("rev-parse", "--git-dir").returncode:
        pytest.skip("not a git checkout")
    _, src = status.render(ROOT)
    read = sorted(set(src.read) | {str(p.relative_to(ROOT)) for p in
                                   (ROOT / "benchmarks" / "results").glob("*.md")})
    ignored = _git("check-ignore", *read)
    assert ignored.stdout.strip() == "", f"reads git-ignored files: {ignored.stdout.split()}"


def test_every_placeholder_is_known_and_found():
    templates = status.load_templates(ROOT)
    values = status.collect(status.Sources(ROOT), templates)
    parts = [row.get(k, "") for row in templates["row"] for k in ("state", "measured")]
    parts.append(templates.get("footer", ""))
    names = {n for p in parts for n in status._PLACEHOLDER.findall(p)}
    assert names <= set(values), sorted(names - set(values))
    # In this tree every committed output is there: no figure is "?".
    missing = {n: values[n].why for n in names if isinstance(values[n], status.Missing)}
    assert not missing, missing


def test_a_missing_output_is_said_not_replaced_by_an_old_number(tmp_path):
    root = _copy_tree(tmp_path)
    (root / "benchmarks" / "results" / "b1_sweep.json").unlink()
    (root / "docs" / "REPRODUCTION.md").unlink()
    block, _ = status.render(root, test_record=None)
    rows = _rows_by_area(block)
    sweeps = rows["Sweeps and analysis"]
    assert ("not measured in this clone: no benchmarks/results/b1_sweep.json"
            in sweeps["measured"])
    assert "4.67" not in sweeps["measured"] and "259x" not in sweeps["measured"]
    assert "? s on one core" in sweeps["measured"]
    assert "Validated on textbook systems" in sweeps["state"]  # the other cells stay
    assert "no docs/REPRODUCTION.md" in rows["Reproduction of the paper"]["measured"]
    assert "reproduced 1" not in rows["Reproduction of the paper"]["measured"]
    assert rows["Design"]["tests"] == "no recorded run in this clone"
    assert all(len(c) <= status.MAX_CELL for r in rows.values() for c in r.values())


def test_check_fails_on_a_hand_edit_and_the_generator_repairs_it(tmp_path):
    root = _copy_tree(tmp_path)
    script = [sys.executable, str(ROOT / "scripts" / "status.py"), "--root", str(root)]
    readme = root / "README.md"
    status.main(["--root", str(root)])  # up to date with this copy, whatever the record
    readme.write_text(readme.read_text().replace("cold points", "cold points!", 1))
    res = subprocess.run(script + ["--check"], capture_output=True, text=True)
    assert res.returncode == 1
    assert "1 row(s) differ (Sweeps and analysis)" in res.stdout
    assert len(res.stdout.strip().splitlines()) == 1
    res = subprocess.run(script, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert subprocess.run(script + ["--check"], capture_output=True).returncode == 0
    text = readme.read_text()
    assert text.count(status.BEGIN) == 1 and "## Read more" in text  # the rest is kept


def test_test_counts_come_from_the_record():
    rec = {"date_utc": "2030-01-02 03:04", "seconds": 600.0, "jobs": 2, "pytest_args": [],
           "slow_tests": False, "load_average_at_start": [1.5, 1, 1],
           "machine": {"cpu": "CPU", "cores": 2}, "files": 2, "failed_files": ["test_cli.py"],
           "totals": {"passed": 11, "failed": 1, "errors": 0, "skipped": 2},
           "per_file": [
               {"file": "test_cli.py", "status": "FAILED", "exit_code": 1, "seconds": 500.0,
                "passed": 9, "failed": 1, "errors": 0, "skipped": 0},
               {"file": "test_new.py", "status": "ok", "exit_code": 0, "seconds": 100.0,
                "passed": 2, "failed": 0, "errors": 0, "skipped": 2}]}
    block, _ = status.render(ROOT, test_record=rec)
    rows = _rows_by_area(block)
    cli = rows["Command line"]["tests"]
    assert cli.startswith("9 passed, **1 failed** in 1 file")
    assert "**failed: `test_cli.py`**" in cli
    assert "not in the last recorded run: `test_fuzz.py`" in cli
    assert rows["Physics and parameters"]["tests"] == (
        "none recorded; not in the last recorded run: `test_physics.py`, `test_params.py`")
    assert rows["Tests and CI"]["tests"] == "2 passed, 2 skipped in 1 file"  # unassigned
    assert "11 passed, **1 failed**, 2 skipped in 2 files" in rows["Tests and CI"]["measured"]
    assert "last recorded `make test`, 2030-01-02 03:04 UTC" in block


# ------------------------------------------------------------------ documents as a manual

_DOCS = ["README.md", "BENCHMARKS.md", "CHANGELOG.md", *sorted(
    str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
_DIARY = re.compile(r"\bsessions?\b|\bissues?\s*#?\d+", re.I)


def _prose_files():
    """(path, text) of the project's documents, the status templates, the benchmark and
    study scripts, the benchmarks' results and the notebooks' text cells."""
    files = [ROOT / p for p in _DOCS] + [ROOT / "docs" / "status.toml",
                                         ROOT / "data" / "README.md"]
    for folder, patterns in (("benchmarks", ("*.py", "*.sh")), ("scripts", ("*.py",)),
                             ("benchmarks/results", ("*.md", "*.json"))):
        for pattern in patterns:
            files += sorted((ROOT / folder).glob(pattern))
    out = [(p, p.read_text(encoding="utf-8")) for p in files if p.is_file()]
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(nb.read_text(encoding="utf-8"))["cells"]
        out.append((nb, "\n".join("".join(c["source"]) for c in cells
                                  if c["cell_type"] == "markdown")))
    return out


def test_no_document_reads_as_a_diary():
    """Say what changed and why; which work session or issue it came from is git's."""
    found = [f"{p.relative_to(ROOT)}: {m.group(0)!r}" for p, text in _prose_files()
             for m in _DIARY.finditer(text)]
    assert not found, "\n".join(found[:20])


def _links(text):
    """Markdown link and image targets outside code blocks and code spans."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return re.findall(r"\]\(([^)\s]+)\)", text)


def _anchors(path: Path) -> set[str]:
    return {run_all.slug(m) for m in re.findall(r"^#+ (.+)$", path.read_text(), re.M)}


@pytest.mark.parametrize("doc", _DOCS)
def test_the_documents_links_resolve(doc):
    path = ROOT / doc
    broken = []
    for target in _links(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(target)
    assert not broken, f"{doc}: {broken}"


def test_every_cited_section_of_physics_md_exists():
    """The code and the documents cite the contract as "physics.md section N" (or §N):
    docs/physics.md has each of those sections."""
    headings = set(re.findall(r"^## (\d+)\. ", (ROOT / "docs" / "physics.md").read_text(),
                              re.M))
    cited = {}
    for folder in ("bsfs_jax", "identification", "tests", "scripts", "benchmarks", "docs",
                   "notebooks"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix not in (".py", ".md", ".toml", ".ipynb") or not path.is_file():
                continue
            text = path.read_text(encoding="utf-8", errors="replace")
            for m in re.finditer(r"physics\.md(?:'s)?,?\s+(?:sections?|§|s)\s?(\d+)", text):
                cited.setdefault(m.group(1), str(path.relative_to(ROOT)))
    assert cited, "found no citation of physics.md: the pattern is stale"
    missing = {n: where for n, where in cited.items() if n not in headings}
    assert not missing, f"docs/physics.md lacks the sections cited: {missing}"


def test_architecture_s_layer_table_is_the_one_the_layer_test_enforces():
    """tests/test_layers.py enforces the table it reads from docs/ARCHITECTURE.md, and the
    table has a row for every package of the source."""
    from tests import test_layers as layers

    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    assert layers.ALLOWED == layers.read_layer_table(text)
    packages = {p.parent.name for p in (ROOT / "bsfs_jax").glob("*/__init__.py")}
    assert packages <= set(layers.ALLOWED), packages - set(layers.ALLOWED)
    assert {"identification", "cli", "bsfs_jax"} <= set(layers.ALLOWED)


# ------------------------------------------------------------- the test runner's record


def test_run_each_reads_pytest_summary_lines():
    parse = run_each.parse_summary
    assert parse("...\n1 failed, 7 passed, 1 skipped, 2 warnings in 3.10s\n") == {
        "passed": 7, "failed": 1, "errors": 0, "skipped": 1}
    assert parse("= 2 passed, 1 error in 9.0s (0:00:09) =")["errors"] == 1
    assert parse("3 deselected in 0.50s")["deselected"] == 3
    assert parse("no tests ran in 0.01s")["passed"] == 0
    assert parse("Fatal Python error: Segmentation fault") is None


def test_run_each_records_the_run(tmp_path, monkeypatch, capsys):
    (tmp_path / "test_tiny.py").write_text(
        "import pytest\n\ndef test_a():\n    pass\n\n\ndef test_b():\n    assert False\n\n\n"
        "@pytest.mark.skip\ndef test_c():\n    pass\n")
    record = tmp_path / "record.json"
    monkeypatch.setenv("BSFS_TEST_RECORD", str(record))
    monkeypatch.setenv("BSFS_TEST_JOBS", "1")
    assert run_each.main(["-p", "no:cacheprovider"], files=[tmp_path / "test_tiny.py"]) == 1
    out = capsys.readouterr().out
    assert "1 failed, 1 passed, 1 skipped" in out and "FAILED files (1): test_tiny.py" in out
    rec = json.loads(record.read_text())
    assert rec["totals"] == {"passed": 1, "failed": 1, "errors": 0, "skipped": 1}
    assert rec["failed_files"] == ["test_tiny.py"] and rec["files"] == 1
    assert rec["pytest_args"] == ["-p", "no:cacheprovider"]
    assert rec["machine"]["cores"] and len(rec["date_utc"]) == 16
    (row,) = rec["per_file"]
    assert row["file"] == "test_tiny.py" and row["status"] == "FAILED" and row["seconds"] > 0
    block, _ = status.render(ROOT, test_record=rec)  # the generator takes what it wrote
    assert "with pytest arguments `-p no:cacheprovider` (a partial run)" in block


def test_run_each_starts_a_unit_after_the_one_whose_programs_it_loads(monkeypatch):
    """The notebooks run a process each; each starts only after the file it follows has
    ended (the shared cache then holds its programs), and the longest chain goes first."""
    monkeypatch.setattr(run_each, "_SPLIT", {"test_nb.py": lambda: ["run[x]", "run[y]"]})
    units = run_each.units_of([Path("tests/test_a.py"), Path("tests/test_nb.py"),
                               Path("tests/test_b.py")])
    assert units == ["tests/test_a.py", "tests/test_nb.py::run[x]", "tests/test_nb.py::run[y]",
                     "tests/test_b.py"]
    monkeypatch.setattr(run_each, "_EXPECTED_S", {"test_a.py": 10, "test_b.py": 50,
                                                  "test_nb.py::run[x]": 45,
                                                  "test_nb.py::run[y]": 1})
    monkeypatch.setattr(run_each, "_AFTER", {"test_nb.py::run[x]": "test_a.py",
                                             "test_nb.py::run[y]": "test_missing.py"})
    # a's chain (10 + 45) is longer than b's 50; y's predecessor is not run: free to start
    assert [run_each._name(u) for u in run_each.order(units)] == [
        "test_a.py", "test_b.py", "test_nb.py::run[x]", "test_nb.py::run[y]"]
    events = []

    def run(unit):  # three slots: x alone must wait, for a, which takes longest
        events.append(("start", run_each._name(unit)))
        time.sleep(0.3 if unit.endswith("test_a.py") else 0.0)
        return run_each._name(unit)

    for name in run_each.run_ordered(units, 3, run):
        events.append(("end", name))
    assert events.index(("start", "test_nb.py::run[x]")) > events.index(("end", "test_a.py"))
    merged = run_each.merge_rows([
        {"file": "test_nb.py::run[x]", "status": "ok", "exit_code": 0, "seconds": 2.0,
         "passed": 1, "failed": 0},
        {"file": "test_nb.py::run[y]", "status": "FAILED", "exit_code": 1, "seconds": 3.0,
         "passed": 0, "failed": 1},
        {"file": "test_a.py", "status": "ok", "exit_code": 0, "seconds": 1.0, "passed": 4}])
    assert [r["file"] for r in merged] == ["test_a.py", "test_nb.py"]
    nb = merged[1]
    assert (nb["passed"], nb["failed"], nb["seconds"], nb["status"]) == (1, 1, 5.0, "FAILED")
    assert [u["node"] for u in nb["units"]] == ["run[x]", "run[y]"]


def test_run_all_check_is_one_line_and_exits_1_on_a_difference(tmp_path, monkeypatch, capsys):
    fake = tmp_path / "benchmarks"
    (fake / "results").mkdir(parents=True)
    (fake / "results" / "simulate.md").write_text("# S1\n\ntext\n")
    (fake / "results" / "b1_sweep_quick.md").write_text("# quick check\n")
    monkeypatch.setattr(run_all, "HERE", fake)
    assert run_all.main(["--assemble-only"]) == 0
    text = (tmp_path / "BENCHMARKS.md").read_text()
    assert "## S1" in text and "quick check" not in text
    capsys.readouterr()
    assert run_all.main(["--check"]) == 0
    (tmp_path / "BENCHMARKS.md").write_text(text.replace("text", "edited"))
    assert run_all.main(["--check"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1].startswith("BENCHMARKS.md differs") and "1 line(s) differ" in out[-1]
