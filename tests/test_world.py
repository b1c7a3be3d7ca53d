"""Endless worlds: a tile is a pure function of (model, seed, i, j), its
shared faces are equal to the bit, the union of a block is one surface, and
a far tile does the work a near one does."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.runtime import generate, load_model, world, world_maps, world_tiles, write
from sinshape.runtime.request import SampleRequest
from test_cli_train import assert_one_line_error


@pytest.fixture(scope="module")
def model(tiny_model):
    return load_model(tiny_model, threads=1)


@pytest.fixture
def fresh():
    """No window kept from earlier tiles."""
    world._windows.clear()
    yield
    world._windows.clear()


@pytest.mark.parametrize("scale", [1, 2.5])
def test_neighbours_agree_on_their_shared_faces_to_the_bit(model, scale):
    h0, h1 = world.world_tiling(model).horizontal
    grids = {(i, j): world_tiles.tile_occupancy(model, 7, (i, j), scale) for i in (2, 3) for j in (-1, 0)}
    for (i, j), grid in grids.items():
        if (i + 1, j) in grids:
            assert np.array_equal(np.take(grid, -1, h0), np.take(grids[i + 1, j], 0, h0))
        if (i, j + 1) in grids:
            assert np.array_equal(np.take(grid, -1, h1), np.take(grids[i, j + 1], 0, h1))
    assert not np.array_equal(grids[2, -1], grids[3, 0])  # and they are not the same tile


def test_a_window_made_finer_goes_on_from_its_coarser_level_to_the_same_planes(model, fresh, monkeypatch):
    """A far tile come nearer: its windows' finer level runs only the levels
    past the coarser one kept, and gives the planes of the whole chain."""
    tiling = world.world_tiling(model)
    finest = len(model.manifest.sizes) - 1
    whole = world.window(model, tiling, 5, 2, -1, finest)
    world._windows.clear()
    starts = []
    monkeypatch.setattr(world, "triplane", lambda *args, start=None: starts.append(start and start[0])
                        or generate.triplane(*args, start=start))
    world.window(model, tiling, 5, 2, -1, finest - 1)
    refined = world.window(model, tiling, 5, 2, -1, finest)
    assert starts == [None, finest - 1]
    for a, b in zip(whole.planes + whole.chain, refined.planes + refined.chain):
        assert np.array_equal(a, b)


def block_mesh(model, seed, tiles, scale=1.0):
    """Tiles' meshes put together by their exact corners: (vertices, faces) with shared vertices merged."""
    vertices, faces = [], []
    count = 0
    for tile in tiles:
        v, f = world_tiles.tile_mesh(model, seed, tile, scale)
        vertices.append(v + np.array(world_tiles.tile_corner(model, tile)))
        faces.append(f + count)
        count += len(v)
    vertices = np.concatenate(vertices)
    unique, index = np.unique(vertices, axis=0, return_inverse=True)  # exact coordinates: a shared vertex is one
    return unique, index.reshape(-1)[np.concatenate(faces)]


def test_a_block_of_tiles_is_one_surface_open_only_on_its_outer_sides(model):
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    vertices, faces = block_mesh(model, 5, [(i, j) for i in range(3) for j in range(3)], scale=1.5)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2  # a manifold: no edge in three faces (no doubled border)
    open_edges = unique[counts == 1]
    ends = vertices[open_edges]  # (E, 2, 3)
    outer = [(axis, side * 3 * tiling.stride[axis]) for axis in (h0, h1) for side in (0, 1)]
    on_outer_side = np.zeros(len(open_edges), bool)
    for axis, at in outer:
        on_outer_side |= (ends[:, :, axis] == at).all(axis=1)
    assert len(open_edges) and on_outer_side.all()  # every crack-free inside, open only where the block ends


def test_a_tile_is_the_same_whatever_was_made_before(model, fresh):
    alone = write.request_bytes(model, SampleRequest(11, tile=(5, 3)), "t.ply")[0]
    for tile in [(4, 3), (5, 2), (6, 4), (-70, 9)]:
        world_tiles.tile_mesh(model, 11, tile)
    assert write.request_bytes(model, SampleRequest(11, tile=(5, 3)), "t.ply")[0] == alone
    world._windows.clear()
    assert write.request_bytes(model, SampleRequest(11, tile=(5, 3)), "t.ply")[0] == alone


