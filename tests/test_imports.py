"""The import rules of docs/ARCHITECTURE.md hold for every module: no package
imports one above it (the table there is read, not copied).

Every way of naming a module counts: `import sinshape.x`, `from sinshape
import x`, `from sinshape.x import y`, relative imports (`from .. import x`,
`from ..x import y`), imports inside functions, and importlib.import_module
or __import__ of a name the source spells out (a constant, or an f-string
whose head says which package). A module that imports a name it computes
(runtime/__init__.py's lazy table) has each string naming a sinshape module
read as an import of it."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "prep", "runtime", "trainer", "models", "serve", "cli", "blender")
UNREADABLE = "an import_module of sinshape whose package the source does not spell out"


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


def names(path: str) -> tuple:
    """(module, package) of a file: runtime/write.py -> (sinshape.runtime.write,
    sinshape.runtime); runtime/__init__.py -> (sinshape.runtime, sinshape.runtime)."""
    parts = ("sinshape",) + Path(path).with_suffix("").parts
    package = ".".join(parts[:-1])
    return (package, package) if parts[-1] == "__init__" else (".".join(parts), package)


def absolute(name: str, level: int, package: str) -> str:
    """A relative module name made absolute from `package`, as Python resolves it."""
    if not level:
        return name
    base = package.split(".")[:len(package.split(".")) - level + 1]
    return ".".join(base + ([name] if name else []))


def layer(name: str) -> str | None:
    """The sinshape package (or torch) a whole dotted module name is in."""
    parts = name.split(".")
    if parts[0] == "torch":
        return "torch"
    return parts[1] if parts[0] == "sinshape" and len(parts) > 1 else None


def head_layer(head: str) -> str | None:
    """The same for the known head of a name whose tail is computed (an
    f-string): UNREADABLE where the head is sinshape's but stops before the package."""
    spelled_out = head.rpartition(".")[0]
    if spelled_out.split(".")[0] == "torch" or spelled_out.count(".") >= 1:
        return layer(spelled_out)
    return UNREADABLE if head and ("sinshape.".startswith(head) or head.startswith("sinshape.")) else None


