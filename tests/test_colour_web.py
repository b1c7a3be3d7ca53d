"""Colour in the browser: coloured models in the JavaScript runtime against
the Python runtime in Debian's headless chromium (the same seed, the same
colours at the same vertices, for a sample and a world's tiles), and the page
showing vertex colours, for a shape and in world mode.

A format-5 model's colour is read by correspondence (colour.js, the mirror of
runtime/colour.py): given the same hidden sums, the browser's matches and
colours are Python's to the bit, both ways; on its own (onnxruntime-web's
planes differ from onnxruntime's in the last float32 bits), the only
differences allowed are near-ties, a hidden sum within that distance of a
rounding boundary of the patches or of the band's logit, which can move a
voxel's match. A format-4 model keeps its colour head (query.js)."""

import base64
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from browser import exported_site_page, open_page, wait_world
from test_web import browser, load_in_page, playwright, wait_done  # noqa: F401 (the fixtures of the browser's tests)
from sinshape.core import manifest as fmt
from sinshape.core.errors import InputError
from sinshape.runtime import colour, load, mesh, query, world
from sinshape.runtime.generate import sample

COLOUR_ONNX = Path(__file__).parent / "data" / "tiny_colour.onnx"  # format 5: colour tiles
HEAD_ONNX = Path(__file__).parent / "data" / "tiny_colour_v4.onnx"  # format 4: a colour head
RELIEF_ONNX = Path(__file__).parent / "data" / "tiny_relief.onnx"  # format 5: geometry only, relief tiles
NAME, HEAD_NAME, RELIEF_NAME = COLOUR_ONNX.stem, HEAD_ONNX.stem, RELIEF_ONNX.stem
TOLERANCE = 1e-4  # the runtimes' occupancy agrees within it (tests/test_web.py): so must a colour head's colours
SAME_BYTES = 0.995  # the share of vertices whose colour bytes must be Python's, a format-5 sample made by each runtime
SAME_MATCHES = 0.97  # ...and of the band's voxels whose match must be (a match moved moves a few vertices' colour)

# The start of the page scripts below, given `name`: the runtime `s`, the model of that name (loaded
# once per page) `model`, the world's module `W`, and `b64`, a typed array's bytes as base64.
IN_PAGE = """
  const s = await import('./static/sinshape/runtime.js');
  const W = await import('./static/sinshape/world.js');
  window.models ??= {};
  window.models[name] ??= await s.loadModel(new Uint8Array(await (await fetch(`models/${name}.onnx`)).arrayBuffer()),
                                            { name: `${name}.onnx` });
  const model = window.models[name];
  const b64 = (array) => {
    const bytes = new Uint8Array(array.buffer, array.byteOffset, array.byteLength);
    let text = '';
    for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
    return btoa(text);
  };
"""

# Runs in the page: a sample's mesh and its colours, or a tile's (at `scale`, its vertices' colours
# standing for 1 / scale voxels, as a tile's file has them), made by the browser's runtime.
COLOURS_JS = """async ([name, seed, tile, options]) => {""" + IN_PAGE + """
  let mesh, colours;
  if (tile) {
    const { scale, ...given } = options, world = W.worldOptions(given);
    mesh = await s.tileMesh(model, BigInt(seed), tile.map(BigInt), scale, world);
    colours = await s.tileColours(model, BigInt(seed), tile.map(BigInt), mesh.positions, world, 1 / scale);
  } else {
    const tri = await s.sample(model, seed, [1, 1, 1]);
    mesh = s.surface(await s.dense(model, tri, 1), tri.size, model.manifest);
    colours = await s.vertexColours(model, tri, mesh.positions);
  }
  return { positions: b64(mesh.positions), colours: b64(colours), coloured: model.manifest.colour };
}"""


@pytest.fixture(scope="module")
def coloured():
    model = load.load_model(COLOUR_ONNX, threads=2)
    assert model.manifest.raw["format_version"] == fmt.TILES_VERSION and model.tiles is not None
    return model


@pytest.fixture(scope="module")
def headed():
    model = load.load_model(HEAD_ONNX, threads=2)
    assert model.manifest.raw["format_version"] == fmt.COLOUR_VERSION
    return model


@pytest.fixture(scope="module")
def colour_page(tmp_path_factory, browser):  # noqa: F811
    """A site of the coloured models, the relief-only one and the terrain (grey), in chromium."""
    with exported_site_page(browser, [str(COLOUR_ONNX), str(HEAD_ONNX), str(RELIEF_ONNX), "terrain"],
                            tmp_path_factory.mktemp("colour") / "site") as page:
        yield page


def colours_in_page(page, seed, tile=None, name=NAME, scale=1, arrange="blend", lod=0) -> tuple:
    made = page.evaluate(COLOURS_JS, [name, seed, [str(t) for t in tile] if tile else None,
                                      {"scale": scale, "arrange": arrange, "lod": lod}])
    assert made["coloured"]
    array = lambda text: np.frombuffer(base64.b64decode(text), np.float32).reshape(-1, 3)  # noqa: E731
    return array(made["positions"]), array(made["colours"])


