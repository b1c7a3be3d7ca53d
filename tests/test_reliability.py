"""Hostile input, class by class (docs/RELIABILITY.md): bounds taken from
what is really read, readers that never trace back, no user file deleted,
every HTTP error one line of JSON, and the same rules on every front end."""

import io
import json
import os
import re
import socket
import struct
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape import models
from sinshape.cli.main import cli
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.runtime import edit, load_model
from sinshape.runtime import layout as L, layout_files
from sinshape.runtime.request import MAX_PARTS, Layout, SampleRequest
from conftest import TINY_ONNX as TINY, finishes
from test_cli_train import assert_one_line_error


@pytest.fixture(scope="module")
def terrain():
    return load_model(models.find("terrain"), threads=1)


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def npy(array=None, header=None, data=b"") -> bytes:
    """An .npy member: an array's, or a header of our choosing followed by `data`."""
    out = io.BytesIO()
    if array is not None:
        np.save(out, array)
        return out.getvalue()
    np.lib.format.write_array_header_1_0(out, header)
    return out.getvalue() + data


def npz(**members) -> bytes:
    """A zip of the given members (name: bytes), deflated."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name.replace("__", "."), data)
    return out.getvalue()


# -- 1. a bound is taken from what will be read --------------------------------

def test_an_npz_layout_is_read_from_the_member_its_header_was_checked_in():
    """np.load reads a member named plain `layout` before `layout.npy`: an
    archive with both is refused, whatever either holds."""
    data = npz(layout__npy=npy(np.zeros((4, 4, 4), bool)), layout=npy(np.ones((300, 300, 300), bool)))
    with pytest.raises(InputError, match="holds 'layout.npy', 'layout'"):
        layout_files.parse_layout(data, ".npz", "l.npz")
    for members in ({"layout": npy(np.ones((4, 4, 4), bool))},  # no .npy: np.load reads it, the check did not
                    {"layout__npy": npy(np.ones((4, 4, 4), bool)), "notes__txt": b"x"}, {}):
        with pytest.raises(InputError, match="one array, layout.npy"):
            layout_files.parse_layout(npz(**members), ".npz", "l.npz")


def refusal_peak(data: bytes, fragment: str) -> int:
    """The most memory Python and numpy held (tracemalloc) while the layout
    `data` was refused with `fragment`, in bytes."""
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=fragment):
            layout_files.parse_layout(data, ".npz", "l.npz")
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_an_npz_layout_is_bounded_before_its_data_is_decompressed():
    """Headers declaring 128 MB and 1024 MB of floats over a few bytes of data:
    refused with the figure, without allocating what the header says. The
    refusal's peak does not grow with the header's figure: eight times more
    declared, the same peak within 1 MiB (allocating what each declares
    would differ by 896 MB). Traced allocations, not the machine's: another
    process's load does not enter."""
    def declaring(shape):
        data = npz(layout__npy=npy(header={"descr": "<f8", "fortran_order": False, "shape": shape}, data=bytes(1000)))
        assert len(data) < 2048
        return data

    peaks = [refusal_peak(declaring((256, 256, 256)), "holds 128 MB; a layout holds at most 64 MB"),
             refusal_peak(declaring((512, 512, 512)), "holds 1024 MB; a layout holds at most 64 MB")]
    assert abs(peaks[1] - peaks[0]) < 1 << 20, peaks
    # Data shorter (or longer) than its header declares: refused, named.
    short = npz(layout__npy=npy(header={"descr": "|b1", "fortran_order": False, "shape": (64, 64, 64)},
                                data=bytes(1000)))
    with pytest.raises(InputError, match="its data is 1000 bytes and its header declares 262144"):
        layout_files.parse_layout(short, ".npz", "l.npz")


