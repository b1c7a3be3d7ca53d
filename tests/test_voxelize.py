"""Tests of `sinshape.prep.voxelize`.

Synthetic meshes are checked against exact oracles (plane equations of convex
bodies, an analytic torus, exact voxel sets of a plane and a thin slab); the
procedural example shapes and a real mesh (towerruins, in tests/data: not
watertight, many bodies) against the generalized winding number, an
independent and hole-tolerant inside test. Grids use slightly different spacings per axis and
an origin off any round number, so that nothing lines up by luck.
"""

import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy import ndimage
from skimage import measure

from sinshape.core.errors import InputError
from sinshape.prep import shapes
from sinshape.prep.voxelize import _add_crossings, _split_to_size, load_mesh, voxelize

TOWERRUINS = Path(__file__).parent / "data" / "towerruins" / "towerruins.obj"
# Small versions of the procedural shapes: thin walls, columns, steps. (Not
# cheese: its enclosed bubbles are filled by design, see voxelize.)
SHAPE_DETAIL = {"terrain": 48, "acropolis": 4, "stairs": 8, "wall": 6}


def example_mesh(name: str) -> trimesh.Trimesh:
    """A procedural shape by name, or the real mesh "towerruins"."""
    return load_mesh(TOWERRUINS) if name == "towerruins" else shapes.make_shape(name, detail=SHAPE_DETAIL[name])


def _grid(low, high, res, pad=2):
    """Grid over the box [low, high] with `res` voxels along its longest side
    and `pad` empty voxels around it."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    spacing = (high - low).max() / res * np.array([1.0, 1.0 + 1 / 37, 1.0 - 1 / 53])
    shift = np.array([0.31, 0.17, 0.43])
    origin = low - (pad + shift) * spacing
    shape = np.ceil((high - low) / spacing + shift).astype(int) + 2 * pad
    return origin, spacing, shape


def _centres(origin, spacing, shape):
    """(X, Y, Z, 3) voxel centres."""
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1)
    return origin + (index + 0.5) * spacing


def _half_diagonal(spacing):
    return 0.5 * np.linalg.norm(spacing)


def _plane_excess(mesh, points):
    """Largest signed distance of `points` (..., 3) to the face planes of the
    convex, outward-facing `mesh`: < 0 exactly inside; outside, a lower bound
    on the distance to the mesh."""
    normals = mesh.face_normals
    offsets = np.einsum("ij,ij->i", normals, mesh.triangles[:, 0])
    flat = points.reshape(-1, 3)
    excess = np.full(len(flat), -np.inf)
    for first in range(0, len(normals), 64):
        part = flat @ normals[first:first + 64].T - offsets[first:first + 64]
        excess = np.maximum(excess, part.max(axis=1))
    return excess.reshape(points.shape[:-1])


def _assert_surface_solid(mesh, solid, origin, spacing):
    """Every voxel holding a point sampled on the surface is solid."""
    points, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    index = np.floor((points - origin) / spacing).astype(int)
    assert solid[tuple(index.T)].all()


def _assert_matches(solid, inside, far_outside):
    """Solid at every `inside` centre, empty at every `far_outside` centre."""
    assert inside.sum() > 50 and far_outside.sum() > 50  # the check is not vacuous
    assert solid[inside].all(), f"{np.sum(inside & ~solid)} inside voxels are empty"
    assert not solid[far_outside].any(), f"{np.sum(far_outside & solid)} outside voxels are solid"


def _check_convex_union(bodies, mesh, res=24):
    """Voxelize `mesh` (which covers the union of the convex `bodies`) and check
    it against the bodies' plane equations and against surface samples."""
    origin, spacing, shape = _grid(*mesh.bounds, res)
    solid = voxelize(mesh, origin, spacing, shape)
    assert solid.shape == tuple(shape) and solid.dtype == bool
    centres = _centres(origin, spacing, shape)
    excess = np.min([_plane_excess(body, centres) for body in bodies], axis=0)
    _assert_matches(solid, excess < 0, excess > _half_diagonal(spacing))
    _assert_surface_solid(mesh, solid, origin, spacing)
    return solid, centres


