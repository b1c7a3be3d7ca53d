"""Colour in the browser: a coloured model (format 4) in the JavaScript
runtime against the Python runtime in Debian's headless chromium (the same
seed, the same colours at the same vertices, for a sample and a world's
tiles), and the page showing vertex colours, for a shape and in world mode."""

import base64
from pathlib import Path

import numpy as np
import pytest

from browser import site_server_process, open_page, wait_world
from test_web import browser, playwright, wait_done  # noqa: F401 (the fixtures of the browser's tests)
from sinshape.runtime import colour, load, query, world
from sinshape.runtime.generate import sample
from sinshape.serve import site

COLOUR_ONNX = Path(__file__).parent / "data" / "tiny_colour.onnx"
NAME = COLOUR_ONNX.stem
TOLERANCE = 1e-4  # the runtimes' occupancy agrees within it (tests/test_web.py): so must their colours

# Runs in the page: a sample's mesh and its colours, or a tile's, made by the browser's runtime.
COLOURS_JS = """async ([name, seed, tile]) => {
  const s = await import('./static/sinshape/runtime.js');
  window.models ??= {};
  window.models[name] ??= await s.loadModel(new Uint8Array(await (await fetch(`models/${name}.onnx`)).arrayBuffer()),
                                            { name: `${name}.onnx` });
  const model = window.models[name];
  let mesh, colours;
  if (tile) {
    mesh = await s.tileMesh(model, BigInt(seed), tile.map(BigInt));
    colours = await s.tileColours(model, BigInt(seed), tile.map(BigInt), mesh.positions);
  } else {
    const tri = await s.sample(model, seed, [1, 1, 1]);
    mesh = s.surface(await s.dense(model, tri, 1), tri.size, model.manifest);
    colours = await s.vertexColours(model, tri, mesh.positions);
  }
  const b64 = (array) => {
    const bytes = new Uint8Array(array.buffer, array.byteOffset, array.byteLength);
    let text = '';
    for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
    return btoa(text);
  };
  return { positions: b64(mesh.positions), colours: b64(colours), coloured: model.manifest.colour };
}"""


@pytest.fixture(scope="module")
def coloured():
    return load.load_model(COLOUR_ONNX, threads=2)


@pytest.fixture(scope="module")
def colour_page(tmp_path_factory, browser):  # noqa: F811
    """A site of the coloured model (and the terrain, grey), in chromium."""
    folder = tmp_path_factory.mktemp("colour") / "site"
    site.export_site([str(COLOUR_ONNX), "terrain"], folder)
    with site_server_process(folder) as base:
        page = open_page(browser, base)
        page.base = base
        page.goto(f"{base}/README.txt")
        yield page
        page.close()


def colours_in_page(page, seed, tile=None) -> tuple:
    made = page.evaluate(COLOURS_JS, [NAME, seed, [str(t) for t in tile] if tile else None])
    assert made["coloured"]
    array = lambda text: np.frombuffer(base64.b64decode(text), np.float32).reshape(-1, 3)  # noqa: E731
    return array(made["positions"]), array(made["colours"])


def test_a_samples_colours_are_the_python_runtimes_at_the_same_vertices(colour_page, coloured):
    positions, colours = colours_in_page(colour_page, 3)
    manifest = coloured.manifest
    coords = (positions - np.asarray(manifest.origin)) / np.asarray(manifest.spacing)
    expected = colour.colours(coloured, sample(coloured, 3), coords)
    assert len(colours) > 500 and colours.std(axis=0).max() > 0.01  # colour that varies over the shape
    assert np.abs(colours - expected).max() < TOLERANCE
    assert np.abs(colours - expected[::-1]).max() > 10 * TOLERANCE  # a vertex's colour from the wrong place shows