def test_an_npz_layout_compressed_to_unpack_at_once_is_refused():
    """bzip2 unpacks a chunk whole (zipfile gives it no bound): 261 bytes
    hold 16 MB of layout, and a few kB gigabytes."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_BZIP2) as archive:
        archive.writestr("layout.npy", npy(np.zeros((256, 256, 256), bool)))
    assert len(out.getvalue()) < 400
    with pytest.raises(InputError, match="compressed other than as NumPy writes it"):
        layout_files.parse_layout(out.getvalue(), ".npz", "l.npz")


def test_grow_is_refused_up_front_with_the_figure_that_it_needs(terrain, monkeypatch):
    """grow 40,40,1 of the terrain holds about 15 GiB at its peak (16,16,1
    measured 2.15 GB, this estimate 2.66): refused before any work where
    8 GiB are available, where the old estimate (6.7 GiB) let it start."""
    def started(*_):
        raise AssertionError("work started")

    monkeypatch.setattr(edit, "draw_noise", started)
    with pytest.raises(MemoryLimitError, match=r"composing 1 part into a sample of 2560x1640x15 voxels needs "
                                               r"about 15\.\d GiB of memory \(limit 8\.0 GiB\)"):
        edit.grow(terrain, 3, (40.0, 40.0, 1.0), memory_limit=8 << 30)


def test_kept_boxes_are_capped_once_for_every_front_end(monkeypatch):
    boxes = ["3:0%,0%,0%:50%,100%,100%"] * (MAX_PARTS + 1)
    with pytest.raises(InputError, match=f"keep takes at most {MAX_PARTS} parts"):
        SampleRequest(1, keep=boxes)
    monkeypatch.setattr("sinshape.runtime.write.write_request", lambda *_, **__: pytest.fail("work started"))
    result = run("sample", "terrain", *[a for box in boxes for a in ("--keep", box)], "-o", "x.ply")
    assert "--keep takes at most 16 parts" in result.output and result.exit_code != 0


def test_a_layout_too_large_for_its_format_is_refused_from_the_arguments(tmp_path, monkeypatch):
    """Level 0 of a 10,10,1 terrain is 270x180x15: .vox holds 256 a side,
    which the arguments say before the layout is made."""
    monkeypatch.setattr(L, "generate_sample", lambda *_: pytest.fail("the layout was made first"))
    assert_one_line_error(run("layout", "terrain", "--size", "10,10,1", "-o", tmp_path / "l.vox"),
                          "a 270x180x15 layout; .vox holds at most 256 voxels per axis")
    assert not (tmp_path / "l.vox").exists()


# -- 2. binary and structured readers never trace back -------------------------

def vox(main_content=0, main_children=None, size=(4, 4, 4), count=1, extra=b"") -> bytes:
    """A .vox of one model with MAIN's sizes and the chunks' fields of our choosing."""
    size_chunk = b"SIZE" + struct.pack("<2i3i", 12, 0, *size)
    xyzi = b"XYZI" + struct.pack("<2ii", 8, 0, count) + bytes([1, 1, 1, 1])
    children = size_chunk + xyzi + extra
    main_children = len(children) if main_children is None else main_children
    return b"VOX " + struct.pack("<i", 150) + b"MAIN" + struct.pack("<2i", main_content, main_children) + children


@pytest.mark.parametrize("data, fragment", [
    (vox(main_content=-100), "MAIN declares -100"),  # was a 46-line struct.error traceback
    (vox(main_content=-20), "MAIN declares -20"),
    (vox(main_children=-1), "MAIN declares 0 and -1"),
    (vox(main_children=2**31 - 1), "runs past the end"),
    (vox(extra=b"nTRN" + struct.pack("<2i", -5, 0)), "declares -5"),
    (vox(count=-1), "count does not fit"),
    (vox(size=(0, 4, 4)), "a layout has 1 to 256"),
])
def test_a_vox_with_hostile_sizes_is_one_line(tmp_path, data, fragment):
    path = tmp_path / "l.vox"
    path.write_bytes(data)
    with pytest.raises(InputError, match=re.escape(fragment)):
        layout_files.read_layout(path)
    assert_one_line_error(run("sample", "terrain", "--layout", path, "-o", tmp_path / "s.ply"), fragment)


def test_an_h5_level_that_is_a_null_or_odd_dataset_is_refused(tmp_path):
    h5py = pytest.importorskip("h5py")
    from sinshape.prep import pyramid

    cases = {"null": h5py.Empty("f4"), "strings": np.array([[[b"ab"] * 15] * 15] * 15),
             "compound": np.zeros((15, 15, 15), [("a", "f4"), ("b", "i2")])}
    for name, value in cases.items():
        path = tmp_path / f"{name}.h5"
        with h5py.File(path, "w") as f:
            f.attrs["n_scales"] = 1
            f.create_dataset("scale0", data=value)
        with pytest.raises(InputError, match="scale0 is not"):
            pyramid.load_pyramid(path, res=64)
    null = tmp_path / "null_count.h5"
    with h5py.File(null, "w") as f:
        f.attrs["n_scales"] = h5py.Empty("i4")
    with pytest.raises(InputError, match="n_scales must be a whole number"):
        pyramid.load_pyramid(null, res=64)


@pytest.mark.parametrize("seed", ["1" + "0" * 400, "-1", "1e400", "3.0", '"3"', "[3]", "null", "true"])
def test_a_batch_index_with_a_hostile_seed_is_one_line_on_resume(tmp_path, seed):
    """A seed of 10**400 made a file name too long to look up: OSError."""
    out = tmp_path / "s{seed}.npz"
    assert run("sample", TINY, "--seeds", "0-1", "-o", out, "--workers", 1).exit_code == 0
    index = tmp_path / "sindex.jsonl"
    index.write_text(index.read_text() + f'{{"seed": {seed}, "file": "x", "bytes": 1, "sha256": "a"}}\n')
    assert_one_line_error(run("sample", TINY, "--seeds", "0-2", "-o", out, "--workers", 1),
                          "line 4 is not a seed's JSON record")  # after the job's line and two seeds'


@pytest.mark.parametrize("line", ['{"seed": 2, "bytes": -1}', '{"seed": 2, "sha256": 7}', '"' + "x" * 5000 + '"',
                                  "[" * 3000 + "]" * 3000, '{"seed": 2, "bytes": 1e400}'])
def test_a_batch_index_with_hostile_fields_is_one_line(tmp_path, line):
    from sinshape.runtime import many_index

    index = tmp_path / "index.jsonl"
    index.write_text(line + "\n")
    with pytest.raises(InputError, match="line 1 is not a seed's JSON record"):
        many_index.read_index(index)


def test_a_mesh_is_read_within_its_folder_and_its_memory(tmp_path, monkeypatch):
    trimesh = pytest.importorskip("trimesh")
    from sinshape.core import budget
    from sinshape.prep import voxelize

    trimesh.creation.box().export(tmp_path / "box.gltf")
    for buffer in tmp_path.glob("*.bin"):
        buffer.unlink()
    with pytest.raises(InputError, match="buffer 0's file gltf_buffer_0.bin is missing"):
        voxelize.load_mesh(tmp_path / "box.gltf")
    gltf = json.loads((tmp_path / "box.gltf").read_text())
    gltf["buffers"][0]["uri"] = "../../etc/passwd"
    (tmp_path / "out.gltf").write_text(json.dumps(gltf))
    with pytest.raises(InputError, match="buffer 0's file ../../etc/passwd lies outside its folder"):
        voxelize.load_mesh(tmp_path / "out.gltf")
    trimesh.creation.icosphere().export(tmp_path / "ball.stl")  # 64 kB, 1.5 MB to load
    monkeypatch.setattr(budget, "available_memory", lambda: 1 << 20)
    with pytest.raises(MemoryLimitError, match="reading the mesh .*ball.stl needs about"):
        voxelize.load_mesh(tmp_path / "ball.stl")


@pytest.fixture(scope="module")
def checkpoint(tiny_model):
    """The session's tiny model's checkpoint, which conftest's training leaves beside it."""
    pytest.importorskip("torch")
    return tiny_model.with_name("tiny.ckpt.pt")


