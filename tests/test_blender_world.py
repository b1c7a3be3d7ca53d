"""The Blender extension's world object, in real Blender (bpy, headless):
its tiles are `sinrun world`'s, around the point it follows, those left
behind dropped; a changed setting remakes them; bad input is one reported
line and nothing half made; a saved file reopens and makes the same tiles.
Marked `blender`; skipped where bpy cannot be imported."""

import json
import subprocess
import sys
import threading

import numpy as np
import pytest
from click.testing import CliRunner

from test_blender import ROOT, pytestmark  # noqa: F401 (marked and skipped as the Blender tests are)


def add_world(model, **options):
    import bpy

    assert bpy.ops.sinshape.add_world(model=str(model), **options) == {"FINISHED"}
    return bpy.context.active_object


def sinrun_world(tmp_path, model, seed, tiles, frame) -> dict:
    """`sinrun world` for `tiles` (a list of (i, j)) in `frame`, with skirts as Blender's, read back:
    (i, j) -> (vertices, faces)."""
    from blender import convert
    from sinshape.cli.main import cli

    out = tmp_path / f"world_{frame}_{seed}"
    (i0, j0), (i1, j1) = np.min(tiles, axis=0), np.max(tiles, axis=0)
    result = CliRunner().invoke(cli, ["world", str(model), "--seed", str(seed), "--tiles", f"{i0}:{i1},{j0}:{j1}",
                                      "--frame", frame, "--skirt", "-o", str(out)])
    assert result.exit_code == 0, result.output
    return {tuple(tile): convert.ply_arrays((out / f"tile_{tile[0]}_{tile[1]}.ply").read_bytes()) for tile in tiles}


def tiles_of(obj) -> dict:
    from blender import worlds

    return worlds.tile_objects(obj)


def tile_at(model_path, point, obj) -> tuple:
    """The tile holding a point of Blender's space, in world object `obj`'s space."""
    from mathutils import Vector

    from blender import worlds
    from sinshape.runtime import world
    from sinshape.runtime.load import load_model

    model = load_model(model_path, threads=1)
    return worlds.centre_tile(model, world.world_tiling(model), obj.matrix_world.inverted() @ Vector(point))


def assert_tiles_are_the_command_lines(obj, tmp_path, model_path, seed) -> None:
    """Each tile object's mesh is runtime.world's tile mesh from the tile's
    corner (frame 'tile'), in the model's frame (Z up turned back); placed
    at the tile's corner, in the world's space it is `sinrun world`'s."""
    from blender import convert
    from sinshape.runtime import world, world_tiles
    from sinshape.runtime.load import load_model

    model = load_model(model_path, threads=1)
    tiles = tiles_of(obj)
    placed = sinrun_world(tmp_path, model_path, seed, list(tiles), "input")
    for tile, child in tiles.items():
        vertices, faces = convert.mesh_arrays(child.data)
        surface = world_tiles.tile_surface(model, seed, tile, options=world.WorldOptions(**convert.FIXED))
        expected, expected_faces = surface.vertices, surface.faces
        assert vertices.shape == expected.shape and np.array_equal(faces, expected_faces)
        assert np.abs(convert.to_model(vertices, "z") - world_tiles.placed(model, tile, expected, "tile")).max() < 1e-5
        in_world = vertices @ np.array(child.matrix_parent_inverse)[:3, :3].T + np.array(child.location)
        assert np.array_equal(faces, placed[tile][1])
        assert np.abs(convert.to_model(in_world, "z") - placed[tile][0]).max() < 1e-4


