"""The Blender extension, in real Blender (bpy, headless): registration,
each operator, a setting's change, meshes equal to `sinrun sample`'s, and
bad input reported Blender's way. Marked `blender`; skipped where bpy
cannot be imported (it exists for Python 3.11 only: the blender extra).
Saving, reopening and the built zip: tests/test_blender_files.py."""

import importlib.util
import threading
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
HAS_BPY = importlib.util.find_spec("bpy") is not None
pytestmark = [pytest.mark.blender,
              pytest.mark.skipif(not HAS_BPY, reason="needs bpy, Blender as a Python module: "
                                                     "pip install 'sinshape[blender]' (Python 3.11)")]


def add(model, **options):
    import bpy

    assert bpy.ops.sinshape.add_sample(model=str(model), **options) == {"FINISHED"}
    return bpy.context.active_object


def model_frame(obj, up: str) -> tuple:
    """An object's mesh in the model's frame: (vertices, faces)."""
    from blender import convert

    vertices, faces = convert.mesh_arrays(obj.data)
    return convert.to_model(vertices, up), faces


def sinrun_sample(tmp_path, *args) -> tuple:
    """`sinrun sample ARGS` to a .ply, read back: (vertices, faces)."""
    from blender import convert
    from sinshape.cli.main import cli

    out = tmp_path / f"cli{len(list(tmp_path.glob('cli*.ply')))}.ply"
    result = CliRunner().invoke(cli, ["sample", *map(str, args), "-o", str(out)])
    assert result.exit_code == 0, result.output
    return convert.ply_arrays(out.read_bytes())


def assert_same_mesh(obj, up, expected) -> None:
    vertices, faces = model_frame(obj, up)
    assert vertices.shape == expected[0].shape and faces.shape == expected[1].shape
    assert np.array_equal(faces, expected[1])
    assert np.abs(vertices - expected[0]).max() < 1e-5


def test_register_and_unregister_leave_blender_as_it_was(addon):
    import bpy

    def registered():
        return (hasattr(bpy.types.Object, "sinshape"), hasattr(bpy.types, "SINSHAPE_OT_add_sample"),
                addon.moved in bpy.app.handlers.depsgraph_update_post)

    assert registered() == (True, True, True)
    addon.unregister()
    try:
        assert registered() == (False, False, False)
    finally:
        addon.register()
    assert registered() == (True, True, True)


def test_added_sample_is_the_command_lines_and_a_changed_seed_remakes_it(scene, tiny_model, tmp_path):
    obj = add(tiny_model, seed=3, size=(1.5, 1, 1))
    assert obj.sinshape.active and obj.sinshape.model_sha256  # a file is recorded by its SHA-256
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 3, "--size", "1.5,1,1"))
    obj.sinshape.seed = 4  # background mode: the update makes the mesh before it returns
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 4, "--size", "1.5,1,1"))
    obj.sinshape.smooth = 2
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 4, "--size", "1.5,1,1",
                                             "--smooth", 2))
    assert obj.sinshape.error == ""


@pytest.mark.parametrize("name", ["towerruins", "terrain", "acropolis"])
def test_shipped_models_come_as_the_command_line_makes_them_turned_to_z_up(scene, tmp_path, name):
    from sinshape import models
    from sinshape.runtime.load import load_model

    up = load_model(models.find(name), threads=1).manifest.up
    obj = add(name, seed=5, size=(1, 1.25, 1))  # Blender's y: the model's -z where y is up
    size = "1,1,1.25" if up == "y" else "1,1.25,1"
    assert_same_mesh(obj, up, sinrun_sample(tmp_path, name, "--seed", 5, "--size", size))
    height = np.ptp(np.array(obj.bound_box)[:, 2])
    assert np.isclose(height, np.ptp(model_frame(obj, up)[0][:, "xyz".index(up)]), rtol=1e-6)  # up is Blender's z


def test_a_finer_scale_is_the_command_lines_too(scene, tmp_path):
    obj = add("terrain", seed=2, scale=4)
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, "terrain", "--seed", 2, "--scale", 4))


