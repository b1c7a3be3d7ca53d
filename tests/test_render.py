"""The software renderer: silhouettes where they belong, the z-buffer, lighting, the outputs."""

import numpy as np
import pytest
import trimesh
from PIL import Image

from sinshape.runtime import raster, render as R

BACKGROUND = np.round(np.array(R.BACKGROUND) * 255).astype(np.uint8)


def foreground(image):
    """(H, W) bool: pixels that are not plain background."""
    return (image != BACKGROUND).any(axis=-1)


def extent(mask):
    """(width, height) of the bounding box of a mask's true pixels."""
    rows, cols = np.nonzero(mask)
    return cols.max() - cols.min() + 1, rows.max() - rows.min() + 1


def box(extents, centre=(0, 0, 0)):
    return trimesh.creation.box(extents, trimesh.transformations.translation_matrix(centre))


def brute_force(corners, nearness, size):
    """Reference z-buffer: every pixel centre against every triangle."""
    width, height = size
    ys, xs = np.mgrid[0:height, 0:width] + 0.5
    owner = np.full((height, width), -1)
    zbuffer = np.full((height, width), -np.inf)
    for i, ((a, b, c), near) in enumerate(zip(corners, nearness)):
        m = np.array([b - a, c - a]).T
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        u, v = np.linalg.solve(m, np.stack([xs.ravel() - a[0], ys.ravel() - a[1]])).reshape(2, height, width)
        z = near[0] + u * (near[1] - near[0]) + v * (near[2] - near[0])
        wins = (u >= 0) & (v >= 0) & (u + v <= 1) & (z > zbuffer)
        owner[wins], zbuffer[wins] = i, z[wins]
    return owner, zbuffer


def test_sphere_is_a_centred_disc():
    image = R.render(trimesh.creation.icosphere(subdivisions=3), size=(64, 48))
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    mask = foreground(image)
    assert not mask[[0, 0, -1, -1], [0, -1, 0, -1]].any()  # corners are background
    rows, cols = np.nonzero(mask)
    assert abs(rows.mean() - 23.5) < 1 and abs(cols.mean() - 31.5) < 1
    width, height = extent(mask)
    assert abs(width - height) <= 1
    assert abs(height - 48 * (1 - 2 * R.MARGIN)) <= 2  # framed: fills the height less the margin
    assert abs(mask.sum() / (width * height) - np.pi / 4) < 0.05  # a disc, not a square


@pytest.mark.parametrize("extents, up, azimuth, wide", [
    ((4, 1, 1), "y", 0, True),
    ((1, 4, 1), "y", 0, False),
    ((1, 1, 4), "y", 90, True),  # seen from +x, z runs across the picture
    ((1, 1, 4), "z", 90, False),  # ... unless z is up
])
def test_long_box_lies_along_its_axis(extents, up, azimuth, wide):
    width, height = extent(foreground(R.render(box(extents), (60, 60), azimuth, 0, up=up)))
    assert (width > 3 * height) if wide else (height > 3 * width)


def test_picture_is_not_mirrored_or_upside_down():
    # Seen from the front, +x is on the right and up is up: a big box at -x,
    # a small one at +x, and a cone whose tip points up.
    boxes = trimesh.util.concatenate([box((2, 2, 2), (-3, 0, 0)), box((1, 1, 1), (3, 0, 0))])
    mask = foreground(R.render(boxes, (80, 40), 0, 0, up="y"))
    assert mask[:, :40].sum() > 2 * mask[:, 40:].sum()
    cone = trimesh.creation.cone(radius=1, height=2)  # tip at +z
    mask = foreground(R.render(cone, (40, 40), 0, 0, up="z"))
    assert mask[:20].sum() < 0.6 * mask[20:].sum()


def test_camera_axes_are_a_right_handed_frame_turning_towards_x():
    for up in ("y", "z"):
        for azimuth, elevation in [(0, 0), (35, 25), (200, -60), (10, 90)]:
            axes = R.camera_axes(azimuth, elevation, up)
            assert np.allclose(axes @ axes.T, np.eye(3))
            assert np.allclose(np.cross(axes[0], axes[1]), axes[2])
        assert np.allclose(R.camera_axes(90, 0, up)[2], [1, 0, 0])  # the eye moved to +x
        assert np.allclose(R.camera_axes(0, 90, up)[2], R.FRAMES[up]["up"])  # ... and above
    assert np.allclose(R.camera_axes(0, 0, "y")[2], [0, 0, 1])
    assert np.allclose(R.camera_axes(0, 0, "z")[2], [0, -1, 0])


