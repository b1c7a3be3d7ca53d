"""The import rules of docs/ARCHITECTURE.md hold for every module: no package
imports one above it (the table there is read, not copied); inside a
package the modules form one order, with no cycle however late an import
comes (the runtime's, the order ARCHITECTURE.md draws); and an import waits
inside a function only for a reason LATER gives. `python tests/test_imports.py`
prints each package's cycles and imports inside functions.

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


def table_rows(name: str) -> list:
    """The cells of each row of ARCHITECTURE.md's table marked `name`."""
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    table = text.split(f"<!-- {name}: read by tests/test_imports.py -->")[1].split(f"<!-- end of {name} -->")[0]
    return [[c.strip() for c in row.strip().strip("|").split("|")] for row in table.splitlines()]


def rules() -> dict:
    """{package: the packages it may import}, from ARCHITECTURE.md's table."""
    allowed = {}
    for cells in table_rows("import rules"):
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


# ---- inside a package: its modules form one order, and an import waits
# inside a function only for a reason

CYCLE_PACKAGES = ("core", "prep", "runtime", "trainer", "serve", "cli", "blender")


def package_files(package: str) -> dict:
    """{module name: its path from the root} of a package's files."""
    return {names(path)[0]: path for path in (str(p.relative_to(ROOT)) for p in sorted((ROOT / package).glob("*.py")))}


def module_imports(source: str, path: str, modules=()) -> list:
    """(module imported, the function it is imported in: None at module
    level) for each import of the file at `path`, at any depth, relative or
    absolute. `from . import write` imports sinshape.runtime.write where that
    is one of `modules`, and the package itself where it is not (`from .
    import Part`). An import_module of a computed name (runtime/__init__.py's
    lazy table) imports each of `modules` whose name, or last part, the file
    spells as a string."""
    module, package = names(path)
    found, computing = [], []

    def visit(node, function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.Import):
                found.extend((alias.name, function) for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = absolute(child.module or "", child.level, package)
                found.extend((f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules
                               or not base.startswith("sinshape") else base, function) for alias in child.names)
            elif isinstance(child, ast.Call) and child.args and \
                    getattr(child.func, "attr", getattr(child.func, "id", None)) in ("import_module", "__import__"):
                for text, whole in spelled(child.args[0]):
                    level = len(text) - len(text.lstrip("."))
                    if not whole:
                        computing.append(function)
                    elif level:  # relative: import_module(".x", __name__ or __package__)
                        found.append((absolute(text[level:], level, package), function))
                    else:
                        found.append((text, function))
            visit(child, child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else function)

    tree = ast.parse(source)
    visit(tree, None)
    if computing:
        spelt = {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)}
        found.extend((name, computing[0]) for name in modules
                     if name != module and (name in spelt or name.rpartition(".")[2] in spelt))
    return [(name, function) for name, function in found if name != module]


def import_graph(package: str) -> dict:
    """{module: the modules of its own package it imports, at any depth}."""
    files = package_files(package)
    return {module: sorted({name for name, _ in module_imports((ROOT / path).read_text(), path, files)
                            if name in files})
            for module, path in files.items()}


def cycles(graph: dict) -> list:
    """Every elementary cycle of a graph ({node: [nodes]}), each as a list of
    its nodes starting from its least, found once."""
    found = []

    def walk(start, node, path, on_path):
        for nxt in graph.get(node, ()):
            if nxt == start:
                found.append(path[:])
            elif nxt > start and nxt not in on_path:
                on_path.add(nxt)
                path.append(nxt)
                walk(start, nxt, path, on_path)
                path.pop()
                on_path.discard(nxt)

    for start in sorted(graph):
        walk(start, start, [start], {start})
    return found


def function_imports(package: str) -> list:
    """(path, module imported, function) of each import a package's files make inside a function."""
    files = package_files(package)
    return [(path, name, function) for path in files.values()
            for name, function in module_imports((ROOT / path).read_text(), path, files) if function]


def test_cycles_finds_each_cycle_once():
    graph = {"a": ["b"], "b": ["c", "a"], "c": ["a"], "d": ["d"], "e": ["a"]}
    assert sorted(cycles(graph)) == [["a", "b"], ["a", "b", "c"], ["d"]]
    assert cycles({"a": ["b"], "b": ["c"], "c": []}) == []


@pytest.mark.parametrize("source, seen", [
    ("from . import write\n", [("sinshape.runtime.write", None)]),
    ("from .write import mesh_bytes\n", [("sinshape.runtime.write", None)]),
    ("from . import SampleRequest\n", [("sinshape.runtime", None)]),
    ("from sinshape.runtime import world as worlds\n", [("sinshape.runtime.world", None)]),
    ("import sinshape.runtime.world\n", [("sinshape.runtime.world", None)]),
    ("def f():\n    from . import write\n", [("sinshape.runtime.write", "f")]),
    ("class A:\n    def f(self):\n        if x:\n            from ..runtime import write\n",
     [("sinshape.runtime.write", "f")]),
    ("import importlib\ndef f():\n    importlib.import_module('.write', __name__)\n",
     [("importlib", None), ("sinshape.runtime.write", "f")]),
    ("import importlib\nT = {'a': 'write'}\ndef f(n):\n    importlib.import_module(f'.{T[n]}', __name__)\n",
     [("importlib", None), ("sinshape.runtime.write", "f")]),
])
def test_every_form_of_an_import_inside_a_package_is_an_edge(source, seen):
    modules = {"sinshape.runtime", "sinshape.runtime.write", "sinshape.runtime.world"}
    assert module_imports(source, "runtime/many.py", modules) == seen


