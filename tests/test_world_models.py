"""Several models in one scattered world, placed by a model map: each cell's
object is a sample of the model its pixel names, and the world keeps what
one model's does (any tile alone, the same bytes in any order, seams equal
to the bit)."""

import numpy as np
import pytest

from sinshape.core.errors import InputError
from sinshape.runtime import load_model, mesh, world, world_maps, world_points, world_tiles
from test_world import identical_windows

# With this map, cells a < 0 (their centres in tiles below 0 along the
# first horizontal axis) hold model 0's objects and cells a >= 0 model 1's,
# the edge going on either way.
SPLIT = world_maps.ModelMap.of([[0], [1]])


def objects(model, tile, options) -> list:
    """Which model each object reaching into a tile is drawn from (the test's premise)."""
    return [found.model for found in world.objects_near(model, world.world_tiling(model), 7, tile, 1, options)]


@pytest.fixture(scope="module")
def model(tiny_model):
    return load_model(tiny_model, threads=1)


@pytest.fixture(scope="module")
def still(model):
    """A second model, the first with no noise: the same shape of objects, other contents."""
    return identical_windows(model)


@pytest.fixture(scope="module")
def coloured(tiny_colour_model):
    return load_model(tiny_colour_model, threads=1)


def fresh_surface(model, tile, options):
    world._windows.clear()
    world_points._colourings.clear()
    return world_tiles.tile_surface(model, 7, tile, options=options)


def test_each_object_comes_from_the_model_its_pixel_names(model, still):
    """Where the map names model 1 the world is, to the bit, model 1's own scattered world, and
    where it names 0, model 0's: an object drawn from the wrong model changes the grid."""
    mixed = world.WorldOptions("scatter", models=(still,), models_map=SPLIT)
    alone = world.WorldOptions("scatter")
    FAR_LEFT, FAR_RIGHT = (-11, 1), (7, 1)
    assert objects(model, FAR_LEFT, mixed) == [0] and objects(model, FAR_RIGHT, mixed) == [1]
    left = world_tiles.tile_occupancy(model, 7, FAR_LEFT, options=mixed)
    right = world_tiles.tile_occupancy(model, 7, FAR_RIGHT, options=mixed)
    assert np.array_equal(left, world_tiles.tile_occupancy(model, 7, FAR_LEFT, options=alone))
    assert np.array_equal(right, world_tiles.tile_occupancy(still, 7, FAR_RIGHT, options=alone))
    assert not np.array_equal(right, world_tiles.tile_occupancy(model, 7, FAR_RIGHT, options=alone))
    everywhere_still = world.WorldOptions("scatter", models=(still,), models_map=world_maps.ModelMap.of([[1]]))
    assert np.array_equal(world_tiles.tile_occupancy(model, 7, FAR_LEFT, options=everywhere_still),
                          world_tiles.tile_occupancy(still, 7, FAR_LEFT, options=alone))


@pytest.fixture(scope="module")
def two_kinds(coloured):
    """A world of the plain tiny model and, where the map says 1, the coloured one (another
    size, another up axis, another voxel size)."""
    return world.WorldOptions("scatter", models=(coloured,), models_map=SPLIT)