def test_perspective_shrinks_the_far_end_and_orthographic_does_not():
    rod = box((1, 1, 6))  # seen from the side, its ends are at different depths

    def end_heights(projection):
        mask = foreground(R.render(rod, (120, 60), 60, 0, projection=projection, outline=False))
        cols = np.flatnonzero(mask.any(axis=0))
        return mask[:, cols[2]].sum(), mask[:, cols[-3]].sum()

    left, right = end_heights("orthographic")
    assert abs(left - right) <= 1
    left, right = end_heights("perspective")
    assert max(left, right) > 1.15 * min(left, right)


@pytest.mark.parametrize("near_first", [False, True])
def test_nearer_box_hides_the_farther_one(near_first):
    near, far = box((1, 1, 1), (0, 0, 2)), box((3, 3, 1), (0, 0, -2))  # the eye is at +z
    parts = [near, far] if near_first else [far, near]
    camera = R.camera_triangles(trimesh.util.concatenate(parts), 0, 0, "y")
    owner, _ = raster.rasterise(*R.project(camera, (40, 40), "perspective"), (40, 40))
    near_faces = range(0, 12) if near_first else range(12, 24)
    assert owner[20, 20] in near_faces  # both cover the centre
    assert owner[4, 20] not in near_faces and owner[4, 20] >= 0  # only the far box reaches up there


def test_rasterise_matches_brute_force():
    rng = np.random.default_rng(3)
    corners = rng.uniform([-4, -4], [28, 20], size=(30, 3, 2))  # some faces run off the picture
    corners[0, 2] = corners[0, 0] + 2 * (corners[0, 1] - corners[0, 0])  # a degenerate one
    corners[1] = [[5.2, 5.3], [5.9, 5.6], [5.4, 6.0]]  # a tiny one
    nearness = rng.uniform(0, 1, size=(30, 3))
    owner, zbuffer = raster.rasterise(corners, nearness, (24, 16))
    expected_owner, expected_z = brute_force(corners, nearness, (24, 16))
    assert (owner == expected_owner).all()
    assert np.allclose(zbuffer, expected_z)


def test_side_facing_the_light_is_brighter():
    grey = R.render(trimesh.creation.icosphere(subdivisions=4), (64, 64), outline=False).mean(axis=-1)
    # LIGHTS' key light comes from the upper left, whatever the view.
    assert grey[12:32, 12:32].mean() > grey[32:52, 32:52].mean() + 40


def test_winding_does_not_change_the_picture():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    flipped = trimesh.Trimesh(sphere.vertices, sphere.faces[:, ::-1], process=False)
    half = sphere.faces.copy()
    half[::2] = half[::2, ::-1]
    mixed = trimesh.Trimesh(sphere.vertices, half, process=False)
    image = R.render(sphere, (48, 48))
    assert (R.render(flipped, (48, 48)) == image).all()
    assert (R.render(mixed, (48, 48)) == image).all()


def test_outline_darkens_only_the_silhouette():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    plain, outlined = R.render(sphere, (48, 48), outline=False), R.render(sphere, (48, 48))
    changed = (plain != outlined).any(axis=-1)
    assert changed.sum() > 48 and outlined.min() < plain.min()
    # Every changed pixel lies within 2 pixels of the background.
    near_background = ~foreground(plain)
    for _ in range(2):
        near_background[1:] |= near_background[:-1].copy()
        near_background[:-1] |= near_background[1:].copy()
        near_background[:, 1:] |= near_background[:, :-1].copy()
        near_background[:, :-1] |= near_background[:, 1:].copy()
    assert not (changed & ~near_background).any()