@pytest.mark.parametrize("package", CYCLE_PACKAGES)
def test_a_package_has_no_cycle(package):
    """docs/ARCHITECTURE.md: the modules of a package form one order, imports
    inside functions counted: a module never needs, however late, a module
    that needs it."""
    found = cycles(import_graph(package))
    assert not found, f"{package} has import cycles: " + "; ".join(
        " -> ".join(name.rpartition(".")[2] or name for name in cycle + cycle[:1]) for cycle in found)


def runtime_rows() -> dict:
    """{runtime module: its row} from ARCHITECTURE.md's table of the runtime's order."""
    rows = {}
    for cells in table_rows("runtime order"):
        if cells[0].isdigit():
            rows.update({f"sinshape.runtime.{name}": int(cells[0]) for name in re.findall(r"`(\w+)`", cells[1])})
    return rows


def test_the_runtime_stands_in_the_order_architecture_draws():
    """Each runtime module is in one row of the table, and imports only
    modules of the rows above (runtime/__init__.py, above them all, imports
    its public names on first use)."""
    rows, graph = runtime_rows(), import_graph("runtime")
    assert set(rows) == set(graph) - {"sinshape.runtime"}, "ARCHITECTURE.md's runtime order lists other modules"
    climbing = [f"{module.rpartition('.')[2]} (row {rows[module]}) imports {name.rpartition('.')[2]} (row {rows[name]})"
                for module, imported in graph.items() if module in rows for name in imported
                if rows[name] >= rows[module]]
    assert not climbing, f"imports that climb ARCHITECTURE.md's runtime order: {climbing}"


# What may be imported inside a function, and why; anything else is imported
# at the top of its module, where its cost and its failure show at once.
# A module name is matched with everything under it; a (place, module) key
# holds only in the files whose path starts with the place.
LATER = {
    "torch": "the train extra (several hundred MB), asked for only by training",
    "onnx": "the train extra",
    "scipy": "the prep extra",
    "h5py": "the prep extra",
    "skimage": "the prep extra",
    "meshoptimizer": "the assets extra",
    "xatlas": "the assets extra",
    "coacd": "the assets extra, for convex hulls alone",
    "ray": "the ray extra",
    "uvicorn": "the serve extra",
    "h11": "the serve extra's (uvicorn's) HTTP parser",
    "trimesh": "half a second to import: only a whole mesh in memory needs it, a streamed .ply does not",
    "PIL": "pillow: Blender's Python has none of its own (tools/build_blender.py bundles it), and the extension "
           "imports the runtime's worlds and assets; only an image needs it",
    "importlib.metadata": "costs more than the rest of an import, and only __version__ needs it",
    "resource": "Unix only: Windows has none",
    ("runtime/", "sinshape.prep"): "the prep extra (scipy, h5py, scikit-image): evaluation and mesh layouts only",
    ("runtime/__init__.py", "sinshape.runtime"): "the package's public names, each imported on first use",
    ("cli/", "sinshape"): "sinrun --help stays instant: a command imports numpy, onnxruntime, torch or fastapi "
                         "when it runs",
}


def later_reason(path: str, name: str) -> str | None:
    """Why `name` may be imported inside a function of the file at `path` (None: it may not)."""
    for key, reason in LATER.items():
        place, module = key if isinstance(key, tuple) else ("", key)
        if path.startswith(place) and (name == module or name.startswith(module + ".")):
            return reason
    return None


@pytest.mark.parametrize("package", CYCLE_PACKAGES)
def test_an_import_waits_inside_a_function_only_for_a_reason(package):
    waiting = [f"{path}: {name} in {function}()" for path, name, function in function_imports(package)
               if later_reason(path, name) is None]
    assert not waiting, f"imports inside functions with no reason in LATER (tests/test_imports.py): {waiting}"


def test_later_reasons_hold_for_their_package_only():
    assert later_reason("runtime/world.py", "trimesh.exchange") is not None
    assert later_reason("cli/main.py", "sinshape.runtime.write") is not None
    assert later_reason("runtime/many.py", "sinshape.runtime.write") is None
    assert later_reason("runtime/__init__.py", "sinshape.runtime.write") is not None
    assert later_reason("serve/app.py", "sinshape.runtime.write") is None
    assert later_reason("runtime/world.py", "json") is None


if __name__ == "__main__":  # the figures: python tests/test_imports.py
    for package in CYCLE_PACKAGES:
        found, waiting = cycles(import_graph(package)), function_imports(package)
        own = sum(name.startswith(f"sinshape.{package}") for _, name, _ in waiting)
        print(f"{package:8} {len(found):3} cycles  {len(waiting):3} names imported inside functions "
              f"({own} of its own package, {sum(later_reason(p, n) is None for p, n, _ in waiting)} without a reason)")
        for cycle in found:
            print("    " + " -> ".join(name.rpartition(".")[2] for name in cycle + cycle[:1]))
