"""Commands are thin: each parses, calls the library, and reports. The rules
and the work live in the library, which names its parameters; the CLI says
them as options."""

import ast
import os
import subprocess
import sys
import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli, command_line_message
from sinshape.core.errors import ConflictError, InputError

ROOT = Path(__file__).resolve().parent.parent
MAIN = ROOT / "cli" / "main.py"
MOST_LINES = 20
LIBRARY = ("core", "prep", "runtime", "trainer", "models", "serve")  # every package but the CLI
OPTION = re.compile(r"(?<![\w-])--[a-z]")


def command_bodies(source: str) -> dict:
    """{function name: lines of its body} for every function a click
    decorator (`@cli.command`, `@click.group`, ...) makes a command: the
    lines from its first statement after the docstring to its last."""
    bodies = {}
    for node in ast.parse(source).body:
        if not isinstance(node, ast.FunctionDef):
            continue
        decorators = [d.func if isinstance(d, ast.Call) else d for d in node.decorator_list]
        if not any(isinstance(d, ast.Attribute) and d.attr in ("command", "group") for d in decorators):
            continue
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            body = body[1:]  # the docstring is the help, not the body
        bodies[node.name] = body[-1].end_lineno - body[0].lineno + 1 if body else 0
    return bodies


def test_every_command_body_is_at_most_20_lines():
    bodies = command_bodies(MAIN.read_text())
    assert {command.callback.__name__ for command in cli.commands.values()} <= set(bodies)  # none is missed
    long = {name: lines for name, lines in bodies.items() if lines > MOST_LINES}
    assert not long, f"command bodies over {MOST_LINES} lines (move the work into the library): {long}"


def test_the_measure_counts_from_the_first_statement_to_the_last():
    source = ('@cli.command()\n@click.option("-n")\ndef c(n):\n    """Help."""\n    a = 1\n\n'
              '    if a:\n        b = (1,\n             2)\n')
    assert command_bodies(source) == {"c": 5}
    assert command_bodies("def helper():\n    a = 1\n    b = 2\n") == {}


def strings_naming_options(source: str) -> list:
    """The strings of a module that name a command-line option (`--seed`),
    docstrings left out: they may say what the command line does."""
    tree = ast.parse(source)
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
    return [node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docstrings and OPTION.search(node.value)]


def test_library_messages_name_parameters_not_options():
    found = {}
    for package in LIBRARY:
        for path in sorted((ROOT / package).rglob("*.py")):
            if strings := strings_naming_options(path.read_text()):
                found[str(path.relative_to(ROOT))] = strings
    assert not found, f"library strings that name options (name the parameter; the CLI writes its option): {found}"



