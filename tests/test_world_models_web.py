"""Worlds of several models in the browser: the JavaScript runtime's tiles of
a scattered world of two models placed by a model map
(serve/static/sinshape/world.js) against runtime/world.py in Debian's
headless chromium; the page reading a model map's .png as Pillow does (in
node); and the page's world mode making such a world, in its worker on a
site written by `sinrun export-web` and from the tile route of `sinrun
serve`, with the runtime's refusals shown in one line."""

import base64
import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from browser import exported_site_page, open_page, wait_world
from test_colour_web import IN_PAGE
from test_mirror import run_node  # noqa: F401 (node, beside a copy of the browser runtime's modules)
from test_web import browser, playwright, wait_done  # noqa: F401 (the fixtures of the browser's tests)
from sinshape import models
from sinshape.core.errors import InputError
from sinshape.runtime import load, world

HEAD_ONNX = Path(__file__).parent / "data" / "tiny_colour_v4.onnx"  # format 4: a colour head, another up axis
# Models' indices over tiles (0..1, 0..1), the edge going on beyond: cells whose centres lie
# where exactly one of i, j is negative draw model 1's objects, the others model 0's.
CHECKERBOARD = [[0, 1], [1, 0]]
FIRST = "acropolis"
# Per second model: a tile of seed 3 holding one of the acropolis's objects (model 0), and one
# holding the second model's (model 1).
TILES = {"towerruins": ((-3, -1), (1, -4)), HEAD_ONNX.stem: ((-3, -1), (0, -3))}
TOLERANCE = 1e-4  # the runtimes' occupancy agrees within it (tests/test_world_web.py)


@pytest.fixture(scope="module")
def first():
    return load.load_model(models.find(FIRST), threads=2)


def other_model(name):
    return load.load_model(HEAD_ONNX if name == HEAD_ONNX.stem else models.find(name), threads=2)


@pytest.fixture(scope="module")
def site_page(tmp_path_factory, browser):  # noqa: F811
    """`sinrun export-web acropolis towerruins tiny_colour_v4.onnx`, served as its README says, in chromium."""
    with exported_site_page(browser, [FIRST, "towerruins", str(HEAD_ONNX)],
                            tmp_path_factory.mktemp("models_web") / "site") as page:
        yield page


# Runs in the page: tiles of the world of `names` (the first, then models 1, 2, ...) placed by `map`
# (or of the first alone, without), made by world.js: each one's occupancy grid and surface, as
# base64 of their bytes.
TILES_JS = """async ([names, seed, tiles, map]) => {
  const name = names[0];""" + IN_PAGE + """
  for (const other of names.slice(1)) {
    window.models[other] ??= await s.loadModel(new Uint8Array(await (await fetch(`models/${other}.onnx`)).arrayBuffer()),
                                               { name: `${other}.onnx` });
  }
  const others = names.slice(1).map((other) => window.models[other]);
  const options = W.worldOptions({ arrange: 'scatter', models: others, models_map: map && W.ModelMap.of(map.flat(), [map.length, map[0].length]) });
  const out = [];
  for (const tile of tiles.map((t) => t.map(BigInt))) {
    const grid = await W.tileOccupancy(model, BigInt(seed), tile, 1, options);
    const surface = await W.tileSurface(model, BigInt(seed), tile, 1, options);
    out.push({ grid: b64(grid.data), shape: grid.shape, positions: b64(surface.positions), faces: b64(surface.faces),
               normals: b64(surface.normals), colours: surface.colours && b64(surface.colours) });
  }
  return out;
}"""


def tiles_in_page(page, names, tiles, map=None) -> list:
    """Each tile made in the page: {grid (X, Y, Z), vertices (V, 3), faces (F, 3), normals (V, 3), colours (V, 3)
    or None}."""
    made = page.evaluate(TILES_JS, [names, 3, [[str(i), str(j)] for i, j in tiles], map])
    array = lambda text, kind, width: np.frombuffer(base64.b64decode(text), kind).reshape(-1, width)  # noqa: E731
    return [{"grid": array(t["grid"], np.float32, 1).reshape(t["shape"]),
             "vertices": array(t["positions"], np.float32, 3),
             "faces": array(t["faces"], np.uint32, 3), "normals": array(t["normals"], np.float32, 3),
             "colours": t["colours"] and array(t["colours"], np.float32, 3)} for t in made]


