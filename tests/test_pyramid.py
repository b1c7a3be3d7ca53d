"""Pyramid sizes, HDF5 reading and training targets."""

import subprocess
import sys
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from conftest import write_pyramid
from sinshape.prep import pyramid, shapes
from sinshape.runtime.errors import InputError


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
    with pytest.raises(InputError, match="no such file"):
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