def test_a_world_fills_the_tiles_around_the_cursor_as_sinrun_world_makes_them(scene, tiny_model, tmp_path):
    scene.cursor.location = (30.0, -12.0, 0.0)
    obj = add_world(tiny_model, seed=4, radius=1)
    obj.location = (0, 0, 0)  # the world at the origin, the cursor where it was
    scene.view_layers[0].update()
    ci, cj = tile_at(tiny_model, (30.0, -12.0, 0.0), obj)
    assert (ci, cj) != (0, 0)
    assert set(tiles_of(obj)) == {(ci + di, cj + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)}
    assert sum(len(child.data.polygons) for child in tiles_of(obj).values()) > 0
    assert obj.sinshape_world.error == ""
    assert_tiles_are_the_command_lines(obj, tmp_path, tiny_model, 4)
    scene.cursor.location = (-30.0, 12.0, 0.0)  # the cursor moved: the scene's update moves the world on
    scene.view_layers[0].update()
    ci, cj = tile_at(tiny_model, (-30.0, 12.0, 0.0), obj)
    assert set(tiles_of(obj)) == {(ci + di, cj + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)}


def test_tiles_follow_an_object_and_those_left_behind_are_dropped(scene, tiny_model, tmp_path):
    import bpy

    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=2, radius=1)
    camera = bpy.data.objects.new("camera", None)
    scene.collection.objects.link(camera)
    obj.sinshape_world.follow = camera  # at the origin too: the same tiles, none made again
    before = {tile: child.as_pointer() for tile, child in tiles_of(obj).items()}
    centre = tile_at(tiny_model, (0, 0, 0), obj)
    while tile_at(tiny_model, tuple(camera.location), obj)[0] < centre[0] + 2:
        camera.location.x += 0.25
    bpy.context.view_layer.update()  # the depsgraph's update moves the world on
    moved = tile_at(tiny_model, tuple(camera.location), obj)
    after = tiles_of(obj)
    assert set(after) == {(moved[0] + di, moved[1] + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)}
    kept = set(before) & set(after)
    assert kept and all(after[tile].as_pointer() == before[tile] for tile in kept)  # not made again
    assert len([o for o in bpy.data.objects if o.parent == obj]) == 9  # the rest were dropped
    assert_tiles_are_the_command_lines(obj, tmp_path, tiny_model, 2)


def test_a_changed_seed_remakes_every_tile(scene, tiny_model, tmp_path):
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=1, radius=1)
    first = {tile: len(child.data.vertices) for tile, child in tiles_of(obj).items()}
    obj.sinshape_world.seed = 9  # background mode: made before the assignment returns
    assert {tile: child["sinshape_made"].split(":")[1] for tile, child in tiles_of(obj).items()} == \
        {tile: "9" for tile in first}
    assert_tiles_are_the_command_lines(obj, tmp_path, tiny_model, 9)


def in_a_side(model, vertices, faces) -> np.ndarray:
    """Which faces of a tile's mesh (Blender's axes) lie in one of its four sides: its skirt's."""
    from blender import worlds

    _, sides, _ = worlds.tile_sides(model, np.asarray(vertices, np.float32))
    return np.any([(side[faces] == end).all(axis=1) for side in sides for end in (1, 2)], axis=0)


def border_normals(obj, first, second, model_path) -> float:
    """The largest difference between the normals Blender shades two
    neighbouring tiles with at the surface's vertices they share (in the
    world's space; not their skirts' own, which hang inside the solid
    facing away from each other)."""
    from sinshape.runtime.load import load_model

    tiles = tiles_of(obj)
    model = load_model(model_path, threads=1)

    def on_surface(child) -> np.ndarray:  # the vertices of a face that lies in none of the tile's sides
        from blender import convert

        vertices, faces = convert.mesh_arrays(child.data)
        return np.isin(np.arange(len(vertices)), faces[~in_a_side(model, vertices, faces)])

    def shading(child):
        from blender import convert

        mesh = child.data
        corners = np.empty(len(mesh.loops), np.int32)
        mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
        normals = np.empty(len(mesh.loops) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        places = convert.mesh_vertices(mesh).astype(np.float64) + np.array(child.location)
        return places, corners, normals.reshape(-1, 3)

    (places_a, corners_a, normals_a), (places_b, corners_b, normals_b) = shading(tiles[first]), shading(tiles[second])
    surface_a, surface_b = on_surface(tiles[first]), on_surface(tiles[second])
    index = {tuple(np.round(p, 4)): i for i, p in enumerate(places_a) if surface_a[i]}
    worst, shared = 0.0, 0
    for j, place in enumerate(places_b):
        i = index.get(tuple(np.round(place, 4)))
        if i is not None and surface_b[j]:
            shared += 1
            worst = max(worst, np.abs(normals_a[corners_a == i] - normals_b[corners_b == j][:1]).max())
    assert shared > 5
    return worst


def test_tiles_shade_as_one_surface_across_their_borders(scene, tiny_model):
    """A border vertex's normal is summed over the tiles on both sides, as
    the joined surface's would be: no crease along every border."""
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=2, radius=1)
    centre = sorted(tiles_of(obj))[4]
    assert border_normals(obj, centre, (centre[0] + 1, centre[1]), tiny_model) < 0.01  # Blender keeps custom normals to ~1e-3
    assert border_normals(obj, centre, (centre[0], centre[1] + 1), tiny_model) < 0.01


