"""Hostile jobs (docs/RELIABILITY.md): a resume that checks it is the job
its index records, world blocks and tile ranges bounded up front, indexes
that are regular files, a tile's sampling slot freed when it is given up,
the exported site's serve.py answering in JSON, and a checkpoint that cannot
be written."""

import json
import os
import resource
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request

import pytest
from click.testing import CliRunner

from conftest import TINY_ONNX as TINY, finishes
from sinshape.cli.main import cli
from sinshape.core import budget
from sinshape.core.errors import InputError
from sinshape.runtime import many
from test_cli_train import assert_one_line_error


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


# -- 3. a resume checks that it is the job its index records --------------------------------------

def test_a_seeds_job_over_another_jobs_index_is_refused_naming_the_difference(tmp_path):
    """`--seeds --scale 2` over a `--scale 1` job said "wrote 0 files, 2
    already done" and left the other job's files."""
    out = tmp_path / "{seed}.npz"
    assert run("sample", TINY, "--seeds", "0-1", "-o", out, "--workers", 1).exit_code == 0
    before = (tmp_path / "0.npz").read_bytes()
    assert_one_line_error(run("sample", TINY, "--seeds", "0-1", "--scale", 2, "-o", out, "--workers", 1),
                          "index.jsonl: records another job (scale 1.0, not 2.0); --restart makes the files again")
    assert (tmp_path / "0.npz").read_bytes() == before
    assert_one_line_error(run("sample", "terrain", "--seeds", "0-1", "-o", out, "--workers", 1),
                          "records another job (another model (tiny.onnx, sha256")
    result = run("sample", TINY, "--seeds", "0-1", "--scale", 2, "-o", out, "--workers", 1, "--restart")
    assert result.exit_code == 0 and "wrote 2 files" in result.output, result.output
    assert (tmp_path / "0.npz").read_bytes() != before
    job = json.loads((tmp_path / "index.jsonl").read_text().splitlines()[0])["job"]
    assert job["request"]["scale"] == 2.0 and job["files"] == "{seed}.npz" and len(job["model"]) == 64
    again = run("sample", TINY, "--seeds", "0-2", "--scale", 2, "-o", out, "--workers", 1)
    assert again.exit_code == 0 and "wrote 1 files, 2 already done" in again.output  # the same job resumes


def test_a_world_over_another_worlds_folder_is_refused(tmp_path):
    """A world of seed 5 in seed 0's folder, or of another model: "wrote 0 files, N already done"."""
    out = tmp_path / "w"
    assert run("world", TINY, "--seed", 0, "--tiles", "0,0:1", "-o", out, "--workers", 1).exit_code == 0
    assert_one_line_error(run("world", TINY, "--seed", 5, "--tiles", "0,0:1", "-o", out, "--workers", 1),
                          "tile_index.jsonl: records another job (seed 0, not 5)")
    assert_one_line_error(run("world", "terrain", "--seed", 0, "--tiles", "0,0:1", "-o", out, "--workers", 1),
                          "records another job (another model")


def test_an_index_written_before_a_request_field_was_added_resumes_at_its_default(tmp_path):
    """A world's index from before `underside` (its job without the field) resumes the same job,
    made as the tiles were then, closed underneath; asked open underneath, it is another job."""
    out = tmp_path / "w"
    assert run("world", TINY, "--tiles", "0,0:1", "-o", out, "--workers", 1).exit_code == 0
    index = out / "tile_index.jsonl"
    first, *rest = index.read_text().splitlines()
    job = json.loads(first)
    assert job["job"]["request"].pop("underside") is True
    index.write_text("\n".join([json.dumps(job), *rest]) + "\n")
    again = run("world", TINY, "--tiles", "0,0:2", "-o", out, "--workers", 1)
    assert again.exit_code == 0 and "wrote 1 files, 2 already done" in again.output, again.output
    assert_one_line_error(run("world", TINY, "--tiles", "0,0:2", "--no-underside", "-o", out, "--workers", 1),
                          "records another job (underside null, not false)")


def test_an_index_that_records_no_job_is_refused(tmp_path):
    (tmp_path / "index.jsonl").write_text('{"seed": 0, "file": "0.npz", "bytes": 1, "sha256": "x"}\n')
    with pytest.raises(InputError, match="records no job .*; restart makes the files again"):
        many.sample_many(TINY, [0], tmp_path / "{seed}.npz", workers=1)
    assert many.sample_many(TINY, [0], tmp_path / "{seed}.npz", workers=1, restart=True)["written"] == 1