def test_render_views_puts_views_side_by_side():
    mesh = box((2, 1, 0.5))
    strip = R.render_views(mesh, size=(100, 80))
    assert strip.shape == (80, 400, 3)
    assert (strip[:, 100:200] == R.render(mesh, (100, 80), 125, 25)).all()


def test_render_grid_layout_and_labels():
    meshes = [box((1, 1, 1)), trimesh.creation.icosphere(subdivisions=2)] * 2 + [box((2, 1, 1))]
    strip = R.label_height((40, 30))
    labelled = R.render_grid(meshes, ["one", "two", "three", "four", "five"], columns=3, size=(40, 30))
    unlabelled = R.render_grid(meshes, [""] * 5, columns=3, size=(40, 30))
    assert labelled.shape == (2 * (30 + strip), 120, 3)
    in_strips = np.zeros(labelled.shape[:2], bool)
    in_strips[30:30 + strip] = in_strips[60 + strip:] = True
    differs = (labelled != unlabelled).any(axis=-1)
    assert differs.sum() > 20 and not (differs & ~in_strips).any()
    assert (unlabelled[30 + strip:, 80:] == BACKGROUND).all()  # the sixth cell is empty
    assert (labelled[30 + strip:60 + strip, 40:80] == R.render(meshes[4], (40, 30))).all()


def test_render_grid_wants_a_label_per_mesh():
    with pytest.raises(ValueError, match="labels"):
        R.render_grid([box((1, 1, 1))], ["a", "b"], columns=1)


def test_save_png_round_trip(tmp_path):
    image = R.render(box((1, 2, 3)), (50, 30))
    R.save_png(image, tmp_path / "box.png")
    with Image.open(tmp_path / "box.png") as png:
        assert png.format == "PNG" and png.size == (50, 30)
        assert (np.asarray(png) == image).all()
    assert [p.name for p in tmp_path.iterdir()] == ["box.png"]


def test_save_png_failing_midway_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "box.png"
    path.write_bytes(b"old")

    def half_save(self, fp, *args, **kwargs):
        fp.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", half_save)
    with pytest.raises(ValueError, match="cannot write"):
        R.save_png(np.zeros((4, 4, 3), np.uint8), path)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["box.png"]


def test_a_close_up_cuts_faces_at_the_box_and_paints_them_as_before():
    """A cube's top face in a box a quarter of its area: only that quarter
    is kept (whole faces kept by their centres would keep all of it, a
    sawtooth a face deep where faces are small), with no point outside the
    box, and each point of a cut face is painted as the same point of the
    face it came from."""
    cube = box((1, 1, 1))
    cube.metadata[R.PAINT] = lambda face, w: np.einsum("nc,ncx->nx", w, cube.triangles[face])
    part = R.crop(cube, 2, focus=(0.5, 0.5, 1.0))  # x, y in [-0.25, 0.25], z in [0.25, 0.75]
    assert part.area == pytest.approx(0.25)
    assert np.all(np.abs(part.vertices[:, :2]) <= 0.25 + 1e-12) and np.allclose(part.vertices[:, 2], 0.5)
    w = np.random.default_rng(0).dirichlet((1, 1, 1), size=len(part.faces))
    points = np.einsum("nc,ncx->nx", w, part.triangles)
    assert np.allclose(part.metadata[R.PAINT](np.arange(len(part.faces)), w), points)
    coloured = box((1, 1, 1))  # vertex colours follow the cut too: red rising with x
    coloured.visual.vertex_colors = np.column_stack([np.round((coloured.vertices[:, 0] + 0.5) * 200),
                                                     np.zeros((8, 2)), np.full(8, 255)]).astype(np.uint8)
    part = R.crop(coloured, 2, focus=(0.5, 0.5, 1.0))
    assert np.allclose(part.visual.vertex_colors[:, 0], np.round((part.vertices[:, 0] + 0.5) * 200), atol=1)


def test_empty_mesh_is_refused():
    with pytest.raises(ValueError, match="empty mesh"):
        R.render(trimesh.Trimesh())


@pytest.mark.parametrize("options", [{"up": "x"}, {"projection": "fisheye"}, {"size": (0, 10)}])
def test_bad_options_are_refused(options):
    with pytest.raises(ValueError):
        R.render(box((1, 1, 1)), **options)