def test_a_border_with_no_tile_beyond_shades_as_its_surface_not_as_its_skirt(scene, tiny_model):
    """Every tile hangs a skirt; on a border with no tile beyond it, a vertex
    shades by the surface's faces alone (angle-weighted, as Blender weighs
    them), not tilted out by the skirt hanging from it."""
    from blender import convert, worlds
    from sinshape.runtime.load import load_model

    model = load_model(tiny_model, threads=1)
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=2, radius=0)  # one tile: no border has a tile beyond it
    ((_, child),) = tiles_of(obj).items()
    vertices, faces = convert.mesh_arrays(child.data)
    vertices = vertices.astype(np.float64)
    _, sides, _ = worlds.tile_sides(model, vertices.astype(np.float32))
    in_side = in_a_side(model, vertices, faces)
    assert in_side.sum() > 10  # the premise: it has a skirt
    surface = faces[~in_side]
    expected = np.zeros_like(vertices)
    for k in range(3):
        a, b, c = (vertices[surface[:, (k + m) % 3]] for m in range(3))
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        angle = np.arccos(np.clip(np.einsum("ij,ij->i", b - a, c - a)
                                  / (np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - a, axis=1)), -1, 1))
        np.add.at(expected, surface[:, k], normal * angle[:, None])
    expected /= np.maximum(np.linalg.norm(expected, axis=1, keepdims=True), 1e-300)
    mesh = child.data
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    shaded = np.empty(len(mesh.loops) * 3, np.float32)
    mesh.corner_normals.foreach_get("vector", shaded)
    shaded = shaded.reshape(-1, 3)
    border = np.flatnonzero((sides[0] > 0) | (sides[1] > 0))
    border = border[np.isin(border, surface)]
    assert len(border) > 5
    worst = max(np.abs(shaded[corners == v] - expected[v]).max() for v in border)
    assert worst < 0.01, worst


def test_a_jump_keeps_the_old_tiles_until_the_new_ones_are_made(scene, tiny_model, monkeypatch):
    """Off the main thread, as with Blender's event loop: the tiles left
    behind stay shown while the new ones are made, and go when they are."""
    from blender import work

    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=2, radius=0)
    (old,) = tiles_of(obj)
    worker = work.Worker(synchronous=False)
    monkeypatch.setattr(work, "WORKER", worker)
    scene.cursor.location = (400.0, 0, 0)  # many tiles away
    scene.view_layers[0].update()
    assert old in tiles_of(obj)  # still shown while the new one is made
    for _ in range(500):
        if worker.poll() is None:
            break
        threading.Event().wait(0.02)
    (new,) = tiles_of(obj)
    assert new != old and new == tile_at(tiny_model, (400.0, 0, 0), obj)


def test_tiles_far_from_the_world_origin_say_where_float32_ends(scene, tiny_model):
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=2, radius=0)
    assert obj.sinshape_world.error == ""
    scene.cursor.location = (1e7, 0, 0)  # the world object stays at the origin
    scene.view_layers[0].update()
    (tile,) = tiles_of(obj)  # made all the same
    assert tile == tile_at(tiny_model, (1e7, 0, 0), obj)
    assert "32-bit locations" in obj.sinshape_world.error and "\n" not in obj.sinshape_world.error
    scene.cursor.location = (0, 0, 0)
    scene.view_layers[0].update()
    assert obj.sinshape_world.error == ""