def test_a_kept_box_is_the_command_lines_keep(scene, tiny_model, tmp_path):
    import bpy

    obj = add(tiny_model, seed=7)
    whole = np.array(obj.bound_box)
    assert bpy.ops.sinshape.keep_box_add() == {"FINISHED"}
    settings = obj.sinshape
    assert settings.edit == "KEEP" and settings.keep_seed == 8 and settings.keep_box is not None
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 7, "--keep", settings.keep_part))
    # The box's bounds, in the model's frame, are the part: the lower half along x.
    seed, low, high = settings.keep_part.split(":")
    low, high = (np.array([float(v) for v in corner.split(",")]) for corner in (low, high))
    assert seed == "8" and np.isclose(high[0], (whole[:, 0].min() + whole[:, 0].max()) / 2, atol=1e-5)
    # Moving the box regenerates the sample with the part it now holds.
    before = settings.keep_part
    settings.keep_box.location.x += 0.2 * (whole[:, 0].max() - whole[:, 0].min())
    bpy.context.view_layer.update()
    assert settings.keep_part != before
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 7, "--keep", settings.keep_part))


def test_a_keep_box_works_wherever_the_sample_stands(scene, tiny_model, tmp_path):
    """Samples are added at the 3D cursor: the box, made in the sample's
    space, keeps the same part anywhere; one the sample refuses leaves
    nothing behind."""
    import bpy

    parts = []
    for place in ((0, 0, 0), (20, -3, 2)):
        bpy.context.scene.cursor.location = place
        obj = add(tiny_model, seed=7)
        assert bpy.ops.sinshape.keep_box_add() == {"FINISHED"}
        parts.append(np.array([float(v) for corner in obj.sinshape.keep_part.split(":")[1:]
                               for v in corner.split(",")]))
    assert np.abs(parts[0] - parts[1]).max() < 1e-4
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 7, "--keep", obj.sinshape.keep_part))
    moved = tmp_path / "moved.onnx"
    moved.write_bytes(tiny_model.read_bytes())
    lost = add(moved, seed=7)
    moved.unlink()  # the sample cannot be made again
    objects = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="is missing"):
        bpy.ops.sinshape.keep_box_add()
    assert len(bpy.data.objects) == objects and lost.sinshape.edit == "NONE" and lost.sinshape.keep_box is None


def test_a_model_in_voxel_units_comes_in_a_sensible_size(scene, tiny_model, tmp_path):
    """A model trained from an .h5 pyramid has voxels for units: its object
    is scaled to about the shipped models' size, its mesh left the command line's."""
    obj = add(tiny_model, seed=3)  # tiny_model is trained on a pyramid: 19 voxels long
    assert 4 < max(obj.dimensions) < 8
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 3))
    assert tuple(add("terrain", seed=3).scale) == (1.0, 1.0, 1.0)  # a mesh's own units stay


def test_leaving_edit_mode_makes_the_change_refused_in_it(scene, tiny_model, tmp_path):
    import bpy

    obj = add(tiny_model, seed=3)
    bpy.ops.object.mode_set(mode="EDIT")
    obj.sinshape.seed = 5
    assert "edit mode" in obj.sinshape.error
    bpy.ops.object.mode_set(mode="OBJECT")
    assert obj.sinshape.error == ""
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 5))


def test_a_linked_duplicate_reseeded_leaves_the_original_as_it_was(scene, tiny_model, tmp_path):
    import bpy

    obj = add(tiny_model, seed=3)
    bpy.ops.object.duplicate(linked=True)  # Alt+D: the same mesh
    duplicate = bpy.context.active_object
    assert duplicate != obj and duplicate.data == obj.data
    duplicate.sinshape.seed = 9
    assert duplicate.data != obj.data and obj.sinshape.seed == 3
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 3))
    assert_same_mesh(duplicate, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 9))


def test_a_shipped_model_is_pinned_to_its_sha256(scene, addon):
    """An update of the extension may replace a shipped model: an object
    made from another version says so, and keeps its mesh, until the model
    is chosen again."""
    import hashlib

    import bpy

    from sinshape import models

    obj = add("terrain", seed=3)
    assert obj.sinshape.model_sha256 == hashlib.sha256(models.find("terrain").read_bytes()).hexdigest()
    obj.sinshape.model_sha256 = "0" * 64  # as saved by an extension that shipped another terrain
    before = model_frame(obj, "z")
    with pytest.raises(RuntimeError, match="the shipped model terrain has changed"):
        obj.sinshape.seed = 4
        bpy.ops.sinshape.regenerate()
    assert all(np.array_equal(a, b) for a, b in zip(model_frame(obj, "z"), before))
    obj.sinshape.error = ""
    addon.live.check_models()  # what opening the file does
    assert "the shipped model terrain has changed" in obj.sinshape.error
    obj.sinshape.model = "terrain"  # chosen again: taken as it is now
    assert obj.sinshape.error == "" and obj.sinshape.model_sha256 != "0" * 64
    assert not all(np.array_equal(a, b) for a, b in zip(model_frame(obj, "z"), before))  # seed 4 now


