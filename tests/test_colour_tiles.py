"""Colour by correspondence: the example's colour tiles keep detail finer
than a voxel, a sample's voxels are matched to the example's the same way
wherever they lie, the reconstruction matches itself, and a model's tiles
are checked when it loads."""

import numpy as np
import pytest
import trimesh
from PIL import Image

from sinshape.core.errors import InputError
from sinshape.prep import appearance, colour as example_colour, voxelize
from sinshape.runtime import colour, generate, load_model, world, world_tiles

STRIPES = ((230, 200, 40), (40, 60, 160))  # sRGB


def striped_box(tmp_path, texels: int = 128):
    """A 2 x 1 x 1 box whose texture has stripes two texels wide across x:
    at res 16 (voxels of 0.125), two whole stripe periods in every voxel."""
    mesh = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    for _ in range(3):
        mesh = mesh.subdivide()
    column = (np.arange(texels) // 2) % 2
    image = np.array(STRIPES, np.uint8)[column][None].repeat(8, axis=0)  # 8 rows, stripes along u
    u = (mesh.vertices[:, 0] + 1.0) / 2.0
    v = 0.5 + 0.1 * mesh.vertices[:, 2]
    visual = trimesh.visual.TextureVisuals(uv=np.stack([u, v], axis=1), material=trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(image)))
    path = tmp_path / "striped.glb"
    path.write_bytes(trimesh.Trimesh(mesh.vertices, mesh.faces, visual=visual, process=False).export(file_type="glb"))
    return path


def grid_of(path, res: int = 16):
    """The finest level a model of `res` would have: (scene, box_low,
    spacing, the level's solid voxels (X, Y, Z) bool)."""
    scene, _ = voxelize.read_scene(path)
    mesh = voxelize.scene_mesh(scene, path)
    low, high = mesh.bounds
    voxel = (high - low).max() / res
    shape = tuple(int(np.ceil(e / voxel - 1e-6)) for e in high - low)
    box = np.array(shape) * voxel
    box_low, spacing = (low + high) / 2 - box / 2, box / np.array(shape)
    return scene, box_low, spacing, voxelize.voxelize(mesh, box_low, spacing, shape)


def surface_points(path, count: int = 20000):
    """Points on the example's surface and their true colour there."""
    scene, _ = voxelize.read_scene(path)
    surface = appearance.coloured_surface(scene, path)
    face, weights = example_colour.sample_faces(surface.triangles, count / 10, np.random.default_rng(1))
    return np.einsum("nk,nkc->nc", weights, surface.triangles[face]), surface.colour(face, weights)


def psnr(a, b) -> float:
    return float(10 * np.log10(1 / np.mean((a - b) ** 2)))


def test_tiles_keep_stripes_finer_than_a_voxel(tmp_path):
    path = striped_box(tmp_path)
    scene, box_low, spacing, solid = grid_of(path)
    shape = solid.shape
    surface = appearance.coloured_surface(scene, path)
    tiles = appearance.example_tiles(surface, box_low, spacing, solid)
    assert tiles.images.shape[1] >= 8  # the texture's 8 texels a voxel, kept
    read = colour.Tiles.of(tiles.voxels, tiles.directions, tiles.images, tiles.distance)
    points, truth = surface_points(path)
    model_points = (points - box_low) / spacing - 0.5
    found = colour.read_colours(read, lambda voxels: voxels, model_points, shape)
    assert psnr(found, truth) > 28
    # The colour field the decoder's head is trained on, one colour a voxel,
    # cannot hold them: the tiles' detail is not the voxel grid's.
    field = example_colour.surface_colour(scene, path, b"", float(spacing.min()))
    rgb, _ = example_colour.colour_grid(field, box_low, spacing, shape)
    voxel = np.clip(np.floor(model_points + 0.5).astype(int), 0, np.array(shape) - 1)
    assert psnr(rgb[:, voxel[:, 0], voxel[:, 1], voxel[:, 2]].T, truth) < 15
    # Both stripes inside one voxel, a stripe's colour exactly (no blend).
    front = np.flatnonzero(np.isclose(points[:, 1], points[:, 1].min()))
    inside = front[np.all(voxel[front] == voxel[front[0]], axis=1)]
    near = np.abs(found[inside] * 255 - np.array(STRIPES)[:, None]).max(axis=2) <= 2
    assert near[0].any() and near[1].any()


