"""Property-based fuzzing of every reader of a file a user hands over
(layouts .vox and .npz, .h5 pyramids, a batch job's index, meshes, the
material libraries and glTF images a textured mesh names, training
checkpoints): files structurally valid, their fields hostile
(negative, huge, of the wrong type or dtype, null), not only random bytes.
Each reader gives what it promises or one InputError; never another
exception (docs/RELIABILITY.md).

CI runs a derandomised pass of EXAMPLES cases per reader; a longer run
draws new ones:

    SINSHAPE_FUZZ_EXAMPLES=1000 pytest tests/test_fuzz_readers.py
"""

import io
import json
import os
import shutil
import struct
import zipfile
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from sinshape.core.errors import InputError
from sinshape.prep import meshfiles
from sinshape.runtime import layout_files
from sinshape.runtime import many_index

RUNS = int(os.environ.get("SINSHAPE_FUZZ_EXAMPLES", "0"))
EXAMPLES = RUNS or 60
# deadline: a hang guard only, far above what a case takes
READERS = settings(max_examples=EXAMPLES, deadline=timedelta(seconds=10), derandomize=not RUNS, database=None,
                   suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                          HealthCheck.data_too_large])

# Whole numbers a hostile field holds: the edges of each width, and small ones.
INT32 = st.one_of(st.integers(-4, 300), st.sampled_from([-2**31, -1, 2**31 - 1, 2**16, 256, 257]),
                  st.integers(-2**31, 2**31 - 1))
HOSTILE = st.one_of(st.integers(-3, 3), st.sampled_from([2**63, -2**63, 10**400, 2**31]),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5), st.none(), st.booleans(),
                    st.lists(st.integers(-2, 2), max_size=3))


def refused_or(read, check):
    """read() gives a value passing check(), or raises InputError with one line."""
    try:
        value = read()
    except InputError as error:
        assert "\n" not in str(error) and str(error)
        event("refused")
        return
    event("read")
    check(value)


def a_layout(grid):
    assert grid.dtype == bool and grid.ndim == 3 and 0 not in grid.shape
    assert grid.size <= layout_files.MAX_LAYOUT_CELLS


@READERS
@given(version=INT32, main=st.tuples(INT32, INT32), size=st.tuples(INT32, INT32, INT32), count=INT32,
       voxels=st.binary(max_size=64), chunks=st.lists(st.tuples(st.sampled_from([b"SIZE", b"XYZI", b"nTRN", b"RGBA"]),
                                                                INT32, INT32, st.binary(max_size=16)), max_size=3),
       honest=st.booleans())
def test_vox_fields(version, main, size, count, voxels, chunks, honest):
    """MAIN, SIZE, XYZI and other chunks whose declared sizes, dimensions and
    voxel counts are drawn (or, with honest, MAIN's sizes are true)."""
    body = b"SIZE" + struct.pack("<2i3i", 12, 0, *size) + b"XYZI" + struct.pack("<2ii", 4 + len(voxels), 0, count)
    body += voxels + b"".join(name + struct.pack("<2i", a, b) + extra for name, a, b, extra in chunks)
    content, children = (0, len(body)) if honest else main
    data = b"VOX " + struct.pack("<i", version) + b"MAIN" + struct.pack("<2i", content, children) + body
    refused_or(lambda: layout_files.parse_layout(data, ".vox", "l.vox"), a_layout)


DTYPES = ["|b1", "<f8", ">f4", "<f2", "<i4", "|u1", "<i8", "|O", "<U3", "<c16", "|V8", "<M8[s]", "[('a', '<f4')]"]


@READERS
@given(names=st.lists(st.sampled_from(["layout.npy", "layout", "other.npy", "layout.npy"]), min_size=0, max_size=3),
       shape=st.lists(st.one_of(st.integers(-2, 40), st.sampled_from([0, 4096, 4097, 2**40, -2**63])), max_size=4),
       descr=st.sampled_from(DTYPES), fortran=st.booleans(), data=st.binary(max_size=512),
       fill=st.sampled_from([None, 0.0, 1.0, float("nan"), float("inf"), -5.0]), stored=st.booleans())