@pytest.mark.parametrize("tile", [(0, 0), (3, -2), (10**9, -10**9)])
def test_a_tiles_colours_are_the_python_runtimes_at_the_same_vertices(colour_page, coloured, tile):
    """Python's tile colours are bytes: the browser's floats round to them, within the tolerance."""
    positions, colours = colours_in_page(colour_page, 5, tile)
    expected = world.tile_colours(coloured, 5, tile, positions.astype(np.float64))[:, :3]
    assert len(colours) > 100 and colours.std(axis=0).max() > 0.01
    assert np.abs(colours * 255 - expected).max() <= 0.5 + 255 * TOLERANCE
    assert np.abs(colours[::-1] * 255 - expected).max() > 2  # a vertex's colour from the wrong place shows


def test_neighbouring_tiles_give_their_shared_vertices_one_colour(colour_page, coloured):
    """In the browser, tiles (0, 0) and (1, 0): each vertex on the face they share has the same
    colour from both sides, to the bit (one window at weight 1 there)."""
    layout = world.world_layout(coloured)
    h0 = layout.horizontal[0]
    (a, ca), (b, cb) = colours_in_page(colour_page, 2, (0, 0)), colours_in_page(colour_page, 2, (1, 0))
    shift = np.zeros(3, np.float32)
    shift[h0] = layout.stride[h0]
    left = {tuple(v - shift): c for v, c in zip(a, ca) if v[h0] == layout.stride[h0]}
    right = {tuple(v): c for v, c in zip(b, cb) if v[h0] == 0}
    shared = set(left) & set(right)
    assert len(shared) > 5 and all(np.array_equal(left[v], right[v]) for v in shared)


SHOWN_JS = """() => { const m = []; window.sinshapeView.scene.traverse((n) => n.isMesh && m.push([
  Boolean(n.geometry.attributes.color), n.material.vertexColors, n.geometry.attributes.position.count])); return m; }"""


def test_the_page_shows_a_coloured_models_vertex_colours_and_a_grey_ones_without(colour_page):
    page = colour_page
    page.goto(f"{page.base}/?model={NAME}&seed=3&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    ((has_colour, vertex_colours, vertices),) = page.evaluate(SHOWN_JS)
    assert has_colour and vertex_colours and vertices > 500
    page.goto(f"{page.base}/?model=terrain&seed=3&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    assert page.evaluate(SHOWN_JS) == [[False, False, page.evaluate(SHOWN_JS)[0][2]]]


def test_world_tiles_in_the_page_carry_colour(colour_page):
    page = colour_page
    page.goto(f"{page.base}/?model={NAME}&seed=3&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    page.select_option("#edit", "world")
    page.select_option("#reach", "1")
    status = wait_world(page)
    made = [t for t in status["tiles"] if t[2] > 0]
    assert made and status["coloured"] == len(made)


COLOURS_SHOWN_JS = """() => { let c = null; window.sinshapeView.scene.traverse((n) => { if (n.isMesh && n.geometry.attributes.color)
  c = Array.from(n.geometry.attributes.color.array); }); return c; }"""


def test_on_sinrun_serve_the_servers_glb_colours_reach_the_page_as_the_browsers_do(browser):  # noqa: F811
    """The server's .glb carries COLOR_0 (linear); the page reads it back and shows it as the
    browser's own sample shows its colours: the same mean colour over the shape."""
    pytest.importorskip("fastapi")
    from test_serve import running_server

    with running_server(COLOUR_ONNX) as (base, _):
        page = open_page(browser, base)
        shown = {}
        for where in ("server", "browser"):
            page.goto(f"{base}/?model={NAME}&seed=3&up=z&where={where}")
            assert wait_done(page) == "ready", page.text_content("#error")
            colours = page.evaluate(COLOURS_SHOWN_JS)
            assert colours, f"no vertex colours shown from the {where}"
            shown[where] = np.array(colours).reshape(-1, 3)
        assert np.abs(shown["server"].mean(axis=0) - shown["browser"].mean(axis=0)).max() < 2e-3
        assert shown["server"].std(axis=0).max() > 0.005
        page.close()