@pytest.mark.parametrize("second", sorted(TILES))
def test_a_two_model_worlds_tiles_are_the_python_runtimes(site_page, first, monkeypatch, second):
    """The acropolis and a second model (the tower ruin: taller, up y; the colour-head model: other
    voxels, up y, coloured) on a checkerboard map. In the browser, a tile of each model's objects
    has Python's occupancy (within the runtimes' 1e-4), the very mesh Python's marching cubes cuts
    from it and as many faces as Python's own tile_surface, Python's normals and (colour) its
    colours at the same vertices; the acropolis's tile is, where the one-model world's grid
    reaches, that world's to the bit, and the second model's tile is not."""
    own, its = TILES[second]
    options = world.WorldOptions("scatter", models=(other_model(second),), models_map=world.ModelMap.of(CHECKERBOARD))
    layout = world.world_layout(first)
    drawn = [[p.model for p in world.objects_near(first, layout, 3, tile, 0, options)] for tile in (own, its)]
    assert drawn == [[0], [1]]
    mixed = tiles_in_page(site_page, [FIRST, second], [own, its], CHECKERBOARD)
    alone = tiles_in_page(site_page, [FIRST], [own, its])
    for tile, made in zip((own, its), mixed):
        expected = world.tile_occupancy(first, 3, tile, options=options)
        assert made["grid"].shape == expected.shape and np.abs(made["grid"] - expected).max() < TOLERANCE
        surface = world.tile_surface(first, 3, tile, options=options)
        assert abs(len(made["faces"]) - len(surface.faces)) <= 2 and len(made["faces"]) > 2000
        with monkeypatch.context() as patched:  # Python's marching cubes on the browser's grid: the browser's mesh
            patched.setattr(world, "tile_occupancy", lambda *args, **kwargs: made["grid"])
            vertices, faces = world.tile_mesh(first, 3, tile, options=options)
        assert (len(faces), len(vertices)) == (len(made["faces"]), len(made["vertices"]))
        assert np.abs(np.sort(made["vertices"], axis=0) - np.sort(vertices, axis=0)).max() < 1e-5
        at = made["vertices"].astype(np.float64)
        assert np.abs(made["normals"] - world.tile_normals(first, 3, tile, at, options)).max() < 1e-3
        if surface.colours is None:
            assert made["colours"] is None
            continue
        python = world.tile_colours(first, 3, tile, at, options, 1.0)[:, :3]
        assert np.abs(made["colours"] * 255 - python).max() <= 0.5 + 255 * TOLERANCE
        objects = (python != 128).any(axis=1).sum()  # the acropolis has no colour: grey, as the ground
        assert objects == 0 if tile == own else objects >= 20
    up = layout.up
    reach = alone[0]["grid"].shape[up]  # the one-model world's heights (a taller second model's reach higher)
    assert np.array_equal(np.take(mixed[0]["grid"], range(reach), up).view(np.uint32), alone[0]["grid"].view(np.uint32))
    assert not np.array_equal(np.take(mixed[1]["grid"], range(reach), up), alone[1]["grid"])
    assert len(mixed[1]["faces"]) != len(alone[1]["faces"])


def palette_png(indices) -> bytes:
    """A palette .png whose pixels read as the model map `indices` ([i][j]: tile (i, j)'s, as sinrun reads it)."""
    image = Image.new("P", (len(indices), len(indices[0])))
    image.putdata(np.flipud(np.array(indices, np.uint8).T).ravel().tolist())
    data = io.BytesIO()
    image.save(data, "png")
    return data.getvalue()


def refused_as_python(page, message: str) -> None:
    """Until the page shows `message` as its error, in one line, as the Python runtime words it."""
    page.wait_for_function("(text) => document.body.dataset.state === 'error' && "
                           "document.getElementById('error').textContent === text", arg=message, timeout=60_000)
    assert "\n" not in message


