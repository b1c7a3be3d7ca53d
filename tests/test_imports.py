"""The import rules of docs/ARCHITECTURE.md hold for every module: no package
imports one above it (the table there is read, not copied)."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "prep", "runtime", "trainer", "models", "serve", "cli", "blender")


def rules() -> dict:
    """{package: the packages it may import}, from ARCHITECTURE.md's table."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    table = text.split("<!-- import rules: read by tests/test_imports.py -->")[1].split("<!-- end of import rules -->")[0]
    allowed = {}
    for row in table.splitlines():
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        if len(cells) == 2 and cells[0].startswith("`"):
            allowed[cells[0].strip("`")] = set(re.findall(r"`(\w+)`", cells[1]))
    return allowed


def imported(source: str, package: str) -> set:
    """The sinshape packages (and torch) a module's source imports, at any depth."""
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            names = [package] if node.level else [node.module or ""]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "sinshape" and len(parts) > 1:
                found.add(parts[1])
            elif parts[0] == "torch":
                found.add("torch")
    return found


def violations(source: str, package: str, allowed: dict) -> set:
    return imported(source, package) - allowed[package] - {package}


def test_the_table_names_every_package():
    assert set(rules()) == set(PACKAGES)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_imports_what_its_package_may_not(package):
    allowed = rules()
    bad = {}
    for path in sorted((ROOT / package).glob("*.py")):
        wrong = violations(path.read_text(), package, allowed)
        if wrong:
            bad[path.name] = sorted(wrong)
    assert not bad, f"{package} imports what docs/ARCHITECTURE.md forbids: {bad}"


def test_a_forbidden_import_is_caught_wherever_it_hides():
    allowed = rules()
    assert violations("def f():\n    from sinshape.runtime import generate\n", "prep", allowed) == {"runtime"}
    assert violations("import sinshape.trainer.train\n", "runtime", allowed) == {"trainer"}
    assert violations("from sinshape.serve.app import run\n", "core", allowed) == {"serve"}
    assert violations("import torch\n", "runtime", allowed) == {"torch"}
    assert violations("from . import generate\n", "runtime", allowed) == set()