@pytest.mark.parametrize("field, value, fragment", [
    ("level", -1, "level must be"), ("level", 99, "level must be"), ("iteration", "x", "iteration"),
    ("sizes", [[15, 15, -15]], "sizes must be"), ("noise_amps", [float("nan")], "noise_amps"),
    ("seconds", "fast", "seconds must be"), ("config", {"res": "big"}, "its config"),
    ("config", {"res": 1}, "its config: res 1 is below"), ("generator", {"levels.0.w": 3}, "tables of tensors"),
    ("source", {"name": 1}, "source must"), ("rng", [1, 2], "rng must be"), ("level_seconds", float("inf"), "level_seconds"),
])
def test_a_checkpoint_with_hostile_fields_is_refused_before_it_is_used(checkpoint, tmp_path, field, value, fragment):
    import torch

    from sinshape.trainer.checkpoint import load_checkpoint

    state = torch.load(checkpoint, weights_only=True)
    state[field] = value
    bad = tmp_path / "bad.ckpt.pt"
    torch.save(state, bad)
    with pytest.raises(InputError, match=f"a damaged checkpoint .*{re.escape(fragment)}"):
        load_checkpoint(bad)


def test_a_checkpoint_holding_a_pickled_object_is_never_unpickled(checkpoint, tmp_path):
    import torch

    from sinshape.trainer.checkpoint import load_checkpoint

    state = torch.load(checkpoint, weights_only=True)
    state["config"] = Exploit()
    bad = tmp_path / "evil.ckpt.pt"
    torch.save(state, bad)
    with pytest.raises(InputError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    assert not (tmp_path / "pwned").exists()


def test_a_checkpoint_whose_tensors_do_not_fit_is_one_line(checkpoint, tmp_path, tiny_pyramid):
    import torch

    state = torch.load(checkpoint, weights_only=True)
    name = next(k for k in state["generator"] if k.endswith("weight"))
    state["generator"][name] = torch.zeros(1)
    state["level"] = 0
    torch.save(state, tmp_path / "m.ckpt.pt")
    result = run("train", tiny_pyramid, "-o", tmp_path / "m.onnx", "--resume")
    last = result.output.strip().splitlines()[-1]
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert last.startswith("Error: ") and "a checkpoint whose state does not fit its networks (Error(s) in " \
        "loading state_dict for TriplaneGenerator: size mismatch" in last


class Exploit:
    def __reduce__(self):
        return (os.system, ("touch pwned",))


# -- 3. nothing the user made is deleted ----------------------------------------

def tree(folder) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_export_web_again_keeps_what_the_user_added(tmp_path):
    """The folder's files and the user's notes: a second export refuses to
    run over the notes (naming them) unless --force, which keeps them."""
    out = tmp_path / "site"
    assert run("export-web", "terrain", "towerruins", "-o", out).exit_code == 0
    (out / "notes.txt").write_text("mine")
    (out / "models" / "mine.csv").write_text("1,2")
    (out / "index.html").write_text(before := (out / "index.html").read_text() + "<!-- my edit -->")
    snapshot = tree(out)
    assert_one_line_error(run("export-web", "terrain", "-o", out),
                          "holds files export-web did not write (index.html, models/mine.csv, notes.txt)", "--force")
    assert tree(out) == snapshot
    result = run("export-web", "terrain", "-o", out, "--force")
    assert result.exit_code == 0, result.output
    after = tree(out)
    assert after["notes.txt"] == b"mine" and after["models/mine.csv"] == b"1,2"
    assert after["index.html"].decode() != before  # the command's own file, replaced as asked
    assert "models/towerruins.onnx" not in after and "models/terrain.onnx" in after  # its own, no longer listed
    assert run("export-web", "terrain", "-o", out).exit_code != 0  # the user's files are still in the way
    (out / "notes.txt").unlink()
    (out / "models" / "mine.csv").unlink()
    assert run("export-web", "terrain", "-o", out).exit_code == 0  # only its own files: replaced, no question


def test_export_web_names_a_link_or_other_thing_in_the_way(tmp_path):
    out = tmp_path / "site"
    assert run("export-web", "terrain", "-o", out).exit_code == 0
    (out / "data").symlink_to(tmp_path)
    assert_one_line_error(run("export-web", "terrain", "-o", out), "did not write (data)")


def test_a_symbolic_link_output_is_written_through_by_every_command(tmp_path):
    """One policy: the file a link leads to is replaced, atomically; the link stays."""
    real, link = tmp_path / "real", tmp_path / "link"
    for suffix, args in [(".npz", ["sample", TINY, "--seed", 1]), (".npz", ["layout", TINY]),
                         (".png", ["render", TINY, "--seeds", "0", "--image-size", 64])]:
        target, name = real.with_suffix(suffix), link.with_suffix(suffix)
        target.write_bytes(b"old")
        name.unlink(missing_ok=True)
        name.symlink_to(target)
        result = run(*args, "-o", name)
        assert result.exit_code == 0, result.output
        assert name.is_symlink() and target.read_bytes() != b"old", args
    folder = tmp_path / "real_site"
    folder.mkdir()
    (tmp_path / "site").symlink_to(folder)
    assert run("export-web", TINY, "-o", tmp_path / "site").exit_code == 0
    assert (tmp_path / "site").is_symlink() and (folder / "index.html").is_file()
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    assert_one_line_error(run("sample", TINY, "-o", tmp_path / "loop"), "goes round in a loop")


# -- 4. every error over HTTP is JSON, from every layer ------------------------

@pytest.fixture(scope="module")
def server():
    pytest.importorskip("uvicorn")
    from test_serve import running_server

    with running_server("terrain", "--threads", 2) as (base, _):
        yield base


def raw(base: str, request: bytes) -> tuple:
    """(status, headers, body) of bytes sent as they are, on one connection that the server closes or we read to its length."""
    host, port = base.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as connection:
        connection.sendall(request)
        data = b""
        while b"\r\n\r\n" not in data:
            data += connection.recv(65536) or b"\r\n\r\n"
        head, body = data.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:] if ":" in line)}
        length = int(headers.get("content-length", 0)) if not request.startswith(b"HEAD") else 0
        while len(body) < length:
            more = connection.recv(65536)
            if not more:
                break
            body += more
    return int(lines[0].split()[1]), headers, body