# -- 4. world blocks, tile ranges and indexes bounded up front ------------------------------------

def test_a_huge_block_of_tiles_is_refused_before_it_is_listed():
    """100000 x 100000 tiles: a MemoryError listing them."""
    assert_one_line_error(run("world", "terrain", "--tiles", "0:99999,0:99999", "-o", "block.ply"),
                          "a block is 1 to 4096 tiles, got 10000000000")


def test_a_block_that_would_not_fit_is_refused_with_the_figure(tmp_path, monkeypatch):
    """4096 tiles at scale 2 under a 2.5 GiB limit: refused after its first tile, with the figure."""
    from sinshape.runtime import world_tiles

    made = []
    tile_mesh = world_tiles.tile_mesh
    monkeypatch.setattr(world_tiles, "tile_mesh", lambda *a, **k: made.append(a[2]) or tile_mesh(*a, **k))
    monkeypatch.setattr(budget, "available_memory", lambda: int(2.5 * 2**30))
    assert_one_line_error(run("world", "terrain", "--tiles", "0:63,0:63", "--scale", 2, "-o", tmp_path / "b.ply"),
                          "a block of 4096 tiles at scale 2 (about", "needs about", "(limit 2.5 GiB)")
    assert made == [(0, 0)] and not (tmp_path / "b.ply").exists()


def test_a_tile_range_whose_length_overflows_is_one_line(tmp_path):
    """len() of 2^62 x 2^62 tiles raised OverflowError."""
    far = f"{-(2**62) + 1}:{2**62 - 1}"
    assert_one_line_error(run("world", "terrain", "--tiles", f"{far},{far}", "-o", tmp_path / "w"),
                          "voxels from the world's origin")
    assert_one_line_error(run("world", "terrain", "--tiles", f"{far},{far}", "-o", tmp_path / "b.ply"),
                          "a block is 1 to 4096 tiles, got 9223372036854775807")


@pytest.mark.parametrize("kind", ["folder", "fifo", "sparse"])
def test_an_index_that_is_not_a_regular_file_is_refused(tmp_path, kind, monkeypatch):
    """An index that is a folder traced back, a FIFO hung, a 6 GiB sparse file
    was read whole: now its first line (a 4 kB bound) is all that is read,
    where memory would allow the whole (here, 1 TiB; else its figure refuses it)."""
    monkeypatch.setattr(budget, "available_memory", lambda: 1 << 40)
    index = tmp_path / "index.jsonl"
    if kind == "folder":
        index.mkdir()
    elif kind == "fifo":
        os.mkfifo(index)
    else:
        with open(index, "wb") as f:
            f.truncate(6 << 30)
    result = finishes(lambda: run("sample", TINY, "--seeds", "0-1", "-o", tmp_path / "{seed}.npz", "--workers", 1))
    fragment = {"folder": "the job's index is a folder, not a regular file",
                "fifo": "the job's index is a FIFO, not a regular file",
                "sparse": "not a sinshape index (line 1 is not a seed's JSON record)"}[kind]
    assert_one_line_error(result, fragment)
    assert not (tmp_path / "0.npz").exists()


def test_a_tiles_work_stops_within_a_slab_when_it_is_given_up():
    """A tile's job never looked at its checkpoint: a client that left a slow
    tile kept its slot busy to the end (22 s). It looks after each window
    and each slab of rows, so the sampler stops it there."""
    from sinshape import models
    from sinshape.runtime import load_model
    from sinshape.runtime.request import SampleRequest
    from sinshape.serve.jobs import Job, make_sample
    from sinshape.serve.sampler import Cancelled

    model = load_model(models.find("terrain"), threads=1)
    calls = []

    def checkpoint(*_):
        calls.append(1)
        if len(calls) == 6:  # the four windows are made, then a slab or two
            raise Cancelled

    with pytest.raises(Cancelled):
        make_sample(model, Job("terrain", SampleRequest(1, scale=4, tile=(2, 3)), "ply"), checkpoint)
    assert len(calls) == 6


def test_a_grids_job_given_up_stops_before_its_grid_is_made(tiny_model, monkeypatch):
    """A sample's .npz job looks at its checkpoint between its tri-plane and
    its dense grid, the larger part of its work: given up by then, no grid is made."""
    from sinshape.runtime import load_model, write
    from sinshape.runtime.request import SampleRequest
    from sinshape.serve.jobs import Job, make_sample
    from sinshape.serve.sampler import Cancelled

    made = []
    monkeypatch.setattr(write, "dense_grids", lambda *args: made.append(args))

    def checkpoint(*_):
        raise Cancelled

    with pytest.raises(Cancelled):
        make_sample(load_model(tiny_model, threads=1), Job("tiny", SampleRequest(1), "npz"), checkpoint)
    assert not made


