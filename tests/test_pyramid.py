"""Pyramid sizes, HDF5 reading and training targets."""

import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from conftest import write_pyramid
from sinshape.prep import pyramid, shapes
from sinshape.cli.main import cli
from sinshape.runtime import load_model
from sinshape.core.errors import InputError


def test_level_count_gives_a_coarsest_side_of_22_to_33():
    assert pyramid.level_count(128) == 6  # 128 96 72 54 41 31
    assert pyramid.level_count(64) == 4  # 64 48 36 27
    assert pyramid.level_count(33) == 1
    for res in range(34, 600, 7):
        count = pyramid.level_count(res)
        sizes = pyramid.level_sizes((res, res, res), count)
        assert 22 <= max(sizes[0]) <= 33


# The level sizes of three pyramids the SSG authors published (their files'
# scale0 .. scale{n-1} shapes; the files themselves are not shipped).
SSG_PYRAMIDS = {
    "Canyon_r128s6": [(31, 31, 15), (41, 41, 15), (54, 54, 15), (72, 72, 15), (96, 96, 20), (128, 128, 26)],
    "NaturalArch_r128s7": [(15, 15, 24), (17, 19, 31), (21, 23, 41), (28, 30, 54), (38, 40, 72), (50, 54, 96),
                           (66, 72, 128)],
    "SmallTown_r128s6": [(31, 15, 21), (41, 15, 27), (54, 20, 36), (72, 26, 48), (96, 34, 64), (128, 46, 84)],
}


@pytest.mark.parametrize("name", SSG_PYRAMIDS)
def test_level_sizes_reproduce_the_ssg_pyramids(name):
    sizes = SSG_PYRAMIDS[name]
    stretched = pyramid.level_sizes(sizes[-1], len(sizes))
    # The longest side follows the ceil(0.75 x) chain exactly. The SSG files
    # voxelised each level at that side and cropped it, so the other axes
    # agree with the per-axis chain to within a voxel.
    assert [max(s) for s in stretched] == [max(s) for s in sizes]
    assert np.abs(np.array(stretched) - np.array(sizes)).max() <= 1


def test_too_many_levels_for_the_15_voxel_minimum_is_refused():
    with pytest.raises(InputError, match="15-voxel minimum; use fewer levels or a higher res$") as refused:
        pyramid.level_sizes((32, 20, 20), 5)
    assert refused.value.parameter == "res"


def test_h5_pyramid_is_read_coarsest_first(tmp_path):
    path = write_pyramid(tmp_path / "p.h5", [(15, 15, 15), (20, 18, 15), (26, 24, 16)])
    p = pyramid.load_pyramid(path, res=64)
    assert p.sizes == [(15, 15, 15), (20, 18, 15), (26, 24, 16)]
    assert p.source_kind == "pyramid" and len(p.source_sha256) == 64
    assert pyramid.load_pyramid(path, res=64, levels=2).sizes == [(20, 18, 15), (26, 24, 16)]


def test_h5_finest_first_is_reordered(tmp_path):
    path = write_pyramid(tmp_path / "p.h5", [(26, 24, 16), (20, 18, 15)])
    assert pyramid.load_pyramid(path, res=64).sizes == [(20, 18, 15), (26, 24, 16)]


def test_bad_h5_files_are_refused(tmp_path):
    no_attr = tmp_path / "a.h5"
    with h5py.File(no_attr, "w") as f:
        f.create_dataset("scale0", data=np.ones((15, 15, 15), bool))
    missing = tmp_path / "b.h5"
    with h5py.File(missing, "w") as f:
        f.attrs["n_scales"] = 2
        f.create_dataset("scale0", data=np.ones((15, 15, 15), bool))
    empty = tmp_path / "c.h5"
    with h5py.File(empty, "w") as f:
        f.attrs["n_scales"] = 1
        f.create_dataset("scale0", data=np.zeros((15, 15, 15), bool))
    garbage = tmp_path / "d.h5"
    garbage.write_bytes(b"not hdf5 at all")
    for path, message in [(no_attr, "n_scales"), (missing, "scale1"), (empty, "empty"), (garbage, "HDF5")]:
        with pytest.raises(InputError, match=message):
            pyramid.load_pyramid(path, res=64)
    with pytest.raises(InputError, match="mesh or .h5 file .* is missing"):
        pyramid.load_pyramid(tmp_path / "nothing.h5", res=64)


