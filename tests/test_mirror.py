"""The browser runtime's constants against the Python's: the table below
pairs each constant the JavaScript shares with Python (the format's limits,
the noise's, sizes and rounding, layout, world and colour-matching
parameters, the mesh's tables) with the Python it mirrors, and the test
loads every JavaScript module in node and compares each pair. Every
upper-case constant of the browser runtime's modules is in the table, or
named below with the reason it has no Python counterpart, so a new one
cannot be added unheld. Within the JavaScript each constant is defined once
and imported where used (PLANE_AXES from query.js).

The page's own modules (serve/static/viewer/: camera, flight, form) hold no
Python constants except the two read here (heights.js, layout-cells.js)."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from sinshape.core import manifest as fmt
from sinshape.core import noise
from sinshape.runtime import cubes, edit, generate, layout, layout_files, load, onnxfile, world, world_maps

STATIC = Path(__file__).resolve().parents[1] / "serve" / "static"
MODULES = sorted(STATIC.glob("sinshape/*.js")) + [STATIC / "viewer" / "heights.js", STATIC / "viewer" / "layout-cells.js"]

MANIFEST = ("FORMAT_NAME", "FORMAT_VERSION", "COLOUR_VERSION", "TILES_VERSION", "READ_VERSION", "COLOUR_SPACE",
            "MAX_TILE_SIDE", "METADATA_KEY", "NOISE_SCHEME", "PLANES", "HEAD_WEIGHTS",
            "MAX_LEVELS", "MIN_LEVEL_SIDE", "MAX_LEVEL_SIDE", "MIN_SPACING", "MAX_MANIFEST_CHARS", "MAX_DEPTH",
            "MAX_NOISE_AMP", "MAX_COORD", "CONTRAST", "CONTRAST_RANGE", "OBJECT_SCALE_RANGE")
LAYOUT = ("FIT_STEPS", "FINER_STEPS", "HOLD_STEPS", "FIT_RATE", "PULL", "MARGIN", "KEEP_WEIGHT", "SLOPE_FLOOR", "SHARE")
WORLD = ("MAX_TILE", "MIN_STRIDE")
WORLD_MAPS = ("MAX_MAP_SIDE", "MAX_RELIEF", "MAX_MODELS")


def same(name, module=None):
    """A row whose JavaScript and Python names are one: (its JS name, Python name, Python value)."""
    return name, f"{module.__name__.removeprefix('sinshape.')}.{name}", getattr(module, name)


# (JavaScript module, then what same() gives: JS name, Python name, Python value)
MIRROR = [
    ("sinshape/noise.js", "GOLDEN", "core.noise.GOLDEN", noise.GOLDEN),
    ("sinshape/noise.js", "GOLDEN_HI", "core.noise.GOLDEN >> 32", noise.GOLDEN >> 32),
    ("sinshape/noise.js", "GOLDEN_LO", "core.noise.GOLDEN & 0xffffffff", noise.GOLDEN & 0xFFFFFFFF),
    ("sinshape/noise.js", "MASK64", "core.noise._MASK64", noise._MASK64),
    ("sinshape/noise.js", "COORD_BITS", "core.noise._COORD_BITS", noise._COORD_BITS),
    ("sinshape/noise.js", *same("Z0_STREAM", noise)),
    ("sinshape/noise.js", *same("PLANE_STREAM", noise)),
    ("sinshape/generate.js", *same("MIN_SIDE", generate)),
    ("sinshape/query.js", *same("PLANE_AXES", fmt)),
    ("sinshape/query.js", *same("MAX_GRID_SIDE", generate)),
    *[("sinshape/model.js", *same(name, fmt)) for name in MANIFEST],
    ("sinshape/model.js", *same("MAX_MODEL_BYTES", load)),
    ("sinshape/model.js", *same("ALLOWED_OPS", load)),
    ("sinshape/model.js", "MAX_COORD_TEXT", "f'{core.manifest.MAX_COORD:g}' (its messages)", f"{fmt.MAX_COORD:g}"),
    ("sinshape/model.js", "SPACING_TEXT", "core.manifest's spacing message",
     f"[{fmt.MIN_SPACING:g}, {fmt.MAX_COORD / fmt.MAX_LEVEL_SIDE:g}]"),
    ("sinshape/seal.js", *same("SEAL_KEY", fmt)),
    ("sinshape/seal.js", *same("SEAL_PREFIX", fmt)),
    ("sinshape/seal.js", *same("SEAL_BYTES", fmt)),
    *[("sinshape/onnx.js", *same(name, onnxfile)) for name in ("FLOAT", "UINT8", "INT8", "INT32", "MAX_DIM")],
    ("sinshape/onnx.js", "ARRAYS", "runtime.onnxfile.DTYPES (numpy's names, and the typed array of each)",
     {k: [np.dtype(v).name, f"{np.dtype(v).name.capitalize()}Array"] for k, v in onnxfile.DTYPES.items()}),
    ("sinshape/mesh.js", "TABLE", "runtime.cubes.TRIANGLES (without its -1 padding)",
     [[int(v) for v in row if v >= 0] for row in cubes.TRIANGLES]),
    ("sinshape/mesh.js", *same("CORNERS", cubes)),
    ("sinshape/mesh.js", *same("EDGES", cubes)),
    ("sinshape/edit.js", *same("MARGIN", edit)),
    *[("sinshape/layout.js", *same(name, layout)) for name in LAYOUT],
    *[("sinshape/world.js", *same(name, world)) for name in WORLD],
    ("sinshape/world.js", *same("UP_AXIS", fmt)),
    *[("sinshape/world.js", *same(name, world_maps)) for name in WORLD_MAPS],
    ("viewer/heights.js", *same("RELIEF", world_maps)),
    ("viewer/heights.js", *same("MAX_MAP_BYTES", world_maps)),
    ("viewer/layout-cells.js", "MAX_SIDE", "runtime.layout_files.MAX_LAYOUT_SIDE", layout_files.MAX_LAYOUT_SIDE),
    ("viewer/layout-cells.js", *same("VOX_VERSION", layout_files)),
    ("sinshape/world.js", "ARRANGEMENTS", "core.manifest.ARRANGEMENTS", fmt.ARRANGEMENTS),
    ("viewer/layout-cells.js", *same("VOX_COLOUR", layout_files)),
]

# Upper-case constants of those modules with no Python counterpart, and why.
BROWSER_ONLY = {
    ("sinshape/noise.js", "TWO32"): "2^32 as a double: the 32-bit halves the browser's 64-bit arithmetic runs on",
    ("sinshape/generate.js", "MAX_BYTES"): "a WebAssembly memory's 4 GiB, the browser's own bound",
    ("sinshape/generate.js", "FLOAT_TEXT"): "Python's float() grammar (Python has float itself); the shared request "
                                            "cases hold it (tests/test_web.py)",
    ("sinshape/query.js", "TAB_BYTES"): "what one piece of work may take in a browser tab",
    ("sinshape/seal.js", "ASCII"): "a TextEncoder",
    ("sinshape/seal.js", "K"): "SHA-256's round constants (FIPS 180-4; Python has hashlib)",
    ("sinshape/onnx.js", "TEXT"): "a TextDecoder",
    ("sinshape/layout.js", "OWN_KEPT"): "how many of a seed's layouts a page keeps",
    ("sinshape/decode-wasm.js", "DECODE_WASM"): "the fit's WebAssembly, built from decode.wat (tests/test_wasm.py)",
}
# The table of a sample's options and the output formats: options.js is written from Python and
# tests/test_options.py holds the copy equal to it; request.js reads its fields, defaults and limits there;
# MAKES (the options the browser runtime makes) is held by tests/test_web.py.
OPTIONS = {("sinshape/options.js", name) for name in ("OPTIONS", "OPTION", "FORMATS")} | {
    ("sinshape/request.js", name) for name in ("DEFAULTS", "MAX_PARTS", "MAKES")}

# Runs in node: the named exports of each module, as JSON (BigInts as {"bigint": text}, sets sorted, typed
# arrays as arrays, functions as their names).
DUMP_JS = """
const wanted = JSON.parse(process.argv[2]);
const plain = (v) => typeof v === 'bigint' ? { bigint: v.toString() }
  : typeof v === 'function' ? v.name
  : v instanceof Set ? [...v].sort().map(plain)
  : ArrayBuffer.isView(v) || Array.isArray(v) ? Array.from(v, plain)
  : v && typeof v === 'object' ? Object.fromEntries(Object.entries(v).map(([k, x]) => [k, plain(x)]))
  : v;
