"""Worlds of several models on the page: a model map's .png read as Pillow
reads it (in node), and the world mode asking `sinrun serve`'s tile route for
a scattered world of two models placed by a model map (the Python runtime
makes worlds; the browser's runtime makes none)."""

import io
import json
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from browser import open_page, wait_world
from test_mirror import run_node  # noqa: F401 (node, beside a copy of the browser runtime's modules)
from test_web import browser, playwright, wait_done  # noqa: F401 (the fixtures of the browser's tests)
from sinshape import models
from sinshape.core.errors import InputError
from sinshape.runtime import load, world, world_maps, world_tiles

# Models' indices over tiles (0..1, 0..1), the edge going on beyond: cells whose centres lie
# where exactly one of i, j is negative draw model 1's objects, the others model 0's.
CHECKERBOARD = [[0, 1], [1, 0]]
FIRST = "acropolis"


@pytest.fixture(scope="module")
def first():
    return load.load_model(models.find(FIRST), threads=2)


def other_model(name):
    return load.load_model(models.find(name), threads=2)


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
    interlaced, every line filter, give world_maps.parse_model_map's map (Pillow's pixels), or its
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
            expected = world_maps.parse_model_map((tmp_path / name).read_bytes(), ".png", name).array().tolist()
        except InputError as error:
            expected = str(error)
        assert got == expected, name
    assert sum(isinstance(got, str) for got in read.values()) == 7  # RGB, LA and RGBA, plain and interlaced; 300


# Runs in node: a map file of more bytes than world_maps.MAX_MAP_BYTES opened by each reader, whose bytes are never read.
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
    for message, parse, what in zip(messages, (world_maps.parse_height_map, world_maps.parse_model_map), ("height", "model")):
        with pytest.raises(InputError) as refused:
            parse(bytes(65 << 20), ".png", "huge.png")
        assert message == str(refused.value) == f"huge.png: 65 MB is too large for a {what} map"


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
            # Each tile asked for at the coarsest level first, then at full detail, with its skirt.
            assert len(tiles) == 2 * 9 and all("&models=towerruins&models_map=0%2C1%3B1%2C0" in url and "skirt=true&underside=false" in url
                                               for url in tiles), tiles
            assert not [url for url in requested if "onnxruntime-web" in url or url.endswith(("/model.js", "/worker.js"))]
            options = world.WorldOptions("scatter", models=(other_model("towerruins"),),
                                         models_map=world_maps.ModelMap.of(CHECKERBOARD), skirt=True, underside=False)
            faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
            assert faces[1, -4] == len(world_tiles.tile_surface(first, 3, (1, -4), options=options).faces) > 4000
            assert page.get_attribute("#download", "href").endswith("models=towerruins&models_map=0%2C1%3B1%2C0")
            assert not page.errors and not page.outside
        finally:
            page.close()