def test_a_far_tile_does_the_work_a_near_one_does(model, fresh, monkeypatch):
    """The same work, counted: as many windows' noise drawn, at the same sizes.
    What a tile costs in seconds, at 0 to 10^9 tiles from the origin, is
    measured by benchmarks/world.py (docs/BENCHMARKS.md, "Endless worlds"),
    not here: a timed test fails when the machine is busy, not when the code
    is wrong."""
    drawn = []
    monkeypatch.setattr(world, "draw_noise", lambda *args, **kw: drawn.append([tuple(size) for size in args[1]])
                        or generate.draw_noise(*args, **kw))
    work = []
    for tile in ((0, 0), (10**9, -10**9)):
        drawn.clear()
        world._windows.clear()
        grid = world_tiles.tile_occupancy(model, 3, tile)
        work.append(sorted(drawn))
        assert np.isfinite(grid).all() and 0 < grid.mean() < 1
    assert work[0] == work[1] and len(work[0]) > 1


def test_no_two_windows_share_their_noise(model):
    seeds = {world.window_seed(3, a, b) for a in range(-3, 4) for b in range(-3, 4)}
    seeds |= {world.window_seed(4, 0, 0), world.window_seed(3, 2**62, -2**62)}
    assert len(seeds) == 51


def test_bad_tiles_are_refused_in_one_line(model, tmp_path):
    for tile in [(2**62, 0), (0, -2**62), (1.5, 0), (1,), "3,4", (True, 0)]:
        with pytest.raises(InputError) as refused:
            world_tiles.tile_occupancy(model, 0, tile)
        assert refused.value.parameter == "tile"
    with pytest.raises(MemoryLimitError):
        world.check_world_scale(world.world_tiling(model), 200, model.manifest.hidden, 1 << 20)
    with pytest.raises(InputError, match="give frame tile"):
        write.request_bytes(model, SampleRequest(0, tile=(10**9, 0)), "far.ply")
    assert write.request_bytes(model, SampleRequest(0, tile=(10**9, 0), frame="tile"), "far.ply")[0]


def test_a_world_needs_room_to_blend_along_its_horizontal_axes(model):
    narrow = load_model(model.path, threads=1)
    narrow.manifest = type(narrow.manifest)(**{**narrow.manifest.__dict__,
                                               "sizes": [(s[0], 8, s[2]) for s in narrow.manifest.sizes]})
    with pytest.raises(InputError, match="a world needs windows of at least 9"):
        world.world_tiling(narrow)