const out = {};
for (const [file, names] of Object.entries(wanted)) {
  const module = await import(`./static/${file}`);
  out[file] = Object.fromEntries(names.map((n) => [n, n in module ? plain(module[n]) : { missing: true }]));
}
console.log(JSON.stringify(out));
"""


def plain(value):
    """A Python value in the form DUMP_JS gives a JavaScript one."""
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    if isinstance(value, bytes):
        return list(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    return value


@pytest.fixture(scope="module")
def run_node(tmp_path_factory):
    """run_node(script, *args): a script run by node beside a copy of the
    browser runtime's modules (./static/sinshape/...); its stdout. node reads
    them as ES modules under a package.json saying so (the page's own copy
    has none)."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (CI has it): the browser runtime's modules are read with it")
    root = tmp_path_factory.mktemp("mirror") / "static"
    for path in MODULES:
        (root / path.parent.name).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, root / path.parent.name / path.name)
    (root / "vendor").symlink_to(STATIC / "vendor")  # model.js imports onnxruntime-web
    (root / "package.json").write_text('{"type": "module"}')

    def run(script: str, *args: str) -> str:
        (root.parent / "script.mjs").write_text(script)
        done = subprocess.run([node, "script.mjs", *args], capture_output=True, text=True, timeout=120,
                              cwd=root.parent)
        assert done.returncode == 0, done.stderr
        return done.stdout

    return run