def png_bytes(pixels: np.ndarray, depth: int, colour: int, interlace: bool) -> bytes:
    """A .png of one sample per pixel (colour 0 grey, 3 palette; or 2, 4 and 6, whose other channels
    repeat it), written here byte by byte (Pillow writes no interlaced image, nor 2- or 4-bit grey):
    each line filtered with the next of the PNG specification's five filters in turn."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    def paeth(a, b, c):
        p = a + b - c
        return a if abs(p - a) <= abs(p - b) and abs(p - a) <= abs(p - c) else b if abs(p - b) <= abs(p - c) else c

    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}[colour]
    step = max(1, depth * channels // 8)
    passes = ([(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2)]
              if interlace else [(0, 0, 1, 1)])
    raw, count = b"", 0
    for x0, y0, dx, dy in passes:
        part = np.repeat(pixels[y0::dy, x0::dx], channels, axis=1)
        above = None
        for row in part:
            bits = "".join(format(int(v), f"0{depth}b") for v in row)
            line = bytes(int(bits[k:k + 8].ljust(8, "0"), 2) for k in range(0, len(bits), 8))
            above = above or bytes(len(line))
            kind, count = count % 5, count + 1
            out = bytearray()
            for k, value in enumerate(line):
                left, corner = (line[k - step], above[k - step]) if k >= step else (0, 0)
                guess = (0, left, above[k], (left + above[k]) // 2, paeth(left, above[k], corner))[kind]
                out.append((value - guess) & 255)
            raw += bytes([kind]) + bytes(out)
            above = line
    header = struct.pack(">IIBBBBB", pixels.shape[1], pixels.shape[0], depth, colour, 0, 0, int(interlace))
    palette = chunk(b"PLTE", bytes(3 << depth)) if colour == 3 else b""
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + palette + chunk(b"IDAT", zlib.compress(raw))
            + chunk(b"IEND", b""))


# Runs in node: viewer/heights.js's readModelMap on each file of a folder (argv[2]): its rows, or its message.
READ_MAPS_JS = """
import { readFileSync, readdirSync } from 'node:fs';
const { readModelMap } = await import('./static/viewer/heights.js');
const out = {};
for (const name of readdirSync(process.argv[2]).sort()) {
  try {
    const map = await readModelMap(new File([readFileSync(`${process.argv[2]}/${name}`)], name));
    out[name] = Array.from({ length: map.shape[0] }, (_, r) => Array.from(map.data.subarray(r * map.shape[1], (r + 1) * map.shape[1])));
  } catch (error) {
    out[name] = error.message;
  }
}
console.log(JSON.stringify(out));
"""


def test_the_page_reads_a_model_map_png_as_pillow_does(run_node, tmp_path):
    """The page decodes a model map's .png itself (a browser's canvas gives colours, not a palette's
    indices, and 8 bits): grey of 1, 2, 4, 8 and 16 bits and palettes of 1 to 8, plain and
    interlaced, every line filter, give world.parse_model_map's map (Pillow's pixels), or its
    message: a colour image, a 16-bit value past 255."""
    rng = np.random.default_rng(5)
    cases = [(depth, colour, interlace) for depth, colour in ((1, 0), (2, 0), (4, 0), (8, 0), (16, 0), (1, 3), (2, 3),
                                                             (4, 3), (8, 3), (8, 2), (8, 4), (8, 6))
             for interlace in (False, True)]
    for depth, colour, interlace in cases:
        pixels = rng.integers(0, min(1 << depth, 4 if depth >= 8 else 1 << depth), size=(11, 13))
        (tmp_path / f"{depth}_{colour}_{int(interlace)}.png").write_bytes(png_bytes(pixels, depth, colour, interlace))
    (tmp_path / "wide.png").write_bytes(png_bytes(np.array([[0, 300]]), 16, 0, False))
    read = json.loads(run_node(READ_MAPS_JS, str(tmp_path)))
    assert len(read) == len(cases) + 1
    for name, got in read.items():
        try:
            expected = world.parse_model_map((tmp_path / name).read_bytes(), ".png", name).array().tolist()
        except InputError as error:
            expected = str(error)
        assert got == expected, name
    assert sum(isinstance(got, str) for got in read.values()) == 7  # RGB, LA and RGBA, plain and interlaced; 300


# Runs in node: a map file of more bytes than world.MAX_MAP_BYTES opened by each reader, whose bytes are never read.
TOO_LARGE_JS = """
const { readHeightMap, readModelMap } = await import('./static/viewer/heights.js');
const file = { name: 'huge.png', size: 65 * 2 ** 20, arrayBuffer: () => { throw new Error('read'); } };
const out = [];
for (const read of [readHeightMap, readModelMap]) {
  try { await read(file, null); out.push('made'); } catch (error) { out.push(error.message); }
}
console.log(JSON.stringify(out));
"""


def test_a_map_file_too_large_is_refused_unread_in_pythons_words(run_node):
    messages = json.loads(run_node(TOO_LARGE_JS))
    for message, parse, what in zip(messages, (world.parse_height_map, world.parse_model_map), ("height", "model")):
        with pytest.raises(InputError) as refused:
            parse(bytes(65 << 20), ".png", "huge.png")
        assert message == str(refused.value) == f"huge.png: 65 MB is too large for a {what} map"


def test_the_page_makes_a_two_model_world_in_its_worker_and_refuses_what_python_refuses(site_page, first, tmp_path):
    """World mode in the browser, another model picked (in the URL, then in the world controls): until
    a model map is opened the request is refused; a palette .png opened as the map (read as sinrun
    reads it), the worker loads the tower ruin and makes the tiles, each the Python runtime's. A
    16-bit greyscale map naming a model the world lacks, the other model unpicked, and a blend world
    with a model map are refused on the page in Python's words, in one line."""
    page = site_page
    (tmp_path / "checkerboard.png").write_bytes(palette_png(CHECKERBOARD))
    assert world.read_model_map(tmp_path / "checkerboard.png") == world.ModelMap.of(CHECKERBOARD)
    page.goto(f"{page.base}/?model={FIRST}&seed=3&up=z&edit=world&at=1,-4&reach=1&arrange=scatter&models=towerruins")
    towers = (other_model("towerruins"),)
    with pytest.raises(InputError) as no_map:
        world.WorldOptions("scatter", models=towers)
    refused_as_python(page, str(no_map.value))
    page.set_input_files("#models-map-file", str(tmp_path / "checkerboard.png"))
    page.wait_for_function("document.getElementById('models-map-label').textContent === 'model map: checkerboard.png'")
    status = wait_world(page)
    options = world.WorldOptions("scatter", models=towers, models_map=world.ModelMap.of(CHECKERBOARD))
    faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
    assert faces.keys() == {(i, j) for i in (0, 1, 2) for j in (-5, -4, -3)}
    for tile, count in faces.items():
        assert abs(count - len(world.tile_surface(first, 3, tile, options=options).faces)) <= 2, tile
    assert [p.model for p in world.objects_near(first, world.world_layout(first), 3, (1, -4), 0, options)] == [1]

    missing = io.BytesIO()
    Image.fromarray(np.flipud(np.array([[0, 1], [2, 0]], np.uint16).T)).save(missing, "png")  # 16-bit grey: I;16
    (tmp_path / "missing.png").write_bytes(missing.getvalue())
    placed = world.read_model_map(tmp_path / "missing.png")
    said = []
    changes = ((dict(models=towers), lambda: page.set_input_files("#models-map-file", str(tmp_path / "missing.png"))),
               ({}, lambda: page.select_option("#models", [])),  # the tower ruin unpicked
               (dict(arrange="blend"), lambda: page.select_option("#arrange", "blend")))
    for refused, change in changes:
        with pytest.raises(InputError) as python:
            world.WorldOptions(**{"arrange": "scatter", "models_map": placed, **refused})
        change()
        refused_as_python(page, str(python.value))
        said.append(str(python.value))
    assert "tile (1, 0) names model 2, and the world has 2" in said[0]
    assert "names model 1, and the world has 1" in said[1]
    assert "for a scatter world" in said[2] and "models=towerruins" not in page.url
    assert not page.errors and not page.outside