def test_training_targets_are_blurred_and_clipped(tiny_pyramid):
    p = pyramid.load_pyramid(tiny_pyramid, res=64)
    for level, target in zip(p.levels, pyramid.training_targets(p, 0.5)):
        assert target.dtype == np.float32 and target.shape == level.shape
        assert target.min() >= 0 and target.max() <= 1
        soft = (target > 0.01) & (target < 0.99)
        assert soft.any()  # the surface is blurred...
        assert np.array_equal(target > 0.5, level) or np.mean((target > 0.5) != level) < 0.01  # ...not moved


def test_prep_does_not_import_torch():
    """Evaluation prepares its reference here on machines without torch."""
    code = ("import sys; from sinshape.prep import pyramid, shapes, voxelize; "
            "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith(('torch.', 'sinshape.trainer'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_reference_grid_follows_the_models_settings(tmp_path):
    """A model trained with another minimum side is scored against a grid
    built with that minimum, not the default one."""
    mesh = tmp_path / "stairs.obj"
    shapes.write_shape("stairs", mesh, detail=4)
    def manifest(**config):
        return SimpleNamespace(raw={"config": {"res": 24, **config}}, sizes=[(24, 24, 24)])

    default = pyramid.reference_grid(mesh, manifest())
    assert default.shape == pyramid.load_pyramid(mesh, res=24, levels=1).levels[-1].shape
    assert min(default.shape) >= pyramid.MIN_SIZE
    tall = pyramid.reference_grid(mesh, manifest(min_size=22))
    assert min(tall.shape) == 22 and max(tall.shape) == 24
    assert pyramid.reference_grid(mesh, manifest(), scale=2).shape[np.argmax(default.shape)] == 48


# Boxes of several aspect ratios; at res 24 the last two have axes under 15
# voxels, which are voxelised with 15 thinner voxels.
BOXES = [(2, 2, 2), (2, 1.2, 0.9), (3, 1, 0.2), (0.3, 2, 0.5)]


@pytest.mark.parametrize("extents", BOXES)
def test_the_frame_puts_the_finest_grid_on_the_mesh(tmp_path, extents):
    """origin + index * spacing (per axis) is where a finest voxel's centre
    lies in the input's frame: the occupied voxels cover the mesh's box."""
    import trimesh

    path = tmp_path / "box.obj"
    trimesh.creation.box(extents).apply_translation((5, -2, 1)).export(path)
    p = pyramid.load_pyramid(path, res=24, levels=1)
    spacing = np.array(p.spacing)
    occupied = np.argwhere(p.levels[-1])
    low = np.array(p.origin) + (occupied.min(axis=0) - 0.5) * spacing
    high = np.array(p.origin) + (occupied.max(axis=0) + 0.5) * spacing
    bounds = trimesh.load(path).bounds
    assert np.all(np.abs(low - bounds[0]) <= spacing) and np.all(np.abs(high - bounds[1]) <= spacing)


def h5_file(path, n_scales="count", **grids):
    """An .h5 file with the given datasets and n_scales (their count by default)."""
    with h5py.File(path, "w") as f:
        if n_scales is not None:
            f.attrs["n_scales"] = len(grids) if n_scales == "count" else n_scales
        for name, data in grids.items():
            f.create_dataset(name, data=data) if isinstance(data, np.ndarray) else f.create_group(name)
    return path


GOOD = np.ones((15, 15, 15), bool)
BAD_H5 = {
    "nan_grid": ({"scale0": np.full((15, 15, 15), np.nan, np.float32)}, "count", "NaN or infinite"),
    "inf_value": ({"scale0": np.where(GOOD, np.inf, 0).astype(np.float32)}, "count", "NaN or infinite"),
    "values_255": ({"scale0": GOOD.astype(np.uint8) * 255}, "count", "not occupancy in [0, 1]"),
    "negative": ({"scale0": -GOOD.astype(np.float32)}, "count", "not occupancy in [0, 1]"),
    "strings": ({"scale0": np.full((15, 15, 15), b"x")}, "count", "not a grid of numbers"),
    "a_group": ({"scale0": None}, "count", "not a grid of numbers"),
    "n_scales_1e9": ({"scale0": GOOD}, 10**9, "n_scales must be a whole number of levels in [1, 32]"),
    "n_scales_float": ({"scale0": GOOD}, 1.0, "n_scales must be"),
    "n_scales_negative": ({"scale0": GOOD}, -3, "n_scales must be"),
    "n_scales_string": ({"scale0": GOOD}, "one", "n_scales must be"),
    "n_scales_bool": ({"scale0": GOOD}, True, "n_scales must be"),
    "n_scales_list": ({"scale0": GOOD}, [1, 2], "n_scales must be"),
    "missing_scale": ({"scale0": GOOD, "scale2": GOOD}, 3, "scale1 is missing"),
    "two_dimensional": ({"scale0": np.ones((15, 15), bool)}, "count", "not a 3-D grid"),
    "too_small": ({"scale0": np.ones((15, 15, 4), bool)}, "count", "not a 3-D grid of 11 to 4096"),
    "finest_too_small": ({"scale0": np.ones((14, 12, 11), bool)}, "count", "under the 15-voxel minimum"),
    "absurd_side": ({"scale0": np.zeros((1, 1, 5000), bool)}, "count", "shape (1, 1, 5000)"),
    "shrinking_axis": ({"scale0": np.ones((15, 30, 15), bool), "scale1": np.ones((40, 20, 40), bool)},
                       "count", "do not grow from coarse to fine"),
}


@pytest.mark.parametrize("case", BAD_H5)
def test_bad_h5_contents_are_refused_by_name(tmp_path, case):
    grids, n_scales, message = BAD_H5[case]
    path = h5_file(tmp_path / "p.h5", n_scales, **grids)
    with pytest.raises(InputError, match=re.escape(message)):
        pyramid.load_pyramid(path, res=64)


def test_h5_grids_that_do_not_fit_in_memory_are_refused_before_reading(tmp_path, monkeypatch):
    """The shape is read, not the data: 4000^3 voxels at 9 bytes each."""
    path = tmp_path / "huge.h5"
    with h5py.File(path, "w") as f:  # chunked and empty: a few kB on disk
        f.attrs["n_scales"] = 1
        f.create_dataset("scale0", shape=(4000, 4000, 4000), dtype=np.float32, chunks=(64, 64, 64))
    monkeypatch.setattr(np, "asarray", lambda *a, **k: pytest.fail("read the grid"))
    with pytest.raises(InputError, match=r"huge.h5 .*needs about 536\.4 GiB"):
        pyramid.load_pyramid(path, res=64)


def test_soft_h5_occupancy_is_read_from_0_5(tmp_path):
    soft = np.zeros((15, 15, 15), np.float32)
    soft[:5], soft[5:8] = 0.9, 0.4
    p = pyramid.load_pyramid(h5_file(tmp_path / "p.h5", scale0=soft), res=64)
    assert p.levels[0][:5].all() and not p.levels[0][5:].any()


@pytest.mark.parametrize("name", ["shapes.obj", "pyramid.h5", "folder"])
def test_a_directory_is_named_as_one(tmp_path, name):
    (tmp_path / name).mkdir()
    with pytest.raises(InputError, match="the mesh or .h5 file .* is a folder, not a regular file"):
        pyramid.load_pyramid(tmp_path / name, res=64)


def ssg_file(path, make) -> Path:
    with h5py.File(path, "w") as f:
        f.attrs["n_scales"] = 1
        make(f)
    return path


def test_h5_files_that_reach_outside_themselves_are_refused(tmp_path, tiny_model):
    """External links, external raw storage and soft links (which can loop) are never followed."""
    secret = tmp_path / "secret.bin"
    secret.write_bytes(bytes(range(256)) * 32)
    cases = {
        "external storage": ssg_file(tmp_path / "storage.h5", lambda f: f.create_dataset(
            "scale0", shape=(16, 16, 32), dtype="u1", external=[(str(secret), 0, 8192)])),
        "a soft link to itself": ssg_file(tmp_path / "loop.h5", lambda f: f.__setitem__("scale0", h5py.SoftLink("/scale0"))),
        "an external link": ssg_file(tmp_path / "link.h5", lambda f: f.__setitem__(
            "scale0", h5py.ExternalLink(str(tmp_path / "storage.h5"), "/scale0"))),
    }
    for what, path in cases.items():
        with pytest.raises(InputError, match="an SSG file holds its grids itself"):
            pyramid.load_pyramid(path, 32)
        result = CliRunner().invoke(cli, ["eval", str(tiny_model), "--reference", str(path), "-n", "2"])
        assert result.exit_code != 0 and "Traceback" not in result.output and "holds its grids itself" in result.output, what


def test_inputs_that_are_not_regular_files_say_what_they_are(tmp_path):
    import os

    fifo = tmp_path / "x.h5"
    os.mkfifo(fifo)
    loop = tmp_path / "loop.onnx"
    loop.symlink_to(loop)
    with pytest.raises(InputError, match="not a regular file"):
        pyramid.load_pyramid(fifo, 32)
    with pytest.raises(InputError, match="symbolic link that goes round in a loop"):
        load_model(loop)
    blocker = tmp_path / "model.sha"
    blocker.write_text("a file")
    result = CliRunner().invoke(cli, ["sample", "terrain", "-o", str(blocker / "x.ply")])
    assert result.exit_code != 0 and "model.sha is a file, not a folder" in result.output