@pytest.fixture(scope="module")
def browser_constants(run_node):
    wanted = {}
    for file, name, *_ in MIRROR:
        wanted.setdefault(file, []).append(name)
    bigints = lambda d: int(d["bigint"]) if set(d) == {"bigint"} else d  # noqa: E731
    return json.loads(run_node(DUMP_JS, json.dumps(wanted)), object_hook=bigints)


@pytest.mark.parametrize(("file", "name", "python", "value"), MIRROR, ids=[f"{f}:{n}" for f, n, *_ in MIRROR])
def test_each_browser_constant_is_the_pythons(browser_constants, file, name, python, value):
    got = browser_constants[file][name]
    assert got != {"missing": True}, f"{file} exports no {name}"
    assert got == plain(value), f"{file}'s {name} is {got!r}; {python} is {plain(value)!r}"


def defined(path: Path) -> list:
    """The upper-case constants a module defines at its top level (several to a line too)."""
    names = []
    for line in path.read_text().splitlines():
        if re.match(r"(export )?(const|let) [A-Z]", line):
            head = line.split("//")[0]
            names += re.findall(r"(?:const |, )([A-Z][A-Z0-9_]*) =", head)
    return names


def test_every_constant_of_the_browser_runtime_is_held_or_named():
    """A constant added to a module of the browser runtime is in MIRROR,
    BROWSER_ONLY (with its reason) or the options' table; and each is
    defined in one module only (a copy is imported instead)."""
    rows = {(file, name) for file, name, *_ in MIRROR}
    listed = rows | set(BROWSER_ONLY) | OPTIONS
    found = [(f"{path.parent.name}/{path.name}", name) for path in MODULES for name in defined(path)]
    assert len(rows) == len(MIRROR), "a constant is in MIRROR twice"
    assert not set(found) - listed, f"constants neither compared nor named: {sorted(set(found) - listed)}"
    assert not listed - set(found), f"listed constants no module defines: {sorted(listed - set(found))}"
    values = {}
    for path in MODULES:  # one definition per constant: the same name and value twice is a copy
        for line in path.read_text().splitlines():
            for name, value in re.findall(r"^(?:export )?const ([A-Z][A-Z0-9_]*) = ([^;]*);", line):
                values.setdefault((name, value), []).append(path.name)
    copies = {key: files for key, files in values.items() if len(files) > 1}
    assert not copies, f"constants defined more than once: {copies}"
    print(f"{len(MIRROR)} constants compared with Python's; {len(BROWSER_ONLY)} the browser's own; "
          f"{len(OPTIONS)} built from the options' table")