@pytest.mark.parametrize("options, said", [({"model": "missing.onnx"}, "is missing"),
                                            ({"scale": 3000.0}, "scale")])
def test_bad_world_input_is_one_reported_line_and_nothing_half_made(scene, tiny_model, tmp_path, capfd,
                                                                    options, said):
    import bpy

    values = {"model": str(tiny_model), **options}
    if options.get("model"):
        values["model"] = str(tmp_path / options["model"])
    with pytest.raises(RuntimeError, match=said) as raised:
        bpy.ops.sinshape.add_world(**values)
    assert len(str(raised.value).strip().splitlines()) == 1
    assert len(bpy.data.objects) == 0 and len(bpy.data.meshes) == 0
    obj = add_world(tiny_model, seed=1, radius=0)
    before = {tile: len(child.data.vertices) for tile, child in tiles_of(obj).items()}
    for key, value in values.items():
        if key in options:
            setattr(obj.sinshape_world, key, value)
    assert said in obj.sinshape_world.error and "\n" not in obj.sinshape_world.error
    assert {tile: len(child.data.vertices) for tile, child in tiles_of(obj).items()} == before  # as it was
    assert "Traceback" not in capfd.readouterr().err


REOPEN = """
import json, sys
import numpy as np
sys.path.insert(0, {root!r})
import bpy, blender
from blender import convert, worlds
blender.register()
bpy.ops.wm.open_mainfile(filepath={blend!r})
(obj,) = [o for o in bpy.data.objects if o.sinshape_world.active]
saved = {{t: convert.mesh_arrays(c.data) for t, c in worlds.tile_objects(obj).items()}}
for other in bpy.data.objects:
    other.select_set(other == obj)
bpy.context.view_layer.objects.active = obj
bpy.ops.sinshape.regenerate()
made = {{t: convert.mesh_arrays(c.data) for t, c in worlds.tile_objects(obj).items()}}
print("RESULT" + json.dumps(dict(error=obj.sinshape_world.error, tiles=sorted(map(list, made)),
                                 saved=sorted(map(list, saved)),
                                 same=all(np.array_equal(saved[t][0], made[t][0]) and np.array_equal(saved[t][1], made[t][1])
                                          for t in made))))
"""


def test_a_saved_world_reopens_and_makes_the_same_tiles(scene, tiny_model, tmp_path):
    import bpy

    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=6, radius=1)
    tiles = sorted(map(list, tiles_of(obj)))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "world.blend"))
    script = REOPEN.format(root=str(ROOT), blend=str(tmp_path / "world.blend"))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    result = json.loads(done.stdout.split("RESULT", 1)[1])
    assert result == dict(error="", tiles=tiles, saved=tiles, same=True)


def test_far_tiles_are_made_coarser_with_a_skirt_and_a_scattered_world_is_the_runtimes(scene, tiny_model):
    """Past the fine radius a tile is a level coarser per tile (world_tiles.tile_surface at that lod: the
    runtime's mesh and its skirt); a wider fine radius remakes those at full detail."""
    from blender import convert
    from sinshape.runtime import world, world_tiles
    from sinshape.runtime.load import load_model

    model = load_model(tiny_model, threads=1)
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=3, radius=2)
    obj.sinshape_world.arrange = "scatter"  # background mode: every tile made again before this returns
    ci, cj = tile_at(tiny_model, (0, 0, 0), obj)
    lods = {tile: int(child["sinshape_made"].rsplit(":", 1)[1]) for tile, child in tiles_of(obj).items()}
    assert lods == {(ci + di, cj + dj): min(1, max(0, max(abs(di), abs(dj)) - 1)) for di in range(-2, 3) for dj in range(-2, 3)}
    far = (ci + 2, cj)
    surface = world_tiles.tile_surface(model, 3, far, options=world.WorldOptions("scatter", lod=1))
    vertices, faces = convert.mesh_arrays(tiles_of(obj)[far].data)
    assert len(faces) > len(world_tiles.tile_mesh(model, 3, far, options=world.WorldOptions("scatter", lod=1))[1])
    assert np.array_equal(faces, surface.faces)
    assert np.abs(convert.to_model(vertices, "z") - world_tiles.placed(model, far, surface.vertices, "tile")).max() < 1e-5
    obj.sinshape_world.fine = 2
    assert {int(child["sinshape_made"].rsplit(":", 1)[1]) for child in tiles_of(obj).values()} == {0}


