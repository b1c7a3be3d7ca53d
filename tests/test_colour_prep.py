"""An example's colour: read from vertex colours and textures, turned into
each level's colour field, and refused in one line when it cannot be read."""

import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sinshape.core import manifest as fmt
from sinshape.core.errors import InputError
from sinshape.prep import colour, shapes
from sinshape.prep.pyramid import load_pyramid

DATA = Path(__file__).parent / "data" / "colour"
TOP, BOTTOM = np.array([220, 40, 30]) / 255, np.array([30, 60, 200]) / 255
PAINTED = ["box_vertex.ply", "box_texture.glb", "box_texture.obj"]


def band_colour(pyramid, z: int) -> np.ndarray:
    """The mean colour of the finest level's surface band at z slice `z`."""
    rgb, band = pyramid.colours[-1], pyramid.bands[-1]
    return rgb[..., z][:, band[..., z] > 0].mean(axis=1)


@pytest.mark.parametrize("name", PAINTED)
def test_a_box_painted_by_height_gives_its_colours_at_the_right_heights(name):
    # Vertex colours, a GLB texture and an OBJ texture whose UVs lie in [1, 2]
    # (read by repeating) all paint the top red and the bottom blue.
    pyramid = load_pyramid(DATA / name, res=24, levels=2)
    assert len(pyramid.colours) == len(pyramid.bands) == 2
    for rgb, band, level in zip(pyramid.colours, pyramid.bands, pyramid.levels):
        assert rgb.shape == (3, *level.shape) and band.shape == level.shape and rgb.dtype == np.float32
        assert 0 < band.mean() < 1  # the band around the surface, not everything
    z = pyramid.levels[-1].shape[2]
    np.testing.assert_allclose(band_colour(pyramid, z - 2), TOP, atol=0.02)
    np.testing.assert_allclose(band_colour(pyramid, 1), BOTTOM, atol=0.02)


