"""A coloured model's samples carry colour in every output format, each
vertex's colour the model's at that vertex (read from the example by
correspondence: runtime/colour.py), through edits too; a geometry-only
model's fine meshes carry its example's relief (and no colour), and one
without tiles gives its outputs as it always did."""

import json
import struct

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from scipy.spatial import cKDTree

from sinshape.cli.main import cli
from sinshape.core import manifest as fmt
from sinshape.core.manifest import DEPTH_RANGE, DISTANCE_STEP
from sinshape.runtime import colour, edit, generate, load_model, query
from sinshape.runtime.request import SampleRequest, make


def sinrun(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


@pytest.fixture(scope="module")
def model(tiny_colour_model):
    return load_model(tiny_colour_model, threads=1)


def read_ply(path) -> tuple:
    """(vertices float32 (n, 3), colours uint8 (n, 3) or None) of a binary PLY as sinshape writes it
    (a world's tiles with normals between them)."""
    data = path.read_bytes()
    header, body = data.split(b"end_header\n", 1)
    count = int(header.split(b"element vertex ")[1].split()[0])
    fields = [("p", "<f4", (3,))] + [("n", "<f4", (3,))] * (b"property float nx" in header)
    if b"property uchar red" not in header:
        return np.frombuffer(body, np.dtype(fields), count)["p"], None
    records = np.frombuffer(body, np.dtype(fields + [("c", "u1", (3,))]), count)
    return records["p"], records["c"]


def decoder_colour(model, triplane, points: np.ndarray) -> np.ndarray:
    """The decoder's colour at points (model coordinates), worked out apart
    from the runtime's query: each projected plane interpolated by hand,
    then the graph's own head stage (onnxruntime), not its numpy copy."""
    planes = query.project(model, triplane).planes
    hidden = []
    for plane, (a, b) in zip(planes, fmt.PLANE_AXES):
        u = np.clip(points[:, a], 0, plane.shape[0] - 1)
        v = np.clip(points[:, b], 0, plane.shape[1] - 1)
        u0, v0 = np.minimum(np.floor(u).astype(int), plane.shape[0] - 2), np.minimum(np.floor(v).astype(int), plane.shape[1] - 2)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        hidden.append((plane[u0, v0] * (1 - fu) * (1 - fv) + plane[u0 + 1, v0] * fu * (1 - fv)
                       + plane[u0, v0 + 1] * (1 - fu) * fv + plane[u0 + 1, v0 + 1] * fu * fv)[:, None, None])
    _, colour = model.decoder_head.run(hidden)
    return colour[:, 0, 0]


def model_coordinates(model, vertices: np.ndarray) -> np.ndarray:
    return (vertices - np.asarray(model.manifest.origin)) / np.asarray(model.manifest.spacing)


def matching_share(written: np.ndarray, expected: np.ndarray) -> float:
    """The share of vertices whose 8-bit colour is the expected colour: a
    vertex written as float32 can fall on the other side of a voxel's edge
    than its float64 self, and take a neighbouring voxel's match there."""
    return float(np.mean(np.abs(written / 255 - expected).max(axis=1) <= 0.6 / 255 + 1e-3))


@pytest.mark.parametrize("options", [(), ("--scale", 1.7), ("--smooth", 3), ("--size", "1.3,1,0.8")])
def test_each_vertex_has_the_models_colour_at_that_vertex(model, tmp_path, options):
    # The streamed .ply, a finer grid, smoothed vertices (coloured where they
    # end up), another size: every vertex's 8-bit colour is the model's
    # there, averaged over the vertex's spacing (1 / scale voxels).
    out = tmp_path / "s.ply"
    sinrun("sample", model.path, "--seed", 5, *options, "-o", out)
    vertices, colours = read_ply(out)
    assert colours is not None and len(colours) == len(vertices) > 100
    factors = (1.3, 1, 0.8) if "--size" in options else (1.0, 1.0, 1.0)
    scale = 1.7 if "--scale" in options else 1.0
    triplane = generate.sample(model, 5, factors)
    points = model_coordinates(model, vertices.astype(np.float64))
    assert matching_share(colours, colour.colours(model, triplane, points, 1 / scale)) > 0.99
    # Not the decoder's colour head: the tiles'.
    assert matching_share(colours, decoder_colour(model, triplane, points)) < 0.5
    # The colours differ over the shape: not one colour everywhere.
    assert np.ptp(colours.astype(int), axis=0).max() > 3


def test_every_mesh_format_and_the_grid_carry_the_same_colours(model, tmp_path):
    for suffix in (".ply", ".obj", ".glb", ".npz"):
        sinrun("sample", model.path, "--seed", 2, "-o", tmp_path / f"s{suffix}")
    vertices, colours = read_ply(tmp_path / "s.ply")
    obj = np.loadtxt(tmp_path / "s.obj", comments=("#", "f", "o", "mtllib", "usemtl"), usecols=(1, 2, 3, 4, 5, 6))
    tree = cKDTree(vertices)

    def ply_colour_at(points):  # the .ply's colour of the vertex at each point
        distance, index = tree.query(points)
        assert distance.max() < 1e-4
        return colours[index]

    assert np.abs(obj[:, 3:] * 255 - ply_colour_at(obj[:, :3])).max() <= 0.5
    # GLB: COLOR_0 holds linear values, as glTF says.
    (glb,) = trimesh.load_scene(tmp_path / "s.glb", process=False).geometry.values()
    linear = glb.visual.vertex_colors[:, :3] / 255
    np.testing.assert_allclose(linear, fmt.srgb_to_linear(ply_colour_at(glb.vertices) / 255), atol=1 / 255)
    # The grid's colours are the model's at its points (not its colour head's).
    grid = np.load(tmp_path / "s.npz")
    assert grid["colour"].shape == grid["occupancy"].shape + (3,) and grid["colour"].dtype == np.uint8
    triplane = generate.sample(model, 2)
    index = np.argwhere(grid["occupancy"] > -1)[::37].astype(float)
    np.testing.assert_allclose(grid["colour"][tuple(index.astype(int).T)] / 255,
                               colour.colours(model, triplane, index, 1.0), atol=0.6 / 255)
    assert matching_share(grid["colour"][tuple(index.astype(int).T)], decoder_colour(model, triplane, index)) < 0.5


def test_the_streamed_ply_is_the_whole_mesh_ply(model, tmp_path):
    from sinshape.runtime.write import sample_bytes

    sinrun("sample", model.path, "--seed", 4, "-o", tmp_path / "s.ply")
    data, _ = sample_bytes(model, generate.sample(model, 4), tmp_path / "t.ply")
    assert (tmp_path / "s.ply").read_bytes() == data


def test_a_kept_box_keeps_the_other_seeds_colours(model, tmp_path):
    out = tmp_path / "k.ply"
    sinrun("sample", model.path, "--seed", 7, "--keep", "3:0%,0%,0%:60%,100%,100%", "--frame", "model", "-o", out)
    vertices, colours = read_ply(out)
    size = np.array(model.manifest.sizes[-1])
    deep = vertices[:, 0] < 0.6 * (size[0] - 1) - 2 * edit.MARGIN - 2  # well inside the kept box
    far = vertices[:, 0] > 0.6 * (size[0] - 1) + 2 * edit.MARGIN + 2
    assert deep.sum() > 50 and far.sum() > 50
    kept = generate.sample(model, 3)
    points = vertices.astype(np.float64)
    # Deep in the box the features are the kept seed's, and so are the
    # matches: the box's own (TriPlane.kept), not the composed sample's,
    # whose coarse blocks reach across the box's join.
    assert matching_share(colours[deep], colour.colours(model, kept, points[deep], 1.0)) > 0.99
    # ...and elsewhere not the kept seed's: the colour came from the box, not from anywhere.
    assert matching_share(colours[far], colour.colours(model, kept, points[far], 1.0)) < 0.9


@pytest.mark.parametrize("edit_options", [("--grow", "1.5,1,1"), ("--keep", "3:0%,0%,0%:50%,100%,100%")])
def test_edits_are_coloured_by_their_own_triplane(model, tmp_path, edit_options):
    out = tmp_path / "e.ply"
    sinrun("sample", model.path, "--seed", 7, *edit_options, "--frame", "model", "-o", out)
    vertices, colours = read_ply(out)
    request = SampleRequest(seed=7, **({"grow": (1.5, 1.0, 1.0)} if edit_options[0] == "--grow" else
                                       {"keep": (edit.parse_part(edit_options[1], model.manifest,
                                                                 model.manifest.sizes[-1]),)}))
    expected = colour.colours(model, make(model, request), vertices.astype(np.float64), 1.0)
    assert matching_share(colours, expected) > 0.99


def test_geometry_only_outputs_have_no_colour(tiny_model, tmp_path):
    for suffix in (".ply", ".obj", ".glb", ".npz"):
        sinrun("sample", tiny_model, "--seed", 2, "-o", tmp_path / f"s{suffix}")
    assert b"red" not in (tmp_path / "s.ply").read_bytes()[:400]
    assert all(len(line.split()) == 4 for line in (tmp_path / "s.obj").read_text().splitlines() if line.startswith("v "))
    assert "colour" not in np.load(tmp_path / "s.npz")
    data = (tmp_path / "s.glb").read_bytes()
    meta = json.loads(data[20:20 + struct.unpack_from("<I", data, 12)[0]])
    assert all("COLOR_0" not in p["attributes"] for mesh in meta["meshes"] for p in mesh["primitives"])


def test_a_coloured_tiles_glb_carries_the_fields_normals(model):
    """A coloured tile's .glb holds its colours and the normals the runtime made (the field's gradient,
    which agree across tiles): colouring it for glTF must not drop them for normals of its faces."""
    from sinshape.runtime import world_tiles, write

    data, _ = write.request_bytes(model, SampleRequest(seed=3, tile=(0, 0), frame="tile"), "t.glb")
    length = struct.unpack_from("<I", data, 12)[0]
    meta = json.loads(data[20:20 + length])
    (primitive,) = meta["meshes"][0]["primitives"]
    assert {"POSITION", "NORMAL", "COLOR_0"} <= primitive["attributes"].keys()
    view = meta["bufferViews"][meta["accessors"][primitive["attributes"]["NORMAL"]]["bufferView"]]
    start = 20 + length + 8 + view.get("byteOffset", 0)
    normals = np.frombuffer(data[start:start + view["byteLength"]], np.float32).reshape(-1, 3)
    surface = world_tiles.tile_surface(model, 3, (0, 0), 1.0, SampleRequest(seed=3, tile=(0, 0)).world_options())
    expected = world_tiles.frame_normals(model, surface.normals)
    assert np.abs(normals - expected).max() < 1e-6
    faces = trimesh.Trimesh(surface.vertices, surface.faces, process=False).vertex_normals
    assert np.abs(normals - faces).max() > 1e-3  # not the faces' normals, which the field's differ from


def test_world_tiles_are_coloured_seamlessly(model, tmp_path):
    from sinshape.runtime import world, world_points, world_tiles

    # tile_colours at the tile grid's own points is the grid's colour, made the other way.
    occupancy, grid = world_tiles.tile_occupancy(model, 3, (0, 1), colour=True)
    tiling = world.world_tiling(model)
    points = np.argwhere(occupancy > -1)[::29].astype(np.float64)
    positions = points * np.array(tiling.stride) / (np.array(occupancy.shape) - 1)
    np.testing.assert_allclose(world_points.tile_colours(model, 3, (0, 1), positions)[:, :3].astype(int),
                               grid[tuple(points.astype(int).T)].astype(int), atol=1)
    # Neighbours give the vertices of the face they share the same colour.
    h0 = tiling.horizontal[0]
    a, _ = world_tiles.tile_mesh(model, 3, (0, 0))
    b, _ = world_tiles.tile_mesh(model, 3, (1, 0))
    on_a = a[np.isclose(a[:, h0], tiling.stride[h0])]
    on_b = b[np.isclose(b[:, h0], 0)]
    assert len(on_a) > 3
    shift = np.zeros(3)
    shift[h0] = tiling.stride[h0]
    np.testing.assert_array_equal(world_points.tile_colours(model, 3, (0, 0), on_a),
                                  world_points.tile_colours(model, 3, (1, 0), on_a - shift))
    assert len(on_b) == len(on_a)
    # Read from the example in the windows, not the colour head's: the box's red and blue, or blends of them.
    from sinshape.runtime.query import head_colour

    rgb = world_points.tile_colours(model, 3, (0, 0), a)[:, :3].astype(float)
    head = np.round(head_colour(model.head, world_points.point_field(model, 3, (0, 0), a)[1]) * 255)
    assert np.mean(np.abs(rgb - head).max(axis=1) <= 1) < 0.5
    red, blue = np.array([220, 40, 30]), np.array([30, 60, 200])
    t = np.clip(((rgb - blue) @ (red - blue)) / ((red - blue) @ (red - blue)), 0, 1)
    assert np.linalg.norm(rgb - (blue + t[:, None] * (red - blue)), axis=1).max() < 3
    # A block, a tile file: coloured with those colours.
    sinrun("world", model.path, "--seed", 3, "--tiles", "0:1,0:0", "--frame", "model", "-o", tmp_path / "b.ply")
    sinrun("world", model.path, "--seed", 3, "--tiles", "0:0,0:0", "--frame", "model", "-o", tmp_path / "t/")
    block, block_colours = read_ply(tmp_path / "b.ply")
    tile, tile_colours = read_ply(tmp_path / "t" / "tile_0_0.ply")
    assert block_colours is not None and tile_colours is not None
    tree = cKDTree(block)
    distance, index = tree.query(tile[tile[:, h0] < tiling.stride[h0] - 1])
    assert distance.max() < 1e-4
    np.testing.assert_array_equal(block_colours[index], tile_colours[tile[:, h0] < tiling.stride[h0] - 1])


def test_batch_jobs_write_the_coloured_sample_itself(model, tmp_path):
    sinrun("sample", model.path, "--seeds", "1-2", "--workers", 1, "-o", tmp_path / "{seed}.ply")
    sinrun("sample", model.path, "--seed", 2, "-o", tmp_path / "one.ply")
    assert (tmp_path / "2.ply").read_bytes() == (tmp_path / "one.ply").read_bytes()
    assert read_ply(tmp_path / "1.ply")[1] is not None


def test_render_draws_a_coloured_mesh_in_its_colours(tmp_path):
    from sinshape.runtime.render import CLAY, render

    box = trimesh.creation.box(extents=(2, 1, 1))
    plain = render(box, size=(64, 64), outline=False)
    red = box.copy()
    red.visual.vertex_colors = np.tile([230, 20, 20, 255], (len(box.vertices), 1)).astype(np.uint8)
    drawn = render(red, size=(64, 64), outline=False)
    solid = (plain != plain[0, 0]).any(axis=2)
    assert solid.mean() > 0.2
    assert (drawn[solid][:, 0] > 3 * drawn[solid][:, 1]).mean() > 0.9  # red where the box is (its edges blend)
    assert np.array_equal(render(box, size=(64, 64), outline=False, color=CLAY), plain)


@pytest.mark.parametrize("seed", [None, 1, 2])
def test_a_box_painted_by_height_gives_its_high_vertices_the_top_colour(tmp_path, seed):
    # The committed model learnt the box red above its middle, blue below
    # (z up in the file): its samples keep red on top and blue underneath.
    from conftest import TINY_COLOUR_ONNX

    out = tmp_path / "s.ply"
    sinrun("sample", TINY_COLOUR_ONNX, *(["--recon"] if seed is None else ["--seed", seed]), "-o", out)
    vertices, colours = read_ply(out)
    z, rgb = vertices[:, 2], colours.astype(int)
    top, bottom = rgb[z > np.quantile(z, 0.8)].mean(axis=0), rgb[z < np.quantile(z, 0.2)].mean(axis=0)
    assert top[0] > top[2] + 100 and bottom[2] > bottom[0] + 100, (top, bottom)


def sampled_with_relief(model, tmp_path, scale) -> list:
    """`sinrun sample` of seed 4 at `scale` as .ply and .obj, each file's vertices checked to be the
    mesh's moved by the example's relief under them (on a grid at least RELIEF_SCALE times finer;
    coarser, unmoved): each file's colours (None for the .obj and a geometry-only .ply)."""
    from sinshape.runtime import mesh as meshing

    triplane = generate.sample(model, 4)
    plain = meshing.band_mesh(model, triplane, scale).vertices
    expected = colour.colouring(model, triplane).relief(plain) if scale >= colour.RELIEF_SCALE else plain
    found = []
    for suffix in (".ply", ".obj"):
        out = tmp_path / f"s{suffix}"
        sinrun("sample", model.path, "--seed", 4, "--scale", scale, "--frame", "model", "-o", out)
        vertices, colours = read_ply(out) if suffix == ".ply" else (trimesh.load(out, process=False).vertices, None)
        assert len(vertices) == len(plain)
        assert np.abs(vertices - expected).max() < 1e-4
        assert (np.abs(vertices - plain).max() > 0.05) == (scale >= colour.RELIEF_SCALE)
        found.append(colours)
    return found


@pytest.mark.parametrize("scale", [1, 2])
def test_a_fine_meshs_vertices_move_by_the_examples_relief(model, tmp_path, scale):
    # Every output (the streamed .ply and the whole mesh alike) takes the relief.
    sampled_with_relief(model, tmp_path, scale)


@pytest.fixture(scope="module")
def relief_model(tiny_relief_model):
    return load_model(tiny_relief_model, threads=1)


@pytest.mark.parametrize("scale", [1, 2])
def test_a_geometry_only_models_fine_mesh_takes_its_examples_relief_and_no_colour(relief_model, tmp_path, scale):
    model = relief_model
    assert model.manifest.raw["format_version"] == fmt.TILES_VERSION and model.example_tiles is not None
    assert not model.manifest.colour and model.example_tiles.mips == []
    assert sampled_with_relief(model, tmp_path, scale) == [None, None]


def test_without_detail_a_mesh_has_no_relief_and_its_colour_heads_colours(relief_model, model, tmp_path):
    # --no-detail: a relief model's fine mesh is the voxels' surface; a coloured one's colours are its head's.
    from sinshape.runtime import mesh as meshing

    triplane = generate.sample(relief_model, 4)
    plain = meshing.band_mesh(relief_model, triplane, 2).vertices
    out = tmp_path / "plain.ply"
    sinrun("sample", relief_model.path, "--seed", 4, "--scale", 2, "--frame", "model", "--no-detail", "-o", out)
    np.testing.assert_allclose(read_ply(out)[0], plain, atol=1e-5)
    triplane = generate.sample(model, 4)
    head = meshing.band_mesh(model, triplane, 2)
    sinrun("sample", model.path, "--seed", 4, "--scale", 2, "--frame", "model", "--no-detail", "-o", out)
    vertices, colours = read_ply(out)
    np.testing.assert_allclose(vertices, head.vertices, atol=1e-5)
    expected = np.round(np.clip(query.colouring(model, triplane)(head.vertices), 0, 1) * 255)
    assert np.abs(colours.astype(int) - expected).max() <= 1
    assert np.abs(colours.astype(int) - np.round(colour.colours(model, triplane, head.vertices, 0.5) * 255)).max() > 20


def ridge_height(model, vertices: np.ndarray) -> float:
    """How far the ridged block's ridges (tests/data/relief) stand above its joints on a mesh's top:
    the mean height of the top's vertices in the middle of the ridges less that in the middle of
    the joints, in the example's units (the example's own: 0.03)."""
    points = mesh_in_frame(model, vertices)
    top = points[points[:, 2] > 0.9]
    phase = (top[:, 0] + 1) % 0.25  # the ridges rise over [0, 0.19) of every 0.25 along x
    ridge, joint = (phase > 0.04) & (phase < 0.15), (phase > 0.2) & (phase < 0.24)
    return float(top[ridge, 2].mean() - top[joint, 2].mean())


def mesh_in_frame(model, vertices):
    return np.asarray(model.manifest.origin) + vertices * np.asarray(model.manifest.spacing)


def test_relief_shows_ridges_a_voxel_grid_rounds_away():
    # The committed model (trained 60 iterations: it reconstructs its block) at scale 4: its ridges a
    # quarter voxel high and two voxels wide come out about as high as the example's with relief (0.026
    # measured), under half as high without (0.011: the voxels' trilinear surface rounds them).
    from conftest import TINY_RELIEF_ONNX
    from sinshape.runtime import mesh as meshing

    model = load_model(TINY_RELIEF_ONNX, threads=1)
    triplane = generate.sample(model, None)
    plain = meshing.band_mesh(model, triplane, 4).vertices
    assert ridge_height(model, plain) < 0.015
    assert 0.02 < ridge_height(model, colour.colouring(model, triplane).relief(plain)) < 0.035


def striped_floor(side: int = 8) -> colour.Tiles:
    """The colour tiles of a floor at z = 2 of a 6^3 grid, looking up, whose every voxel's tile
    stands up a quarter voxel in its middle rows along x (a brick) and sinks as far at its edges (mortar)."""
    voxels = np.array([(x, y, 2) for x in range(1, 5) for y in range(1, 5)])
    height = np.where((np.arange(side) >= side // 4) & (np.arange(side) < side - side // 4), 0.25, -0.25)
    depth = np.round((height / (2 * DEPTH_RANGE) + 0.5) * 255).astype(np.uint8)
    images = np.zeros((len(voxels), side, side, 4), np.uint8)
    images[..., 3] = depth[None, :, None]
    z = np.arange(6)[None, None, :] - 2.0
    distance = np.round(np.broadcast_to(z, (6, 6, 6)) / DISTANCE_STEP)
    return colour.Tiles.of(voxels, np.full(len(voxels), 5), images, distance)


def test_relief_raises_a_point_by_the_examples_depth_under_it():
    tiles = striped_floor()
    x = np.linspace(1.6, 3.4, 37)
    points = np.stack([x, np.full_like(x, 2.0), np.full_like(x, 2.0)], axis=1)
    moved = colour.relief(tiles, lambda voxels: voxels, points, np.array([6, 6, 6]), tiles.distance)
    np.testing.assert_allclose(moved[:, :2], points[:, :2])  # along the floor's normal only
    rows = (x + 0.5) % 1 * 8  # texel rows along x within each voxel's tile
    brick, mortar = (rows > 2.6) & (rows < 5.4), (rows < 1.4) | (rows > 6.6)
    assert brick.sum() > 5 and mortar.sum() > 5
    np.testing.assert_allclose(moved[brick, 2], 2.25, atol=0.01)
    np.testing.assert_allclose(moved[mortar, 2], 1.75, atol=0.01)
    # A point off the floor's smooth surface takes the same detail: only the relief is carried.
    lifted = colour.relief(tiles, lambda voxels: voxels, points + (0, 0, 0.2), np.array([6, 6, 6]), tiles.distance)
    np.testing.assert_allclose(lifted[:, 2] - 0.2, moved[:, 2], atol=0.005)  # the grid holds distances in steps of 1/63.5


def test_neighbouring_voxels_copy_coherent_pieces_of_the_example(model):
    """A sample's surface band copies its example in pieces many voxels wide
    (neighbours that copy neighbouring places, colour.piece_sizes), where
    the finest level's search alone, with the same patches compared,
    leaves a patchwork: measured 19% against 69% of the band in pieces
    under 27 voxels, median pieces of 204 against 18 voxels (seeds 1-3)."""
    from sinshape.runtime import query

    small, medians, alone_small = [], [], []
    finest = colour.Level(model.example_tiles.band(), *reference_at_voxels(model))
    for seed in (1, 2, 3):
        triplane = generate.sample(model, seed)
        planes = query.project(model, triplane).planes
        matched = colour.Correspondence(model, planes, triplane.size)
        sizes = colour.piece_sizes(matched.band, matched.matched)
        small.append(np.mean(sizes < 27))
        medians.append(np.median(sizes))
        alone = finest.search(colour.pyramid(model, planes, triplane.size).at(0), matched.band)
        alone_small.append(np.mean(colour.piece_sizes(matched.band, alone) < 27))
    assert np.mean(small) < 0.3 and np.median(medians) > 100
    assert np.mean(alone_small) > 0.5  # the measure sees a patchwork where there is one


def reference_at_voxels(model) -> tuple:
    """The reconstruction's integer hidden sums at voxels, and its grid's size."""
    from sinshape.runtime import query

    recon = generate.sample(model, None)
    reference = colour.pyramid(model, query.project(model, recon).planes, recon.size)
    return reference.at(0), reference.size


def test_relief_ramps_across_a_seam_between_two_pieces_instead_of_stepping():
    """Where neighbouring voxels copy different places of the example, a
    point just either side of the face between them moves alike (each
    blends the two pieces' moves, half and half at the face), where each
    piece's own move differs. On the committed model (trained 60
    iterations: a model of a few iterations, as tiny_relief_model is where
    torch is, copies other pieces)."""
    from conftest import TINY_RELIEF_ONNX
    from sinshape.runtime import query

    model = load_model(TINY_RELIEF_ONNX, threads=1)
    triplane = generate.sample(model, 4)
    surface = colour.planes_colouring(model, query.project(model, triplane).planes, triplane.size)
    matched, learnt = surface.matched, surface.learnt
    band = matched.band
    beside = band + (1, 0, 0)
    seam = np.flatnonzero(np.any(matched(beside) - beside != matched(band) - band, axis=1)
                          & (beside[:, 0] < triplane.size[0]))
    assert len(seam) > 20
    face = band[seam] + (0.5, 0, 0)
    low, high = (surface.relief(face + (d, 0, 0)) - (face + (d, 0, 0)) for d in (-1e-7, 1e-7))
    apart = [colour.relief_moves(model.example_tiles, face + (matched(v) - v), learnt) for v in (band[seam], beside[seam])]
    stepped = np.linalg.norm(apart[0] - apart[1], axis=1)
    gap = np.linalg.norm(low - high, axis=1)
    # Measured: the pieces' own moves 0.16 voxel apart at the 75th percentile, the blended ones 1e-7 (a few
    # faces still step where the tile read itself changes from one voxel to the next: a mean of 0.007
    # against 0.18); without the blend, 0.17 and 0.18.
    assert np.percentile(stepped, 75) > 0.05
    assert np.percentile(gap, 75) < 1e-4 and np.mean(gap) < 0.2 * np.mean(stepped)


def test_relief_and_colour_are_the_same_on_any_number_of_threads(model):
    """SampleSurface reads its points in chunks on the model's threads: each
    point is read alone, so one thread and two, in chunks of any size, give
    the same bits (and a chunk lost or read twice would not)."""
    from sinshape.runtime import mesh as meshing

    triplane = generate.sample(model, 2)
    points = meshing.band_mesh(model, triplane, 2).vertices
    alone = colour.planes_colouring(model, query.project(model, triplane).planes, triplane.size, chunk=len(points))
    moved, painted = alone.relief(points), alone(points, 0.5)
    assert np.abs(moved - points).max() > 0.01  # the relief moves points: the comparison below sees it
    threads = model.threads
    try:
        for model.threads in (1, 2):
            chunked = colour.planes_colouring(model, query.project(model, triplane).planes, triplane.size,
                                              chunk=len(points) // 7 + 1)
            assert np.array_equal(chunked.relief(points), moved)
            assert np.array_equal(chunked(points, 0.5), painted)
    finally:
        model.threads = threads


def test_a_block_whose_match_fell_off_the_band_takes_a_block_near_it_before_the_whole_example():
    """refine: a block matched off the example's band tries the band within LOST_REACH of its match,
    nearest first, and takes the best of them even where a far block fits better (a near piece
    continued); only with none within reach does it search the whole example."""
    size = (20, 4, 4)
    band = np.array([(2, 1, 1), (3, 1, 1), (18, 1, 1)])  # near the match, a step farther, and far away
    values = {(2, 1, 1): 40.0, (3, 1, 1): 10.0, (18, 1, 1): 0.0}

    def reference_at(voxels):
        return np.array([[values.get(tuple(v), 99.0)] for v in voxels], np.float32)

    level = colour.Level(band, reference_at, size, colour.FINEST_PATCH, rounds=0)
    sample = lambda voxels: np.zeros((len(voxels), 1), np.float32)  # noqa: E731  fits the far block exactly
    blocks = np.array([(0, 1, 1), (10, 1, 1)])
    off = np.array([(0, 1, 1), (10, 1, 1)])  # both matched off the band; the second has no band within 3
    matched = level.refine(sample, blocks, off)
    assert matched[0].tolist() == [3, 1, 1]  # of the two in reach (2 and 3 away), the better fit
    assert matched[1].tolist() == [18, 1, 1]  # the whole example's best