def spelled(node) -> list:
    """(text, whole) for each string an import_module argument can be: a
    constant is whole; an f-string gives its constant head; a conditional
    either branch; anything else is computed: an empty head."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [(node.value, True)]
    if isinstance(node, ast.JoinedStr):
        head = ""
        for value in node.values:
            if not isinstance(value, ast.Constant):
                return [(head, False)]
            head += value.value
        return [(head, True)]
    if isinstance(node, ast.IfExp):
        return spelled(node.body) + spelled(node.orelse)
    return [("", False)]


def dynamic(call: ast.Call, module: str, package: str) -> tuple:
    """(the packages an importlib.import_module or __import__ call imports,
    whether its name is computed)."""
    func = call.func
    called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if called not in ("import_module", "__import__") or not call.args:
        return set(), False
    anchor = call.args[1] if called == "import_module" and len(call.args) > 1 else None
    if isinstance(anchor, ast.Name):
        anchor = {"__name__": module, "__package__": package}.get(anchor.id)
    anchor = anchor.value if isinstance(anchor, ast.Constant) else anchor
    found, texts = set(), spelled(call.args[0])
    for text, whole in texts:
        level = len(text) - len(text.lstrip("."))
        if level and not isinstance(anchor, str):
            found.add(UNREADABLE)
        elif not whole:
            found.add(head_layer(absolute("", level, anchor) + "." + text[level:] if level else text))
        else:
            found.add(layer(absolute(text[level:], level, anchor)))
    return found, ("", False) in texts


def imported(source: str, path: str) -> set:
    """The sinshape packages (and torch) the source of the file at `path`
    (runtime/write.py) imports, in any form and at any depth."""
    module, package = names(path)
    tree = ast.parse(source)
    found, computed = set(), False
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(layer(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = absolute(node.module or "", node.level, package)
            if base == "sinshape":  # from sinshape import trainer; from .. import trainer
                found.update(alias.name for alias in node.names)
            else:
                found.add(layer(base))
        elif isinstance(node, ast.Call):
            packages, computes = dynamic(node, module, package)
            found |= packages
            computed |= computes
    if computed:  # a table of names to import: each that names a sinshape module counts
        found.update(layer(node.value) for node in ast.walk(tree) if isinstance(node, ast.Constant)
                     and isinstance(node.value, str) and re.fullmatch(r"sinshape(\.\w+)+", node.value)
                     and node.value.split(".")[1] in PACKAGES)
    found.discard(None)
    return found


def violations(source: str, path: str, allowed: dict) -> set:
    package = Path(path).parts[0]
    return imported(source, path) - allowed[package] - {package}


def test_the_table_names_every_package():
    assert set(rules()) == set(PACKAGES)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_imports_what_its_package_may_not(package):
    allowed = rules()
    bad = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        wrong = violations(path.read_text(), str(path.relative_to(ROOT)), allowed)
        if wrong:
            bad[str(path.relative_to(ROOT))] = sorted(wrong)
    assert not bad, f"{package} imports what docs/ARCHITECTURE.md forbids: {bad}"


def test_a_forbidden_import_is_caught_wherever_it_hides():
    allowed = rules()
    assert violations("def f():\n    from sinshape.runtime import generate\n", "prep/x.py", allowed) == {"runtime"}
    assert violations("import sinshape.trainer.train\n", "runtime/x.py", allowed) == {"trainer"}
    assert violations("from sinshape.serve.app import run\n", "core/x.py", allowed) == {"serve"}
    assert violations("import torch\n", "runtime/x.py", allowed) == {"torch"}
    assert violations("from . import generate\n", "runtime/x.py", allowed) == set()


# One planted violation of each form: runtime may not import trainer (nor torch).
FORMS = {
    "import a package": "import sinshape.trainer\n",
    "import a module as a name": "import sinshape.trainer.train as t\n",
    "from sinshape import the package": "from sinshape import trainer\n",
    "from sinshape import several, renamed": "from sinshape import core as c, trainer as t\n",
    "from the package import a module": "from sinshape.trainer import train\n",
    "from .. import the package": "from .. import trainer\n",
    "from ..package import a name": "from ..trainer import train\n",
    "from ..package.module import a name": "from ..trainer.train import train\n",
    "inside a function": "def f():\n    from sinshape.trainer import train\n",
    "inside a method, under a condition": "class A:\n    def f(self):\n        if x:\n            import sinshape.trainer\n",
    "importlib.import_module of a constant": "import importlib\nimportlib.import_module('sinshape.trainer.train')\n",
    "import_module imported by name": "from importlib import import_module\nimport_module('sinshape.trainer')\n",
    "import_module relative to a constant package":
        "import importlib\nimportlib.import_module('.train', 'sinshape.trainer')\n",
    "import_module climbing out of __package__": "import importlib\nimportlib.import_module('..trainer', __package__)\n",
    "import_module of an f-string": "import importlib\nimportlib.import_module(f'sinshape.trainer.{name}')\n",
    "import_module of a computed name, from a table":
        "import importlib\nNAMES = {'x': 'sinshape.trainer.train'}\nimportlib.import_module(NAMES[n])\n",
    "__import__": "__import__('sinshape.trainer.train')\n",
    "torch, from a function": "def f():\n    from torch import nn\n",
}


@pytest.mark.parametrize("form", FORMS)
def test_each_form_of_a_forbidden_import_is_caught(form):
    found = violations(FORMS[form], "runtime/x.py", rules())
    assert found == ({"torch"} if "torch" in form else {"trainer"}), found


@pytest.mark.parametrize("source", [
    "from . import generate\n",
    "from .generate import sample\n",
    "from .. import core\n",
    "from ..core.errors import InputError\n",
    "import importlib\nimportlib.import_module('.generate', __name__)\n",
    "import importlib\nimportlib.import_module(f'.{name}', __name__)\n",
    "import importlib\nT = {'a': 'sinshape.core.errors', 'b': 'load'}\nm = T[n]\n"
    "importlib.import_module(m if '.' in m else f'.{m}', __name__)\n",
    "import importlib\nimportlib.import_module('numpy')\n",
    "log = 'sinshape.trainer'  # a string is no import where nothing is imported by a computed name\n",
])
def test_what_a_package_may_import_is_not_flagged(source):
    assert violations(source, "runtime/__init__.py", rules()) == set()


def test_an_import_module_that_does_not_say_which_package_is_flagged():
    found = violations("import importlib\nimportlib.import_module(f'sinshape.{name}')\n", "runtime/x.py", rules())
    assert found == {UNREADABLE}