def _rotated(mesh):
    """`mesh` turned off the grid axes."""
    return mesh.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.5, 0.7))


@pytest.mark.parametrize(
    "make",
    [
        lambda: trimesh.creation.icosphere(subdivisions=2, radius=1.0),
        lambda: trimesh.creation.box(extents=(1.0, 0.7, 0.45)),
        lambda: _rotated(trimesh.creation.box(extents=(1.0, 0.7, 0.45))),
        lambda: _rotated(trimesh.creation.capsule(height=1.0, radius=0.35)),
    ],
    ids=["sphere", "box", "rotated-box", "rotated-capsule"],
)
def test_convex_solid_matches_plane_equations(make):
    mesh = make()
    assert mesh.is_watertight and mesh.volume > 0
    _check_convex_union([mesh], mesh)


def test_watertight_volume_is_bracketed():
    # Every voxel that meets a closed solid is solid (its centre is inside,
    # or the surface passes between the centre and an inside point), and
    # every solid voxel meets the solid. So the voxels hold the solid and lie
    # within it grown by one voxel diagonal: for a capsule inscribed in the
    # ideal one, the ideal capsule with its radius grown by that much.
    height, radius = 1.0, 0.35
    mesh = _rotated(trimesh.creation.capsule(height=height, radius=radius))
    origin, spacing, shape = _grid(*mesh.bounds, 20)
    voxel_volume = voxelize(mesh, origin, spacing, shape).sum() * np.prod(spacing)
    grown = radius + np.linalg.norm(spacing)
    assert mesh.volume <= voxel_volume <= np.pi * grown**2 * height + 4 / 3 * np.pi * grown**3


def test_torus_keeps_its_hole():
    major, minor = 1.0, 0.35
    mesh = trimesh.creation.torus(major, minor, major_sections=48, minor_sections=24)
    origin, spacing, shape = _grid(*mesh.bounds, 32)
    solid = voxelize(mesh, origin, spacing, shape)

    def distance(p):  # signed distance to the ideal torus
        return np.hypot(np.hypot(p[..., 0], p[..., 1]) - major, p[..., 2]) - minor

    # The faces are chords of the ideal torus: measure how far they stray.
    stray = 1.5 * np.abs(distance(trimesh.sample.sample_surface(mesh, 20000, seed=1)[0])).max()
    d = distance(_centres(origin, spacing, shape))
    _assert_matches(solid, d < -stray, d > stray + _half_diagonal(spacing))
    _assert_surface_solid(mesh, solid, origin, spacing)
    # The hole through the middle is empty (centre column of the grid).
    centre = np.floor((0.0 - origin) / spacing).astype(int)
    assert not solid[centre[0], centre[1], :].any()


def test_sphere_with_holes_is_still_solid_between_them():
    # Caps cut off at both poles: the rays along z through the holes see no
    # crossing at all, yet the 4 votes along x and y keep the middle solid.
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    rim = 0.6
    keep = np.abs(sphere.triangles_center[:, 2]) < rim
    holed = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    assert not holed.is_watertight
    origin, spacing, shape = _grid(*sphere.bounds, 24)
    solid = voxelize(holed, origin, spacing, shape)
    centres = _centres(origin, spacing, shape)
    excess = _plane_excess(sphere, centres)
    # Inside the caps nothing is known: their surface is gone.
    between = np.abs(centres[..., 2]) < rim - spacing[2]
    _assert_matches(solid, (excess < 0) & between, excess > _half_diagonal(spacing))
    _assert_surface_solid(holed, solid, origin, spacing)


def test_sphere_with_flipped_normals_is_solid():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    flipped = sphere.copy()
    flipped.invert()
    assert flipped.volume < 0
    _check_convex_union([sphere], flipped)