def test_models_of_other_sizes_meet_without_a_seam_in_any_order(model, two_kinds):
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    pairs = (((-3, 1), (-2, 1), h0), ((8, 0), (9, 0), h0), ((8, 0), (8, 1), h1))
    assert objects(model, (-3, 1), two_kinds) == [0] and objects(model, (8, 0), two_kinds) == [1]
    for a, b, axis in pairs:
        grid_a, grid_b = (world_tiles.tile_occupancy(model, 7, t, options=two_kinds) for t in (a, b))
        assert np.array_equal(np.take(grid_a, -1, axis), np.take(grid_b, 0, axis))
        made = [world_tiles.tile_surface(model, 7, t, options=two_kinds) for t in (a, b)]
        mine = {tuple(v - np.eye(3)[axis] * tiling.stride[axis]): (tuple(n), tuple(c))
                for v, n, c in zip(made[0].vertices, made[0].normals, made[0].colours) if v[axis] == tiling.stride[axis]}
        theirs = {tuple(v): (tuple(n), tuple(c)) for v, n, c in zip(made[1].vertices, made[1].normals, made[1].colours)
                  if v[axis] == 0}
        assert len(mine) > 5 and mine == theirs
    tiles = [(9, 0), (8, 0), (-3, 1)]
    first = {t: fresh_surface(model, t, two_kinds) for t in tiles}
    world._windows.clear()
    world_points._colourings.clear()
    after = {t: world_tiles.tile_surface(model, 7, t, options=two_kinds) for t in reversed(tiles)}
    for t in tiles:
        assert all(np.array_equal(getattr(first[t], f), getattr(after[t], f))
                   for f in ("vertices", "faces", "normals", "colours"))


def test_each_object_is_coloured_by_its_own_model(model, coloured, two_kinds):
    """The plain model's objects are grey as the ground (it has no colour); the coloured model's
    show its colours; the coloured model's objects stand taller than the first model's grid."""
    FAR_LEFT, FAR_RIGHT = (-3, 1), (9, 1)  # cells are wider here: room for the coloured model's objects
    assert objects(model, FAR_LEFT, two_kinds) == [0] and objects(model, FAR_RIGHT, two_kinds) == [1]
    left = world_tiles.tile_surface(model, 7, FAR_LEFT, options=two_kinds)
    right = world_tiles.tile_surface(model, 7, FAR_RIGHT, options=two_kinds)
    grey = np.array(mesh.colour_bytes(np.array([world.GROUND_COLOUR], np.float32))[0])
    assert len(left.faces) and (left.colours == grey).all()
    assert (right.colours != grey).any(axis=1).sum() >= 20  # its object's surface (the rest is ground): coloured
    up = world.world_tiling(model).up
    cut = world.world_tiling(coloured)
    assert right.vertices[:, up].max() > world.world_tiling(model).stride[up]
    assert right.vertices[:, up].max() <= cut.stride[cut.up] + 0.5


@pytest.mark.parametrize("options, says", [
    (dict(arrange="scatter", models_map=world_maps.ModelMap.of([[0, 2]])), "names model 2, and the world has 2"),
    (dict(arrange="scatter"), "need a model map"),
    (dict(arrange="blend", models_map=SPLIT), "for a scatter world"),
])
def test_a_bad_model_map_is_refused_in_one_line(still, options, says):
    with pytest.raises(InputError, match=says):
        world.WorldOptions(models=(still,), **options)
    for bad in ([[0.5]], [[-1]], [[256]], [[np.nan]], np.zeros((2, 2, 2)), [[]]):
        with pytest.raises(InputError, match="a model map"):
            world_maps.ModelMap.of(bad)
    import io

    from PIL import Image

    coloured_image = io.BytesIO()
    Image.new("RGB", (2, 2)).save(coloured_image, "png")
    with pytest.raises(InputError, match="palette or greyscale image"):
        world_maps.parse_model_map(coloured_image.getvalue(), ".png", "map.png")
    with pytest.raises(InputError, match="not a readable image"):
        world_maps.parse_model_map(b"not a png", ".png", "map.png")