def ask(method: str, path: str, *headers: str, body: bytes = b"") -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1", "Connection: close", *headers]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


def assert_json_error(answer, status, fragment=""):
    got, headers, body = answer
    assert got == status and headers["content-type"] == "application/json", answer
    detail = json.loads(body)["detail"]
    assert isinstance(detail, str) and "\n" not in detail and fragment in detail, detail


@pytest.mark.parametrize("request_bytes, status, fragment", [
    (ask("GET", "/static/viewer.js", "Range: bytes=abc"), 400, "Range header"),
    (ask("GET", "/static/viewer.js", "Range: bytes=99999999-"), 416, "Range Not Satisfiable"),
    (ask("POST", "/api/models/terrain/sample", "Content-Length: -5"), 400, "Invalid HTTP request"),
    (b"GARBAGE\r\n\r\n", 400, "Invalid HTTP request"),
    (ask("GET", "/nowhere"), 404, "Not Found"),
    (ask("GET", "/static/nothing.js"), 404, "Not Found"),
    (ask("DELETE", "/health"), 405, "Method Not Allowed"),
    (ask("GET", "/api/models/terrain/sample?" + "&".join(["keep=3:0%,0%,0%:50%,100%,100%"] * 17)), 400,
     "keep takes at most 16 parts"),
    (ask("POST", "/api/models/terrain/sample", "Content-Length: 60",
         body=b"VOX \x96\x00\x00\x00MAIN\x9c\xff\xff\xff" + bytes(44)), 400, "MAIN declares -100"),
])
def test_every_http_error_is_one_line_of_json(server, request_bytes, status, fragment):
    assert_json_error(raw(server, request_bytes), status, fragment)