@pytest.mark.parametrize("flip_second", [False, True], ids=["both-outward", "second-flipped"])
def test_overlapping_spheres_are_solid_where_they_overlap(flip_second):
    first = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    second = first.copy().apply_translation([0.8, 0.3, 0.0])
    if flip_second:
        second.invert()
    # A triangle soup (no shared vertices), like an OBJ split at UV seams.
    triangles = np.concatenate([first.triangles, second.triangles])
    soup = trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(len(triangles) * 3).reshape(-1, 3),
                           process=False)
    outward = [first, first.copy().apply_translation([0.8, 0.3, 0.0])]
    solid, centres = _check_convex_union(outward, soup)
    # The lens where the bodies overlap has winding number 2 (or 0 if one of
    # them were left flipped): it must be solid.
    lens = np.max([_plane_excess(body, centres) for body in outward], axis=0) < 0
    assert lens.sum() > 50 and solid[lens].all()


def test_plane_gives_exactly_the_voxels_it_passes_through():
    # A triangle much larger than the grid, in the plane n . x = c: a voxel is
    # touched when its corners lie on both sides. This includes voxels only
    # clipped at a corner, which point sampling would miss. A single sheet
    # has no inside, so the result is exactly that set.
    origin, spacing, shape = _grid([0, 0, 0], [1.0, 0.9, 0.8], 10, pad=0)
    normal = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    centre = origin + 0.5 * shape * spacing
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    angles = np.radians([0.0, 120.0, 240.0])
    corners = centre + 3.0 * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * w)
    triangle = trimesh.Trimesh(corners, [[0, 1, 2]], process=False)
    solid = voxelize(triangle, origin, spacing, shape)

    lower = _centres(origin, spacing, shape) - 0.5 * spacing
    offsets = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(-1, 3)
    side = np.stack([(lower + o * spacing - centre) @ normal for o in offsets], axis=-1)
    expected = (side.min(axis=-1) < 0) & (side.max(axis=-1) > 0)
    assert 0 < expected.sum() < expected.size
    np.testing.assert_array_equal(solid, expected)


def test_wall_thinner_than_a_voxel_is_one_voxel_thick():
    origin, spacing, shape = np.array([-0.05, 0.02, 0.0]), np.array([0.1, 0.11, 0.09]), (12, 10, 8)
    low, high = np.array([0.12, 0.23, 0.37]), np.array([0.93, 0.81, 0.39])  # 0.02 thick in z
    wall = trimesh.creation.box(bounds=[low, high])
    solid = voxelize(wall, origin, spacing, shape)
    # Voxel i covers [i, i + 1) * spacing from the origin.
    first = np.floor((low - origin) / spacing).astype(int)
    last = np.floor((high - origin) / spacing).astype(int)
    expected = np.zeros(shape, dtype=bool)
    expected[first[0]:last[0] + 1, first[1]:last[1] + 1, first[2]:last[2] + 1] = True
    assert first[2] == last[2]
    np.testing.assert_array_equal(solid, expected)


def test_marching_cubes_mesh_on_its_own_grid():
    # The project voxelizes meshes extracted from its own grids: their
    # vertices lie exactly on the lines through the voxel centres, which the
    # rays follow. Sample values give the truth: a negative sample is inside,
    # a voxel whose 27 neighbourhood samples are all positive meets no face.
    n, h, low = 24, 0.1, -1.2
    c = low + (np.arange(n) + 0.5) * h
    x, y, z = np.meshgrid(c, c, c, indexing="ij")
    sdf = np.minimum(np.sqrt(x**2 + y**2 + z**2) - 0.7,
                     np.sqrt((x - 0.45) ** 2 + (y - 0.3) ** 2 + z**2) - 0.5)
    vertices, faces, _, _ = measure.marching_cubes(sdf, 0.0, spacing=(h, h, h))
    mesh = trimesh.Trimesh(vertices + c[0], faces)
    assert mesh.is_watertight
    origin, spacing, shape = np.full(3, low), np.full(3, h), (n, n, n)
    solid = voxelize(mesh, origin, spacing, shape)
    far = ndimage.minimum_filter(sdf, size=3, mode="nearest") > 0
    _assert_matches(solid, sdf < 0, far)

    # White-box: every ray enters a closed mesh as often as it leaves, so its
    # signed crossings sum to zero. A ray through a vertex exactly would count
    # it once per face around it; the 6-vote majority hides such single-ray
    # errors in the result above, hence the look inside.
    pieces = _split_to_size((mesh.triangles - origin) / spacing)
    vert = np.ascontiguousarray(pieces.transpose(1, 2, 0))
    for axis in range(3):
        totals = np.zeros([1 if k == axis else n for k in range(3)], dtype=np.int16)
        _add_crossings(vert, axis, np.zeros(shape, dtype=np.int16), totals)
        assert not totals.any()


