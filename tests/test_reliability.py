"""Hostile input, class by class (docs/RELIABILITY.md): bounds taken from
what is really read, readers that never trace back, no user file deleted,
every HTTP error one line of JSON, and the same rules on every front end."""

import io
import json
import tracemalloc
import zipfile

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape import models
from sinshape.cli.main import cli
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.runtime import edit, load_model
from sinshape.runtime import layout as L
from sinshape.runtime.request import MAX_PARTS, SampleRequest
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
        L.parse_layout(data, ".npz", "l.npz")
    for members in ({"layout": npy(np.ones((4, 4, 4), bool))},  # no .npy: np.load reads it, the check did not
                    {"layout__npy": npy(np.ones((4, 4, 4), bool)), "notes__txt": b"x"}, {}):
        with pytest.raises(InputError, match="one array, layout.npy"):
            L.parse_layout(npz(**members), ".npz", "l.npz")


def test_an_npz_layout_is_bounded_before_its_data_is_decompressed():
    """A header declaring 128 MB of floats over a few bytes of data: refused
    with the figure, without allocating what the header says."""
    huge = npz(layout__npy=npy(header={"descr": "<f8", "fortran_order": False, "shape": (256, 256, 256)},
                               data=bytes(1000)))
    assert len(huge) < 2048
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match="holds 128 MB; a layout holds at most 64 MB"):
            L.parse_layout(huge, ".npz", "l.npz")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20, peak
    # Data shorter (or longer) than its header declares: refused, named.
    short = npz(layout__npy=npy(header={"descr": "|b1", "fortran_order": False, "shape": (64, 64, 64)},
                                data=bytes(1000)))
    with pytest.raises(InputError, match="its data is 1000 bytes and its header declares 262144"):
        L.parse_layout(short, ".npz", "l.npz")


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