def test_world_writes_a_world_of_two_models_and_refuses_bad_model_maps(tiny_model, tiny_colour_model, tmp_path):
    """`sinrun world FIRST SECOND --models-map`: each tile as the library makes it; an image map is
    read as the array; a rerun with another second model is refused, naming it; bad maps in one line."""
    from click.testing import CliRunner
    from PIL import Image

    from sinshape.cli.main import cli
    from test_cli_train import assert_one_line_error

    np.save(tmp_path / "map.npy", np.array([[0], [1]]))
    Image.fromarray(np.array([[0, 1]], np.uint8)).save(tmp_path / "map.png")  # columns along the first axis
    args = ["world", str(tiny_model), str(tiny_colour_model), "--arrange", "scatter", "--seed", "7", "--tiles", "7,0",
            "--format", "npz", "--frame", "tile"]
    for name in ("map.npy", "map.png"):
        made = CliRunner().invoke(cli, [*args, "--models-map", str(tmp_path / name), "-o", str(tmp_path / name[-3:])])
        assert made.exit_code == 0, made.output
    assert world_maps.read_model_map(tmp_path / "map.png") == SPLIT
    grid = np.load(tmp_path / "npy" / "tile_7_0.npz")["occupancy"]
    options = world.WorldOptions("scatter", models=(load_model(tiny_colour_model),), models_map=SPLIT)
    assert np.array_equal(grid, world_tiles.tile_occupancy(load_model(tiny_model), 7, (7, 0), options=options))
    assert np.array_equal(grid, np.load(tmp_path / "png" / "tile_7_0.npz")["occupancy"])
    other = CliRunner().invoke(cli, ["world", str(tiny_model), str(tiny_model), *args[3:], "--models-map",
                                     str(tmp_path / "map.npy"), "-o", str(tmp_path / "npy")])
    assert_one_line_error(other, "records another job (models")
    np.save(tmp_path / "bad.npy", np.array([[0], [2]]))
    np.save(tmp_path / "half.npy", np.array([[0.5]]))
    for extra, says in ((["--models-map", str(tmp_path / "bad.npy")], "names model 2"),
                        (["--models-map", str(tmp_path / "half.npy")], "whole numbers"),
                        ([], "need a model map"),
                        (["--models-map", str(tmp_path / "map.npy"), "--arrange", "blend"], "for a scatter world"),
                        (["--models-map", str(tmp_path / "map.npy"), "--engine", "ray"], "engine local")):
        assert_one_line_error(CliRunner().invoke(cli, [*args, *extra, "-o", str(tmp_path / "bad")]), says)


def test_a_coarser_tile_and_a_block_of_two_models(model, coloured, tiny_model, tiny_colour_model, tmp_path):
    """At lod 1 each object is read at its own model's level as many from its finest, and the
    tiles still share their faces; a block of a two-model world is one mesh, coloured by its objects' model
    and grey on the ground."""
    import trimesh

    from sinshape.runtime import write
    from sinshape.runtime.request import SampleRequest

    coarse = world.WorldOptions("scatter", lod=1, models=(coloured,), models_map=SPLIT)
    h0 = world.world_tiling(model).horizontal[0]
    a, b = (world_tiles.tile_occupancy(model, 7, t, options=coarse) for t in ((7, 0), (8, 0)))
    assert np.array_equal(np.take(a, -1, h0), np.take(b, 0, h0))
    fine = world_tiles.tile_occupancy(model, 7, (7, 0), options=world.WorldOptions("scatter", models=(coloured,),
                                                                               models_map=SPLIT))
    assert a.shape != fine.shape
    request = SampleRequest(7, arrange="scatter", models=(str(tiny_colour_model),), models_map=SPLIT, frame="model")
    write.write_block(model, request, [(7, 0), (8, 0), (7, 1), (8, 1)], tmp_path / "block.ply")
    block = trimesh.load(tmp_path / "block.ply", process=False)
    painted = np.asarray(block.visual.vertex_colors)[:, :3]
    assert (painted != 128).any(axis=1).any() and (painted == 128).all(axis=1).any()


def test_a_tiles_memory_is_counted_at_its_widest_models_width(model, still, monkeypatch):
    """The memory check before a tile's grid counts the hidden vectors its points hold: the widest
    model's (hidden_width), not only the first's (the shipped and test models are all 32 wide, so the
    width is made to differ here)."""
    counted = []
    monkeypatch.setattr(world, "hidden_width", lambda first, options: first.manifest.hidden + 7 * len(options.models))
    monkeypatch.setattr(world, "check_world_scale", lambda tiling, scale, hidden, *rest: counted.append(hidden))
    world_tiles.tile_occupancy(model, 7, (0, 0), options=world.WorldOptions("scatter", models=(still,), models_map=SPLIT))
    assert counted == [model.manifest.hidden + 7]