# -- 5. a colour head that gives no finite colour is refused at load ------------------------------

def test_a_colour_head_that_overflows_is_refused_at_load(tmp_path):
    """Finite colour weights of +-3e38, sealed: samples of NaN colours were written black, exit 0."""
    onnx = pytest.importorskip("onnx")
    import numpy as np
    from onnx import numpy_helper

    from conftest import sealed_bytes

    proto = onnx.load(TINY.with_name("tiny_colour.onnx"))
    for weight in proto.graph.initializer:
        if weight.name == "decoder_head.weight_colour":
            values = numpy_helper.to_array(weight)
            signs = np.where(np.arange(values.size).reshape(values.shape) % 2, 1, -1)
            weight.CopyFrom(numpy_helper.from_array((3e38 * signs).astype(np.float32), weight.name))
    (tmp_path / "bad.onnx").write_bytes(sealed_bytes(proto))
    assert_one_line_error(run("sample", tmp_path / "bad.onnx", "-o", tmp_path / "s.ply"),
                          "its colour head gives no finite colour for its own reconstruction")
    assert not (tmp_path / "s.ply").exists()
    assert run("sample", TINY.with_name("tiny_colour.onnx"), "-o", tmp_path / "s.ply").exit_code == 0


# -- 6. the site's serve.py, and a checkpoint that cannot be written ------------------------------

def site_server(*args) -> subprocess.CompletedProcess:
    from sinshape.serve import site_server as module

    return subprocess.run([sys.executable, "-I", "-S", module.__file__, *map(str, args)], capture_output=True,
                          text=True, timeout=30)


@pytest.mark.parametrize("port, fragment", [("http", "give one port, a whole number from 0 to 65535"),
                                            ("70000", "a whole number from 0 to 65535"), ("-1", "0 to 65535"),
                                            ("1 2", "give one port")])
def test_the_sites_serve_py_refuses_a_bad_port_in_one_line(port, fragment):
    result = site_server(*port.split())
    assert_one_line_error(result, fragment)


def test_the_sites_serve_py_refuses_a_taken_port_in_one_line():
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert_one_line_error(site_server(port), f"cannot listen on 127.0.0.1:{port}")


def test_the_sites_serve_py_answers_errors_in_json(tmp_path):
    from sinshape.serve import site_server as module

    (tmp_path / "index.html").write_text("hi")
    server = module.make_server(str(tmp_path), 0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    try:
        for path, method, status in (("/nothing.js", "GET", 404), ("/", "POST", 501), ("/nothing.js", "HEAD", 404)):
            with pytest.raises(urllib.error.HTTPError) as answer:
                urllib.request.urlopen(urllib.request.Request(base + path, method=method), timeout=10)
            assert answer.value.code == status and answer.value.headers["Content-Type"] == "application/json"
            body = answer.value.read()
            if method != "HEAD":
                detail = json.loads(body)["detail"]
                assert isinstance(detail, str) and detail and "\n" not in detail
    finally:
        server.shutdown()
        server.server_close()


def test_a_checkpoint_that_cannot_be_written_is_one_line_and_keeps_the_last(tmp_path):
    """Under a file-size limit (or on a full disk) torch's writer traced back
    (inline_container.cc): the real writer, against a real limit."""
    torch = pytest.importorskip("torch")
    from sinshape.trainer.checkpoint import atomic_save

    checkpoint = tmp_path / "m.ckpt.pt"
    atomic_save({"weights": torch.zeros(1000)}, checkpoint)
    kept = checkpoint.read_bytes()
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    ignored = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # write() then fails with EFBIG, as on a full disk
    try:
        resource.setrlimit(resource.RLIMIT_FSIZE, (len(kept) + 1000, limits[1]))
        with pytest.raises(InputError) as error:
            atomic_save({"weights": torch.zeros(100000)}, checkpoint)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, limits)
        signal.signal(signal.SIGXFSZ, ignored)
    assert str(error.value) == (f"{checkpoint}: cannot write the checkpoint (writing it failed: a full disk, or a "
                                "file-size limit?); the last checkpoint written is kept")
    assert checkpoint.read_bytes() == kept and [p.name for p in tmp_path.iterdir()] == ["m.ckpt.pt"]