def test_faces_that_no_texels_ray_meets_make_tiles_too(tmp_path):
    # A thin plate's edges are strips narrower than a texel: no ray along x or y through a texel
    # meets them (all miss), and the tiles are made from the faces that are met.
    path = tmp_path / "plate.ply"
    mesh = trimesh.creation.box(extents=(2.0, 1.0, 0.01))
    mesh.apply_translation((0, 0, 0.031))
    colours = np.tile(np.array([[200, 60, 40, 255]], np.uint8), (len(mesh.vertices), 1))
    trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colours, process=False).export(path)
    scene, box_low, spacing, solid = grid_of(path, res=8)
    tiles = appearance.example_tiles(appearance.coloured_surface(scene, path), box_low, spacing, solid, 1 << 10)
    assert set(tiles.directions) >= {4, 5} and len(tiles.voxels) >= 16
    assert (np.abs(tiles.images[..., :3].astype(int) - (200, 60, 40)).max(axis=-1) <= 2).mean() > 0.9


def test_a_geometry_only_examples_depth_tiles_keep_its_relief_finer_than_a_voxel():
    # The ridged block (tests/data/relief) at res 16: voxels of 0.125, ridges 0.03 high (a quarter
    # voxel) over 0.19 of every 0.25. Its tiles hold depth alone, as finely as its faces are cut.
    from conftest import RIDGED_BOX

    scene, box_low, spacing, solid = grid_of(RIDGED_BOX)
    surface = appearance.relief_surface(scene)
    assert surface.colour is None
    tiles = appearance.example_tiles(surface, box_low, spacing, solid)
    assert tiles.images.shape[1:] == (16, 16, 1)  # its profile's columns 1/64 apart, 8 a voxel: twice that
    read = colour.Tiles.of(tiles.voxels, tiles.directions, tiles.images, tiles.distance)
    # Points along the top where a model's surface lies (the distance grid's zero: flat, 0.6 voxel
    # above the joints) take its ridges and joints: within a tenth of a voxel of the block's own top.
    x = np.linspace(-0.95, 0.95, 400)
    flat = np.stack([x, np.zeros_like(x), np.full_like(x, 1.07)], axis=1)
    moved = colour.relief(read, lambda voxels: voxels, (flat - box_low) / spacing - 0.5, np.array(solid.shape),
                          read.distance)
    height = box_low[2] + (moved[:, 2] + 0.5) * spacing[2]
    top = 1.0 + 0.03 * ((x + 1) % 0.25 < 0.19)
    assert np.abs(height - top).mean() < 0.1 * spacing[2]
    phase = (x + 1) % 0.25
    ridge, joint = (phase > 0.03) & (phase < 0.16), (phase > 0.2) & (phase < 0.24)
    assert ridge.sum() > 100 and joint.sum() > 30
    assert height[ridge].min() > height[joint].max()  # every ridge above every joint