def test_voxelize_rejects_a_bad_grid():
    mesh = trimesh.creation.box()
    with pytest.raises(ValueError):
        voxelize(mesh, [0, 0, 0], [0.1, 0.0, 0.1], [4, 4, 4])
    with pytest.raises(ValueError):
        voxelize(mesh, [0, 0, 0], [0.1, 0.1, 0.1], [4, 0, 4])


def _winding_numbers(mesh, points):
    """Generalized winding number (Jacobson et al. 2013) of `mesh` at
    `points` (n, 3): the summed solid angle of the faces over 4 pi. It is 1
    inside and 0 outside a closed surface and degrades smoothly near holes."""
    corners = np.ascontiguousarray(mesh.triangles.transpose(1, 2, 0))  # (vertex, xyz, face)
    numbers = np.empty(len(points))
    for i, p in enumerate(points):
        a, b, c = corners - p[:, None]
        la, lb, lc = (np.sqrt((v * v).sum(axis=0)) for v in (a, b, c))
        det = (a * np.cross(b, c, axis=0)).sum(axis=0)
        dots = (a * b).sum(axis=0) * lc + (b * c).sum(axis=0) * la + (c * a).sum(axis=0) * lb
        numbers[i] = np.arctan2(det, la * lb * lc + dots).sum() / (2 * np.pi)
    return numbers


def _distance_lower_bound(mesh, points):
    """(n,) lower bound on the distance of `points` to the mesh: the distance
    to the nearest bounding sphere of a face."""
    centre = mesh.triangles.mean(axis=1)
    radius = np.linalg.norm(mesh.triangles - centre[:, None], axis=2).max(axis=1)
    centre = np.ascontiguousarray(centre.T)
    return np.array([(np.linalg.norm(centre - p[:, None], axis=0) - radius).min() for p in points])


@pytest.mark.parametrize("name", [*SHAPE_DETAIL, "towerruins"])
def test_example_mesh_is_a_plausible_solid(name):
    mesh = example_mesh(name)
    origin, spacing, shape = _grid(*mesh.bounds, 40)
    solid = voxelize(mesh, origin, spacing, shape)

    # No fill leaks out along the rays: the padding around the mesh is empty.
    border = np.ones(shape, dtype=bool)
    border[1:-1, 1:-1, 1:-1] = False
    assert not solid[border].any()

    # Random voxel centres in the mesh's box against the generalized winding
    # number: solid where clearly inside, empty where clearly outside.
    rng = np.random.default_rng(0)
    points = mesh.bounds[0] + rng.random((120, 3)) * mesh.extents
    index = np.floor((points - origin) / spacing).astype(int)
    centres = origin + (index + 0.5) * spacing
    number = _winding_numbers(mesh, centres)
    far = _distance_lower_bound(mesh, centres) > _half_diagonal(spacing)
    hit = solid[tuple(index.T)]
    inside, outside = number > 0.75, (number < 0.25) & far
    assert inside.sum() >= 10 and outside.sum() >= 10
    assert hit[inside].all() and not hit[outside].any()

    # Not a hollow shell: at most a few empty voxels are enclosed by solid
    # ones (gaps between touching bodies of towerruins at finer grids).
    enclosed = ndimage.binary_fill_holes(solid) & ~solid
    assert enclosed.sum() <= 0.01 * solid.sum()


