"""Hostile textured meshes (docs/RELIABILITY.md, "The files a mesh names"):
every file a mesh names is read from its own folder, is a regular file and
is read without blocking; a glTF's structure and an image's size are checked
before use; and training says which colour it read, and warns where a user
would be surprised."""

import copy
import json
import os
import re
import shutil
import struct
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from sinshape.cli.main import cli
from sinshape.core import budget
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.prep import meshfiles, voxelize
from sinshape.prep.pyramid import load_pyramid
from conftest import finishes
from test_cli_train import assert_one_line_error

DATA = Path(__file__).parent / "data" / "colour"
TOP, BOTTOM = np.array([220, 40, 30]) / 255, np.array([30, 60, 200]) / 255


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def textured_obj(folder: Path, mtl: str | None = None, texture: bytes | None = None) -> Path:
    """The committed textured box as OBJ + MTL + PNG in `folder`, its MTL or texture replaced."""
    for name in ("box_texture.obj", "box_texture.mtl", "box_texture.png"):
        shutil.copy(DATA / name, folder / name)
    if mtl is not None:
        (folder / "box_texture.mtl").write_text(mtl)
    if texture is not None:
        (folder / "box_texture.png").write_bytes(texture)
    return folder / "box_texture.obj"


def glb_parts() -> tuple:
    """The committed textured box's glTF JSON and binary chunk."""
    return meshfiles.gltf_json((DATA / "box_texture.glb").read_bytes(), "box_texture.glb")


def textured_gltf(folder: Path, change=None, image_file: bool = True) -> Path:
    """The textured box as a .gltf with its buffer (box.bin) and, with
    `image_file`, its texture (tex.png) beside it; change(meta) edits the JSON."""
    meta, binary = glb_parts()
    meta = copy.deepcopy(meta)
    meta["buffers"][0]["uri"] = "box.bin"
    (folder / "box.bin").write_bytes(binary)
    if image_file:
        view = meta["bufferViews"][meta["images"][0]["bufferView"]]
        (folder / "tex.png").write_bytes(binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]])
        meta["images"][0] = {"uri": "tex.png"}
    if change:
        change(meta)
    (folder / "box.gltf").write_text(json.dumps(meta))
    return folder / "box.gltf"


def png(width: int, height: int, bits: int = 8, colour_type: int = 2, rows: bytes | None = None) -> bytes:
    """A PNG of width x height whose pixel rows are `rows` (default: zeros), deflated."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    channels = {0: 1, 2: 3, 6: 4}[colour_type]
    if rows is None:
        rows = (b"\0" + bytes(-(-width * channels * bits // 8))) * height
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bits, colour_type, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b""))


def refused(path, fragment, **options):
    """Reading `path` for training is refused in one line holding `fragment`."""
    with pytest.raises(InputError) as error:
        finishes(lambda: load_pyramid(path, res=16, levels=1, **options))
    assert fragment in str(error.value) and "\n" not in str(error.value), str(error.value)
    return str(error.value)


# -- 1. every file a mesh names is read from its own folder ---------------------------------------

@pytest.fixture
def outside(tmp_path):
    """A readable image outside the mesh's folder, and the folder the mesh is in."""
    (tmp_path / "mesh").mkdir()
    shutil.copy(DATA / "box_texture.png", tmp_path / "secret.png")
    return tmp_path / "secret.png", tmp_path / "mesh"


@pytest.mark.parametrize("statement", ["map_Kd {absolute}", "map_Kd ../secret.png", "map_Kd -s 1 1 1 ../secret.png",
                                       "map_Kd /etc/passwd", "map_Kd /proc/self/environ"])
def test_an_mtl_texture_outside_the_folder_is_refused(outside, statement):
    secret, folder = outside
    path = textured_obj(folder, mtl="newmtl painted\nKd 1 1 1\n" + statement.format(absolute=secret) + "\n")
    refused(path, "lies outside its folder")


@pytest.mark.parametrize("library", ["/etc/passwd", "../x.mtl", "{absolute}"])
def test_a_material_library_outside_the_folder_is_refused(outside, library):
    secret, folder = outside
    (folder.parent / "x.mtl").write_text("newmtl painted\nmap_Kd secret.png\n")
    path = textured_obj(folder)
    path.write_text(path.read_text().replace("mtllib box_texture.mtl",
                                             "mtllib " + library.format(absolute=folder.parent / "x.mtl")))
    refused(path, "material library")