def marked_names(source: str) -> list:
    """(name, its error's parameters) for each name a message of an
    InputError, ConflictError or MemoryLimitError marks (`scale`)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("InputError", "ConflictError",
                                                                               "MemoryLimitError"):
            given = node.args[1] if len(node.args) > 1 else None
            parameters = {e.value for e in (given.elts if isinstance(given, ast.Tuple) else [given])
                          if isinstance(e, ast.Constant)}
            texts = [c.value for c in ast.walk(node.args[0]) if isinstance(c, ast.Constant) and isinstance(c.value, str)]
            found += [(name, parameters) for text in texts for name in re.findall(r"`(\w+)`", text)]
    return found


def test_the_names_a_message_marks_are_parameters_the_front_ends_know():
    """A marked name is its error's parameter or an option the command line
    spells: a misspelt mark would print as written, naming nothing."""
    from sinshape.cli.main import option_names

    strays = {}
    for package in (*LIBRARY, "blender"):
        for path in sorted((ROOT / package).rglob("*.py")):
            names = marked_names(path.read_text())
            if stray := [name for name, parameters in names if name not in parameters | set(option_names()) | {"seed"}]:
                strays[str(path.relative_to(ROOT))] = stray
    assert not strays, strays
    assert marked_names('raise InputError(f"`scle` must be {x}", "scale")') == [("scle", {"scale"})]


def test_the_search_finds_options_in_messages_not_in_docstrings():
    source = 'def f(seed):\n    """As `sinrun sample --seed`."""\n    raise InputError(f"{seed}: try --seed 3")\n'
    assert strings_naming_options(source) == [": try --seed 3"]
    assert strings_naming_options('x = "a-b--c, -1, 2--3"\n') == []


def test_parameters_given_together_are_named_each_as_its_option():
    error = ConflictError("`resume` continues with the checkpoint's settings; leave out `iters`, `min_iters`",
                          ("resume", "iters", "min_iters"))
    assert command_line_message(error, {"resume": "--resume", "iters": "--iters", "min_iters": "--min-iters"}) == (
        "--resume continues with the checkpoint's settings; leave out --iters, --min-iters")
    assert command_line_message(InputError("give `iters`", ("iters", "minutes"))) == "give --iters"
    assert command_line_message(InputError("iters and minutes", "iters")) == "iters and minutes"  # words, unmarked


def test_the_training_config_refuses_what_contradicts_itself():
    from sinshape.trainer.config import make_config

    with pytest.raises(ConflictError, match="give iters or minutes, not both") as both:
        make_config("tiny", iters=5, minutes=2.0)
    assert both.value.parameter == ("iters", "minutes")
    with pytest.raises(ConflictError, match="leave out preset, seed") as resumed:
        make_config("tiny", resume=True, seed=3, lr=None)
    assert resumed.value.parameter == ("resume", "preset", "seed")
    assert make_config(resume=True) is None
    assert make_config(iters=5) == make_config("default", iters=5)


def test_a_conflict_is_a_usage_error_naming_options(tmp_path):
    pytest.importorskip("torch")  # without it, `train` says how to install it first
    result = CliRunner().invoke(cli, ["train", str(tmp_path / "x.obj"), "-o", str(tmp_path / "m.onnx"), "--resume",
                                      "--seed", "3", "--min-iters", "2"])
    assert result.exit_code == 2 and "Usage:" in result.output
    assert "Error: --resume continues with the checkpoint's settings; leave out --min-iters, --seed" in result.output


def test_blend_weights_span_the_range_and_are_checked_first():
    from sinshape.runtime import generate

    alpha = generate.blend_weights(-0.5, 1.5, 5)
    assert [alpha(k) for k in range(5)] == [-0.5, 0.0, 0.5, 1.0, 1.5]
    assert generate.blend_weights(0.25, 0.75, 1)(0) == 0.25
    with pytest.raises(InputError, match="alpha must be a number") as refused:
        generate.blend_weights(0, 1e308, 3)
    assert refused.value.parameter == "alpha"


def test_evaluation_checks_warns_and_writes_its_json(tiny_model, tiny_pyramid, tmp_path):
    from conftest import write_pyramid

    from sinshape.runtime import evaluate, load

    model, out, told, shown = load.load_model(tiny_model), tmp_path / "e.json", [], []
    other = write_pyramid(tmp_path / "other.h5", [(20, 18, 14), (20, 18, 15)])
    with pytest.raises(InputError, match="scale must be a positive number") as refused:
        evaluate.evaluate_model(model, other, 2, scale=0.0, json_path=out, warn=told.append)
    assert refused.value.parameter == "scale" and not told and not out.exists()
    results = evaluate.evaluate_model(model, other, 2, json_path=out, warn=told.append,
                                      progress=lambda *shown_now: shown.append(shown_now))
    assert len(told) == 1 and told[0].startswith("other.h5 is not the file") and "--force" not in told[0]
    assert shown == [("sampling", 0, 2), ("sampling", 1, 2), ("sampling", 2, 2)]
    assert json.loads(out.read_text()) == results
    assert evaluate.not_training_input(model, tiny_pyramid) is None


def test_one_edited_sample_never_overwrites_its_layout(tiny_model, tmp_path):
    from sinshape.runtime import layout_files, load, write
    from sinshape.runtime.request import Layout, SampleRequest

    model, vox = load.load_model(tiny_model), tmp_path / "l.vox"
    layout_files.export(model, 3, vox)
    request = SampleRequest(4, layout=Layout.of(layout_files.read_layout(vox)))
    with pytest.raises(InputError, match="is the input"):
        write.write_request(model, request, vox, inputs=[vox])
    write.write_request(model, request, tmp_path / "e.npz", inputs=[vox])
    assert (tmp_path / "e.npz").is_file()


# Run in a fresh interpreter: whether numpy, imported by the command line, asks the kernel for huge pages.
HUGE_PAGES = """import sinshape.cli.main, numpy
core = getattr(numpy, "_core", None) or numpy.core
print(core.multiarray._set_madvise_hugepage(False))"""


@pytest.mark.parametrize("given, asked", [(None, "False"), ("1", "True")])
def test_the_command_line_asks_for_no_huge_pages_unless_the_user_does(given, asked):
    """numpy's huge pages made large arrays wait on the kernel compacting memory (the asset's bake
    1.4x slower): the command line turns them off before numpy is imported, and leaves a user's choice."""
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if given is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = given
    shown = subprocess.run([sys.executable, "-c", HUGE_PAGES], env=env, capture_output=True, text=True, check=True)
    assert shown.stdout.strip() == asked