def off_the_line(rgb, a, b) -> np.ndarray:
    """Each colour's distance (8-bit steps) from the nearest blend of colours
    a and b, and where along a..b it lies: ((n,), (n,) in [0, 1])."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.clip(((rgb - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(rgb - (a + t[:, None] * (b - a)), axis=1), t


def test_every_colour_a_tile_holds_is_the_examples(tmp_path):
    # A stripe's colour, or at a stripe's edge a blend of the two (the
    # texture is read bilinearly, as a renderer reads it): no other hue.
    path = striped_box(tmp_path)
    scene, box_low, spacing, solid = grid_of(path)
    tiles = appearance.example_tiles(appearance.coloured_surface(scene, path), box_low, spacing, solid)
    distance, t = off_the_line(tiles.images[..., :3].reshape(-1, 3).astype(float), *STRIPES)
    assert distance.max() <= 1.5
    assert (t < 0.05).mean() > 0.15 and (t > 0.95).mean() > 0.15


@pytest.fixture(scope="module")
def model(tiny_colour_model):
    loaded = load_model(tiny_colour_model, threads=1)
    assert loaded.example_tiles is not None and loaded.manifest.raw["format_version"] == 5
    return loaded


def planes_of(model, triplane):
    return colour.query.project(model, triplane).planes


def band_of(model, planes, size):
    return colour.surface_band(model, colour.grid_hidden(model, planes, size), size)


def test_the_reconstruction_matches_itself(model):
    matcher = colour.matcher(model)
    recon = generate.sample(model, None)
    planes = planes_of(model, recon)
    band = band_of(model, planes, recon.size)
    ours = band[matcher.levels[0].rows(band) >= 0]  # the voxels the example's band holds too
    assert len(ours) > 50
    np.testing.assert_array_equal(matcher.match(colour.pyramid(model, planes, recon.size), ours), ours)


def test_a_match_follows_content_not_place_or_order(model):
    matcher = colour.matcher(model)
    triplane = generate.sample(model, 3)
    planes = planes_of(model, triplane)
    band = band_of(model, planes, triplane.size)
    matched = matcher.match(colour.pyramid(model, planes, triplane.size), band)
    order = np.random.default_rng(0).permutation(len(band))
    np.testing.assert_array_equal(matcher.match(colour.pyramid(model, planes, triplane.size), band[order]),
                                  matched[order])
    # The same content moved by whole coarsest blocks: mostly the same example voxels, but where the
    # moved grid's blocks see what was padded in at its low edges and PatchMatch carries that a few
    # blocks in (on these tiny grids 78-100% the same a block in from the edges, by model and seed)...
    shift = (1 << colour.LEVELS) * np.array([2, 1, 1])
    moved = [np.pad(plane, ((shift[a], 0), (shift[b], 0), (0, 0)), mode="edge")
             for plane, (a, b) in zip(planes, ((0, 1), (0, 2), (1, 2)))]
    again = matcher.match(colour.pyramid(model, moved, np.array(triplane.size) + shift), band + shift)
    inner = np.all(band >= 1 << colour.LEVELS, axis=1)
    assert inner.sum() > 50
    same = (again[inner] == matched[inner]).all(axis=1).mean()
    # ...and other content, other matches.
    other = matcher.match(colour.pyramid(model, planes_of(model, generate.sample(model, 4)), triplane.size), band)
    differs = (other[inner] == matched[inner]).all(axis=1).mean()
    assert same > 0.7 and same > differs + 0.4, (same, differs)


def test_neighbouring_voxels_copy_neighbouring_places_of_the_example(model):
    """Coarse to fine, a sample's surface copies the example in pieces many voxels wide: most of its
    band lies in pieces (neighbours whose matches differ by the step between them) of over 27 voxels,
    where matching voxels alone, at the finest level, leaves almost all in smaller ones (measured on
    this model: 56-60% against 3-5%, seeds 3-5)."""
    triplane = generate.sample(model, 3)
    planes = planes_of(model, triplane)
    band = band_of(model, planes, triplane.size)
    sample = colour.pyramid(model, planes, triplane.size)
    matcher = colour.matcher(model)
    coarse_to_fine = colour.piece_sizes(band, matcher.match(sample, band))
    alone = colour.piece_sizes(band, matcher.levels[0].search(sample.at(0), band))
    assert np.mean(coarse_to_fine > 27) > 0.45
    assert np.mean(coarse_to_fine > 27) > np.mean(alone > 27) + 0.3


def faces_off_the_band(level, band: np.ndarray, matched: np.ndarray) -> int:
    """Seam faces across which a piece, continued, would be read off the example's band: at each face
    between neighbours that copy different pieces, the neighbour's piece at this voxel and this one's
    at the neighbour, counted where the example's band lacks them."""
    lookup = colour.voxel_lookup(band)
    offset = matched - band
    count = 0
    for step in colour.axis_steps(1)[::2]:
        beside = lookup(band + step)
        has = np.flatnonzero(beside >= 0)
        cut = has[np.any(offset[has] != offset[beside[has]], axis=1)]
        here, there = band[cut], band[beside[cut]]
        count += int((level.rows(here + offset[beside[cut]]) < 0).sum() + (level.rows(there + offset[cut]) < 0).sum())
    return count


def test_seams_settle_where_both_pieces_go_on(model):
    """After coarse to fine, a voxel on a seam takes the piece that can go on across its faces
    (Level.settle): a piece read off the example's band shows other places' colours. On this model
    the faces where one would be fall by half (measured 1748 -> 823 and 2361 -> 1085, seeds 3 and 4)
    and the pieces grow (13.2% -> 12.8% and 16.9% -> 15.7% of the band in pieces under 27 voxels):
    a seam moves as a whole, not voxel by voxel."""
    matcher = colour.matcher(model)
    assert matcher.settles  # a coloured example's
    for seed in (3, 4):
        triplane = generate.sample(model, seed)
        planes = planes_of(model, triplane)
        band = band_of(model, planes, triplane.size)
        sample = colour.pyramid(model, planes, triplane.size)
        settled = matcher.match(sample, band)
        matcher.settles = False
        try:
            unsettled = matcher.match(sample, band)
        finally:
            matcher.settles = True
        before, after = (faces_off_the_band(matcher.levels[0], band, m) for m in (unsettled, settled))
        assert after < before * 0.6, (before, after)
        small = [np.mean(colour.piece_sizes(band, m) < 27) for m in (unsettled, settled)]
        assert small[1] < small[0], small