# Runs in node: layout.js's fit on the inputs Python's had at each level (files in argv[2]), its planes written beside.
FIT_JS = """
import { readFileSync, writeFileSync } from 'node:fs';
import { fit } from './static/sinshape/layout.js';
const dir = process.argv[2], meta = JSON.parse(readFileSync(`${dir}/meta.json`, 'utf8'));
const read = (name, Type) => { const b = readFileSync(`${dir}/${name}`); return new Type(b.buffer.slice(b.byteOffset, b.byteOffset + b.byteLength)); };
const model = { head: { bias1: read('bias1', Float32Array), weight2: read('weight2', Float32Array), bias2: meta.bias2 } };
const weights = [0, 1, 2].map((k) => read(`weights${k}`, Float32Array));
meta.levels.forEach(({ steps, hold, dims }, i) => {
  const planes = dims.map((d, k) => ({ data: read(`in${i}_${k}`, Float32Array), dims: d }));
  const made = fit(model, weights, planes, read(`target${i}`, Uint8Array), meta.shape, steps, read(`edited${i}`, Uint8Array), hold);
  made.forEach((p, k) => writeFileSync(`${dir}/out${i}_${k}`, p.data));
});
"""


def test_the_browsers_layout_fit_is_pythons_to_the_bit(run_node, tmp_path, monkeypatch):
    """layout.js's fit, given the planes Python's fit was given at each level
    of from_layout (terrain, seed 3, a tower's top cut off and a block
    added), makes Python's planes to the bit: every sum in one order, in
    float32, and the sigmoid in float64 in both. (The whole edit in the
    browser differs only by its generators' and decoder's: onnxruntime-web's
    float32 differs from onnxruntime's in the last bits, tests/test_web.py.)"""
    from sinshape import models
    from sinshape.runtime import load_model

    model = load_model(models.find("terrain"), threads=1)
    target = layout.layout(model, 3)
    target[10:14, 6:10, 5:] = False
    target[3, 3, 9] = True
    calls, fit = [], layout.fit

    def recorded(model, planes, target, steps, edited, hold=False):
        made = fit(model, planes, target, steps, edited, hold)
        calls.append((planes, target, steps, edited, hold, made))
        return made

    monkeypatch.setattr(layout, "fit", recorded)
    layout.from_layout(model, 3, target)
    assert len(calls) == len(model.manifest.sizes)  # the layout's level and each finer one
    meta = {"shape": list(target.shape), "bias2": model.head.bias2, "levels": []}
    write = lambda name, array: (tmp_path / name).write_bytes(np.ascontiguousarray(array).tobytes())  # noqa: E731
    for k, weights in enumerate(layout.first_layer(model)):
        write(f"weights{k}", weights.astype(np.float32))
    write("bias1", model.head.bias1.astype(np.float32))
    write("weight2", model.head.weight2.astype(np.float32))
    for i, (planes, target, steps, edited, hold, _) in enumerate(calls):
        meta["levels"].append({"steps": steps, "hold": hold, "dims": [list(p.shape) for p in planes]})
        write(f"target{i}", target.astype(np.uint8))
        write(f"edited{i}", edited.astype(np.uint8))
        for k, plane in enumerate(planes):
            write(f"in{i}_{k}", plane.astype(np.float32))
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    run_node(FIT_JS, str(tmp_path))
    for i, (planes, *_, made) in enumerate(calls):
        for k, (given, expected) in enumerate(zip(planes, made)):
            got = np.fromfile(tmp_path / f"out{i}_{k}", np.float32).reshape(expected.shape)
            moved = (expected != given).sum()
            assert k == 2 or moved > 100, f"level {i}'s fit moved {moved} values of plane {k}"  # yz: not for this edit
            same = (got == expected).mean()
            assert same == 1, f"level {i}, plane {k}: {same:.4%} of the values are Python's"