@pytest.mark.parametrize("path", ["/health", "/api/models/terrain", "/api/models/terrain/onnx", "/static/viewer.js",
                                  "/", "/api/models/terrain/sample?seed=2&format=npz"])
def test_head_answers_wherever_get_does(server, path):
    status, headers, body = raw(server, ask("GET", path))
    head_status, head_headers, head_body = raw(server, ask("HEAD", path))
    assert status == head_status == 200 and head_body == b""
    assert head_headers.get("etag") == headers.get("etag") and head_headers["content-type"] == headers["content-type"]


@pytest.mark.parametrize("path", ["/api/models/terrain/onnx", "/static/viewer.js", "/api/models/terrain/sample?seed=2",
                                  "/health"])
def test_if_none_match_star_is_304_where_the_resource_exists(server, path):
    status, headers, body = raw(server, ask("GET", path, "If-None-Match: *"))
    assert status == 304 and body == b"", (status, body[:200])
    assert_json_error(raw(server, ask("GET", "/api/models/nothing/onnx", "If-None-Match: *")), 404, "unknown model")


# -- 5. the same rules on every front end, and messages that say what is wrong --

def test_anchor_without_grow_is_refused_over_http_as_on_the_command_line(server):
    result = run("sample", TINY, "--anchor", "0.5,0,0", "-o", "x.npz")
    assert result.exit_code == 2 and result.output.strip().endswith("Error: --anchor is for --grow")
    assert_json_error(raw(server, ask("GET", "/api/models/terrain/sample?seed=1&anchor=0.5,0,0")), 400,
                      "anchor is for grow")