@pytest.mark.parametrize("uri", ["/etc/passwd", "../secret.png", "{absolute}", "/etc/shadow"])
def test_a_gltf_image_or_buffer_outside_the_folder_is_refused(outside, uri):
    secret, folder = outside
    uri = uri.format(absolute=secret)

    def image(meta):
        meta["images"][0]["uri"] = uri

    def buffer(meta):
        meta["buffers"][0]["uri"] = uri

    refused(textured_gltf(folder, image), f"image 0's file {uri} lies outside its folder")
    refused(textured_gltf(folder, buffer), f"buffer 0's file {uri} lies outside its folder")
    with pytest.raises(InputError, match="lies outside its folder"):  # geometry alone reads the buffers too
        voxelize.load_mesh(folder / "box.gltf")


def test_a_texture_linked_from_outside_is_refused_not_dropped(outside):
    secret, folder = outside
    path = textured_obj(folder)
    (folder / "box_texture.png").unlink()
    (folder / "box_texture.png").symlink_to(secret)
    refused(path, "texture box_texture.png (named in box_texture.mtl) lies outside its folder")
    (folder / "inside.png").write_bytes(secret.read_bytes())  # a link that stays inside is followed
    (folder / "box_texture.png").unlink()
    (folder / "box_texture.png").symlink_to(folder / "inside.png")
    assert load_pyramid(path, res=16, levels=1).colours is not None


def test_the_asset_folder_option_widens_the_folder(outside):
    """A user whose textures lie beside the mesh's folder names the folder
    that holds both; the CLI's message says how."""
    secret, folder = outside
    path = textured_obj(folder, mtl="newmtl painted\nKd 1 1 1\nmap_Kd ../secret.png\n")
    message = refused(path, "lies outside its folder")
    assert "asset_folder widens it" in message
    assert load_pyramid(path, res=16, levels=1, asset_folder=folder.parent).colours is not None
    assert "--asset-folder widens it" in run("render", path, "-o", folder / "p.png").output


@pytest.mark.parametrize("which", ["texture", "mtl", "buffer", "image"])
def test_a_fifo_named_as_a_file_is_refused_at_once(tmp_path, which):
    """A FIFO hung training, render and sample --layout for ever."""
    if which in ("texture", "mtl"):
        path = textured_obj(tmp_path)
        fifo = tmp_path / ("box_texture.png" if which == "texture" else "box_texture.mtl")
    else:
        path = textured_gltf(tmp_path)
        fifo = tmp_path / ("box.bin" if which == "buffer" else "tex.png")
    fifo.unlink()
    os.mkfifo(fifo)
    refused(path, "is a FIFO, not a regular file")
    result = finishes(lambda: run("render", path, "-o", tmp_path / "p.png", "--image-size", 32))
    if which == "buffer":  # the geometry itself: render and a mesh layout (load_mesh) refuse it
        assert_one_line_error(result, "buffer 0's file box.bin is a FIFO, not a regular file")
        with pytest.raises(InputError, match="is a FIFO"):
            finishes(lambda: voxelize.load_mesh(path))
    else:  # a picture of the geometry, and a warning that its colour cannot be read
        assert result.exit_code == 0 and "is a FIFO, not a regular file; drawn without its colour" in result.output
        assert len(finishes(lambda: voxelize.load_mesh(path)).faces)  # geometry alone reads no material


def test_a_folder_or_device_named_as_a_texture_is_refused(tmp_path):
    refused(textured_obj(tmp_path, mtl="newmtl painted\nmap_Kd /dev/zero\n"), "lies outside its folder")
    path = textured_obj(tmp_path)
    (tmp_path / "box_texture.png").unlink()
    (tmp_path / "box_texture.png").mkdir()
    refused(path, "texture box_texture.png (named in box_texture.mtl) is a folder, not a regular file")


# -- 2. glTF structure and image sizes are checked before use -------------------------------------