def test_a_colour_heads_colours_are_the_python_runtimes_at_the_same_vertices(colour_page, headed):
    positions, colours = colours_in_page(colour_page, 3, name=HEAD_NAME)
    manifest = headed.manifest
    coords = (positions - np.asarray(manifest.origin)) / np.asarray(manifest.spacing)
    expected = colour.colours(headed, sample(headed, 3), coords)
    assert len(colours) > 500 and colours.std(axis=0).max() > 0.01  # colour that varies over the shape
    assert np.abs(colours - expected).max() < TOLERANCE
    assert np.abs(colours - expected[::-1]).max() > 10 * TOLERANCE  # a vertex's colour from the wrong place shows


def b64(array) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode()


def unb64(text, dtype, width: int) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype).reshape(-1, width)


# Runs in the page: a format-5 sample's matches and colours, first as the runtime makes them (its own
# planes), then with Python's planes (`given`): the matching and the reading alone.
MATCH_JS = """async ([name, seed, scale, given]) => {""" + IN_PAGE + """
  const C = await import('./static/sinshape/colour.js');
  const bytes = (text) => Uint8Array.from(atob(text), (c) => c.charCodeAt(0)).buffer;
  const tri = await s.sample(model, seed, [1, 1, 1]);
  const m = s.surface(await s.dense(model, tri, scale), tri.size, model.manifest);
  const ownPlanes = (await s.project(model, tri)).planes;
  const own = new C.Correspondence(await C.matcher(model), model, ownPlanes, tri.size);
  const colours = await s.vertexColours(model, tri, m.positions, 1 / scale);

  const planes = (texts, size) => texts.map((text, k) => ({ data: new Float32Array(bytes(text)),
    dims: [...[[0, 1], [0, 2], [1, 2]][k].map((a) => size[a]), model.manifest.hidden] }));
  const reconPlanes = planes(given.recon, given.reconSize);
  const example = new C.Matcher(model.tiles, C.pyramid(model, reconPlanes, given.reconSize));
  const theirs = planes(given.sample, tri.size);
  const matched = new C.Correspondence(example, model, theirs, tri.size);
  const slab = example.match(C.pyramid(model, theirs, tri.size), new Int32Array(bytes(given.slab)));
  const { origin, spacing } = model.manifest;
  const coords = Float64Array.from(m.positions, (p, i) => (p - origin[i % 3]) / spacing[i % 3]);
  const read = C.readColours(model.tiles, (voxels) => matched.call(voxels), coords, tri.size, 1 / scale);
  const moved = C.relief(model.tiles, (voxels) => matched.call(voxels), coords, tri.size);
  const painted = await s.paintMesh(model, tri, m.positions, scale);
  const row = C.voxelLookup(new Int32Array(bytes(given.slab)));
  const slabJ = (voxels) => Int32Array.from(voxels, (_, i) => slab[3 * row(...voxels.subarray(i - i % 3, i - i % 3 + 3)) + i % 3]);
  const slabRead = C.readColours(model.tiles, slabJ, new Float64Array(bytes(given.points)), tri.size, 1 / scale);
  return { positions: b64(m.positions), colours: b64(colours), band: b64(own.band), matched: b64(own.matched),
           planes: ownPlanes.map((p) => b64(p.data)),
           givenBand: b64(matched.band), givenMatched: b64(matched.matched), slab: b64(slab), given: b64(read),
           slabRead: b64(slabRead), along: b64(model.tiles.along), moved: b64(moved),
           paintedPositions: b64(painted.positions), paintedColours: b64(painted.colours) };
}"""