def test_a_world_of_two_models_on_a_model_map_is_the_runtimes(scene, tmp_path):
    """Temples and tower ruins where a 2 x 2 checkerboard map says: each tile
    world_tiles.tile_surface's with the same WorldOptions, not the temples' world
    alone; the second model changed to the first, the temples' world again."""
    import bpy

    from blender import convert
    from sinshape import models
    from sinshape.runtime import world, world_maps, world_tiles
    from sinshape.runtime.load import load_model

    first, second = (load_model(models.find(name), threads=1) for name in ("acropolis", "towerruins"))
    checkerboard = [[0, 1], [1, 0]]
    np.save(tmp_path / "map.npy", np.array(checkerboard))
    options = world.WorldOptions("scatter", models=(second,), models_map=world_maps.ModelMap.of(checkerboard),
                                 **convert.FIXED)
    scene.cursor.location = (0, 0, 0)
    obj = add_world("acropolis", seed=6, radius=1)  # scattered, as the temple records
    alone = {tile: convert.mesh_arrays(child.data) for tile, child in tiles_of(obj).items()}
    tiling = world.world_tiling(first)
    assert {found.model for tile in alone for found in world.objects_near(first, tiling, 6, tile, 0, options)} \
        == {0, 1}  # the premise: these tiles hold objects of both models
    assert bpy.ops.sinshape.world_model_add() == {"FINISHED"}
    obj.sinshape_world.models[0].model = "towerruins"
    obj.sinshape_world.models_map = str(tmp_path / "map.npy")  # background mode: every tile made again
    assert obj.sinshape_world.error == ""
    tiles = tiles_of(obj)
    assert set(tiles) == set(alone)
    changed = 0
    for tile, child in tiles.items():
        vertices, faces = convert.mesh_arrays(child.data)
        surface = world_tiles.tile_surface(first, 6, tile, options=options)
        assert np.array_equal(faces, surface.faces)
        assert np.abs(convert.to_model(vertices, first.manifest.up)
                      - world_tiles.placed(first, tile, surface.vertices, "tile")).max() < 1e-5
        changed += not (np.array_equal(vertices, alone[tile][0]) and np.array_equal(faces, alone[tile][1]))
    assert changed
    obj.sinshape_world.models[0].model = "acropolis"  # its SHA-256 is the tiles' key: all made again
    for tile, child in tiles_of(obj).items():
        vertices, faces = convert.mesh_arrays(child.data)
        assert np.array_equal(vertices, alone[tile][0]) and np.array_equal(faces, alone[tile][1])


def test_a_scattered_worlds_density_and_spacing_are_the_runtimes(scene, tiny_model):
    """Density and Spacing make the tiles runtime.world makes with them; a blended world leaves them be."""
    from blender import convert
    from sinshape.runtime import world, world_tiles
    from sinshape.runtime.load import load_model

    model = load_model(tiny_model, threads=1)
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=4, radius=1)
    obj.sinshape_world.density, obj.sinshape_world.spacing = 0.9, 4.0  # blended: no change, no error
    assert obj.sinshape_world.error == ""
    obj.sinshape_world.arrange = "scatter"
    assert obj.sinshape_world.error == ""
    options = world.WorldOptions("scatter", density=0.9, spacing=4.0, **convert.FIXED)
    assert any(world.objects_near(model, world.world_tiling(model), 4, tile, 0, options) for tile in tiles_of(obj))
    for tile, child in tiles_of(obj).items():
        vertices, faces = convert.mesh_arrays(child.data)
        surface = world_tiles.tile_surface(model, 4, tile, options=options)
        assert np.array_equal(faces, surface.faces)
        assert np.abs(convert.to_model(vertices, model.manifest.up)
                      - world_tiles.placed(model, tile, surface.vertices, "tile")).max() < 1e-5