GLTF_CASES = {
    "texture index out of range": (lambda m: m["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"].update(
        index=5), "material 0's base colour texture is 5, not one of its 1 textures"),
    "image index out of range": (lambda m: m["textures"][0].update(source=3), "texture 0's source is 3, not one of"),
    "no images": (lambda m: m.update(images=[]), "texture 0's source is 0, not one of its 0 images"),
    "an index that is a string": (lambda m: m["textures"][0].update(source="0"), "texture 0's source is \"0\""),
    "a data URI without a comma": (lambda m: m["images"][0].update(uri="data:image/png;base64"),
                                   "image 0's uri is a data: URI that is not base64"),
    "a data URI of bad base64": (lambda m: m["images"][0].update(uri="data:image/png;base64,@@@@"),
                                 "image 0's uri is a data: URI whose base64 does not decode"),
    "a buffer of bad base64": (lambda m: m["buffers"][0].update(uri="data:application/octet-stream;base64,x"),
                               "buffer 0's uri is a data: URI whose base64 does not decode"),
    "a NaN base colour factor": (lambda m: m["materials"][0]["pbrMetallicRoughness"].update(
        baseColorFactor=[float("nan"), 1, 1, 1]), "baseColorFactor must be four numbers in [0, 1], got [NaN"),
    "a base colour factor of 300": (lambda m: m["materials"][0]["pbrMetallicRoughness"].update(
        baseColorFactor=[300, 1, 1, 1]), "baseColorFactor must be four numbers in [0, 1]"),
    "a view past its buffer": (lambda m: m["bufferViews"][2].update(byteLength=10**9),
                               "buffer view 2 does not lie inside buffer 0"),
    "a material index out of range": (lambda m: m["meshes"][0]["primitives"][0].update(material=7),
                                      "a primitive's material is 7, not one of its 1 materials"),
}


@pytest.mark.parametrize("case", sorted(GLTF_CASES))
def test_a_gltf_of_bad_structure_is_one_line(tmp_path, case):
    change, fragment = GLTF_CASES[case]
    refused(textured_gltf(tmp_path, change), fragment)


def test_an_image_is_counted_against_memory_from_its_header(tmp_path, monkeypatch):
    """A 1-bit PNG of 16384 x 8192 pixels is 16 kB and took 4.8 GB to read:
    refused with the figure from its header, before a pixel is decoded. The
    refusal's peak does not grow with the picture: one of a quarter of the
    pixels is refused at the same peak, within 4 MiB (decoding either would
    differ by gigabytes). Traced allocations, not the machine's: another
    process's load does not enter."""
    monkeypatch.setattr(budget, "available_memory", lambda: 1 << 30)
    peaks = []
    for width, height, needs in ((8192, 4096, "1.2"), (16384, 8192, "5.0")):
        bomb = png(width, height, bits=1, colour_type=0)
        assert len(bomb) < 20_000
        path = textured_obj(tmp_path, texture=bomb)
        tracemalloc.start()
        try:
            with pytest.raises(MemoryLimitError, match=rf"decoding box_texture.obj: texture box_texture.png "
                                                        rf"\({width}x{height}\) needs about {needs} GiB of memory "
                                                        rf"\(limit 1.0 GiB\)"):
                load_pyramid(path, res=16, levels=1)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert abs(peaks[1] - peaks[0]) < 4 << 20, peaks


def test_a_texture_padded_to_gigabytes_is_refused_unread(tmp_path):
    path = textured_obj(tmp_path)
    with open(tmp_path / "box_texture.png", "r+b") as f:  # sparse: nothing is written but the image
        f.truncate(6 << 30)
    refused(path, "texture box_texture.png (named in box_texture.mtl) is 6144.0 MiB; at most 1024 MiB is read")


def test_uvs_of_absurd_size_are_refused(tmp_path):
    path = textured_obj(tmp_path)
    path.write_text(re.sub(r"^vt \S+", "vt 3e38", path.read_text(), count=1, flags=re.MULTILINE))
    refused(path, "texture coordinates beyond +-1e+06")


@pytest.mark.parametrize("kd", ["nan nan nan", "1 1", "2 0 0", "-1 0 0"])
def test_an_mtl_colour_that_is_not_one_is_refused(tmp_path, kd):
    refused(textured_obj(tmp_path, mtl=f"newmtl painted\nKd {kd}\nmap_Kd box_texture.png\n"),
            "a diffuse colour (Kd) must be three numbers in [0, 1]")