def test_a_seam_between_two_pieces_is_a_curve_not_the_voxels_edge():
    """Two pieces meet at the face x = 3.5 (voxels below x 4 copy themselves,
    the rest a place ten voxels on): points on either side near the face read
    the other piece where the seam wanders past them, by up to SEAM_WANDER;
    along each line across the face one piece gives way to the other once;
    where the line crosses varies along the face; and it follows what the
    pieces copy, not where they lie (the same copies two voxels on along y
    meet along the same curve, moved)."""
    def matched(voxels):
        return voxels + np.where(voxels[:, :1] >= 4, [10, 0, 0], [0, 0, 0])

    grid = (8, 12, 8)
    x = np.linspace(3.0, 4.0, 201)
    y = np.linspace(2.0, 6.0, 81)
    points = np.stack(np.meshgrid(x, y, indexing="ij"), axis=-1).reshape(-1, 2)
    points = np.column_stack([points, np.full(len(points), 3.2)])
    voxels, matches = colour.seam_voxels(matched, points, grid)
    assert np.array_equal(matches, matched(voxels))
    upper = (voxels[:, 0] == 4).reshape(len(x), len(y))
    assert np.array_equal(voxels[:, 1:], colour.own_voxels(points, grid)[:, 1:])  # only across the face
    far = np.abs(x - 3.5) > colour.SEAM_WANDER
    assert np.array_equal(upper[far], np.broadcast_to((x > 3.5)[far, None], upper[far].shape))
    assert np.all(np.diff(upper.astype(int), axis=0) >= 0)  # one crossing a line
    crossing = x[np.argmax(upper, axis=0)]
    assert crossing.std() > 0.05 and (crossing < 3.49).any() and (crossing > 3.51).any(), crossing
    moved, _ = colour.seam_voxels(lambda v: matched(v - [0, 2, 0]), points + [0, 2, 0], grid)
    assert np.array_equal(moved - [0, 2, 0], voxels)


def test_a_samples_colours_are_the_examples(model):
    # The box is red above and blue below: at full detail every colour a
    # sample shows is one of the two, or a blend of neighbouring texels of both.
    triplane = generate.sample(model, 5)
    points = np.argwhere(colour.query.dense(model, triplane, 2.0) > 0.5) / 2.0
    distance, t = off_the_line(colour.colours(model, triplane, points) * 255, (30, 60, 200), (220, 40, 30))
    assert distance.max() < 3
    assert (t > 0.9).mean() > 0.1 and (t < 0.1).mean() > 0.1


def test_a_coarser_world_tile_shows_only_the_examples_colours(model):
    """A coarser tile (lod > 0) has no finest planes to match: the colour head's colour there is
    made the nearest of the example's tiles' means, so no hue the example lacks shows far away."""
    got = world_tiles.tile_surface(model, 5, (3, -2), options=world.WorldOptions(lod=1)).colours[:, :3]
    palette = {tuple(c) for c in colour.example_palette(model.example_tiles)}
    assert len(got) > 100 and all(tuple(c) in palette for c in got)  # the head's own: none of them (measured)


def test_the_nearest_colour_of_a_palette_is_the_first_of_equals():
    palette = np.array([[10, 10, 10], [200, 200, 200], [210, 200, 200]], np.uint8)
    colours = np.array([[0, 0, 0], [205, 200, 200], [255, 255, 255], [0, 0, 0]], np.uint8)
    np.testing.assert_array_equal(colour.nearest_in_palette(colours, palette), palette[[0, 1, 2, 0]])


def damaged(model_path, tmp_path, change):
    import onnx
    from onnx import numpy_helper

    from sinshape.core import manifest as fmt

    proto = onnx.load(model_path)
    arrays = {t.name: numpy_helper.to_array(t) for t in proto.graph.initializer if t.name in fmt.TILE_TENSORS}
    change(arrays)
    for tensor in proto.graph.initializer:
        if tensor.name in arrays:
            tensor.CopyFrom(numpy_helper.from_array(arrays[tensor.name], tensor.name))
    out = tmp_path / "damaged.onnx"
    out.write_bytes(fmt.seal(proto.SerializeToString()))
    return out


@pytest.mark.parametrize("change, message", [
    (lambda a: a.update({"colour_tiles.voxels": a["colour_tiles.voxels"] + 1000}), "outside the model's finest level"),
    (lambda a: a.update({"colour_tiles.directions": a["colour_tiles.directions"] * 0 + 6}), "outside"),
    (lambda a: a.update({"colour_tiles.voxels": a["colour_tiles.voxels"][::-1].copy()}), "in order"),
    (lambda a: a.update({"colour_tiles.images": a["colour_tiles.images"][:-1]}), "do not match the manifest"),
    (lambda a: a.update({"colour_tiles.voxels": a["colour_tiles.voxels"].astype(np.float32)}), "not int32"),
    (lambda a: a.update({"colour_tiles.distance": a["colour_tiles.distance"][:-1]}), "distance grid"),
])
def test_damaged_tiles_are_refused_in_one_line(tiny_colour_model, tmp_path, change, message):
    pytest.importorskip("onnx")
    with pytest.raises(InputError, match=message) as error:
        load_model(damaged(tiny_colour_model, tmp_path, change))
    assert "\n" not in str(error.value)