def test_an_all_nan_layout_is_refused_not_read_as_empty(tmp_path):
    path = tmp_path / "l.npz"
    np.savez(path, layout=np.full((27, 18, 15), np.nan))
    assert_one_line_error(run("sample", "terrain", "--layout", path, "-o", tmp_path / "s.ply"), "NaN or infinite")
    with pytest.raises(InputError, match="not NaN"):
        SampleRequest(1, layout=Layout.of(np.full((4, 4, 4), np.inf)))
    assert not (tmp_path / "s.ply").exists()


def test_a_truncated_model_says_truncated_or_corrupt(tmp_path):
    path = tmp_path / "cut.onnx"
    path.write_bytes(TINY.read_bytes()[:len(TINY.read_bytes()) // 2])
    assert_one_line_error(run("sample", path, "-o", tmp_path / "s.npz"), "cut.onnx: not an ONNX file (truncated or corrupt)")


def varint(n: int) -> bytes:
    out = b""
    while True:
        out += bytes([(n & 0x7F) | (0x80 if n > 0x7F else 0)])
        n >>= 7
        if not n:
            return out


def test_a_sealed_model_with_two_manifests_is_refused(tmp_path):
    """Which manifest would be the model's? Neither: refused, sealed or not."""
    from sinshape.core import manifest as fmt
    from sinshape.runtime import onnxfile

    body, sealed, intact = fmt.unseal(TINY.read_bytes())
    assert sealed and intact
    text = json.loads(onnxfile.parse(body).metadata[fmt.METADATA_KEY])
    text["levels"][0]["noise_amp"] = 2.0
    entry = b"\x0a" + varint(len(fmt.METADATA_KEY)) + fmt.METADATA_KEY.encode()
    value = json.dumps(text).encode()
    entry += b"\x12" + varint(len(value)) + value
    path = tmp_path / "two.onnx"
    path.write_bytes(fmt.seal(body + b"\x72" + varint(len(entry)) + entry))
    assert_one_line_error(run("info", path), "corrupt model: it holds sinshape.manifest twice")


def test_a_box_in_percent_is_refused_in_percent_too(terrain):
    with pytest.raises(InputError, match=re.escape("the box is 3.15 (5%) voxels along x: a kept box needs more than "
                                                   "8 (12.6984%)")):
        edit.parse_part("3:40%,0%,0%:45%,100%,100%", terrain.manifest, (64, 41, 15))
    with pytest.raises(InputError, match=re.escape("the box is 3.99994 (0.5) voxels along x: a kept box needs more than 8 (1.00002)")):
        edit.parse_part("3:1,0%,0%:1.5,100%,100%", terrain.manifest, (64, 41, 15))  # the model's frame
    with pytest.raises(InputError, match=re.escape("94.5 (150%) voxels along x) leaves the sample, whose voxels run 0 to 63 (100%)")):
        edit.parse_part("3:0%,0%,0%:150%,100%,100%", terrain.manifest, (64, 41, 15))


def test_seed_in_a_folder_name_is_refused_not_taken_literally(tmp_path):
    (tmp_path / "d_{seed}").mkdir()
    for args in (["--seeds", "0-1"], ["--seed", "1"]):
        result = run("sample", TINY, *args, "-o", tmp_path / "d_{seed}" / "s.npz")
        assert result.exit_code in (1, 2) and "{seed} fills in the file's name, not its folder" in result.output
        assert "Traceback" not in result.output
    assert not any((tmp_path / "d_{seed}").iterdir())
    from sinshape.runtime import many

    with pytest.raises(InputError, match="fills in the file's name"):
        many.sample_many(TINY, [0], tmp_path / "d_{seed}" / "s{seed}.npz")


@pytest.mark.parametrize("name", ["a\nError: fake.npz", "a\rb.npz", "tab\there.npz"])
def test_an_output_name_with_a_control_character_is_refused_in_one_line(tmp_path, name):
    result = run("sample", TINY, "-o", tmp_path / name)
    assert_one_line_error(result, "a file name with a control character")
    assert list(tmp_path.iterdir()) == []


# -- every file a user names is looked at before a byte of it is read ------------------------------

def special_file(tmp_path, kind: str, suffix: str) -> Path:
    """A FIFO, /dev/zero or a link to it, named like the file asked for."""
    if kind == "device":
        return Path("/dev/zero")
    path = tmp_path / f"special{suffix}"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")
    return path


FILES = [(["world", "terrain", "--tiles", "0:0,0:0", "-o", "{out}", "--map"], ".npy", "the height map"),
         (["world", "terrain", "--tiles", "0:0,0:0", "-o", "{out}", "--map"], ".png", "the height map"),
         (["world", "terrain", "--tiles", "0:0,0:0", "--arrange", "scatter", "-o", "{out}", "--models-map"], ".png",
          "the model map"),
         (["sample", "terrain", "-o", "{out}.ply", "--layout"], ".npz", "the layout"),
         (["sample", "-o", "{out}.ply"], ".onnx", "the model file"),
         (["train", "-o", "{out}.onnx"], ".obj", "the mesh or .h5 file")]


# /dev/zero itself where no file type is read from the name (a map's is its content's)
SPECIAL = [(kind, *file) for file in FILES for kind in ("fifo", "link", *(("device",) if "map" in file[2] else ()))]


@pytest.mark.parametrize("kind, command, suffix, what", SPECIAL,
                         ids=[f"{k}-{c[0]}-{w.split()[-1]}{s}" for k, c, s, w in SPECIAL])
def test_a_named_file_that_is_not_a_regular_file_is_refused_before_it_is_read(tmp_path, kind, command, suffix, what):
    """A FIFO as a map hung `sinrun world` for ever; /dev/zero (or a link to
    it) was read until memory ran out, ending in a MemoryError traceback."""
    path = special_file(tmp_path, kind, suffix)
    args = [a.replace("{out}", str(tmp_path / "out")) for a in command] + [path]
    if command[0] == "train":
        pytest.importorskip("torch", reason="train needs the train extra")
        args = ["train", path, *args[1:-1]]
    elif command[0] == "sample" and suffix == ".onnx":
        args = ["sample", path, *args[1:-1]]
    result = finishes(lambda: run(*args))
    device = "a FIFO" if kind == "fifo" else "a device"
    assert result.exit_code != 0 and f"{what} {path} is {device}, not a regular file" in result.output, result.output
    assert result.output.count("\n") == 1 and not list(tmp_path.glob("out*"))


def test_a_map_too_large_is_refused_by_its_size_before_it_is_read(tmp_path):
    """A 2 GB sparse .npy map was refused only after 2.1 GB had been read into memory."""
    path = tmp_path / "s.npy"
    with open(path, "wb") as file:
        file.truncate(1 << 30)
    tracemalloc.start()
    result = run("world", "terrain", "--tiles", "0:0,0:0", "--map", path, "-o", tmp_path / "w")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert result.exit_code == 1 and f"the height map {path} is 1024.0 MiB; at most 64 MiB is read for it" in result.output
    assert peak < 64 << 20, f"{peak >> 20} MiB held before the refusal"