@pytest.mark.parametrize("options", ["-s 1 1 1", "-o 0 0", "-blendu on -clamp off", "-mm 0 1", "-s 1"])
def test_mtl_texture_options_are_read_as_the_format_defines(tmp_path, options):
    """`map_Kd -s 1 1 1 tex.png` was refused as a missing file '1 1 tex.png'."""
    path = textured_obj(tmp_path, mtl=f"newmtl painted\nKd 1 1 1\nmap_Kd {options} box_texture.png\n")
    pyramid = load_pyramid(path, res=16, levels=1)
    assert pyramid.colours is not None and "texture box_texture.png" in pyramid.colour_read


def test_mtl_offset_and_scale_move_the_texture(tmp_path):
    """-o 0 0.5 shifts v by half: the box's top (red at v in [0.5, 1]) reads the texture's bottom half."""
    plain = load_pyramid(textured_obj(tmp_path), res=16, levels=1)
    shifted = load_pyramid(textured_obj(tmp_path, mtl="newmtl painted\nKd 1 1 1\nmap_Kd -o 0 0.5 box_texture.png\n"),
                           res=16, levels=1)
    z = plain.levels[-1].shape[2]
    top = lambda p: p.colours[-1][..., z - 2][:, p.bands[-1][..., z - 2] > 0].mean(axis=1)  # noqa: E731
    np.testing.assert_allclose(top(plain), TOP, atol=0.03)
    np.testing.assert_allclose(top(shifted), BOTTOM, atol=0.03)


@pytest.mark.parametrize("statement, fragment", [
    ("map_Kd -s box_texture.png", "-s takes 1 argument"), ("map_Kd -clamp maybe box_texture.png", "on or off"),
    ("map_Kd -zz 1 box_texture.png", "an option the format does not define: '-zz'"), ("map_Kd -o", "-o takes 1 argument"),
])
def test_a_bad_mtl_texture_statement_is_one_line(tmp_path, statement, fragment):
    refused(textured_obj(tmp_path, mtl=f"newmtl painted\n{statement}\n"), fragment)


# -- honest colour input ---------------------------------------------------------------------------

def test_training_says_which_colour_it_read(tmp_path):
    assert load_pyramid(textured_obj(tmp_path), res=16, levels=1).colour_read == "texture box_texture.png (4x8)"
    assert load_pyramid(DATA / "box_vertex.ply", res=16, levels=1).colour_read == "vertex colours"
    assert load_pyramid(DATA / "box_texture.glb", res=16, levels=1).colour_read == \
        "texture embedded image 0 (4x8)"


def test_gltf_vertex_colours_and_a_texture_are_multiplied(tmp_path):
    """glTF's base colour is factor x texture x COLOR_0; the vertex colours
    were dropped without a word. Half-grey vertex colours darken the texture."""
    mesh = trimesh.load(DATA / "box_texture.glb", force="mesh", process=False)
    mesh.visual.vertex_attributes["color"] = np.full((len(mesh.vertices), 4), 128, np.uint8)  # 0.5 as bytes
    (tmp_path / "tinted.glb").write_bytes(mesh.export(file_type="glb"))
    meta, _ = meshfiles.gltf_json((tmp_path / "tinted.glb").read_bytes(), "t")
    assert "COLOR_0" in meta["meshes"][0]["primitives"][0]["attributes"]
    pyramid = load_pyramid(tmp_path / "tinted.glb", res=16, levels=1)
    assert pyramid.colour_read.endswith("(4x8) times vertex colours (COLOR_0, as glTF defines)")
    z = pyramid.levels[-1].shape[2]
    top = pyramid.colours[-1][..., z - 2][:, pyramid.bands[-1][..., z - 2] > 0].mean(axis=1)
    from sinshape.core.manifest import linear_to_srgb, srgb_to_linear
    np.testing.assert_allclose(top, linear_to_srgb(srgb_to_linear(TOP) * 128 / 255), atol=0.03)


def test_obj_vertex_colours_beside_a_texture_are_warned_about(tmp_path):
    path = textured_obj(tmp_path)
    text = path.read_text()
    path.write_text("\n".join(line + " 0.2 0.9 0.1" if line.startswith("v ") else line for line in text.splitlines()))
    pyramid = load_pyramid(path, res=16, levels=1)
    assert any("vertex colours are not used" in w for w in pyramid.colour_warnings)


