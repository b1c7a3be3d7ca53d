"""Procedural example shapes: closed solids, deterministic, and shaped like their names."""

import numpy as np
import pytest
import trimesh

from sinshape.core.errors import InputError
from sinshape.prep import shapes, textured

# Small versions, each made in well under a second.
SMALL = {"terrain": 32, "painted_terrain": 32, "acropolis": 4, "stairs": 6, "wall": 6, "cheese": 40, "relief_wall": 3}
# The textured ones: quads and charts of their own (not one welded solid), and their texture.
TEXTURED = {"brick_ruin": (4, (768, 1024)), "lichen_rock": (2, (512, 512))}


def test_every_shape_has_a_small_detail():
    assert set(SMALL) | set(TEXTURED) == set(shapes.SHAPES)


@pytest.mark.parametrize("name", TEXTURED)
def test_a_textured_shape_has_its_texture_and_uvs_on_every_vertex(name, tmp_path):
    detail, (height, width) = TEXTURED[name]
    mesh = shapes.make_shape(name, detail=detail)
    image = getattr(mesh.visual.material, "baseColorTexture", None) or mesh.visual.material.image
    assert image.size == (width, height)
    assert mesh.visual.uv.shape == (len(mesh.vertices), 2) and np.isfinite(mesh.visual.uv).all()
    assert np.asarray(image).std(axis=(0, 1)).max() > 10  # a pattern, not one colour
    # Written so that a reader gets its texture back: .glb, and .obj beside its .mtl and .png.
    for suffix in (".glb", ".obj"):
        shapes.write_shape(name, tmp_path / f"shape{suffix}", detail=detail)
    assert (tmp_path / "shape.mtl").is_file() and (tmp_path / "shape.png").is_file()
    loaded = trimesh.load(tmp_path / "shape.obj", process=False)
    assert loaded.visual.material.image.size == (width, height)
    with pytest.raises(InputError, match="textured"):
        shapes.write_shape(name, tmp_path / "shape.ply", detail=detail)


@pytest.mark.parametrize("name", SMALL)
def test_shape_is_a_closed_solid(name):
    mesh = shapes.make_shape(name, detail=SMALL[name])
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.is_volume
    assert mesh.volume > 0


@pytest.mark.parametrize("name", SMALL)
def test_same_seed_gives_the_same_mesh_and_other_seeds_differ(name):
    a, b = (shapes.make_shape(name, seed=3, detail=SMALL[name]) for _ in range(2))
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    other = shapes.make_shape(name, seed=4, detail=SMALL[name])
    assert a.vertices.shape != other.vertices.shape or not np.array_equal(a.vertices, other.vertices)


@pytest.mark.parametrize(
    "name, check",
    [
        ("terrain", lambda x, y, z: z < 0.5 * min(x, y)),  # wide and flat
        ("painted_terrain", lambda x, y, z: z < 0.5 * min(x, y)),
        ("acropolis", lambda x, y, z: x > y and x > z),
        ("stairs", lambda x, y, z: x > y and z > y),  # a narrow flight climbing along x
        ("wall", lambda x, y, z: x > 4 * y and z > y),  # long and thin
        ("cheese", lambda x, y, z: x > y > z),
    ],
)
def test_proportions(name, check):
    extents = shapes.make_shape(name, detail=SMALL[name]).extents
    assert check(*extents), extents
    assert 1 <= extents.max() <= 10


def test_default_details_make_modest_meshes():
    # The relief wall is meshed finer than its joints (0.04 units, a quarter of that a step) so that its
    # relief (0.012) is exact: 310k faces.
    for name in shapes.SHAPES:
        assert len(shapes.make_shape(name).faces) < (400_000 if name == "relief_wall" else 200_000)


def test_terrain_has_relief_on_a_flat_bottom():
    mesh = shapes.make_shape("terrain", detail=SMALL["terrain"])
    down = mesh.face_normals[:, 2] < -0.999
    # The bottom is one flat face as large as the footprint, at the lowest point.
    assert mesh.area_faces[down].sum() == pytest.approx(mesh.extents[0] * mesh.extents[1], rel=1e-3)
    assert np.allclose(mesh.triangles_center[down, 2], mesh.bounds[0, 2])
    up = mesh.face_normals[:, 2] > 0
    assert np.ptp(mesh.triangles_center[up, 2]) > 0.5 * mesh.extents[2]  # ridges and valleys