def test_watertight_concave_mesh_volume_is_bracketed():
    mesh = example_mesh("stairs")  # steps, a wall and a railing, closed by construction
    assert mesh.is_watertight
    origin, spacing, shape = _grid(*mesh.bounds, 40)
    voxel_volume = voxelize(mesh, origin, spacing, shape).sum() * np.prod(spacing)
    # As for the capsule; the solid grown by a voxel diagonal has no closed
    # form here, so take its first-order volume. That is loose (surface
    # voxels stick out by about half a diagonal on average), not tight.
    assert mesh.volume <= voxel_volume <= mesh.volume + mesh.area * np.linalg.norm(spacing)


def test_load_mesh_concatenates_a_scene_with_its_transforms(tmp_path):
    scene = trimesh.Scene()
    box = trimesh.creation.box()
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix([5, 0, 0]))
    scene.add_geometry(box)
    path = tmp_path / "two boxes.glb"
    scene.export(path)
    mesh = load_mesh(path)
    assert isinstance(mesh, trimesh.Trimesh) and len(mesh.faces) == 24
    np.testing.assert_allclose(mesh.bounds, [[-0.5, -0.5, -0.5], [5.5, 0.5, 0.5]])


def test_load_mesh_reads_obj_with_a_missing_material_file():
    assert "mtllib model.mtl" in TOWERRUINS.read_text()[:200]
    assert not (TOWERRUINS.parent / "model.mtl").exists()
    mesh = load_mesh(str(TOWERRUINS))
    assert len(mesh.faces) == 23952


def test_load_mesh_accepts_a_thin_solid(tmp_path):
    path = tmp_path / "thin.stl"
    trimesh.creation.box(extents=(1.0, 1.0, 0.01)).export(path)
    assert len(load_mesh(path).faces) == 12


def _write_text(text):
    return lambda path: path.write_text(text)


def _export(mesh):
    return lambda path: mesh.export(path)


BAD_FILES = [  # (file name, how to write it or None, part of the message)
    ("absent.obj", None, "is missing"),
    ("shape.abc", _write_text("v 0 0 0\n"), ".obj"),
    ("empty.obj", _write_text(""), "empty file"),
    ("points.obj", _write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"), "no triangles"),
    ("cloud.ply", _export(trimesh.PointCloud(np.random.default_rng(0).random((20, 3)))),
     "no triangles"),
    ("broken.ply", lambda path: path.write_bytes(b"\x00\x01 not a ply\n" * 8), "cannot read"),
    ("triangle.obj", _write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), "flat"),
    ("square.stl", _export(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                                           [[0, 1, 2], [0, 2, 3]])), "flat"),
    ("sheet.off", _export(trimesh.creation.box(extents=(1.0, 1.0, 1e-4))), "flat"),
    # Not along an axis: a tilted triangle, a tilted thin sheet, points on a diagonal.
    ("tilted.obj", _write_text("v 0 0 0\nv 1 1 0\nv 0 1 1\nf 1 2 3\n"), "lie in a plane"),
    ("tilted-sheet.stl", _export(trimesh.creation.box(extents=(1.0, 1.0, 1e-4)).apply_transform(
        trimesh.transformations.rotation_matrix(0.7, [1, 2, 3]))), "lie in a plane"),
    ("diagonal.obj", _write_text("v 0 0 0\nv 1 1 1\nv 2 2 2\nv 3 3 3\nf 1 2 3\nf 1 3 4\n"), "on a line"),
    ("point.obj", _write_text("v 1 2 3\nv 1 2 3\nv 1 2 3\nf 1 2 3\n"), "coincide"),
    # NaN or infinite coordinates: trimesh would drop their faces (a cube trains as a wedge).
    ("nan.obj", lambda path: path.write_text(_cube_obj().replace("v -0.5 -0.5 -0.5", "v nan -0.5 -0.5")),
     "NaN or infinite"),
    ("inf.obj", lambda path: path.write_text(_cube_obj().replace("v -0.5 -0.5 -0.5", "v -inf -0.5 -0.5")),
     "NaN or infinite"),
    # Binary garbage is named as such, not as a missing optional module.
    ("garbage.obj", lambda path: path.write_bytes(bytes(range(256)) * 4), "binary data, not .obj text"),
    ("garbage.stl", lambda path: path.write_bytes(bytes(range(256)) * 4), "neither binary STL"),
    ("garbage.off", lambda path: path.write_bytes(b"OFF\n" + bytes(range(256))), "binary data"),
    # Numbers past what the checks can square (a LinAlgError once), faces without area, far strays.
    ("huge.obj", lambda path: path.write_text(_cube_obj().replace("v -0.5 -0.5 -0.5", "v -1e300 -0.5 -0.5")),
     "coordinates beyond"),
    ("no-area.obj", _write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 0 2 0\nv 0 0 1\nf 1 2 3\nf 1 4 5\nf 1 1 6\n"),
     "zero area"),
    ("stray.obj", _export(trimesh.util.concatenate([trimesh.creation.icosphere(3), trimesh.creation.icosphere(
        1, radius=0.01).apply_translation([1e6, 0, 0])])), "lie far from the rest"),
]


