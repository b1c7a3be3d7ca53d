"""A sample's coarse layout: written and read as .vox and .npz, edited, and
followed by the shape generated from it, with the seed still varying detail."""

import struct

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime import dense, load_model, sample
from sinshape.runtime import layout as L, layout_files
from sinshape.core.errors import InputError
from test_cli_train import assert_one_line_error


@pytest.fixture(scope="module")
def acropolis():
    return load_model(models.find("acropolis"), threads=1)


@pytest.fixture(scope="module")
def seed3(acropolis):
    return L.layout(acropolis, 3)


def followed(model, seed, target, before) -> tuple:
    """The generated shape area-averaged to the layout's grid: its IoU with
    the layout, and the share of the edited cells (where `target` differs
    from `before`) that it follows."""
    pooled = L.pool(dense(model, L.from_layout(model, seed, target)), target.shape) > 0.5
    edited = target != before
    return (pooled & target).sum() / (pooled | target).sum(), np.mean(pooled[edited] == target[edited])


def edits(layout) -> dict:
    x = layout.shape[0]
    removed, duplicated, moved, added = (layout.copy() for _ in range(4))
    removed[x // 3:x // 2, :, 4:] = False  # a gap through the roof and columns
    duplicated[x // 2:x // 2 + 8] = layout[4:12]  # a bay copied along x
    moved[:, :, 4:] = np.roll(layout[:, :, 4:], 5, axis=0)  # everything above the floor shifted
    added[2:6, 2:6, :] = True  # a new tower at a corner
    return {"removed": removed, "duplicated": duplicated, "moved": moved, "added": added}


@pytest.mark.parametrize("name", ["removed", "duplicated", "moved", "added"])
def test_an_edited_layout_is_followed(acropolis, seed3, name):
    target = edits(seed3)[name]
    assert (target != seed3).sum() >= 20
    iou, edited = followed(acropolis, 3, target, seed3)
    # The unedited cells too: without the last level's hold, cells beside an
    # edit that the finer levels moved across 0.5 stay there (IoU 0.90-0.97).
    assert iou >= 0.97 and edited >= 0.95, (iou, edited)


def test_an_edit_changes_only_the_plane_cells_its_cells_need(acropolis, seed3):
    """A gap cut along x changes the xy and xz planes over the gap: the yz
    plane, which every x reads, stays the seed's, and so does the shape away
    from the gap, but for the few voxels the finer levels' instance norms
    pass the change to (they normalise each plane as a whole)."""
    target = edits(seed3)["removed"]
    masks = L.plane_masks(target != seed3)
    x = seed3.shape[0]
    assert not masks[2].any()
    assert masks[0][x // 3:x // 2].any() and not masks[0][:x // 3 - 1].any() and not masks[0][x // 2 + 1:].any()
    single = np.zeros_like(seed3)
    single[5, 5, 5] = True
    assert sum(m.sum() for m in L.plane_masks(single)) == 5  # one plane: the cell and its four neighbours

    edited, own = L.from_layout(acropolis, 3, target), sample(acropolis, 3)
    assert np.array_equal(edited.planes[2], own.planes[2])
    a, b = dense(acropolis, edited), dense(acropolis, own)
    far = np.zeros(a.shape, bool)
    far[:a.shape[0] // 4] = far[a.shape[0] * 3 // 4:] = True
    assert np.mean((a > 0.5)[far] != (b > 0.5)[far]) < 0.01 and np.abs(a - b).max() > 0.5


def test_the_seed_varies_the_detail_and_the_same_inputs_give_the_same_shape(acropolis, seed3):
    target = edits(seed3)["removed"]
    a, b = (dense(acropolis, L.from_layout(acropolis, s, target)) for s in (3, 5))
    assert np.sum((a > 0.5) != (b > 0.5)) > 200  # of 64x37x32 voxels
    assert np.array_equal(a, dense(acropolis, L.from_layout(acropolis, 3, target)))


def test_the_layout_is_the_sample_averaged_over_a_level(acropolis):
    grid = dense(acropolis, sample(acropolis, 4))
    for level in (0, 1):
        shape = acropolis.manifest.sizes[level]
        layout = L.layout(acropolis, 4, level)
        assert layout.shape == tuple(shape)
        assert np.array_equal(layout, L.pool(grid, shape) > 0.5)
    assert L.pool(np.ones((4, 4, 4)), (2, 2, 2)).tolist() == np.ones((2, 2, 2)).tolist()
    assert L.pool(np.arange(4.0)[:, None, None] * np.ones((4, 1, 1)), (2, 1, 1)).ravel().tolist() == [0.5, 2.5]


@pytest.mark.parametrize("suffix", [".vox", ".npz"])
def test_layout_files_round_trip(tmp_path, seed3, suffix):
    path = tmp_path / f"l{suffix}"
    layout_files.write_layout(seed3, path)
    assert np.array_equal(layout_files.read_layout(path), seed3)


def test_vox_files_are_magicavoxel_chunks(tmp_path, seed3):
    data = layout_files.vox_bytes(seed3)
    assert data[:8] == b"VOX " + struct.pack("<i", 150) and data[8:12] == b"MAIN"
    assert struct.unpack_from("<3i", data, 32) == seed3.shape  # SIZE's content
    assert struct.unpack_from("<i", data, 56)[0] == seed3.sum()  # XYZI's count
    # A palette chunk after the model, as MagicaVoxel writes, is skipped.
    rgba = b"RGBA" + struct.pack("<2i", 1024, 0) + bytes(1024)
    path = tmp_path / "palette.vox"
    path.write_bytes(data + rgba)
    assert np.array_equal(layout_files.read_layout(path), seed3)


def vox(size=(4, 4, 4), voxels=((0, 0, 0, 1),), models=1) -> bytes:
    body = b""
    for _ in range(models):
        xyzi = struct.pack("<i", len(voxels)) + bytes(v for voxel in voxels for v in voxel)
        body += b"SIZE" + struct.pack("<2i", 12, 0) + struct.pack("<3i", *size)
        body += b"XYZI" + struct.pack("<2i", len(xyzi), 0) + xyzi
    return b"VOX " + struct.pack("<i", 150) + b"MAIN" + struct.pack("<2i", 0, len(body)) + body


@pytest.mark.parametrize("name, data, fragment", [
    ("text.vox", b"hello, not a voxel file", "not a readable MagicaVoxel file"),
    ("cut.vox", vox()[:-3], "runs past the end"),
    ("huge.vox", vox(size=(300, 4, 4)), "a layout has 1 to 256"),
    ("two.vox", vox(models=2), "holds 2 models"),
    ("outside.vox", vox(voxels=((9, 0, 0, 1),)), "outside its model's size"),
    ("count.vox", vox()[:-8] + struct.pack("<i", 10**6) + vox()[-4:], "count does not fit"),
    ("bad.npz", b"PK not a zip", "not a readable .npz"),
    ("l.txt", b"", "a layout is a .vox or .npz file"),
])
def test_bad_layout_files_are_refused_in_one_line(tmp_path, name, data, fragment):
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(InputError, match=fragment):
        layout_files.read_layout(path)
    out = tmp_path / "s.ply"
    assert_one_line_error(CliRunner().invoke(cli, ["sample", "acropolis", "--layout", str(path), "-o", str(out)]),
                          fragment)
    assert not out.exists()


def test_a_layout_of_another_size_is_refused_or_resampled(acropolis, tmp_path, seed3):
    path = tmp_path / "big.npz"
    layout_files.write_layout(np.repeat(seed3, 2, axis=0), path)
    out = tmp_path / "s.npz"
    result = CliRunner().invoke(cli, ["sample", "acropolis", "--layout", str(path), "-o", str(out)])
    assert_one_line_error(result, "the layout is 54x16x15", "27x16x15", "resample")
    assert not out.exists()
    result = CliRunner().invoke(cli, ["sample", "acropolis", "--layout", str(path), "--resample-layout",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert np.array_equal(np.load(out)["occupancy"], dense(acropolis, L.from_layout(acropolis, 0, seed3)))


def test_the_three_commands_of_a_level_designer(tmp_path, acropolis, seed3):
    vox_path, out = tmp_path / "l.vox", tmp_path / "s.npz"
    result = CliRunner().invoke(cli, ["layout", "acropolis", "--seed", "3", "-o", str(vox_path)])
    assert result.exit_code == 0 and "27x16x15 voxels, level 0" in result.output
    layout_files.write_layout(edits(layout_files.read_layout(vox_path))["removed"], vox_path)  # the edit a user makes elsewhere
    result = CliRunner().invoke(cli, ["sample", "acropolis", "--seed", "3", "--layout", str(vox_path), "-o", str(out)])
    assert result.exit_code == 0, result.output
    expected = dense(acropolis, L.from_layout(acropolis, 3, edits(seed3)["removed"]))
    assert np.array_equal(np.load(out)["occupancy"], expected)
    assert_one_line_error(CliRunner().invoke(cli, ["layout", "acropolis", "--level", "3", "-o", str(vox_path)]),
                          "level must be 0 to 2")


def test_a_rough_mesh_is_a_layout(acropolis, tmp_path):
    """A floor and two towers as boxes in the model's frame, voxelised on level 0's grid, and followed."""
    import trimesh

    m = acropolis.manifest
    origin, extent = np.array(m.origin), (np.array(m.sizes[-1]) - 1) * np.array(m.spacing)

    def box(low, high):  # corners as fractions of the sample's extent
        low, high = origin + np.array(low) * extent, origin + np.array(high) * extent
        return trimesh.creation.box(bounds=[low, high])

    path = tmp_path / "rough.obj"
    trimesh.util.concatenate([box((0, 0, 0), (1, 1, 0.15)), box((0.1, 0.3, 0), (0.3, 0.7, 0.9)),
                              box((0.7, 0.3, 0), (0.9, 0.7, 0.9))]).export(path)
    target = layout_files.mesh_layout(acropolis, path)
    assert target.shape == tuple(m.sizes[0]) and 0.2 < target.mean() < 0.5
    assert target[:, :, 0].all() and not target[13, 8, 10]  # the floor, and air between the towers
    pooled = L.pool(dense(acropolis, L.from_layout(acropolis, 3, layout_files.read_any(acropolis, path))), target.shape) > 0.5
    assert np.mean(pooled == target) >= 0.9 and (pooled & target).sum() / (pooled | target).sum() >= 0.8
    far = tmp_path / "far.obj"
    trimesh.creation.box(bounds=[origin + 10 * extent, origin + 11 * extent]).export(far)
    with pytest.raises(InputError, match="lies outside the sample's box"):
        layout_files.mesh_layout(acropolis, far)