@pytest.mark.parametrize("size", [(1, 1), (8, 8)])
def test_a_texture_of_one_colour_is_warned_about(tmp_path, size):
    width, height = size
    rows = (b"\0" + bytes([200, 100, 50]) * width) * height
    pyramid = load_pyramid(textured_obj(tmp_path, texture=png(width, height, rows=rows)), res=16, levels=1)
    assert pyramid.colour_warnings == ("texture box_texture.png is one colour (#c86432): the model learns that "
                                       "colour alone",)
    assert load_pyramid(textured_obj(tmp_path), res=16, levels=1).colour_warnings == ()


def test_a_truncated_texture_is_named_and_no_colour_gets_past_it(tmp_path):
    """The message named the mesh, not the image, and --no-colour failed too."""
    good = (DATA / "box_texture.png").read_bytes()
    path = textured_obj(tmp_path, texture=good[:len(good) - 30])
    refused(path, "box_texture.obj: texture box_texture.png: cannot read it as an image")
    refused(path, "(no_colour trains geometry only)")
    assert load_pyramid(path, res=16, levels=1, colour=False).colours is None
    cut = tmp_path / "cut.glb"
    data = bytearray((DATA / "box_texture.glb").read_bytes())
    meta, binary = glb_parts()
    view = meta["bufferViews"][meta["images"][0]["bufferView"]]
    start = len(data) - len(binary) + view["byteOffset"]
    data[start + 40:start + view["byteLength"]] = bytes(view["byteLength"] - 40)  # the image's data zeroed
    cut.write_bytes(bytes(data))
    refused(cut, "cut.glb: base colour texture embedded image 0: cannot read it as an image")
    assert load_pyramid(cut, res=16, levels=1, colour=False).colours is None


def test_train_says_which_colour_it_read(tmp_path):
    """What a run logs as it opens (the trainer is made, nothing trained)."""
    pytest.importorskip("torch")
    from sinshape.trainer import train
    from sinshape.trainer.config import make_config

    path, said = textured_obj(tmp_path, texture=png(1, 1, rows=b"\0" + bytes([9, 9, 9]))), []
    train.open_run(path, tmp_path / "m.onnx", make_config("tiny", res=16, levels=1), False, "cpu",
                   tmp_path / "m.ckpt.pt", said.append)
    assert "colour: texture box_texture.png (1x1)" in said
    assert "warning: texture box_texture.png is one colour (#090909): the model learns that colour alone" in said


def test_render_draws_a_textured_mesh_in_its_texture(tmp_path):
    """The box's texture is red above and blue below: so is its picture."""
    out = tmp_path / "p.png"
    result = run("render", textured_obj(tmp_path), DATA / "box_texture.glb", "-o", out, "--image-size", 96,
                 "--elevation", 0, "--up", "z")
    assert result.exit_code == 0, result.output
    from PIL import Image

    picture = np.asarray(Image.open(out).convert("RGB"), np.float32) / 255
    for cell in (picture[:96, :96], picture[:96, 96:192]):
        upper, lower = cell[30:40, 40:56].reshape(-1, 3), cell[56:66, 40:56].reshape(-1, 3)
        assert upper[:, 0].mean() > 2 * upper[:, 2].mean(), upper.mean(axis=0)  # red, shaded
        assert lower[:, 2].mean() > 2 * lower[:, 0].mean(), lower.mean(axis=0)  # blue


def test_a_resume_checks_the_colour_it_was_trained_on(tmp_path):
    """A resume after the texture changed, or with --no-colour on a coloured
    checkpoint, went on without a word."""
    pytest.importorskip("torch")
    from sinshape.trainer import train
    from sinshape.trainer.config import make_config

    path, out = textured_obj(tmp_path), tmp_path / "m.onnx"

    def stop(progress):
        raise KeyboardInterrupt

    with pytest.raises(train.Interrupted):
        train.train(path, out, make_config("tiny", res=16, levels=1, iters=2), progress=stop)
    (tmp_path / "box_texture.png").write_bytes(png(4, 4, rows=(b"\0" + bytes(12)) * 4))
    with pytest.raises(InputError, match="the files box_texture.obj names .* have changed since this checkpoint"):
        train.train(path, out, None, resume=True)
    shutil.copy(DATA / "box_texture.png", tmp_path / "box_texture.png")
    assert_one_line_error(run("train", path, "-o", out, "--resume", "--no-colour"),
                          "this checkpoint trains colour, which a resumed run keeps; drop --no-colour")
    assert "coloured" in run("train", path, "-o", out, "--resume").output  # the texture as it was: goes on