def test_every_voxel_takes_the_colour_of_the_nearest_surface_point():
    # A box red above z = 0 and blue below: each voxel's colour follows the
    # side of z = 0 its nearest surface point is on, inside the box too.
    pyramid = load_pyramid(DATA / "box_vertex.ply", res=24, levels=1)
    rgb = pyramid.colours[-1]
    z = pyramid.levels[-1].shape[2]
    red = np.abs(rgb - TOP[:, None, None, None]).max(axis=0) < 0.05
    blue = np.abs(rgb - BOTTOM[:, None, None, None]).max(axis=0) < 0.05
    assert red[..., -3:].all() and blue[..., :3].all()
    assert (red | blue)[..., list(range(0, z // 2 - 2)) + list(range(z // 2 + 2, z))].mean() > 0.95


def test_texture_lookup_repeats_outside_the_unit_square():
    texture = np.random.default_rng(0).random((8, 4, 3)).astype(np.float32)
    uv = np.random.default_rng(1).random((50, 2))
    for shift in ((1, 0), (0, -1), (3, 2)):
        np.testing.assert_allclose(colour.sample_texture(texture, uv + shift), colour.sample_texture(texture, uv),
                                   atol=1e-5)
    # Pixel centres read the pixels themselves; v = 0 is the bottom row.
    centre = np.array([[0.5 / 4, 1 - 0.5 / 8], [3.5 / 4, 0.5 / 8]])
    np.testing.assert_allclose(colour.sample_texture(texture, centre), texture[[0, 7], [0, 3]], atol=1e-6)


def test_srgb_round_trip():
    values = np.linspace(0, 1, 101)
    np.testing.assert_allclose(fmt.srgb_to_linear(fmt.linear_to_srgb(values)), values, atol=1e-6)


def test_a_mesh_without_colour_and_an_h5_pyramid_have_none(tiny_pyramid, tmp_path):
    plain = tmp_path / "box.ply"
    plain.write_bytes(trimesh.creation.box(extents=(2, 1, 1)).export(file_type="ply"))
    assert load_pyramid(plain, res=24, levels=1).colours is None
    assert load_pyramid(tiny_pyramid, res=24).colours is None


def test_no_colour_reads_no_colour_at_all(tmp_path):
    # Geometry only: even a texture that is missing does not matter.
    for name in ("box_texture.obj", "box_texture.mtl"):
        shutil.copy(DATA / name, tmp_path / name)
    pyramid = load_pyramid(tmp_path / "box_texture.obj", res=24, levels=1, colour=False)
    assert pyramid.colours is None and pyramid.bands is None
    with_colour = load_pyramid(DATA / "box_texture.obj", res=24, levels=1)
    np.testing.assert_array_equal(pyramid.levels[0], with_colour.levels[0])


def test_painted_terrain_has_snow_on_top_and_grass_below():
    mesh = shapes.make_shape("painted_terrain", detail=48)
    plain = shapes.make_shape("terrain", detail=48)
    np.testing.assert_array_equal(mesh.vertices, plain.vertices)
    rgb = mesh.visual.vertex_colors[:, :3] / 255
    height = mesh.vertices[:, 2]
    high, low = height > np.quantile(height, 0.97), (height > 0.3) & (height < np.quantile(height, 0.5))
    snow, grass = np.array(shapes.SNOW), np.array(shapes.GRASS)
    assert np.linalg.norm(rgb[high] - snow, axis=1).mean() < np.linalg.norm(rgb[low] - snow, axis=1).mean()
    assert (np.linalg.norm(rgb[low] - grass, axis=1) < 0.05).mean() > 0.3


def png(width: int, height: int) -> bytes:
    """A PNG header claiming width x height, with one tiny data chunk."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b""))


def obj_with(tmp_path, texture: bytes | None) -> Path:
    for name in ("box_texture.obj", "box_texture.mtl"):
        shutil.copy(DATA / name, tmp_path / name)
    if texture is not None:
        (tmp_path / "box_texture.png").write_bytes(texture)
    return tmp_path / "box_texture.obj"


def nan_ply(tmp_path) -> Path:
    mesh = trimesh.creation.box()
    header = ("ply\nformat ascii 1.0\n"
              f"element vertex {len(mesh.vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float red\nproperty float green\nproperty float blue\n"
              f"element face {len(mesh.faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    rows = [f"{x} {y} {z} nan 0.5 0.5" for x, y, z in mesh.vertices] + [f"3 {a} {b} {c}" for a, b, c in mesh.faces]
    (tmp_path / "nan.ply").write_text(header + "\n".join(rows) + "\n")
    return tmp_path / "nan.ply"


def two_parts(tmp_path) -> Path:
    painted = trimesh.load(DATA / "box_vertex.ply", process=False)
    bare = trimesh.creation.box(extents=(1, 1, 1))
    bare.apply_translation((3, 0, 0))
    scene = trimesh.Scene({"painted": painted, "bare": bare})
    (tmp_path / "two.glb").write_bytes(scene.export(file_type="glb"))
    return tmp_path / "two.glb"


BAD = {
    "missing_texture": (lambda tmp: obj_with(tmp, None), "box_texture.png (named in box_texture.mtl) is missing"),
    "unreadable_texture": (lambda tmp: obj_with(tmp, b"not an image at all"), "cannot read it as an image"),
    "absurd_texture": (lambda tmp: obj_with(tmp, png(100_000, 100_000)), "not a usable size"),
    "nan_colours": (nan_ply, "NaN or infinite vertex colours"),
    "part_without_colour": (two_parts, "has no colour while others have"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_colour_that_cannot_be_read_is_refused_in_one_line(tmp_path, case):
    make, fragment = BAD[case]
    with pytest.raises(InputError) as error:
        load_pyramid(make(tmp_path), res=24, levels=1)
    assert fragment in str(error.value) and "\n" not in str(error.value)


def test_glb_vertex_colours_are_read_as_linear(tmp_path):
    # The runtime writes COLOR_0 linear (glTF's rule); read back, the sRGB colours return.
    from sinshape.runtime.write import mesh_bytes

    painted = trimesh.load(DATA / "box_vertex.ply", process=False)
    (tmp_path / "box.glb").write_bytes(mesh_bytes(painted, ".glb"))
    pyramid = load_pyramid(tmp_path / "box.glb", res=24, levels=1)
    z = pyramid.levels[-1].shape[2]
    np.testing.assert_allclose(band_colour(pyramid, z - 2), TOP, atol=0.03)
    np.testing.assert_allclose(band_colour(pyramid, 1), BOTTOM, atol=0.03)