def test_grow_maps_blenders_axes_to_the_models(scene, tmp_path):
    obj = add("towerruins", seed=3)  # y up: Blender (x, y, z) is the model's (x, -z, y)
    with_settings(obj, grow=(1.0, 1.5, 1.0), anchor=(0.0, 1.0, 0.0), edit="GROW")
    assert_same_mesh(obj, "y", sinrun_sample(tmp_path, "towerruins", "--seed", 3, "--grow", "1,1,1.5",
                                             "--anchor", "0,0,0"))


def with_settings(obj, **values):
    """Set several settings, then regenerate once."""
    from blender import live

    with live.suspended():
        for key, value in values.items():
            setattr(obj.sinshape, key, value)
    live.regenerate(obj)


def test_an_edited_layout_is_the_command_lines_layout(scene, tiny_model, tmp_path):
    import bpy

    from blender import convert
    from sinshape.runtime import layout, layout_files
    from sinshape.runtime.load import load_model

    obj = add(tiny_model, seed=3)
    assert bpy.ops.sinshape.layout_show() == {"FINISHED"}
    cubes = obj.sinshape.layout_object
    model = load_model(tiny_model, threads=1)
    own = layout.layout(model, 3)
    assert len(cubes.data.polygons) == 6 * own.sum()  # one cube per full cell
    # Edit with ordinary tools: delete the cubes of the top half along x.
    vertices = convert.mesh_vertices(cubes.data)
    bpy.context.view_layer.objects.active = cubes
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="DESELECT")
    bpy.ops.object.mode_set(mode="OBJECT")
    middle = (vertices[:, 0].min() + vertices[:, 0].max()) / 2
    cubes.data.vertices.foreach_set("select", vertices[:, 0] > middle)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_linked()
    bpy.ops.mesh.delete(type="VERT")
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.sinshape.layout_apply() == {"FINISHED"}
    applied = convert.layout_from_text(obj.sinshape.layout_shape, obj.sinshape.layout_bits).grid()
    corner, spacing, _ = layout.cells(model.manifest)
    kept = corner[0] + (np.arange(own.shape[0]) + 1) * spacing[0] <= middle + 1e-6
    assert np.array_equal(applied, own & kept[:, None, None])  # the cells whose cubes are left
    layout_files.write_layout(applied, tmp_path / "edited.vox")
    assert_same_mesh(obj, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 3, "--layout", tmp_path / "edited.vox"))


def test_cubes_moved_copied_and_extruded_read_back_as_cells(tiny_model):
    from blender import convert
    from sinshape.runtime import layout
    from sinshape.runtime.load import load_model

    manifest = load_model(tiny_model, threads=1).manifest
    corner, spacing, shape = layout.cells(manifest)
    grid = np.zeros(shape, bool)
    grid[1, 1, 1] = grid[3, 2, 1] = True
    vertices, quads = convert.layout_cubes(grid, manifest, (1, 1, 1))
    faces = (quads.ravel(), np.arange(0, quads.size, 4))  # as Blender keeps them: corners, each face's first
    assert np.array_equal(convert.cubes_layout(vertices, *faces, manifest, (1, 1, 1)), grid)
    moved = vertices.copy()
    moved[:8] += spacing * np.array([2.3, 0.2, 0])  # nudged off the grid: the nearest cell
    moved[8:, 2] = np.where(moved[8:, 2] > moved[8:, 2].min(), moved[8:, 2] + 2 * spacing[2], moved[8:, 2])  # extruded up 2
    expected = np.zeros(shape, bool)
    expected[3, 1, 1] = True
    expected[3, 2, 1:4] = True
    assert np.array_equal(convert.cubes_layout(moved, *faces, manifest, (1, 1, 1)), expected)