def test_on_sinrun_serve_the_page_asks_the_tile_route_for_a_two_model_world(browser, first, tmp_path):  # noqa: F811
    """Server mode: the world controls' other model and a .npy model map reach the tile route as
    `models=towerruins` and `models_map=0,1;1,0` with every tile, and each tile shown is the
    Python runtime's; no browser runtime is loaded."""
    pytest.importorskip("fastapi")
    from test_serve import running_server

    np.save(tmp_path / "checkerboard.npy", np.array(CHECKERBOARD))
    with running_server(FIRST, "towerruins") as (base, _):
        page = open_page(browser, base)
        try:
            page.goto(f"{base}/?model={FIRST}&seed=3&up=z&edit=world&at=1,-4&reach=1&arrange=scatter&models=towerruins")
            assert wait_done(page) == "error" and page.text_content("#error") == (
                "several models need a model map saying which goes where")
            page.set_input_files("#models-map-file", str(tmp_path / "checkerboard.npy"))
            status = wait_world(page)
            requested = [url.removeprefix(base) for url in
                         page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")]
            tiles = [url for url in requested if url.startswith(f"/api/models/{FIRST}/tile?")]
            # Each tile asked for at the coarsest level first, then at full detail.
            assert len(tiles) == 2 * 9 and all("&models=towerruins&models_map=0%2C1%3B1%2C0" in url for url in tiles), tiles
            assert not [url for url in requested if "onnxruntime-web" in url or url.endswith(("/model.js", "/worker.js"))]
            options = world.WorldOptions("scatter", models=(other_model("towerruins"),),
                                         models_map=world.ModelMap.of(CHECKERBOARD))
            faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
            assert faces[1, -4] == len(world.tile_surface(first, 3, (1, -4), options=options).faces) > 4000
            assert page.get_attribute("#download", "href").endswith("models=towerruins&models_map=0%2C1%3B1%2C0")
            assert not page.errors and not page.outside
        finally:
            page.close()