def test_npz_fields(names, shape, descr, fortran, data, fill, stored):
    """Members of any names, a header of any shape and dtype, data of any length."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED) as archive:
        for name in names:
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(header, {"descr": descr, "fortran_order": fortran,
                                                          "shape": tuple(shape)})
            body = data
            if fill is not None and descr in ("<f8", ">f4", "<f2") and all(0 < n < 40 for n in shape):
                body = np.full(shape, fill, np.dtype(descr)).tobytes()
            archive.writestr(name, header.getvalue() + body)
    refused_or(lambda: layout_files.parse_layout(out.getvalue(), ".npz", "l.npz"), a_layout)


@READERS
@given(count=HOSTILE, levels=st.lists(st.tuples(
    st.sampled_from(["f4", "f8", "u1", "i2", "?", "S2", "null", "compound"]),
    st.lists(st.sampled_from([1, 11, 15, 16, 20]), min_size=0, max_size=4),
    st.sampled_from([0.0, 1.0, 0.7, 255.0, -1.0, float("nan")])), max_size=3))
def test_h5_fields(tmp_path_factory, count, levels):
    """n_scales of any type and value; levels null, of strings, compound, of any rank and values."""
    h5py = pytest.importorskip("h5py")
    from sinshape.prep import pyramid

    path = tmp_path_factory.mktemp("h5") / "p.h5"
    with h5py.File(path, "w") as f:
        try:
            f.attrs["n_scales"] = count
        except (TypeError, ValueError, OverflowError):
            f.attrs["n_scales"] = repr(count)  # HDF5 holds no NUL in a string
        for i, (dtype, shape, value) in enumerate(levels):
            if dtype == "null":
                f.create_dataset(f"scale{i}", data=h5py.Empty("f4"))
            elif dtype == "compound":
                f.create_dataset(f"scale{i}", data=np.zeros(shape, [("a", "f4"), ("b", "i2")]))
            elif dtype == "S2":
                f.create_dataset(f"scale{i}", data=np.full(shape, b"ab"))
            else:
                with np.errstate(all="ignore"):
                    f.create_dataset(f"scale{i}", data=np.full(shape, value).astype(dtype))

    def check(p):
        assert 1 <= len(p.levels) <= pyramid.MAX_LEVELS and all(g.dtype == bool and g.any() for g in p.levels)

    refused_or(lambda: pyramid.pyramid_from_h5(path), check)


@READERS
@given(records=st.lists(st.one_of(
    st.fixed_dictionaries({"seed": HOSTILE}, optional={"bytes": HOSTILE, "sha256": HOSTILE, "file": HOSTILE}),
    HOSTILE, st.just("[" * 2000), st.just('"' + "x" * 5000 + '"')), max_size=4),
    raw=st.sampled_from(['{"seed": 1e400}', '{"seed": -0}', '{"seed": 1' + "0" * 400 + "}", "", "{}"]))
def test_index_fields(tmp_path_factory, records, raw):
    """Index lines of hostile seeds (huge, negative, inf, text), sizes and hashes, deep or long lines."""
    folder = tmp_path_factory.mktemp("index")
    lines = [line if isinstance(line, str) and line.startswith(("[", '"x')) else json.dumps(line) for line in records]
    (folder / "index.jsonl").write_text("".join(line + "\n" for line in [*lines, raw]))

    def check(found):
        assert all(isinstance(seed, int) and 0 <= seed < 2**63 for seed in found)
        many_index.verified(found, folder / "{seed}.npz")  # looks each file up by the name its seed makes

    refused_or(lambda: many_index.read_index(folder / "index.jsonl"), check)


NUMBERS = st.one_of(st.floats(-10, 10), st.sampled_from(["nan", "inf", "-inf", "1e400", "1e308", "x", "-0"]))


@READERS
@given(vertices=st.lists(st.tuples(NUMBERS, NUMBERS, NUMBERS), min_size=0, max_size=8),
       faces=st.lists(st.tuples(*[st.one_of(st.integers(-10, 10), st.sampled_from([2**31, -2**40, 0]))] * 3),
                      max_size=8),
       refs=st.lists(st.sampled_from(["mtllib missing.mtl", "mtllib ../../etc/passwd", "usemtl a", "vt 0 0",
                                      "vn 0 0 1", "o part", "g", "mtllib /etc/passwd"]), max_size=3),
       triangles=INT32, binary=st.booleans())
def test_mesh_fields(tmp_path_factory, vertices, faces, refs, triangles, binary):
    """An OBJ of hostile numbers, face indices and references; a binary STL whose count lies."""
    from sinshape.prep import voxelize

    folder = tmp_path_factory.mktemp("mesh")
    if binary:
        path = folder / "m.stl"
        body = b"".join(struct.pack("<12fH", *([0.0] * 3), *(float(i % 3) for i in range(9)), 0)
                        for _ in range(len(faces)))
        path.write_bytes(bytes(80) + struct.pack("<i", triangles) + body)
    else:
        path = folder / "m.obj"
        text = [*refs, *(f"v {x} {y} {z}" for x, y, z in vertices), *(f"f {a} {b} {c}" for a, b, c in faces)]
        path.write_text("\n".join(text) + "\n")

    def check(mesh):
        assert len(mesh.faces) and np.isfinite(mesh.vertices).all() and mesh.vertices.shape[1] == 3

    refused_or(lambda: voxelize.load_mesh(path), check)


@pytest.fixture(scope="module")
def checkpoint_state(tiny_model):
    """The state of the session's tiny model's checkpoint (conftest trains it beside the model)."""
    torch = pytest.importorskip("torch")
    return torch.load(tiny_model.with_name("tiny.ckpt.pt"), weights_only=True)


FIELDS = ["format", "version", "config", "source", "sizes", "level", "iteration", "noise_amps", "lrs", "rewinds",
          "plan", "seconds", "level_seconds", "generator", "critic", "opt_g", "opt_d", "rng"]


@READERS
@given(changes=st.lists(st.tuples(st.sampled_from(FIELDS), st.one_of(
    HOSTILE, st.dictionaries(st.text(max_size=4), HOSTILE, max_size=2),
    st.sampled_from(["tensor", "bad tensor", "drop"]))), min_size=1, max_size=3))
def test_checkpoint_fields(tmp_path_factory, checkpoint_state, changes):
    """A checkpoint with fields replaced by values of any type, dropped, or tensors of another dtype."""
    import torch

    from sinshape.trainer.checkpoint import load_checkpoint

    state = dict(checkpoint_state)
    for field, value in changes:
        if value == "drop":
            state.pop(field, None)
        elif value == "tensor":
            state[field] = torch.zeros(3)
        elif value == "bad tensor":
            state[field] = {"levels.x.weight": torch.zeros(2, dtype=torch.int8)}
        else:
            state[field] = value
    path = tmp_path_factory.mktemp("ckpt") / "c.pt"
    torch.save(state, path)

    def check(loaded):
        assert isinstance(loaded["level"], int) and isinstance(loaded["generator"], dict)

    refused_or(lambda: load_checkpoint(path), check)


COLOUR = Path(__file__).parent / "data" / "colour"
MTL_WORDS = st.one_of(st.sampled_from(sorted(meshfiles.MTL_OPTIONS) + ["-zz", "-", "on", "off", "maybe"]),
                      st.sampled_from(["1", "0.5", "-2", "nan", "inf", "1e400", "3e38", "x"]))
TEXTURE_NAMES = st.sampled_from(["box_texture.png", "missing.png", "../box_texture.png", "/etc/passwd",
                                 "sub dir/t.png", "fifo.png", ".", "box_texture.png box_texture.png"])


def surface_colour_of(path):
    """What training reads of a mesh's colour: the scene, its files checked, and its surface's colour."""
    from sinshape.prep import colour, voxelize

    scene, data = voxelize.read_scene(path)
    return colour.surface_colour(scene, path, data, voxel=0.25)


def a_colour(surface):
    assert surface is None or (np.isfinite(surface.rgb).all() and surface.rgb.min() >= 0 and surface.rgb.max() <= 1)


VALID_STATEMENT = st.tuples(st.just("map_Kd"), st.sampled_from([[], ["-s", "2", "1", "1"], ["-o", "0.5"], ["-clamp", "on"],
                                                              ["-mm", "0", "1"], ["-blendu", "off", "-bm", "1"]]),
                            st.just("box_texture.png"))
HOSTILE_STATEMENT = st.tuples(st.sampled_from(["map_Kd", "Kd", "newmtl", "map_kd"]), st.lists(MTL_WORDS, max_size=5),
                              TEXTURE_NAMES)


@READERS
@given(statements=st.lists(st.one_of(VALID_STATEMENT, HOSTILE_STATEMENT), min_size=1, max_size=3),
       uv=st.sampled_from([None, None, "3e38", "nan", "-1e6", "1e7"]))
def test_mtl_fields(tmp_path_factory, statements, uv):
    """An OBJ's material library of hostile statements: texture options of
    any name and argument count, files anywhere (outside, missing, a FIFO),
    colours that are not colours; UVs of hostile size."""
    folder = tmp_path_factory.mktemp("mtl")
    for name in ("box_texture.obj", "box_texture.png"):
        shutil.copy(COLOUR / name, folder / name)
    os.mkfifo(folder / "fifo.png")
    lines = ["newmtl painted"] + [f"{key} {' '.join(words)} {'' if key == 'Kd' else name}".strip()
                                  for key, words, name in statements]
    (folder / "box_texture.mtl").write_text("\n".join(lines) + "\n")
    if uv is not None:
        text = (folder / "box_texture.obj").read_text()
        (folder / "box_texture.obj").write_text(text.replace("\nvt ", f"\nvt {uv} ", 1).replace(f"vt {uv} ", f"vt {uv} 0 #", 1))
    refused_or(lambda: surface_colour_of(folder / "box_texture.obj"), a_colour)


def one_pixel() -> bytes:
    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (1, 1), (200, 100, 50)).save(out, format="PNG")
    return out.getvalue()


IMAGE_BYTES = st.sampled_from(["good", "good", "good", "cut", "junk", "huge header", "one pixel", "empty"])


@READERS
@given(changes=st.lists(st.tuples(st.sampled_from([
    ("images", 0, "uri"), ("images", 0, "bufferView"), ("images", 0, "mimeType"), ("textures", 0, "source"),
    ("materials", 0, "pbrMetallicRoughness"), ("buffers", 0, "uri"), ("buffers", 0, "byteLength"),
    ("bufferViews", 2, "byteOffset"), ("bufferViews", 2, "buffer"), ("meshes", 0, "primitives")]),
    st.one_of(HOSTILE, st.sampled_from(["data:image/png;base64", "data:;base64,@@", "data:,x", "tex.png", "../tex.png",
                                        "/etc/passwd", "box.bin", {"baseColorFactor": [float("nan")] * 4},
                                        {"baseColorTexture": {"index": 3}}, {"baseColorTexture": "0"},
                                        {"baseColorFactor": [0.5, 1, 0.2, 1], "baseColorTexture": {"index": 0}}]),
              st.sampled_from([0, 0, "tex.png", "image/png"]))),
    max_size=2), image=IMAGE_BYTES, top=st.sampled_from([None] * 6 + ["images", "textures", "materials", "bufferViews"]))
def test_gltf_image_fields(tmp_path_factory, changes, image, top):
    """A glTF whose images, textures, materials, buffers and views hold
    hostile values (indices out of range or of the wrong type, data: URIs
    that are not base64, paths outside its folder), its image file good,
    cut short, junk, or claiming a huge size; a top-level list replaced."""
    folder = tmp_path_factory.mktemp("gltf")
    meta, binary = meshfiles.gltf_json((COLOUR / "box_texture.glb").read_bytes(), "box_texture.glb")
    view = meta["bufferViews"][meta["images"][0]["bufferView"]]
    good = binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    (folder / "tex.png").write_bytes({"good": good, "cut": good[:40], "junk": b"\x89PNG junk" * 9, "empty": b"",
                                      "huge header": good[:16] + struct.pack(">II", 2**31 - 1, 2**31 - 1) + good[24:],
                                      "one pixel": one_pixel()}[image])
    (folder / "box.bin").write_bytes(binary)
    meta["buffers"][0]["uri"] = "box.bin"
    meta["images"][0] = {"uri": "tex.png"}
    for (key, number, field), value in changes:
        meta[key][number][field] = value
    if top:
        meta[top] = {"images": [], "textures": [{"source": -1}], "materials": "x", "bufferViews": [{}]}[top]
    (folder / "box.gltf").write_text(json.dumps(meta))
    refused_or(lambda: surface_colour_of(folder / "box.gltf"), a_colour)
