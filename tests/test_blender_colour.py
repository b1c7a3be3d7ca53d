"""A coloured model's objects in Blender (bpy, headless): the mesh carries
the runtime's colours at its vertices (those `sinrun sample` writes) as the
point colour attribute `Col`,
shown by a material; a grey model's carries neither. For a sample and for a
world's tiles. Marked `blender`; skipped where bpy cannot be imported."""

from pathlib import Path

import numpy as np

from test_blender import add, pytestmark, sinrun_sample  # noqa: F401 (marked and skipped as the Blender tests are)
from test_blender_world import add_world, tiles_of

COLOUR_ONNX = Path(__file__).parent / "data" / "tiny_colour.onnx"
TOLERANCE = 1e-5  # Blender keeps float colour linear: the runtime's sRGB bytes in, and out again


def assert_shows_its_colours(obj_mesh, expected) -> None:
    from blender import convert, live

    colours = convert.mesh_colours(obj_mesh)
    assert colours is not None and colours.shape == expected.shape
    assert np.abs(colours - expected).max() < TOLERANCE
    assert expected.std(axis=0).max() > 0.01  # colour that varies: a misplaced one would show
    assert obj_mesh.color_attributes.active_color.name == convert.COLOUR
    (material,) = obj_mesh.materials
    assert material.name == live.COLOUR_MATERIAL
    links = {(link.from_node.bl_idname, getattr(link.from_node, "attribute_name", ""), link.to_socket.name)
             for link in material.node_tree.links}
    assert ("ShaderNodeAttribute", convert.COLOUR, "Base Color") in links


def test_a_coloured_samples_vertices_carry_the_command_lines_colours(scene, tiny_model, tmp_path):
    from blender import convert

    obj = add(COLOUR_ONNX, seed=3, smooth=1)
    vertices, faces, colours = sinrun_sample(tmp_path, COLOUR_ONNX, "--seed", 3, "--smooth", 1)
    assert len(convert.mesh_vertices(obj.data)) == len(vertices)  # the same vertices, in the same order
    assert_shows_its_colours(obj.data, colours)
    obj.sinshape.model = str(tiny_model)  # a grey model: no colour, no colour material
    assert convert.mesh_colours(obj.data) is None and len(obj.data.materials) == 0


def test_detail_off_gives_the_command_lines_colours_without_it(scene, tmp_path):
    """Detail, a setting made from the table's record, reaches the request: off, the
    colours are `sinrun sample --no-detail`'s; on again, the correspondence's."""
    obj = add(COLOUR_ONNX, seed=3, detail=False)
    _, _, plain = sinrun_sample(tmp_path, COLOUR_ONNX, "--seed", 3, "--no-detail")
    _, _, detailed = sinrun_sample(tmp_path, COLOUR_ONNX, "--seed", 3)
    assert plain.shape == detailed.shape and np.abs(plain - detailed).max() > 0.05  # a switch one can see
    assert_shows_its_colours(obj.data, plain)
    obj.sinshape.detail = True
    assert_shows_its_colours(obj.data, detailed)


def test_a_coloured_worlds_tiles_carry_the_runtimes_colours(scene):
    from blender import convert
    from sinshape.runtime import world, world_tiles
    from sinshape.runtime.load import load_model

    model = load_model(COLOUR_ONNX, threads=1)
    scene.cursor.location = (0, 0, 0)
    obj = add_world(COLOUR_ONNX, seed=4, radius=1)
    tiles = tiles_of(obj)
    assert len(tiles) == 9
    for tile, child in tiles.items():
        # what `sinrun world --skirt` writes for the tile
        surface = world_tiles.tile_surface(model, 4, tile, options=world.WorldOptions(**convert.FIXED))
        if len(surface.vertices):
            assert len(convert.mesh_vertices(child.data)) == len(surface.vertices)
            assert_shows_its_colours(child.data, convert.byte_colours(surface.colours))