def test_a_painted_height_map_shapes_the_world_as_sinrun_worlds_map_does(scene, tiny_model, tmp_path):
    """A greyscale .png height map: each tile world_tiles.tile_surface's with read_height_map's heights
    (white RELIEF times the model's height, or the Relief given), not the flat world's; the Relief
    changed, the tiles made again from it."""
    from PIL import Image

    from blender import convert
    from sinshape.runtime import world, world_maps, world_tiles
    from sinshape.runtime.load import load_model

    model = load_model(tiny_model, threads=1)
    Image.fromarray(np.array([[0, 255], [128, 60]], np.uint8)).save(tmp_path / "hills.png")
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=4, radius=1)
    flat = {tile: convert.mesh_arrays(child.data) for tile, child in tiles_of(obj).items()}
    for relief in (0.0, 30.0):
        obj.sinshape_world.relief = relief
        obj.sinshape_world.heights = str(tmp_path / "hills.png")  # background mode: every tile made again
        assert obj.sinshape_world.error == ""
        heights = world_maps.read_height_map(tmp_path / "hills.png", model, relief or None)
        options = world.WorldOptions("blend", heights=heights, **convert.FIXED)
        tiles = tiles_of(obj)
        assert set(tiles) == set(flat)
        for tile, child in tiles.items():
            vertices, faces = convert.mesh_arrays(child.data)
            surface = world_tiles.tile_surface(model, 4, tile, options=options)
            assert np.array_equal(faces, surface.faces)
            assert np.abs(convert.to_model(vertices, model.manifest.up)
                          - world_tiles.placed(model, tile, surface.vertices, "tile")).max() < 1e-5
        assert any(len(faces) != len(flat[tile][1]) or not np.array_equal(vertices, flat[tile][0])
                   for tile, (vertices, faces) in ((t, convert.mesh_arrays(c.data)) for t, c in tiles.items()))
        obj.sinshape_world.heights = ""


@pytest.mark.parametrize("arrange, pixels, said", [
    ("blend", [[0, 1]], "it is for a scatter world"),
    ("scatter", None, "several models need a model map"),
    ("scatter", [[0, 2]], "names model 2, and the world has 2"),
    ("scatter", "missing.npy", "missing.npy is missing"),
    ("scatter", "broken.png", "not a readable image")])
def test_a_refused_model_map_is_one_reported_line_and_the_tiles_stay(scene, tiny_model, tmp_path, capfd,
                                                                     arrange, pixels, said):
    """The command line's refusals, the runtime's own lines: a map for a blend
    world, several models without one, a pixel naming a model the world
    lacks, a map file that is missing or no image. Put right, the error goes."""
    import bpy

    from blender import live

    (tmp_path / "broken.png").write_bytes(b"not an image")
    if isinstance(pixels, list):
        np.save(tmp_path / "map.npy", np.array(pixels))
    scene.cursor.location = (0, 0, 0)
    obj = add_world(tiny_model, seed=1, radius=0)
    before = {tile: len(child.data.vertices) for tile, child in tiles_of(obj).items()}
    settings = obj.sinshape_world
    own = settings.arrange
    with live.suspended():
        settings.arrange = arrange
        settings.models.add().model = str(tiny_model)
        settings.models_map = "" if pixels is None else str(tmp_path / ("map.npy" if isinstance(pixels, list) else pixels))
    with pytest.raises(RuntimeError, match=said) as raised:
        bpy.ops.sinshape.regenerate()
    assert len(str(raised.value).strip().splitlines()) == 1
    assert said in settings.error and "\n" not in settings.error
    assert {tile: len(child.data.vertices) for tile, child in tiles_of(obj).items()} == before
    assert "Traceback" not in capfd.readouterr().err
    with live.suspended():
        settings.arrange, settings.models_map = own, ""
    assert bpy.ops.sinshape.world_model_remove(index=0) == {"FINISHED"}  # the world as it was made
    assert settings.error == "" and len(settings.models) == 0