def test_world_writes_a_resumable_folder_of_tiles(tiny_model, model, tmp_path):
    out = tmp_path / "w"
    result = CliRunner().invoke(cli, ["world", str(tiny_model), "--seed", "4", "--tiles", "-1:0,2", "-o", str(out),
                                      "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["tile_-1_2.ply", "tile_0_2.ply", "tile_index.jsonl"]
    job, *records = [json.loads(line) for line in (out / "tile_index.jsonl").read_text().splitlines()]
    assert job["job"]["request"]["seed"] == 4 and "tile" not in job["job"]["request"]  # the world, not one tile
    assert [r["tile"] for r in records] == [[-1, 2], [0, 2]]
    assert records[0]["corner"] == list(world_tiles.tile_corner(model, (-1, 2)))
    assert (out / "tile_0_2.ply").read_bytes() == write.request_bytes(model, SampleRequest(4, tile=(0, 2)), "x.ply")[0]
    again = CliRunner().invoke(cli, ["world", str(tiny_model), "--seed", "4", "--tiles", "-1:0,2", "-o", str(out),
                                     "--workers", "1"])
    assert again.exit_code == 0 and "2 already done" in again.output
    grid = CliRunner().invoke(cli, ["world", str(tiny_model), "--tiles", "0,0", "-o", str(tmp_path / "g"),
                                    "--format", "npz", "--workers", "1"])
    assert grid.exit_code == 0, grid.output
    with np.load(tmp_path / "g" / "tile_0_0.npz") as npz:
        assert np.array_equal(npz["occupancy"], world_tiles.tile_occupancy(model, 0, (0, 0)))
        assert tuple(npz["tile"]) == (0, 0)


@pytest.mark.parametrize("options, says", [
    (["--tiles", "0:1"], "is not a block of tiles"),
    (["--tiles", "3:1,0"], "counts down"),
    (["--tiles", f"0,{2**62}"], "magnitude below 2**62"),
])
def test_world_refuses_bad_tiles_as_usage_errors(tiny_model, tmp_path, options, says):
    result = CliRunner().invoke(cli, ["world", str(tiny_model), *options, "-o", str(tmp_path / "w")])
    assert result.exit_code == 2 and says in result.output
    assert not (tmp_path / "w").exists()


def test_world_refuses_far_tiles_in_absolute_coordinates_in_one_line(tiny_model, tmp_path):
    assert_one_line_error(CliRunner().invoke(cli, ["world", str(tiny_model), "--tiles", "1000000000,0", "-o",
                                                   str(tmp_path / "w"), "--workers", "1"]), "give --frame tile")
    assert not list((tmp_path / "w").glob("*.ply"))


@pytest.mark.parametrize("name", ["towerruins", "acropolis"])
def test_a_scattered_worlds_block_is_closed(name):
    """A scatter world's ground holds grid values exactly at the level: the
    faces they make have no area once the block is welded, and are dropped."""
    from sinshape import models

    loaded = load_model(models.find(name), threads=1)
    block = world_tiles.block_mesh(loaded, SampleRequest(3, arrange="scatter"), [(0, 0), (0, 1), (1, 0), (1, 1)])
    assert block.is_watertight and block.volume > 0


def test_a_block_at_a_coarser_level_is_one_closed_mesh_and_refuses_a_skirt(model):
    """Tiles of one lod share their faces exactly, so a block of them is one closed surface;
    a skirt, for a tile beside one of another level, has no place in it."""
    tiles = [(0, 0), (0, 1), (1, 0), (1, 1)]
    coarse = world_tiles.block_mesh(model, SampleRequest(3, lod=1, frame="model"), tiles)
    full = world_tiles.block_mesh(model, SampleRequest(3, frame="model"), tiles)
    assert coarse.is_watertight and coarse.volume > 0 and len(coarse.faces) < len(full.faces)
    with pytest.raises(InputError, match="skirt is for a streamed view"):
        world_tiles.block_mesh(model, SampleRequest(3, skirt=True, frame="model"), tiles)
    with pytest.raises(InputError, match=r"open underneath \(underside off\) is for a streamed view"):
        world_tiles.block_mesh(model, SampleRequest(3, underside=False, frame="model"), tiles)


def test_a_block_written_as_one_mesh_is_closed_and_placed(tiny_model, model, tmp_path):
    import trimesh

    out = tmp_path / "block.ply"
    result = CliRunner().invoke(cli, ["world", str(tiny_model), "--seed", "2", "--tiles", "-1:1,0:1", "-o", str(out),
                                      "--frame", "model"])
    assert result.exit_code == 0 and "(6 tiles)" in result.output, result.output
    block = trimesh.load(out)
    assert block.is_watertight and block.volume > 0
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    assert block.bounds[0][h0] < -tiling.stride[h0] + 1 and block.bounds[1][h1] > 2 * tiling.stride[h1] - 1
    tile_frame = CliRunner().invoke(cli, ["world", str(tiny_model), "--tiles", "0,0", "-o", str(tmp_path / "b.ply"),
                                          "--frame", "tile"])
    assert tile_frame.exit_code == 1 and "a block is placed in the world: give --frame input or model" in \
        tile_frame.output and not (tmp_path / "b.ply").exists()


def test_a_folder_of_tiles_in_the_tile_frame_holds_each_tile_as_made_alone(tiny_model, model, tmp_path):
    import trimesh

    result = CliRunner().invoke(cli, ["world", str(tiny_model), "--seed", "2", "--tiles", "0:1,5", "-o",
                                      str(tmp_path / "w"), "--frame", "tile", "--workers", "1"])
    assert result.exit_code == 0, result.output
    for i in (0, 1):
        written = trimesh.load(tmp_path / "w" / f"tile_{i}_5.ply", process=False)
        expected = write.request_bytes(model, SampleRequest(2, tile=(i, 5), frame="tile"), "t.ply")[0]
        assert np.array_equal(written.vertices, trimesh.load(trimesh.util.wrap_as_stream(expected),
                                                             file_type="ply", process=False).vertices)


# ---- how a world is made: scattered, painted, coarser

def identical_windows(model):
    """The model with no noise at all: every window and object the same sample."""
    same = load_model(model.path, threads=1)
    same.manifest = type(same.manifest)(**{**same.manifest.__dict__, "noise_amps": [0.0] * len(same.manifest.noise_amps)})
    return same


def strip_heights(model, options, tiles=12) -> tuple:
    """A strip of tiles along the first horizontal axis, two across: (its height field's grid, stride)."""
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    rows = []
    for i in range(tiles):
        row = [world_tiles.tile_occupancy(model, 5, (i, j), options=options) for j in (0, 1)]
        rows.append(np.concatenate([row[0], np.take(row[1], range(1, row[1].shape[h1]), axis=h1)], axis=h1))
    strip = np.concatenate([rows[0]] + [np.take(r, range(1, r.shape[h0]), axis=h0) for r in rows[1:]], axis=h0)
    return strip, tiling.stride[h0]


def test_a_scattered_world_of_identical_samples_has_no_period(model, fresh):
    """Samples that do not differ: blended on the tile lattice they repeat with it (the height
    field's autocorrelation at the tile period near 1); scattered, their places and mirrors do not."""
    from sinshape.runtime import evaluate

    same = identical_windows(model)
    up = world.world_tiling(same).up
    h0 = world.world_tiling(same).horizontal[0]
    blended, stride = strip_heights(same, world.WorldOptions("blend"))
    assert min(evaluate.height_autocorrelation(blended, up, h0, [stride, 2 * stride])) > 0.9
    scattered, _ = strip_heights(same, world.WorldOptions("scatter"))
    pitch = world.scatter_geometry(same, world.world_tiling(same), world.WorldOptions("scatter"))[0][0]
    at_stride, at_twice, at_pitch = evaluate.height_autocorrelation(scattered, up, h0, [stride, 2 * stride, pitch])
    assert abs(at_stride) < 0.5 and abs(at_twice) < 0.5 and abs(at_pitch) < 0.3  # one per cell, unmoved: 0.52


def test_scattered_objects_face_all_eight_ways_each_the_same_shape_turned(model):
    """With no noise every object is one shape; the world shows it turned a
    quarter about the up axis or not and mirrored along either horizontal
    axis (all eight ways), each its unturned self's height field turned and
    flipped so, on the turned footprint (the tiny model's is 20 x 18)."""
    from sinshape.runtime import world_points

    same = identical_windows(model)
    tiling = world.world_tiling(same)
    (h0, h1), up = tiling.horizontal, tiling.up
    options = world.WorldOptions("scatter")
    found = {}
    for i in range(0, 60, 2):
        for j in range(0, 12, 2):
            for placed in world.objects_near(same, tiling, 5, (i, j), 0, options):
                found.setdefault((placed.turned, placed.mirror), ((i, j), placed))
    assert len(found) == 8

    def heights(tile, placed) -> np.ndarray:  # solid voxels per column over the object's footprint
        e0, e1 = placed.extent
        x, y, z = np.meshgrid(np.arange(e0 + 1), np.arange(e1 + 1), np.arange(tiling.stride[up] + 1), indexing="ij")
        points = np.zeros((x.size, 3))
        points[:, h0], points[:, h1], points[:, up] = (x.ravel() + placed.corner[0], y.ravel() + placed.corner[1],
                                                       z.ravel())
        logits = world_points.point_field(same, 5, tile, points, options)[0]
        return (logits > 0).reshape(x.shape).sum(axis=2)

    reference = heights(*found[(False, (False, False))])
    assert reference.shape == (20, 18) and reference.std() > 0.5  # a shape, not a slab
    for (turned, mirror), (tile, placed) in found.items():
        expected = reference.T if turned else reference
        for axis in (0, 1):
            expected = np.flip(expected, axis) if mirror[axis] else expected
        assert np.array_equal(heights(tile, placed), expected), (turned, mirror)
    # A tile's grid (made a row at a time, not point by point) holds the same turned objects.
    tile = found[(True, (False, False))][0]
    grid = world_tiles.tile_occupancy(same, 5, tile, options=options)
    axes = np.meshgrid(*(np.arange(n) for n in grid.shape), indexing="ij")
    points = np.stack([a.ravel() for a in axes], axis=1).astype(np.float64)
    assert np.array_equal(grid.ravel() > 0.5, world_points.point_field(same, 5, tile, points, options)[0] > 0)


def test_a_painted_circle_stays_round_on_tiles_that_are_not_square(model):
    """A map's pixel is a square of the tiles' longer side (the tiny model's
    tiles are 9 x 8 voxels): a disc painted on it raises a round plateau,
    however the tiles cut it, and neighbouring tiles agree where they meet."""
    tiling = world.world_tiling(model)
    (h0, h1), pixel = tiling.horizontal, world.map_pixel(tiling)
    assert tiling.stride[h0] != tiling.stride[h1] and pixel == max(tiling.stride[h0], tiling.stride[h1])
    rows, columns = np.mgrid[:24, :24]
    heights = world_maps.HeightMap.of(((columns - 11.5) ** 2 + (rows - 11.5) ** 2 <= 36) * 40.0)
    s0, s1 = tiling.stride[h0], tiling.stride[h1]
    count0, count1 = 24 * pixel // s0 + 1, 24 * pixel // s1 + 1
    field = np.full((count0 * s0, count1 * s1), np.nan)
    for i in range(count0):
        for j in range(count1):
            part = world.map_heights(heights, tiling, np.arange(s0 + 1.0), np.arange(s1 + 1.0), (i, j))
            if j + 1 < count1:  # a shared face: the same heights from both tiles
                beside = world.map_heights(heights, tiling, np.arange(s0 + 1.0), np.zeros(1), (i, j + 1))
                assert np.array_equal(part[:, -1:], beside)
            field[i * s0:(i + 1) * s0, j * s1:(j + 1) * s1] = part[:-1, :-1]
    raised = field > 20
    across = [np.ptp(np.flatnonzero(raised.any(axis=1 - axis))) for axis in (0, 1)]
    assert across[0] > 8 * pixel and abs(across[0] - across[1]) <= 1  # round, to a voxel (was 9:8)


def test_density_and_spacing_set_how_many_objects_a_scattered_world_holds(model):
    """`density` is the share of cells holding an object; `spacing` a cell's
    side in tiles (never less than its widest object turned either way)."""
    tiling = world.world_tiling(model)
    (h0, h1), extent = tiling.horizontal, world.scatter_geometry(model, tiling)[1][0]
    for density in (0.2, 0.9):
        options = world.WorldOptions("scatter", density=density)
        pitch = world.scatter_geometry(model, tiling, options)[0]
        present = [world.scatter_cell(5, a, b, extent, pitch, options.density).present
                   for a in range(50) for b in range(40)]
        assert abs(np.mean(present) - density) < 0.03
    wide = world.WorldOptions("scatter", spacing=7.5)
    assert world.scatter_geometry(model, tiling, wide)[0] == tuple(round(7.5 * tiling.stride[h]) for h in (h0, h1))
    narrow = world.scatter_geometry(model, tiling, world.WorldOptions("scatter", spacing=1))[0]
    assert narrow == (max(extent) + tiling.stride[h0] // 2, max(extent) + tiling.stride[h1] // 2)  # an object fits
    sparse = {placed.cell for i in range(12) for j in range(12)
              for placed in world.objects_near(model, tiling, 5, (i, j), 0, wide)}
    dense = {placed.cell for i in range(12) for j in range(12)
             for placed in world.objects_near(model, tiling, 5, (i, j), 0, world.WorldOptions("scatter"))}
    assert 0 < len(sparse) < len(dense) / 3


@pytest.mark.parametrize("fields, said", [
    (dict(density=0.3), "density places whole objects: it is for a scatter world"),
    (dict(arrange="scatter", density=0), "density must be above 0 and at most 1, got 0"),
    (dict(arrange="scatter", density=1.5), "at most 1"), (dict(arrange="scatter", spacing=0.5), "1 to 64 tiles"),
    (dict(arrange="scatter", spacing=float("nan")), "1 to 64 tiles"), (dict(spacing=5), "for a scatter world")])
def test_bad_density_and_spacing_are_refused_in_one_line(fields, said):
    with pytest.raises(InputError, match=said) as error:
        SampleRequest(3, tile=(0, 0), **fields)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("options", [world.WorldOptions("scatter"), world.WorldOptions("blend", lod=1),
                                     world.WorldOptions("scatter", heights=world_maps.HeightMap.of([[0.0, 25.0], [40.0, 7.5]]))],
                         ids=["scatter", "lod", "scatter-map"])
def test_neighbours_agree_on_faces_and_normals_to_the_bit_however_the_world_is_made(model, options):
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    for a, b, axis in (((0, 0), (1, 0), h0), ((1, 0), (1, 1), h1)):
        grid_a, grid_b = (world_tiles.tile_occupancy(model, 7, t, options=options) for t in (a, b))
        assert np.array_equal(np.take(grid_a, -1, axis), np.take(grid_b, 0, axis))
        made = [world_tiles.tile_surface(model, 7, t, options=options) for t in (a, b)]
        mine = {tuple(v - np.eye(3)[axis] * tiling.stride[axis]): tuple(n)
                for v, n in zip(made[0].vertices, made[0].normals) if v[axis] == tiling.stride[axis]}
        theirs = {tuple(v): tuple(n) for v, n in zip(made[1].vertices, made[1].normals) if v[axis] == 0}
        assert len(mine) > 5 and mine == theirs
        assert np.allclose(np.linalg.norm(made[0].normals, axis=1), 1, atol=1e-5)


def test_a_height_map_raises_the_world_where_it_is_painted(model):
    """A plateau painted 50 voxels high over tiles (0..3, 0..3) raises tile (1, 1) by 50 (the map's
    spline is flat there), blended or scattered (the ground), leaves a tile where the map is 0
    where it was, and goes on beyond the map's edges as its edge."""
    plateau = np.zeros((6, 6))
    plateau[:4, :4] = 50
    heights = world_maps.HeightMap.of(plateau)
    up = world.world_tiling(model).up

    def surface(tile, options) -> float:
        """The mean height of the highest solid point of each column that has one."""
        grid = np.moveaxis(world_tiles.tile_occupancy(model, 2, tile, options=options) > 0.5, up, -1)
        z = world.tile_grid(model, world.world_tiling(model), 1.0, options).positions[up]
        solid = grid.any(axis=-1)
        return float(np.mean(z[grid.shape[-1] - 1 - np.argmax(grid[..., ::-1], axis=-1)][solid]))

    for arrange in world.ARRANGEMENTS:
        plain, shaped = world.WorldOptions(arrange), world.WorldOptions(arrange, heights=heights)
        for tile, rise in (((1, 1), 50), ((10**6, 10**6), 0), ((-5, 1), 50)):
            assert abs(surface(tile, shaped) - surface(tile, plain) - rise) < 1e-3 * (1 + rise), (arrange, tile)


def test_the_coarsest_tile_is_cheaper(fresh, monkeypatch):
    """Terrain: a tile at the coarsest level of detail (the sketch) draws a small part of a full
    tile's noise and has a fraction of its points."""
    from sinshape import models

    terrain = load_model(models.find("terrain"), threads=1)
    drawn = []
    monkeypatch.setattr(world, "draw_noise", lambda *args, **kw: drawn.append(args) or generate.draw_noise(*args, **kw))
    counted = []
    for lod in (0, len(terrain.manifest.sizes) - 1):
        world._windows.clear()
        drawn.clear()
        grid = world_tiles.tile_occupancy(terrain, 3, (0, 0), options=world.WorldOptions(lod=lod))
        values = sum(np.prod(size) for args in drawn for size in args[1])
        counted.append((values, grid.size))
    assert counted[1][0] < counted[0][0] / 4 and counted[1][1] < counted[0][1] / 4


def within_tile_correlation(model, tile, lod) -> float:
    """How a tile's height field at `lod` follows its lod-0 self, each tile's mean taken out."""
    a, b, fine = world_tiles.tile_heights(model, 3, tile)
    ca, cb, coarse = world_tiles.tile_heights(model, 3, tile, options=world.WorldOptions(lod=lod))
    along = np.stack([np.interp(b, cb, row) for row in coarse])
    coarse = np.stack([np.interp(a, ca, column) for column in along.T]).T
    return float(np.corrcoef(fine.ravel() - fine.mean(), coarse.ravel() - coarse.mean())[0, 1])


def test_a_farther_tile_keeps_the_shape_and_colour_of_its_full_self():
    """A tile at lod 1 or 2 reads the planes one level below the finest, a model coloured by
    correspondence the finest (world.planes_level): its heights correlate with its lod-0 self
    within the tile at 0.95 and more (read at its own level, lod 2's fell to 0.79-0.87 on these
    tiles; the coloured terrain's lod 1 read one level below, 0.85-0.92), and a coloured tile's
    mean colour is its full self's within 5 sRGB levels (by correspondence in its windows; the
    colour head gave 30-40 levels off, the level below the finest up to 7.6)."""
    from sinshape import models

    terrain = load_model(models.find("terrain"), threads=1)
    for tile in ((0, 0), (2, 1)):
        assert within_tile_correlation(terrain, tile, 1) > 0.95 and within_tile_correlation(terrain, tile, 2) > 0.95
    coloured = load_model(models.find("terrain_colour"), threads=1)
    for tile in ((0, 0), (2, 1)):
        assert within_tile_correlation(coloured, tile, 1) > 0.95
        means = []
        for lod in (0, 1):
            options = world.WorldOptions(lod=lod)
            surface = world_tiles.tile_surface(coloured, 3, tile, options=options)
            own = surface.faces[:len(world_tiles.tile_mesh(coloured, 3, tile, options=options)[1])]
            corners = surface.vertices[own]
            area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
            means.append((surface.colours[own, :3].mean(axis=1) * area[:, None]).sum(axis=0) / area.sum())
        assert np.abs(means[1] - means[0]).max() < 5, means


def covered_by_faces(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which (n, 2) points lie in any of (F, 3, 2) triangles."""
    def side(p, q):
        return (q[0] - p[0]) * (points[:, 1] - p[1]) - (q[1] - p[1]) * (points[:, 0] - p[0])

    hit = np.zeros(len(points), bool)
    for a, b, c in triangles:
        d = np.stack([side(a, b), side(b, c), side(c, a)])
        hit |= (d >= -1e-9).all(axis=0) | (d <= 1e-9).all(axis=0)
    return hit


@pytest.mark.parametrize("lod, skirt", [(1, False), (0, True)])
def test_a_skirt_covers_a_tiles_side_from_its_border_to_the_floor_facing_out(lod, skirt):
    """Terrain: a coarser tile, and a full one asked with `skirt`, hang from every side a skirt
    that covers the side plane from the border down to the floor of the tile's grid, facing
    away from the tile: so whichever of two neighbours' borders is the higher, the crack
    between them is hidden from both sides (the finer side sees the coarser tile's skirt,
    the coarser side the finer's). A full tile without `skirt` has none."""
    from sinshape import models

    terrain = load_model(models.find("terrain"), threads=1)
    tiling = world.world_tiling(terrain)
    h0, h1, up = *tiling.horizontal, tiling.up
    options = world.WorldOptions(lod=lod, skirt=skirt)
    floor = world.tile_grid(terrain, tiling, 1.0, options).positions[up][0]
    vertices, faces = world_tiles.tile_mesh(terrain, 3, (1, 0), options=options)
    surface = world_tiles.tile_surface(terrain, 3, (1, 0), options=options)
    for axis, other in ((h0, h1), (h1, h0)):
        for at, outward in ((0, -1), (tiling.stride[axis], 1)):
            border = vertices[(vertices[:, axis] == at) & (vertices[:, up] > floor + 0.5)]  # not the bottom's
            heights = np.linspace(0.02, 0.98, 9)
            points = np.stack([np.repeat(border[:, other], len(heights)),
                               (floor + heights[None, :] * (border[:, up, None] - floor)).ravel()], axis=1)
            corners = surface.vertices[surface.faces]
            corners = corners[(corners[:, :, axis] == at).all(axis=1)]
            normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])[:, axis]
            facing = corners[normal * outward > 0][:, :, [other, up]]
            assert len(border) > 10 and covered_by_faces(facing, points).all()
            assert not (normal * outward < 0).any()  # none turned to face into the tile
    plain = world_tiles.tile_surface(terrain, 3, (1, 0))
    assert len(plain.faces) == len(world_tiles.tile_mesh(terrain, 3, (1, 0))[1])  # no skirt at lod 0 unless asked


@pytest.mark.parametrize("lod", [0, 2])
def test_a_tile_open_underneath_has_the_same_surface_above_its_floor_and_none_below(lod):
    """Terrain, with and without `underside`: the closed tile's faces under the grid's
    lowest plane (its bottom, facing down) are gone, a quarter of them or more, and every
    face above that plane is the same, vertex for vertex; the skirt still hangs to the floor."""
    from sinshape import models

    terrain = load_model(models.find("terrain"), threads=1)
    tiling = world.world_tiling(terrain)
    up = tiling.up
    closed_options, open_options = world.WorldOptions(lod=lod, skirt=True), world.WorldOptions(lod=lod, skirt=True,
                                                                                              underside=False)
    floor = world.tile_grid(terrain, tiling, 1.0, closed_options).positions[up][0]
    closed, opened = (world_tiles.tile_surface(terrain, 3, (1, 0), options=o) for o in (closed_options, open_options))

    def faces_above(surface, above: bool):
        corners = surface.vertices[surface.faces]
        keep = (corners[:, :, up] >= floor - 1e-9).all(axis=1) == above
        return {tuple(np.round(np.sort(c, axis=0), 9).ravel()) for c in corners[keep]}

    below = faces_above(closed, False)
    assert faces_above(opened, False) == set() and len(below) >= 0.2 * len(opened.faces)
    assert faces_above(opened, True) == faces_above(closed, True)
    bottom = closed.vertices[closed.faces][:, :, up].max(axis=1) < floor - 1e-9
    normals = np.cross(*(closed.vertices[closed.faces[bottom][:, k]] - closed.vertices[closed.faces[bottom][:, 0]]
                         for k in (1, 2)))
    assert (normals[:, up] < 0).all()  # what was cut is the bottom, facing down
    assert np.isclose(opened.vertices[:, up].min(), floor)  # the skirt reaches the floor still


def test_world_writes_a_painted_scattered_coarser_world_and_refuses_a_bad_map(tiny_model, model, tmp_path):
    """--map (a .png: columns along the first axis, rows up the second), --relief, --arrange and
    --lod make the runtime's tiles of that world; a map that is not one is a one-line error."""
    from PIL import Image

    pixels = np.zeros((2, 3), np.uint8)  # rows from the top: the second axis's last row first
    pixels[1, 2] = 255  # bottom row, third column: tile (2, 0)
    Image.fromarray(pixels).save(tmp_path / "map.png")
    heights = world_maps.read_height_map(tmp_path / "map.png", model, 40.0)
    assert heights.shape == (3, 2) and heights.array()[2, 0] == 40 and heights.array().sum() == 40
    result = CliRunner().invoke(cli, ["world", str(tiny_model), "--seed", "4", "--tiles", "1:2,0", "--map",
                                      str(tmp_path / "map.png"), "--relief", "40", "--arrange", "scatter", "--lod", "1",
                                      "--frame", "tile", "--workers", "1", "-o", str(tmp_path / "w")])
    assert result.exit_code == 0, result.output
    wanted = SampleRequest(4, tile=(2, 0), frame="tile", arrange="scatter", heights=heights, lod=1)
    assert (tmp_path / "w" / "tile_2_0.ply").read_bytes() == write.request_bytes(model, wanted, "t.ply")[0]
    assert b"property float nx" in (tmp_path / "w" / "tile_2_0.ply").read_bytes()[:400]  # normals in the file
    (tmp_path / "bad.png").write_bytes(b"not an image")
    assert_one_line_error(CliRunner().invoke(cli, ["world", str(tiny_model), "--tiles", "0,0", "--map",
                                                   str(tmp_path / "bad.png"), "-o", str(tmp_path / "x")]),
                          "bad.png: not a readable image")
    np.save(tmp_path / "map.npy", np.ones((2, 2)))
    assert_one_line_error(CliRunner().invoke(cli, ["world", str(tiny_model), "--tiles", "0,0", "--map",
                                                   str(tmp_path / "map.npy"), "--relief", "3", "-o", str(tmp_path / "x")]),
                          "relief scales an image's")


def test_a_tiles_normals_make_none_of_its_neighbours_windows(model, fresh, monkeypatch):
    """A blended tile, normals and all, makes its own four windows and no other (the points of a
    normal just past a face read only the face's window, which holds the whole weight there)."""
    made = []
    monkeypatch.setattr(world, "draw_noise", lambda *args, **kw: made.append(args[0]) or generate.draw_noise(*args, **kw))
    surface = world_tiles.tile_surface(model, 4, (3, -2))
    assert len(surface.normals) == len(surface.vertices) > 100
    assert sorted(made) == sorted(world.window_seed(4, a, b) for a in (2, 3) for b in (-3, -2))


def test_a_fine_tile_takes_its_examples_relief_and_meets_its_neighbour_to_the_bit(tiny_relief_model):
    """At scale 2 a relief model's tile moves its vertices by the example's
    relief (at most colour.RELIEF voxels) and shades the moved surface; two
    neighbours still share every border vertex and its normal exactly.
    Without `detail`, or at scale 1, the tile is the voxels' surface."""
    from sinshape.runtime import colour

    model = load_model(tiny_relief_model, threads=1)
    tiling = world.world_tiling(model)
    h0 = tiling.horizontal[0]
    made = {t: world_tiles.tile_surface(model, 5, t, 2) for t in ((0, 0), (1, 0))}
    plain = world_tiles.tile_surface(model, 5, (0, 0), 2, world.WorldOptions(detail=False))
    vertices, _ = world_tiles.tile_mesh(model, 5, (0, 0), 2)
    assert np.array_equal(plain.vertices, vertices) and np.array_equal(made[0, 0].faces, plain.faces)
    moved = np.linalg.norm(made[0, 0].vertices - plain.vertices, axis=1)
    assert np.percentile(moved, 90) > 0.05 and moved.max() <= colour.RELIEF + 1e-9
    turned = np.einsum("nc,nc->n", made[0, 0].normals, plain.normals)
    assert np.percentile(turned, 10) < 0.99 and np.allclose(np.linalg.norm(made[0, 0].normals, axis=1), 1, atol=1e-5)
    # The border's vertices, found where they were before the relief moved them.
    plain_right = world_tiles.tile_surface(model, 5, (1, 0), 2, world.WorldOptions(detail=False))
    on_border = [plain.vertices[:, h0] == tiling.stride[h0], plain_right.vertices[:, h0] == 0]
    mine = {tuple(np.round(v - np.eye(3)[h0] * tiling.stride[h0], 12)): tuple(n)
            for v, n in zip(made[0, 0].vertices[on_border[0]], made[0, 0].normals[on_border[0]])}
    theirs = {tuple(np.round(v, 12)): tuple(n)
              for v, n in zip(made[1, 0].vertices[on_border[1]], made[1, 0].normals[on_border[1]])}
    assert len(mine) > 5 and mine == theirs
    coarse = world_tiles.tile_surface(model, 5, (0, 0), 1)
    assert np.array_equal(coarse.vertices, world_tiles.tile_mesh(model, 5, (0, 0), 1)[0])