def test_acropolis_mid_height_slice_cuts_separate_columns():
    mesh = shapes.make_shape("acropolis", detail=SMALL["acropolis"])  # 8 columns, 1 broken or missing
    middle = mesh.bounds.mean(axis=0)
    loops = mesh.section(plane_origin=middle, plane_normal=[0, 0, 1]).discrete
    assert 7 <= len(loops) <= 8
    for loop in loops:
        assert np.ptp(loop[:, :2], axis=0).max() < 0.4  # column-thin, not a wall


def test_stairs_climb_one_even_step_at_a_time():
    detail = SMALL["stairs"]
    mesh = shapes.make_shape("stairs", detail=detail)
    # Upward faces away from the wall and the railing at the sides: the treads.
    centres = mesh.triangles_center
    middle = np.abs(centres[:, 1] - mesh.bounds.mean(axis=0)[1]) < 0.25 * mesh.extents[1]
    x, z = centres[middle & (mesh.face_normals[:, 2] > 0.999)][:, [0, 2]].T
    levels, which = np.unique(np.round(z, 3), return_inverse=True)
    assert len(levels) == detail
    assert np.allclose(np.diff(levels), levels[0])  # even rises from the ground
    assert np.all(np.diff([x[which == k].mean() for k in range(detail)]) > 0)  # each one farther along


def test_wall_top_has_gaps_where_stones_are_missing():
    for seed in range(3):
        mesh = shapes.make_shape("wall", seed=seed, detail=SMALL["wall"])
        x, z = mesh.vertices[:, 0], mesh.vertices[:, 2]
        bins = np.floor((x - x.min()) / 0.05).astype(int)
        top = np.full(bins.max() + 1, -np.inf)
        np.maximum.at(top, bins, z)
        # Weathering and the joints lower the top by < 0.2; a missing stone by a whole row.
        assert top.max() - top.min() > 0.2


def test_cheese_has_holes_but_is_mostly_cheese():
    mesh = shapes.make_shape("cheese", detail=SMALL["cheese"])
    block = np.prod(mesh.extents)
    assert 0.5 * block < mesh.volume < 0.95 * block


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off", ".glb"])
def test_write_shape_round_trips_without_leftovers(tmp_path, suffix):
    path = tmp_path / f"wall{suffix}"
    mesh = shapes.write_shape("wall", path, detail=SMALL["wall"])
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    assert len(trimesh.load(path, force="mesh").faces) == len(mesh.faces)


def test_written_files_are_byte_identical(tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    for path in (a, b):
        shapes.write_shape("cheese", path, seed=1, detail=SMALL["cheese"])
    assert a.read_bytes() == b.read_bytes()


def test_bad_requests_raise_input_error(tmp_path):
    with pytest.raises(InputError, match="terrain, acropolis, stairs, wall, cheese"):
        shapes.make_shape("castle")
    with pytest.raises(InputError, match="detail"):
        shapes.make_shape("wall", detail=1)
    with pytest.raises(InputError, match="seed"):
        shapes.make_shape("wall", seed=-1)
    with pytest.raises(InputError, match=r"\.obj"):
        shapes.write_shape("wall", tmp_path / "wall.blend", detail=SMALL["wall"])
    assert not list(tmp_path.iterdir())


def test_the_relief_walls_bricks_stand_out_of_their_mortar():
    mesh = shapes.make_shape("relief_wall", detail=3)
    rgb = np.asarray(mesh.visual.vertex_colors)[:, :3] / 255
    mortar = np.linalg.norm(rgb - textured.MORTAR, axis=1) < 0.12
    front = mesh.vertex_normals[:, 1] < -0.9  # the face looking -y, its joints recessed
    y = np.asarray(mesh.vertices)[:, 1]
    assert (front & mortar).sum() > 100 and (front & ~mortar).sum() > 100
    np.testing.assert_allclose(np.median(y[front & ~mortar]), 0, atol=0.003)
    np.testing.assert_allclose(np.median(y[front & mortar]), shapes.RELIEF_DEPTH, atol=0.003)