def test_welded_cubes_give_the_layout_they_show(scene, tiny_model):
    """Merge by Distance welds the cubes into one piece and drops the face
    between two of them; Limited Dissolve joins faces into n-gons: the
    cells read back are the cubes', a hollow kept hollow."""
    import bpy

    from blender import convert
    from sinshape.runtime import layout
    from sinshape.runtime.load import load_model

    obj = add(tiny_model, seed=3)
    own = layout.layout(load_model(tiny_model, threads=1), 3)
    assert bpy.ops.sinshape.layout_show() == {"FINISHED"}
    cubes = obj.sinshape.layout_object
    bpy.context.view_layer.objects.active = cubes
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.remove_doubles()
    bpy.ops.mesh.dissolve_limited()
    bpy.ops.object.mode_set(mode="OBJECT")
    assert len(cubes.data.vertices) < 8 * own.sum() / 2 and len(cubes.data.polygons) < 6 * own.sum()  # welded
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.sinshape.layout_apply() == {"FINISHED"}
    assert np.array_equal(convert.layout_from_text(obj.sinshape.layout_shape, obj.sinshape.layout_bits).grid(), own)
    manifest = load_model(tiny_model, threads=1).manifest
    block = np.zeros(layout.cells(manifest)[2], bool)
    block[1:4, 1:4, 1:4] = True
    for grid in (block, block & ~(np.indices(block.shape) == 2).all(axis=0)):  # full, and hollow at its centre
        mesh = bpy.data.meshes.new("block")
        convert.fill_mesh(mesh, *convert.layout_cubes(grid, manifest, (1, 1, 1)))
        welded = bpy.data.objects.new("block", mesh)
        bpy.context.scene.collection.objects.link(welded)
        bpy.context.view_layer.objects.active = welded
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.remove_doubles()
        bpy.ops.object.mode_set(mode="OBJECT")
        read = convert.cubes_layout(convert.mesh_vertices(mesh), *convert.mesh_faces(mesh), manifest, (1, 1, 1))
        assert np.array_equal(read, grid)


def test_variations_are_objects_of_each_seed_in_a_collection(scene, tiny_model, tmp_path):
    import bpy

    obj = add(tiny_model, seed=3, smooth=1)
    assert bpy.ops.sinshape.variations(count=3, first_seed=10, arrange="GRID") == {"FINISHED"}
    (collection,) = [c for c in bpy.data.collections if c.name == f"{obj.name} variations"]
    made = sorted(collection.objects, key=lambda o: o.sinshape.seed)
    assert [o.sinshape.seed for o in made] == [10, 11, 12] and all(o.sinshape.smooth == 1 for o in made)
    for other in made:
        assert_same_mesh(other, "z", sinrun_sample(tmp_path, tiny_model, "--seed", other.sinshape.seed,
                                                   "--smooth", 1))
    assert len({tuple(np.round(o.location, 4)) for o in made} | {tuple(np.round(obj.location, 4))}) == 4  # a grid
    other = made[0]
    other.sinshape.seed = 4  # each is a live sample of its own
    assert_same_mesh(other, "z", sinrun_sample(tmp_path, tiny_model, "--seed", 4, "--smooth", 1))


def test_a_newer_request_supersedes_one_still_running(addon):
    """Off the main thread (as with Blender's event loop): the running job
    stops at its next progress step, a waiting one is replaced, and only the
    newest result is applied, by the timer function on the main thread."""
    from blender import work

    worker = work.Worker(synchronous=False)
    started, release, applied = threading.Event(), threading.Event(), []

    def slow(job):
        started.set()
        release.wait(10)
        job.progress(1, 2)  # raises Superseded: a newer request came
        job.deliver("first")

    def job(compute, label):
        return work.Job("obj", label, compute, applied.append, lambda error: applied.append(error))

    worker.submit(job(slow, "first"))
    assert started.wait(10)
    worker.submit(job(lambda j: j.deliver("second"), "second"))
    worker.submit(job(lambda j: j.deliver("third"), "third"))
    release.set()
    for _ in range(200):
        if worker.poll() is None:
            break
        threading.Event().wait(0.02)
    assert applied == ["third"]


def test_an_input_error_off_the_main_thread_goes_to_the_failure_callback(addon):
    from blender import work
    from sinshape.core.errors import InputError

    worker, failed = work.Worker(synchronous=False), []

    def bad(job):
        raise InputError("scale must be a positive number, got 0", "scale")

    worker.submit(work.Job("obj", "bad", bad, failed.append, failed.append))
    for _ in range(200):
        if worker.poll() is None:
            break
        threading.Event().wait(0.02)
    assert [str(e) for e in failed] == ["scale must be a positive number, got 0"]