def _cube_obj() -> str:
    """A unit cube as OBJ text, its first vertex written `v -0.5 -0.5 -0.5`."""
    box = trimesh.creation.box()
    return ("".join(f"v {' '.join(f'{c:g}' for c in v)}\n" for v in box.vertices)
            + "".join(f"f {' '.join(str(i + 1) for i in f)}\n" for f in box.faces))


@pytest.mark.parametrize("name, write, says", BAD_FILES, ids=[case[0] for case in BAD_FILES])
def test_load_mesh_errors_are_one_line_naming_the_file(tmp_path, name, write, says):
    path = tmp_path / name
    if write is not None:
        write(path)
    with pytest.raises(InputError) as error, warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning lines before the error
        load_mesh(path)
    message = str(error.value)
    assert "\n" not in message and name in message and says in message


def test_an_obj_with_a_latin_1_comment_loads(tmp_path):
    """A byte that is not UTF-8 in a comment does not matter to the geometry."""
    path = tmp_path / "cube.obj"
    path.write_bytes("# made by caf\u00e9 software\n".encode("latin-1") + _cube_obj().encode())
    np.testing.assert_allclose(load_mesh(path).bounds, [[-0.5] * 3, [0.5] * 3])


def test_a_flat_mesh_loads_when_no_solid_is_needed(tmp_path):
    """`sinrun render` draws a flat mesh that voxelizing refuses."""
    path = tmp_path / "square.stl"
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]]).export(path)
    assert len(load_mesh(path, solid=False).faces) == 2
    with pytest.raises(InputError, match="flat"):
        load_mesh(path)


def test_memory_that_grows_with_big_faces_is_refused_up_front():
    """A million copies of one grid-wide triangle: about 10**9 pieces once cut
    to voxel size (the kernel killed this at 7 GB for 40 000 faces)."""
    from sinshape.prep.voxelize import voxelize

    triangle = np.array([[[0.0, 0.0, 0.0], [16.0, 0.0, 0.0], [0.0, 16.0, 16.0]]])
    mesh = trimesh.Trimesh(vertices=np.repeat(triangle, 10**6, axis=0).reshape(-1, 3),
                           faces=np.arange(3 * 10**6).reshape(-1, 3), process=False)
    with pytest.raises(InputError, match="voxelising 1000000 faces on a 16x16x16 grid needs about"):
        voxelize(mesh, (0, 0, 0), (1, 1, 1), (16, 16, 16))