def scaled(model, object_scale: float):
    """The model (in memory) with its objects' scale recorded as `sinrun orient --object-scale` records it."""
    import copy
    import dataclasses

    out = copy.copy(model)
    out.manifest = dataclasses.replace(model.manifest, object_scale=object_scale)
    return out


def test_an_objects_scale_sizes_it_against_the_first_models(model, still):
    """Model 1 recorded at object_scale 2 (against the first's 1) stands its objects twice as wide
    and twice as tall: identical samples (no noise) rise to twice the height they reach at 1, in a
    grid tall enough for them; the same scale recorded on the first model too changes nothing
    (the ratio counts); neighbours still agree on their shared face to the bit."""
    everywhere = world_maps.ModelMap.of([[1]])
    tiling = world.world_tiling(model)
    h0, h1, up = *tiling.horizontal, tiling.up
    E = np.asarray(still.manifest.sizes[-1]) - 1

    def top(options, tiles):
        """The highest occupied level (voxels) over tiles, and the objects seen there."""
        highest, found = 0.0, []
        for tile in tiles:
            grid = world.tile_grid(model, tiling, 1.0, options)
            occupied = world_tiles.tile_occupancy(model, 7, tile, options=options) > 0.5
            levels = np.flatnonzero(occupied.any(axis=(h0, h1)))  # the grid's axes are the model's
            highest = max(highest, grid.positions[up][levels.max()] if len(levels) else 0.0)
            found += world.objects_near(model, tiling, 7, tile, 0, options)
        return highest, found

    tiles = [(i, j) for i in range(4) for j in range(4)]
    same, alone = top(world.WorldOptions("scatter", models=(still,), models_map=everywhere, density=1.0), tiles)
    double, big = top(world.WorldOptions("scatter", models=(scaled(still, 2.0),), models_map=everywhere, density=1.0),
                      tiles)
    assert alone and big and {placed.factor for placed in alone} == {1.0} and {placed.factor for placed in big} == {2.0}
    assert all(sorted(placed.extent) == sorted(2.0 * E[[h0, h1]]) for placed in big)
    assert abs(double - 2 * same) <= 2, (same, double)
    both = world.WorldOptions("scatter", models=(scaled(still, 2.0),), models_map=everywhere)
    assert np.array_equal(world_tiles.tile_occupancy(scaled(model, 2.0), 7, (1, 1), options=both),
                          world_tiles.tile_occupancy(model, 7, (1, 1), options=world.WorldOptions(
                              "scatter", models=(still,), models_map=everywhere)))
    options = world.WorldOptions("scatter", models=(scaled(still, 2.0),), models_map=everywhere, density=1.0)
    assert {placed.factor for placed in world.objects_near(model, tiling, 7, (1, 1), 0, options)} == {2.0}
    grid = world_tiles.tile_occupancy(model, 7, (1, 1), options=options)  # a row at a time; points one by one:
    axes = np.meshgrid(*world.tile_grid(model, tiling, 1.0, options).positions, indexing="ij")
    points = np.stack([a.ravel() for a in axes], axis=1)
    assert np.array_equal(grid.ravel() > 0.5, world_points.point_field(model, 7, (1, 1), points, options)[0] > 0)
    for a, b, axis in (((0, 0), (1, 0), h0), ((1, 0), (1, 1), h1)):
        grid_a, grid_b = (world_tiles.tile_occupancy(model, 7, t, options=options) for t in (a, b))
        assert np.array_equal(np.take(grid_a, -1, axis), np.take(grid_b, 0, axis))