def corrupt_copy(model: Path, tmp_path: Path) -> Path:
    data = bytearray(model.read_bytes())
    data[len(data) // 2] ^= 0xFF
    out = tmp_path / "corrupt.onnx"
    out.write_bytes(bytes(data))
    return out


def foreign_onnx(tmp_path: Path) -> Path:
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "foreign",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    out = tmp_path / "foreign.onnx"
    onnx.save(helper.make_model(graph), out)
    return out


BAD_INPUTS = {
    "missing": (lambda m, t: t / "missing.onnx", {}, "is missing"),
    "corrupt": (corrupt_copy, {}, "corrupt model"),
    "foreign": (lambda m, t: foreign_onnx(t), {}, "not a sinshape model"),
    "memory": (lambda m, t: m, {"scale": 3000.0}, "needs about"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_is_one_reported_line_and_nothing_half_made(scene, tiny_model, tmp_path, capfd, case):
    import bpy

    make, options, said = BAD_INPUTS[case]
    path = make(tiny_model, tmp_path)
    with pytest.raises(RuntimeError, match=said) as raised:  # bpy.ops raises an operator's ERROR report
        bpy.ops.sinshape.add_sample(model=str(path), **options)
    assert len(str(raised.value).strip().splitlines()) == 1
    assert len(bpy.data.objects) == 0 and len(bpy.data.meshes) == 0  # nothing half made
    # On a sample: the setting's change leaves the mesh as it was, with the error on the object.
    obj = add(tiny_model, seed=1)
    before = model_frame(obj, "z")
    with_error = dict(model=str(path)) if not options else options
    for key, value in with_error.items():
        setattr(obj.sinshape, key, value)
    assert said in obj.sinshape.error and "\n" not in obj.sinshape.error
    assert all(np.array_equal(a, b) for a, b in zip(model_frame(obj, "z"), before))
    with pytest.raises(RuntimeError, match=said):
        bpy.ops.sinshape.regenerate()
    assert "Traceback" not in capfd.readouterr().err


def test_a_scale_whose_mesh_would_not_fit_is_refused_in_one_line_before_any_work(scene, tiny_model, monkeypatch,
                                                                                   capfd):
    """The memory check counts the mesh, and the add-on's own copies of it:
    refused before anything is made, on the object and as a report."""
    import bpy

    from sinshape.core import budget

    obj = add(tiny_model, seed=1)
    before = model_frame(obj, "z")
    monkeypatch.setattr(budget, "available_memory", lambda: 256 << 20)
    objects = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match=r"with a mesh of about [\d,]+ faces needs about"):
        bpy.ops.sinshape.add_sample(model=str(tiny_model), scale=40)
    assert len(bpy.data.objects) == objects
    obj.sinshape.scale = 40
    assert "with a mesh of about" in obj.sinshape.error and "\n" not in obj.sinshape.error
    assert all(np.array_equal(a, b) for a, b in zip(model_frame(obj, "z"), before))
    assert "Traceback" not in capfd.readouterr().err


def test_running_out_of_memory_all_the_same_is_one_line_on_the_object(scene, tiny_model, monkeypatch, capfd):
    from blender import live

    obj = add(tiny_model, seed=1)

    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(live.mesh, "extract", exhausted)
    obj.sinshape.seed = 2
    assert "ran out of memory" in obj.sinshape.error and "\n" not in obj.sinshape.error
    assert "Traceback" not in capfd.readouterr().err


def test_arrays_make_a_valid_mesh_in_bulk_and_come_back_the_same(addon):
    import bpy

    from blender import convert

    mesh = bpy.data.meshes.new("arrays")
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    convert.fill_mesh(mesh, vertices, triangles, smooth_shading=True)
    assert not mesh.validate()  # nothing to correct
    assert len(mesh.edges) == 6 and all(p.use_smooth for p in mesh.polygons)
    back = convert.mesh_arrays(mesh)
    assert np.array_equal(back[0], vertices.astype(np.float32)) and np.array_equal(back[1], triangles)
    blenders = {tuple(sorted(e.vertices)) for e in mesh.edges}
    convert.fill_mesh(mesh, vertices, triangles, edges=convert.triangle_edges(triangles))  # edges made in numpy
    assert not mesh.validate() and {tuple(e.vertices) for e in mesh.edges} == blenders
    assert not any(p.use_smooth for p in mesh.polygons)
    convert.fill_mesh(mesh, convert.CUBE_CORNERS, convert.CUBE_FACES)  # quads, flat
    assert not mesh.validate() and len(mesh.polygons) == 6 and not any(p.use_smooth for p in mesh.polygons)
    assert all(np.dot(p.normal, np.array(p.center) - 0.5) > 0 for p in mesh.polygons)  # every face looks out
    convert.fill_mesh(mesh, np.zeros((0, 3)), np.zeros((0, 3), int))
    assert len(mesh.vertices) == len(mesh.polygons) == 0
    bpy.data.meshes.remove(mesh)


def test_blenders_axes_turn_into_the_models_and_back(addon):
    from blender import convert

    points = np.random.default_rng(0).random((4, 3))
    for up in ("y", "z"):
        assert np.array_equal(convert.to_model(convert.to_blender(points, up), up), points)
    assert np.array_equal(convert.to_blender([[1.0, 2.0, 3.0]], "y"), [[1.0, -3.0, 2.0]])  # y up -> Blender's z
    assert convert.factors_to_model((2, 3, 4), "y") == (2.0, 4.0, 3.0)
    assert convert.fractions_to_model((0.1, 0.25, 0.5), "y") == (0.1, 0.5, 0.75)  # Blender's y is the model's -z
    assert convert.fractions_to_model((0.1, 0.25, 0.5), "z") == (0.1, 0.25, 0.5)


def test_export_asset_writes_the_samples_asset_and_adds_its_levels_where_the_sample_is(scene, tiny_model, tmp_path):
    import bpy
    from mathutils import Vector

    from sinshape.runtime import gltf

    obj = add(tiny_model, seed=2)
    obj.location = (5.0, 0.0, 0.0)
    bpy.context.view_layer.update()
    path = tmp_path / "rock.glb"
    assert bpy.ops.sinshape.export_asset(filepath=str(path), lods="800,200", texture=64) == {"FINISHED"}
    document, _ = gltf.read(path.read_bytes())
    assert [node["name"] for node in document["nodes"]] == ["rock_LOD0", "rock_LOD1-noimp", "rock_collision-colonly"]
    level = bpy.data.objects["rock_LOD0"]
    assert len(level.data.polygons) <= 800 and level.name in bpy.context.scene.objects
    for outside in ("rock_LOD1-noimp", "rock_collision-colonly"):  # in the importer's excluded collection
        assert outside in bpy.data.objects and outside not in bpy.context.view_layer.objects
    images = {node.image.size[0] for node in level.active_material.node_tree.nodes if node.type == "TEX_IMAGE"}
    assert images == {64}
    def corners(o):
        return np.array([list(o.matrix_world @ Vector(corner)) for corner in o.bound_box])

    assert np.abs(corners(level).min(axis=0) - corners(obj).min(axis=0)).max() < 1.0  # in place, to a voxel
    assert np.abs(corners(level).max(axis=0) - corners(obj).max(axis=0)).max() < 1.0
    godot = tmp_path / "godot.glb"
    assert bpy.ops.sinshape.export_asset(filepath=str(godot), lods="800,200", texture=64, height=2.0, collision=100,
                                         naming="godot", add_objects=False) == {"FINISHED"}
    document, _ = gltf.read(godot.read_bytes())
    assert [node["name"] for node in document["nodes"]] == ["godot_LOD0", "godot_LOD1-noimp", "godot_collision-colonly"]
    assert document["scenes"][0]["nodes"] == [0, 2]  # the collision in the scene, as Godot 4 reads it
    assert document["nodes"][0]["extras"]["sinshape"]["height_m"] == 2.0
    bad = tmp_path / "bad.glb"
    with pytest.raises(RuntimeError, match="lods asks for 0 triangles") as raised:  # the ERROR report, one line
        bpy.ops.sinshape.export_asset(filepath=str(bad), lods="0", texture=64)
    assert len(str(raised.value).strip().splitlines()) == 1 and not bad.exists()
    # Blender's importer reads no compressed geometry: asked to add it to the scene, refused before any work;
    # written alone, it is written.
    with pytest.raises(RuntimeError, match="importer cannot read an asset made with compress: untick Add to scene"):
        bpy.ops.sinshape.export_asset(filepath=str(bad), lods="800,200", texture=64, compress=True)
    assert not bad.exists()
    assert bpy.ops.sinshape.export_asset(filepath=str(bad), lods="800,200", texture=64, compress=True,
                                         add_objects=False) == {"FINISHED"}
    assert "EXT_meshopt_compression" in gltf.read(bad.read_bytes())[0]["extensionsRequired"]