def test_a_format_5_samples_matches_and_colours_are_pythons(colour_page, coloured):
    """Given the same planes, the browser's band, matches J and colours at its vertices are
    Python's, to the bit, both ways (Python's planes in the browser, the browser's in Python).
    Sampled by the browser itself, the colour bytes are Python's at SAME_BYTES of the vertices
    or more (99.94% measured, on 8 of 13,312 vertices not) and the band's matches at
    SAME_MATCHES (98.8%): the only differences are near-ties, where onnxruntime-web's planes
    (within the runtimes' 1e-4 of onnxruntime's) put a hidden sum on the other side of a
    patch's rounding boundary, a voxel's random draws or distances change, and its match moves
    (and with it, those of the neighbours it offers it to). Such a vertex may take another
    colour of the example's altogether: no tolerance bounds it, the share does."""
    seed, scale = 3, 2
    recon, triplane = sample(coloured, None), sample(coloured, seed)
    recon_planes, planes = query.project(coloured, recon).planes, query.project(coloured, triplane).planes
    x, y, z = triplane.size
    slab = np.argwhere(np.ones((4, y, z), bool)) + (x // 2, 0, 0)  # 4 whole slices of the grid: J off the band too
    points = (slab + np.random.default_rng(0).uniform(-0.49, 0.49, slab.shape)).repeat(2, axis=0)  # 2 in each voxel
    made = colour_page.evaluate(MATCH_JS, [NAME, seed, scale, {
        "recon": [b64(p) for p in recon_planes], "reconSize": list(recon.size),
        "sample": [b64(p) for p in planes], "slab": b64(slab.astype(np.int32)), "points": b64(points)}])
    np.testing.assert_array_equal(unb64(made["along"], np.int32, 6), coloured.tiles.along.reshape(-1, 6))

    ours = colour.Correspondence(coloured, planes, triplane.size)
    np.testing.assert_array_equal(unb64(made["givenBand"], np.int32, 3), ours.band)
    np.testing.assert_array_equal(unb64(made["givenMatched"], np.int32, 3), ours.matched)
    slab_matched = colour.matcher(coloured).match(colour.pyramid(coloured, planes, triplane.size), slab)
    np.testing.assert_array_equal(unb64(made["slab"], np.int32, 3), slab_matched)
    assert len(np.unique(slab_matched, axis=0)) > len(slab) / 4  # matches spread over the example, not one voxel
    positions = unb64(made["positions"], np.float32, 3)
    coords = (positions - np.asarray(coloured.manifest.origin)) / np.asarray(coloured.manifest.spacing)
    given = colour.read_colours(coloured.tiles, ours, coords, np.array(triplane.size), 1 / scale)
    np.testing.assert_array_equal(unb64(made["given"], np.float32, 3), given)
    # The example's relief under the same points, to the bit: the points it moves, and where.
    moved = colour.relief(coloured.tiles, ours, coords, np.array(triplane.size))
    np.testing.assert_array_equal(unb64(made["moved"], np.float64, 3), moved)
    assert np.abs(moved - coords).max() > 0.01
    # The tiles read where the slab's matches say, at points all over its voxels: the example's colours.
    slab_read = colour.read_colours(coloured.tiles, lambda voxels: slab_matched[colour.voxel_lookup(slab)(voxels)],
                                    points, np.array(triplane.size), 1 / scale)
    np.testing.assert_array_equal(unb64(made["slabRead"], np.float32, 3), slab_read)
    assert len(np.unique(mesh.colour_bytes(slab_read), axis=0)) > 10  # many colours, each Python's

    # On its own: planes within the runtimes' tolerance; given them, Python matches as the browser did...
    own_planes = [unb64(text, np.float32, p.shape[-1]).reshape(p.shape) for text, p in zip(made["planes"], planes)]
    assert max(np.abs(a - b).max() for a, b in zip(own_planes, planes)) < TOLERANCE
    theirs = colour.Correspondence(coloured, own_planes, triplane.size)
    np.testing.assert_array_equal(unb64(made["band"], np.int32, 3), theirs.band)
    np.testing.assert_array_equal(unb64(made["matched"], np.int32, 3), theirs.matched)
    # ...and near-ties apart, that is Python's own band, matches and colours.
    assert np.array_equal(theirs.band, ours.band) and len(ours.band) > 1000
    assert (theirs.matched == ours.matched).all(axis=1).mean() >= SAME_MATCHES
    colours = unb64(made["colours"], np.float32, 3)
    np.testing.assert_array_equal(colours, colour.read_colours(coloured.tiles, theirs, coords, np.array(triplane.size),
                                                               1 / scale))
    expected = colour.colours(coloured, triplane, coords, 1 / scale)
    equal = (mesh.colour_bytes(colours) == mesh.colour_bytes(expected)).all(axis=1)
    # The worker's mesh as runtime.mesh.paint makes it: moved by the relief, then coloured there.
    painted = unb64(made["paintedPositions"], np.float32, 3)
    surface = colour.colouring(coloured, triplane)
    relieved = surface.relief(coords)
    # Near-ties apart (the browser matched on its own planes), each vertex where Python moves it.
    placed = (np.abs(painted - mesh.in_frame(relieved, coloured.manifest)) < 1e-5).all(axis=1)
    assert placed.mean() >= SAME_BYTES, f"{placed.mean():.4%} of the vertices placed as Python places them"
    assert np.abs(painted - positions).max() > 1e-3  # it moved
    same = (mesh.colour_bytes(unb64(made["paintedColours"], np.float32, 3))
            == mesh.colour_bytes(surface(relieved, 1 / scale))).all(axis=1)
    assert same.mean() >= SAME_BYTES
    assert len(colours) > 500 and equal.mean() >= SAME_BYTES, f"{equal.mean():.4%} of the vertices' colours equal"
    assert len(np.unique(mesh.colour_bytes(expected), axis=0)) > 2  # the sample shows the example's colours


# Runs in the page: a sample's mesh at `scale` as the browser meshes it, and as its worker paints it.
RELIEF_JS = """async ([name, seed, scale, detail]) => {""" + IN_PAGE + """
  const tri = await s.sample(model, seed, [1, 1, 1]);
  const mesh = s.surface(await s.dense(model, tri, scale), tri.size, model.manifest);
  const painted = await s.paintMesh(model, tri, mesh.positions, scale, detail);
  return { positions: b64(mesh.positions), painted: b64(painted.positions), colours: painted.colours };
}"""


@pytest.mark.parametrize("scale, detail", [(1, True), (2, True), (2, False)])
def test_a_geometry_only_models_relief_in_the_page_is_pythons(colour_page, scale, detail):
    # A relief-only model's mesh in the browser: at scale 2 each vertex where Python's relief moves
    # it (near-ties apart, as for colour), at scale 1 or without detail where it lies; never coloured.
    model = load.load_model(RELIEF_ONNX, threads=2)
    assert not model.manifest.colour and model.tiles is not None
    made = colour_page.evaluate(RELIEF_JS, [RELIEF_NAME, 4, scale, detail])
    assert made["colours"] is None
    positions, painted = unb64(made["positions"], np.float32, 3), unb64(made["painted"], np.float32, 3)
    coords = (positions - np.asarray(model.manifest.origin)) / np.asarray(model.manifest.spacing)
    moves = detail and scale >= colour.RELIEF_SCALE
    expected = colour.colouring(model, sample(model, 4)).relief(coords) if moves else coords
    placed = (np.abs(painted - mesh.in_frame(expected, model.manifest)) < 1e-5).all(axis=1)
    assert len(placed) > 1000 and placed.mean() >= SAME_BYTES, f"{placed.mean():.4%} placed as Python places them"
    moved = np.abs(painted - positions).max() / min(model.manifest.spacing)  # in voxels
    assert (moved > 0.05) == moves


def altered(path: Path, change, source: Path = COLOUR_ONNX) -> Path:
    """A format-5 model (`source`) with its proto changed, sealed again (the change is what is checked)."""
    import onnx

    from conftest import sealed_bytes

    proto = onnx.load(source)
    change(proto)
    path.write_bytes(sealed_bytes(proto))
    return path


def tile_array(name: str, change):
    """A change of the model: one tile tensor replaced by change(its array), or dropped (change None)."""
    def edit(proto):
        from onnx import numpy_helper

        tensor = next(t for t in proto.graph.initializer if t.name == name)
        if change is None:
            proto.graph.initializer.remove(tensor)
        else:
            tensor.CopyFrom(numpy_helper.from_array(np.ascontiguousarray(change(numpy_helper.to_array(tensor))), name))
    return edit


def outside_raw_data(proto):
    from onnx import helper, numpy_helper

    tensor = next(t for t in proto.graph.initializer if t.name == "colour_tiles.voxels")
    array = numpy_helper.to_array(tensor)
    tensor.CopyFrom(helper.make_tensor(tensor.name, tensor.data_type, array.shape, array.ravel().tolist()))


def ragged_raw_data(proto):
    tensor = next(t for t in proto.graph.initializer if t.name == "colour_tiles.voxels")
    tensor.raw_data = tensor.raw_data[:-1]


def tiles_of_side_3(proto):
    import json

    prop = next(p for p in proto.metadata_props if p.key == fmt.METADATA_KEY)
    manifest = json.loads(prop.value)
    manifest["colour"]["tiles"]["side"] = 3
    prop.value = json.dumps(manifest)


def test_damaged_tiles_are_refused_as_the_python_loader_refuses_them(colour_page, tmp_path):
    cases = {
        "outside": tile_array("colour_tiles.voxels", lambda a: a + 1000),
        "direction": tile_array("colour_tiles.directions", lambda a: a * 0 + 6),
        "order": tile_array("colour_tiles.voxels", lambda a: a[::-1]),
        "shape": tile_array("colour_tiles.images", lambda a: a[:-1]),
        "float": tile_array("colour_tiles.voxels", lambda a: a.astype(np.float32)),
        "missing": tile_array("colour_tiles.directions", None),
        "int32_data": outside_raw_data,
        "ragged": ragged_raw_data,
        "side": tiles_of_side_3,
        "distance": tile_array("colour_tiles.distance", lambda a: a[:-1]),
    }
    files = [altered(tmp_path / f"{name}.onnx", change) for name, change in cases.items()]
    messages = dict(zip(cases, load_in_page(colour_page, files)))
    for path, message in zip(files, messages.values()):
        with pytest.raises(InputError) as python:
            load.load_model(path)
        assert message == str(python.value).replace(str(path), path.name)
    assert "\n" not in "".join(messages.values())
    assert messages["outside"].endswith("colour tiles lie outside the model's finest level")
    assert messages["direction"].endswith("colour tiles lie outside the model's finest level")
    assert messages["order"].endswith("colour tiles are not each once, in order of their voxel")
    assert "do not match the manifest's" in messages["shape"] and "is not int32" in messages["float"]
    assert "its colour tiles are missing" in messages["missing"]
    assert "keeps its values outside raw_data" in messages["int32_data"]
    assert "buffer size must be a multiple of element size" in messages["ragged"]
    assert "T a power of two up to 64" in messages["side"]
    assert "a colour distance grid of shape" in messages["distance"]


def manifest_edit(edit):
    """A change of the model: its manifest's JSON edited by edit(dict)."""
    def change(proto):
        import json

        prop = next(p for p in proto.metadata_props if p.key == fmt.METADATA_KEY)
        manifest = json.loads(prop.value)
        edit(manifest)
        prop.value = json.dumps(manifest)
    return change


def test_a_relief_models_damaged_tiles_and_manifest_are_refused_as_python_refuses_them(colour_page, tmp_path):
    tiles = {"count": 1, "side": 2}
    cases = {
        "four_channels": tile_array("colour_tiles.images", lambda a: np.repeat(a, 4, axis=-1)),
        "missing": tile_array("colour_tiles.distance", None),
        "both": manifest_edit(lambda m: m.update(colour={"space": "srgb", "tiles": tiles})),
        "space": manifest_edit(lambda m: m["relief"].update(space="srgb")),
        "v3": manifest_edit(lambda m: m.update(format_version=3)),
        "v4": manifest_edit(lambda m: m.update(format_version=4, colour={"space": "srgb"})),
    }
    files = [altered(tmp_path / f"{name}.onnx", change, RELIEF_ONNX) for name, change in cases.items()]
    messages = dict(zip(cases, load_in_page(colour_page, files)))
    for path, message in zip(files, messages.values()):
        with pytest.raises(InputError) as python:
            load.load_model(path)
        assert message == str(python.value).replace(str(path), path.name)
    assert "relief tiles of shapes" in messages["four_channels"]
    assert "its relief tiles are missing" in messages["missing"]
    assert "colour or relief, not both" in messages["both"] and "needs colour" in messages["space"]
    assert "relief is read from format 5 on, not 3" in messages["v3"]
    assert "relief is read from format 5 on, not 4" in messages["v4"]


# Runs in the page: a format-5 tile's mesh and colours as the browser makes them, and what they come
# from: each vertex's source (world.js's pointField: the window that weighs most, or the object), its
# cells there, and that window's planes.
TILE_JS = """async ([name, seed, tile, options]) => {""" + IN_PAGE + """
  const { scale, ...given } = options, world = W.worldOptions(given), at = tile.map(BigInt);
  const mesh = await W.tileMesh(model, BigInt(seed), at, scale, world);
  const colours = await W.tileColours(model, BigInt(seed), at, mesh.positions, world, 1 / scale);
  const sources = [], layout = W.worldLayout(model.manifest), finest = model.manifest.sizes.length - 1;
  await W.pointField(model, BigInt(seed), at, Float64Array.from(mesh.positions), world, sources);
  const out = [];
  for (const { window: [a, b, arrange], index, cells } of sources) {
    const { planes } = await W.windowAt(model, layout, BigInt(seed), a, b, finest, arrange);
    out.push({ key: [String(a), String(b), arrange], index: b64(index), cells: b64(cells),
               planes: planes.map((p) => b64(p.data)) });
  }
  return { positions: b64(mesh.positions), colours: b64(colours), sources: out };
}"""

# Runs in the page: colour.js's planesColouring of given planes (Python's windows'), read at given cells.
GIVEN_JS = """async ([name, footprint, reads]) => {
  const C = await import('./static/sinshape/colour.js');
  const model = window.models[name];
  const bytes = (text) => Uint8Array.from(atob(text), (c) => c.charCodeAt(0)).buffer;
  const out = [];
  for (const { planes, size, cells } of reads) {
    const given = planes.map((text, k) => ({ data: new Float32Array(bytes(text)),
      dims: [...[[0, 1], [0, 2], [1, 2]][k].map((a) => size[a]), model.manifest.hidden] }));
    const read = (await C.planesColouring(model, given, size))(new Float64Array(bytes(cells)), footprint);
    out.push(btoa(String.fromCharCode(...new Uint8Array(read.buffer))));
  }
  return out;
}"""


def by_window(sources) -> dict:
    """Sources (key, point indices, cells) merged per window: {key: (indices, cells)} in index order
    (a window read by points of two groups, those just past a face among them, comes twice)."""
    merged = {}
    for key, index, cells in sources:
        merged.setdefault(tuple(key), []).append((np.asarray(index, np.int64), np.asarray(cells, np.float64)))
    out = {}
    for key, parts in merged.items():
        index, cells = np.concatenate([i for i, _ in parts]), np.concatenate([c for _, c in parts])
        order = np.argsort(index, kind="stable")
        if len(index):  # a window no vertex reads most is no source
            out[key] = (index[order], cells[order])
    return out


@pytest.mark.parametrize("seed, tile, scale, arrange", [(5, (0, 0), 2, "blend"), (5, (10**9, -10**9), 1, "blend"),
                                                        (5, (3, 4), 1, "scatter")])
def test_a_format_5_tiles_colours_are_pythons_at_the_same_vertices(colour_page, coloured, seed, tile, scale, arrange):
    """A format-5 full-detail tile reads each vertex's colour from the example in one window (the
    one that weighs most there, the first of equals) or its object, as world.tile_colours. At the
    browser's vertices: the same source per vertex and the same cells there, to the bit; given
    Python's window planes, the browser's colouring of each window is Python's, to the bit, and
    given the browser's planes, Python's is the browser's tile colours, to the bit. Made by each
    runtime on its own (onnxruntime-web's planes within 1e-4 of onnxruntime's), the colour bytes
    are Python's at SAME_BYTES of the vertices or more: the near-ties of the sample test, per window
    (100% measured on these tiles)."""
    options = world.WorldOptions(arrange=arrange)
    footprint = 1 / scale
    made = colour_page.evaluate(TILE_JS, [NAME, seed, [str(t) for t in tile], {"scale": scale, "arrange": arrange}])
    positions = unb64(made["positions"], np.float32, 3).astype(np.float64)
    colours = unb64(made["colours"], np.float32, 3)
    ours = []
    _, _, ground = world.point_field(coloured, seed, tile, positions, options, ours)
    assert all(k == 0 for (*_, k), _, _ in ours)  # a world of one model: its objects are all model 0's
    ours = [((a, b, arrange_of), index, cells) for (a, b, arrange_of, _), index, cells in ours]
    theirs = [((int(s["key"][0]), int(s["key"][1]), s["key"][2]), unb64(s["index"], np.int32, 1)[:, 0],
               unb64(s["cells"], np.float64, 3)) for s in made["sources"]]
    ours, planes = by_window(ours), {tuple(s["key"]): s["planes"] for s in made["sources"]}
    assert by_window(theirs).keys() == ours.keys()
    for key, (index, cells) in by_window(theirs).items():  # the same source per vertex, the same cells in it
        np.testing.assert_array_equal(index, ours[key][0])
        np.testing.assert_array_equal(cells, ours[key][1])
    assert len(ours) >= (2 if arrange == "blend" else 1)
    np.testing.assert_array_equal(colours[ground], np.float32(0.5))  # a scatter world's ground is grey
    if arrange == "scatter":
        assert 0.1 < ground.mean() < 0.9  # ground and an object both

    layout = world.world_layout(coloured)
    finest = len(coloured.manifest.sizes) - 1
    reads, expected = [], []
    for (a, b, arrange_of), (index, cells) in ours.items():
        size = world.window_sizes(coloured, layout, arrange_of)[-1]
        python_planes = world.window(coloured, layout, seed, a, b, finest, arrange_of).planes
        reads.append({"planes": [b64(p) for p in python_planes], "size": list(size), "cells": b64(cells)})
        expected.append(world.window_colouring(coloured, layout, seed, a, b, arrange_of)(cells, footprint))
        # The browser's planes in Python: its own tile colours, to the bit.
        browser_planes = [unb64(text, np.float32, p.shape[-1]).reshape(p.shape)
                          for text, p in zip(planes[(str(a), str(b), arrange_of)], python_planes)]
        assert max(np.abs(x - y).max() for x, y in zip(browser_planes, python_planes)) < TOLERANCE
        np.testing.assert_array_equal(colours[index],
                                      colour.planes_colouring(coloured, browser_planes, size)(cells, footprint))
    given = colour_page.evaluate(GIVEN_JS, [NAME, footprint, reads])  # Python's planes in the browser
    for text, python in zip(given, expected):
        np.testing.assert_array_equal(unb64(text, np.float32, 3), python)

    python = world.tile_colours(coloured, seed, tile, positions, options, footprint)
    equal = (mesh.colour_bytes(colours) == python).all(axis=1)
    assert len(colours) > 300 and equal.mean() >= SAME_BYTES, f"{equal.mean():.4%} of the vertices' colours equal"
    assert len(np.unique(python, axis=0)) > 2  # the example's colours, not one
    assert (mesh.colour_bytes(colours[::-1]) != python).any(axis=1).mean() > 0.1  # from the wrong vertices: others


@pytest.mark.parametrize("tile", [(0, 0), (10**9, -10**9)])
def test_a_colour_heads_tile_colours_are_pythons_at_the_same_vertices(colour_page, headed, tile):
    """A format-4 model's tile takes the colour head of the blended hidden vector. Python's tile
    colours are bytes: the browser's floats round to them, within the tolerance."""
    positions, colours = colours_in_page(colour_page, 5, tile, name=HEAD_NAME)
    expected = world.tile_colours(headed, 5, tile, positions.astype(np.float64), world.WorldOptions(), 1.0)[:, :3]
    assert len(colours) > 100 and colours.std(axis=0).max() > 0.01
    assert np.abs(colours * 255 - expected).max() <= 0.5 + 255 * TOLERANCE
    assert np.abs(colours[::-1] * 255 - expected).max() > 2  # a vertex's colour from the wrong place shows


def test_a_coarser_tiles_colours_are_pythons_and_the_examples(colour_page, coloured):
    """A format-5 model's coarser tile (lod 1): the colour head's, made the example's nearest colour,
    in the browser as in Python. The head's colours agree within the tolerance, so one near the middle
    of two of the example's colours may go the other way: SAME_BYTES of the vertices are equal."""
    positions, colours = colours_in_page(colour_page, 5, (3, -2), lod=1)
    expected = world.tile_colours(coloured, 5, (3, -2), positions.astype(np.float64), world.WorldOptions(lod=1),
                                  1.0)[:, :3]
    got = mesh.colour_bytes(colours)[:, :3]
    palette = {tuple(c) for c in colour.example_palette(coloured.tiles)}
    assert len(got) > 100 and len(np.unique(got, axis=0)) > 2
    assert all(tuple(c) in palette for c in got)  # only the example's colours
    assert (got == expected).all(axis=1).mean() >= SAME_BYTES


def test_neighbouring_tiles_give_their_shared_vertices_one_colour(colour_page, coloured):
    """In the browser, a format-5 model's tiles (0, 0) and (1, 0): each vertex on the face they share
    has the same colour from both sides, to the bit (one window at weight 1 there, read at the same
    cells)."""
    layout = world.world_layout(coloured)
    h0 = layout.horizontal[0]
    (a, ca), (b, cb) = colours_in_page(colour_page, 2, (0, 0)), colours_in_page(colour_page, 2, (1, 0))
    shift = np.zeros(3, np.float32)
    shift[h0] = layout.stride[h0]
    left = {tuple(v - shift): c for v, c in zip(a, ca) if v[h0] == layout.stride[h0]}
    right = {tuple(v): c for v, c in zip(b, cb) if v[h0] == 0}
    shared = set(left) & set(right)
    assert len(shared) > 5 and all(np.array_equal(left[v], right[v]) for v in shared)
    assert len({tuple(right[v]) for v in shared}) > 1  # the face's colours vary: not one colour everywhere


SHOWN_JS = """() => { const m = []; window.sinshapeView.scene.traverse((n) => n.isMesh && m.push([
  Boolean(n.geometry.attributes.color), n.material.vertexColors, n.geometry.attributes.position.count])); return m; }"""


SHOWN_MESH_JS = """() => { let g = null; window.sinshapeView.scene.traverse((n) => { if (n.isMesh) g = n.geometry; });
  return { positions: Array.from(g.attributes.position.array), colours: Array.from(g.attributes.color.array) }; }"""


def test_the_page_shows_a_coloured_models_vertex_colours_and_a_grey_ones_without(colour_page, coloured, tmp_path):
    """A format-5 model's colours on the page are Python's at the page's vertices (the worker's
    footprint: 1 / scale); the view is saved as a picture."""
    page = colour_page
    page.goto(f"{page.base}/?model={NAME}&seed=3&scale=2&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    ((has_colour, vertex_colours, vertices),) = page.evaluate(SHOWN_JS)
    assert has_colour and vertex_colours and vertices > 500
    shown = page.evaluate(SHOWN_MESH_JS)
    linear = np.array(shown["colours"]).reshape(-1, 3)  # three.js's linear colours, back to sRGB
    srgb = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.maximum(linear, 0) ** (1 / 2.4) - 0.055)
    positions = np.array(shown["positions"], np.float32).reshape(-1, 3)
    coords = (positions - np.asarray(coloured.manifest.origin)) / np.asarray(coloured.manifest.spacing)
    expected = mesh.colour_bytes(colour.colours(coloured, sample(coloured, 3), coords, 1 / 2))
    assert (np.abs(mesh.colour_bytes(srgb).astype(int) - expected).max(axis=1) <= 1).mean() >= SAME_BYTES
    picture = tmp_path / "format5.png"
    page.locator("#view canvas").screenshot(path=picture)
    rgb = np.asarray(Image.open(picture).convert("RGB"), int).reshape(-1, 3)
    red, blue = (rgb[:, 0] > 2 * rgb[:, 2] + 40).mean(), (rgb[:, 2] > 2 * rgb[:, 0] + 40).mean()
    assert red > 0.05 and blue > 0.05, f"the box's red and blue not both shown ({red:.1%}, {blue:.1%}): {picture}"
    page.goto(f"{page.base}/?model=terrain&seed=3&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    assert page.evaluate(SHOWN_JS) == [[False, False, page.evaluate(SHOWN_JS)[0][2]]]


# Runs in the page: the world mode's tiles of some names ("i,j") as shown (positions in frame tile,
# three.js's linear colours), and the runtime's colours at their vertices (in voxels) with footprints.
WORLD_TILES_JS = """async ([name, seed, tiles, footprints]) => {""" + IN_PAGE + """
  const meshes = [], out = [];
  window.sinshapeView.scene.traverse((n) => { if (n.isMesh && tiles.includes(n.name)) meshes.push(n); });
  for (const n of meshes) {
    const positions = n.geometry.attributes.position.array;
    const voxels = positions.map((p, k) => p / model.manifest.spacing[k % 3]);
    const read = [];
    const tile = n.name.split(',').map(BigInt);
    for (const footprint of footprints) {
      read.push(Array.from(await W.tileColours(model, BigInt(seed), tile, voxels, W.worldOptions(), footprint)));
    }
    out.push([n.name, Array.from(voxels), Array.from(n.geometry.attributes.color.array), read]);
  }
  return out;
}"""


def test_world_tiles_in_the_page_carry_colour(colour_page, coloured):
    """Every world tile of a coloured model is coloured in world mode; a format-5 model's full-detail
    tiles as Python's tile files have them: the runtime's colours with the footprint of a tile's file
    (1 / scale voxels: not those with none), which are world.tile_colours' bytes at the page's
    vertices (within the one byte three.js's linear float32 colours may move them)."""
    page = colour_page
    page.goto(f"{page.base}/?model={NAME}&seed=3&scale=1&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    page.select_option("#edit", "world")
    page.select_option("#reach", "1")
    status = wait_world(page)
    made = [t for t in status["tiles"] if t[2] > 0]
    assert made and status["coloured"] == len(made)
    assert {f"{i},{j}": lod for i, j, _, _, lod in status["tiles"]}.keys() >= {"0,0", "1,0"}
    assert all(lod == 0 for *_, lod in status["tiles"])  # within one tile of the camera's: full detail
    shown, runtime, none, expected = [], [], [], []
    read = page.evaluate(WORLD_TILES_JS, [NAME, 3, ["0,0", "1,0"], [1.0, None]])  # the camera's tile and one more
    assert len(read) == 2
    for name, voxels, linear, (footprint_one, no_footprint) in read:
        linear = np.array(linear).reshape(-1, 3)  # three.js's linear colours, back to sRGB
        shown.append(np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.maximum(linear, 0) ** (1 / 2.4) - 0.055))
        runtime.append(np.reshape(footprint_one, (-1, 3)))
        none.append(np.reshape(no_footprint, (-1, 3)))
        voxels = np.array(voxels, np.float64).reshape(-1, 3)
        expected.append(world.tile_colours(coloured, 3, tuple(int(t) for t in name.split(",")), voxels, footprint=1.0))
    shown, runtime, none, expected = (np.concatenate(a) for a in (shown, runtime, none, expected))
    assert len(shown) > 500
    assert np.abs(shown - runtime).max() < 1e-5  # the footprint of a tile's file...
    assert (np.abs(shown - none).max(axis=1) > 1e-3).mean() > 0.05  # ...which shows (15% of the vertices)
    same = (np.abs(mesh.colour_bytes(shown).astype(int) - expected).max(axis=1) <= 1).mean()
    assert same >= SAME_BYTES, f"{same:.4%} of the vertices' colours equal"


COLOURS_SHOWN_JS = """() => { let c = null; window.sinshapeView.scene.traverse((n) => { if (n.isMesh && n.geometry.attributes.color)
  c = Array.from(n.geometry.attributes.color.array); }); return c; }"""


def test_on_sinrun_serve_the_servers_glb_colours_reach_the_page_as_the_browsers_do(browser):  # noqa: F811
    """The server's .glb carries COLOR_0 (linear); the page reads it back and shows it as the
    browser's own sample shows its colours: the same mean colour over the shape, for a colour
    head and for colour tiles."""
    pytest.importorskip("fastapi")
    from test_serve import running_server

    with running_server(COLOUR_ONNX, HEAD_ONNX) as (base, _):
        page = open_page(browser, base)
        for name in (HEAD_NAME, NAME):
            shown = {}
            for where in ("server", "browser"):
                page.goto(f"{base}/?model={name}&seed=3&up=z&where={where}")
                assert wait_done(page) == "ready", page.text_content("#error")
                colours = page.evaluate(COLOURS_SHOWN_JS)
                assert colours, f"no vertex colours shown from the {where}"
                shown[where] = np.array(colours).reshape(-1, 3)
            assert np.abs(shown["server"].mean(axis=0) - shown["browser"].mean(axis=0)).max() < 2e-3
            if name == HEAD_NAME:  # (how a sample's tiles vary is the example's: tests/test_colour_tiles.py)
                assert shown["server"].std(axis=0).max() > 0.005
        page.close()


# Runs in the page: a sample of `seed` keeping a box of another seed, its mesh at `scale` painted as the
# worker paints it (relief, then colour).
KEPT_JS = """async ([name, seed, keep, scale]) => {""" + IN_PAGE + """
  const request = s.sampleRequest({ seed: BigInt(seed), keep: [keep] });
  const tri = await s.make(model, request);
  const mesh = s.surface(await s.dense(model, tri, scale), tri.size, model.manifest);
  const painted = await s.paintMesh(model, tri, mesh.positions, scale);
  return { plain: b64(mesh.positions), positions: b64(painted.positions), colours: b64(painted.colours) };
}"""


def test_a_kept_boxs_colour_and_relief_in_the_page_are_pythons(colour_page, coloured):
    """Deep in a kept box the page reads the part's own matches, as Python does (TriPlane.kept):
    the same relief and colour at the same vertices, near-ties apart."""
    from sinshape.runtime import edit
    from sinshape.runtime.request import SampleRequest, make

    keep, scale = "3:0%,0%,0%:60%,100%,100%", 2
    made = colour_page.evaluate(KEPT_JS, [NAME, 7, keep, scale])
    plain = unb64(made["plain"], np.float32, 3)
    coords = (plain - np.asarray(coloured.manifest.origin)) / np.asarray(coloured.manifest.spacing)
    part = edit.parse_part(keep, coloured.manifest, coloured.manifest.sizes[-1])
    triplane = make(coloured, SampleRequest(seed=7, keep=(part,)))
    assert len(triplane.kept) == 1
    surface = colour.colouring(coloured, triplane)
    relieved = surface.relief(coords)
    placed = (np.abs(unb64(made["positions"], np.float32, 3) - mesh.in_frame(relieved, coloured.manifest)) < 1e-5).all(axis=1)
    same = (mesh.colour_bytes(unb64(made["colours"], np.float32, 3))
            == mesh.colour_bytes(surface(relieved, 1 / scale))).all(axis=1)
    assert len(plain) > 500 and placed.mean() >= SAME_BYTES and same.mean() >= SAME_BYTES, (placed.mean(), same.mean())
