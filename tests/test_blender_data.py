"""What a .blend holds is untrusted input: every value the extension reads
from one (settings, the applied layout, the layout's cubes, a world's tile
objects) is checked before use and refused in one line, as the runtime
refuses the same value, never a traceback or a huge allocation. Marked
`blender`, skipped where bpy cannot be imported."""

import base64

import numpy as np
import pytest

from test_blender import HAS_BPY, add

pytestmark = [pytest.mark.blender,
              pytest.mark.skipif(not HAS_BPY, reason="needs bpy, Blender as a Python module: "
                                                     "pip install 'sinshape[blender]' (Python 3.11)")]


def refused(obj, said: str) -> None:
    """Regenerating the sample is refused with `said`, in one line, on the object; the mesh stays."""
    import bpy

    from blender import convert

    before = convert.mesh_arrays(obj.data)
    with pytest.raises(RuntimeError, match=said) as raised:
        bpy.ops.sinshape.regenerate()
    assert len(str(raised.value).strip().splitlines()) == 1
    assert said in obj.sinshape.error and "\n" not in obj.sinshape.error
    assert all(np.array_equal(a, b) for a, b in zip(convert.mesh_arrays(obj.data), before))


def with_layout(obj, shape, text: str) -> None:
    from blender import live

    with live.suspended():
        obj.sinshape["layout_shape"] = shape  # as a .blend may hold it: past the property's checks
        obj.sinshape.layout_bits, obj.sinshape.edit = text, "LAYOUT"


def own_layout(obj):
    from blender import convert, live
    from sinshape.runtime import layout

    grid = layout.layout(live.load_model(obj.sinshape), obj.sinshape.seed)
    return convert.layout_text(grid)


def test_an_applied_layout_that_is_not_base64_is_refused(scene, tiny_model):
    obj = add(tiny_model, seed=3)
    shape, _ = own_layout(obj)
    with_layout(obj, shape, "not base64!")
    refused(obj, "not base64")


@pytest.mark.parametrize("shape", [(-1, 2, 2), (0, 4, 4), (5000, 1, 1)])
def test_an_applied_layout_of_an_impossible_shape_is_refused(scene, tiny_model, shape):
    obj = add(tiny_model, seed=3)
    with_layout(obj, shape, base64.b64encode(b"\xff" * 8).decode())
    refused(obj, "a layout is a 3-D grid of 1 to")


def test_a_layout_of_2_to_the_36_cells_is_refused_before_any_allocation(addon):
    from blender import convert
    from sinshape.core.errors import InputError

    with pytest.raises(InputError, match="a layout is a 3-D grid of 1 to"):
        convert.layout_from_text((2**36, 1, 1), base64.b64encode(b"\xff").decode())


def test_an_applied_layout_with_too_few_bits_is_refused(scene, tiny_model):
    obj = add(tiny_model, seed=3)
    shape, text = own_layout(obj)
    with_layout(obj, shape, base64.b64encode(base64.b64decode(text)[:1]).decode())  # 1 byte of bits
    refused(obj, "bytes of packed cells, got 1 bytes")


def test_layout_cubes_with_vertices_that_are_not_numbers_are_refused(scene, tiny_model):
    import bpy

    obj = add(tiny_model, seed=3)
    assert bpy.ops.sinshape.layout_show() == {"FINISHED"}
    cubes = obj.sinshape.layout_object
    cubes.data.vertices[0].co = (float("nan"), 0.0, 0.0)
    with pytest.raises(RuntimeError, match="not finite numbers"):
        bpy.ops.sinshape.layout_apply()
    assert obj.sinshape.edit == "NONE" and not obj.sinshape.layout_bits  # nothing applied


def test_layout_cubes_whose_faces_name_vertices_they_lack_are_refused(addon, tiny_model):
    from blender import convert
    from sinshape.core.errors import InputError
    from sinshape.runtime.load import load_model

    manifest = load_model(tiny_model, threads=1).manifest
    vertices, quads = convert.layout_cubes(np.ones((1, 1, 1), bool), manifest, (1, 1, 1))
    corners, starts = quads.ravel(), np.arange(0, quads.size, 4)
    for bad in (len(vertices), -1, 2**40):
        damaged = corners.astype(np.int64)
        damaged[5] = bad
        with pytest.raises(InputError, match="names a vertex outside"):
            convert.cubes_layout(vertices, damaged, starts, manifest, (1, 1, 1))
    with pytest.raises(InputError, match="fewer than 3 corners"):
        convert.cubes_layout(vertices, corners, np.array([0, 2, 4]), manifest, (1, 1, 1))


@pytest.mark.parametrize("value", ["a,b", "1,2,3", "1", 7, "99999999999999999999,0"])
def test_a_tile_object_that_names_no_tile_is_refused(scene, tiny_model, value):
    import bpy

    from test_blender_world import add_world

    obj = add_world(tiny_model, radius=0)
    (child,) = obj.children
    child["sinshape_tile"] = value
    with pytest.raises(RuntimeError, match="not a tile I,J|tile must be two integers"):
        bpy.ops.sinshape.regenerate()
    assert "\n" not in obj.sinshape_world.error and obj.sinshape_world.error
    assert list(obj.children) == [child]  # nothing removed or made


def test_a_world_radius_past_its_bounds_is_refused(scene, tiny_model):
    import bpy

    from test_blender_world import add_world

    obj = add_world(tiny_model, radius=0)
    obj.sinshape_world["radius"] = 10**6  # (2 r + 1)^2 tiles: as a .blend may hold it
    with pytest.raises(RuntimeError, match="radius must be 0 to 32"):
        bpy.ops.sinshape.regenerate()
    assert len(obj.children) == 1


@pytest.mark.parametrize("text, said", [("3:nan,0,0:1,1,1", "3 finite numbers"), ("x" * 100000, "100000 characters")])
def test_a_kept_part_recorded_on_the_object_is_checked_as_the_runtime_checks_it(scene, tiny_model, text, said):
    from blender import live

    obj = add(tiny_model, seed=3)
    with live.suspended():
        obj.sinshape.keep_part, obj.sinshape.edit = text, "KEEP"
    refused(obj, said)
    assert len(obj.sinshape.error) < 300
