"""Which way is up: read from an .h5 pyramid by SSG's convention and the
data, recorded in the model, and changed later without retraining."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli
from sinshape.core import manifest as fmt
from sinshape.prep.pyramid import load_pyramid, up_axis
from sinshape.runtime import dense, load_model, sample
from conftest import write_pyramid
from test_cli_train import assert_one_line_error


def grid_with_floor(axis=None, shape=(20, 24, 16)):
    """A column of solid in the middle, standing on a full floor across `axis` (None: no floor)."""
    grid = np.zeros(shape, bool)
    grid[8:12, :, 6:10] = True
    if axis is not None:
        index = [slice(None)] * 3
        index[axis] = 0
        grid[tuple(index)] = True
    return grid


@pytest.mark.parametrize("floor, up", [(None, "y"), (1, "y"), (2, "z"), (0, "y")])
def test_up_is_y_by_convention_and_z_over_a_z_floor(floor, up):
    assert up_axis(grid_with_floor(floor)) == up


def test_a_floor_on_both_low_sides_keeps_the_convention():
    grid = grid_with_floor(1)
    grid[:, :, 0] = True
    assert up_axis(grid) == "y"


def test_an_h5_terrain_stored_z_up_is_read_z_up(tmp_path):
    path = write_pyramid(tmp_path / "t.h5", [(15, 15, 15), (20, 18, 15)])  # z < a wave: ground at z = 0
    assert load_pyramid(path, res=32).up == "z"


def test_orient_changes_up_and_nothing_else(tiny_model, tmp_path):
    out = tmp_path / "o.onnx"
    before = load_model(tiny_model, threads=1)
    turned = "y" if before.manifest.up == "z" else "z"
    result = CliRunner().invoke(cli, ["orient", str(tiny_model), "--up", turned, "-o", str(out)])
    assert result.exit_code == 0 and result.output == f"wrote {out} ({turned} points up)\n", result.output
    after = load_model(out, threads=1)
    assert after.manifest.up == turned and after.manifest.raw["format_version"] == fmt.FORMAT_VERSION
    assert {k: v for k, v in after.manifest.raw.items() if k != "up"} == \
        {k: v for k, v in before.manifest.raw.items() if k != "up"}
    assert np.array_equal(dense(after, sample(after, 5)), dense(before, sample(before, 5)))
    assert CliRunner().invoke(cli, ["orient", str(out), "--up", before.manifest.up]).exit_code == 0  # in place
    assert load_model(out, threads=1).manifest.up == before.manifest.up


def test_a_glb_stands_on_the_models_up_as_gltf_asks(tiny_model, tmp_path):
    """glTF's up is +Y: a z-up model's .glb turns its node a quarter turn about x, so that the
    model's z runs along the file's +Y; a y-up model's is written as it is. The .ply keeps the
    frame's own axes either way."""
    import trimesh

    for up in ("y", "z"):
        turned = tmp_path / f"{up}.onnx"
        assert CliRunner().invoke(cli, ["orient", str(tiny_model), "--up", up, "-o", str(turned)]).exit_code == 0
        for suffix in (".glb", ".ply"):
            result = CliRunner().invoke(cli, ["sample", str(turned), "--seed", "2", "-o", str(tmp_path / f"{up}{suffix}")])
            assert result.exit_code == 0, result.output
    frame = trimesh.load(tmp_path / "y.ply", process=False).vertices
    assert np.allclose(trimesh.load(tmp_path / "z.ply", process=False).vertices, frame)
    assert np.allclose(trimesh.load(tmp_path / "y.glb", force="mesh", process=False).vertices, frame, atol=1e-5)
    stood = trimesh.load(tmp_path / "z.glb", force="mesh", process=False).vertices
    assert np.allclose(stood, frame[:, [0, 2, 1]] * (1, 1, -1), atol=1e-5)  # (x, y, z) -> (x, z, -y)


def test_orient_upgrades_an_old_format_and_seals_it(tmp_path):
    old = tmp_path / "v1.onnx"
    old.write_bytes((Path(__file__).parent / "data" / "tiny_v1.onnx").read_bytes())
    assert CliRunner().invoke(cli, ["orient", str(old), "--up", "z"]).exit_code == 0
    model = load_model(old, threads=1)
    assert model.manifest.up == "z" and model.manifest.raw["format_version"] == fmt.FORMAT_VERSION
    assert fmt.unseal(old.read_bytes())[1:] == (True, True)


def test_orient_refuses_what_it_cannot_change(tiny_model, tmp_path):
    assert_one_line_error(CliRunner().invoke(cli, ["orient", "towerruins", "--up", "z"]),
                          "towerruins is a shipped model", "with --output")
    assert_one_line_error(CliRunner().invoke(cli, ["orient", str(tiny_model), "--up", "z", "-o",
                                                   str(tmp_path / "x.ply")]), "written as .onnx")
    assert_one_line_error(CliRunner().invoke(cli, ["orient", str(tmp_path / "none.onnx"), "--up", "z"]),
                          "is missing")
    assert CliRunner().invoke(cli, ["orient", str(tiny_model), "--up", "x"]).exit_code == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_orient_records_how_the_models_world_is_made_and_world_follows_it(tiny_model, tmp_path):
    """--arrange scatter is recorded (and nothing else changes); `sinrun world` then scatters the
    model's world unless told, and a bad manifest value is refused as any other."""
    from sinshape.runtime import world, write
    from sinshape.runtime.request import SampleRequest

    out = tmp_path / "o.onnx"
    result = CliRunner().invoke(cli, ["orient", str(tiny_model), "--arrange", "scatter", "-o", str(out)])
    assert result.exit_code == 0 and result.output == f"wrote {out} (its world scatters)\n", result.output
    before, after = load_model(tiny_model, threads=1), load_model(out, threads=1)
    assert (before.manifest.arrange, after.manifest.arrange) == ("blend", "scatter")
    assert {k: v for k, v in after.manifest.raw.items() if k not in ("arrange", "format_version")} == \
        {k: v for k, v in before.manifest.raw.items() if k != "format_version"}
    for options, arrange in (([], "scatter"), (["--arrange", "blend"], "blend")):
        folder = tmp_path / f"w{arrange}"
        made = CliRunner().invoke(cli, ["world", str(out), "--tiles", "0,0", "--workers", "1", "--frame", "tile", "-o",
                                        str(folder), *options])
        assert made.exit_code == 0, made.output
        expected = write.request_bytes(after, SampleRequest(0, tile=(0, 0), frame="tile", arrange=arrange), "t.ply")[0]
        assert (folder / "tile_0_0.ply").read_bytes() == expected
    assert world.ARRANGEMENTS == fmt.ARRANGEMENTS
    with pytest.raises(Exception, match="arrange must be one of blend, scatter"):
        fmt.parse(__import__("json").dumps({**before.manifest.raw, "arrange": "pile"}))
    assert_one_line_error(CliRunner().invoke(cli, ["orient", str(tiny_model), "-o", str(tmp_path / "n.onnx")]),
                          "nothing to change")


def test_orient_records_a_blended_worlds_contrast_and_its_tiles_follow_it(tiny_model, tmp_path):
    """--contrast is recorded (and nothing else changes); a blended tile reads it where windows
    blend, and is unchanged where one window holds the whole weight (the tile's corner column);
    out of its range it is refused in one line."""
    import copy
    import dataclasses

    from sinshape.runtime import world, world_tiles

    out = tmp_path / "c.onnx"
    result = CliRunner().invoke(cli, ["orient", str(tiny_model), "--contrast", "2", "-o", str(out)])
    assert result.exit_code == 0 and result.output == f"wrote {out} (blend contrast 2)\n", result.output
    before, after = load_model(tiny_model, threads=1), load_model(out, threads=1)
    assert (before.manifest.contrast, after.manifest.contrast) == (fmt.CONTRAST, 2.0)
    assert {k: v for k, v in after.manifest.raw.items() if k not in ("contrast", "format_version")} == \
        {k: v for k, v in before.manifest.raw.items() if k != "format_version"}
    given = copy.copy(before)
    given.manifest = dataclasses.replace(before.manifest, contrast=2.0)
    plain, recorded, asked = (world_tiles.tile_occupancy(m, 3, (1, 1)) for m in (before, after, given))
    assert np.array_equal(recorded, asked) and not np.array_equal(recorded, plain)
    h0, h1 = world.world_tiling(before).horizontal
    corner = [slice(None)] * 3
    corner[h0] = corner[h1] = 0
    assert np.array_equal(recorded[tuple(corner)], plain[tuple(corner)])
    assert_one_line_error(CliRunner().invoke(cli, ["orient", str(tiny_model), "--contrast", "9", "-o",
                                                   str(tmp_path / "n.onnx")]), "contrast must be in [0.5, 4]")
    assert not (tmp_path / "n.onnx").exists()


def test_orient_records_an_objects_scale_and_info_says_it(tiny_model, tmp_path):
    """--object-scale is recorded (and nothing else changes), `sinrun info` prints it, and a value
    outside 1/16 to 16 is refused in one line, writing nothing."""
    out = tmp_path / "big.onnx"
    result = CliRunner().invoke(cli, ["orient", str(tiny_model), "--object-scale", "2", "-o", str(out)])
    assert result.exit_code == 0 and result.output == f"wrote {out} (object scale 2)\n", result.output
    before, after = load_model(tiny_model, threads=1), load_model(out, threads=1)
    assert (before.manifest.object_scale, after.manifest.object_scale) == (1.0, 2.0)
    assert {k: v for k, v in after.manifest.raw.items() if k not in ("object_scale", "format_version")} == \
        {k: v for k, v in before.manifest.raw.items() if k != "format_version"}
    assert "object scale 2" in CliRunner().invoke(cli, ["info", str(out)]).output
    assert "object scale 1" in CliRunner().invoke(cli, ["info", str(tiny_model)]).output
    assert_one_line_error(CliRunner().invoke(cli, ["orient", str(tiny_model), "--object-scale", "20", "-o",
                                                   str(tmp_path / "n.onnx")]), "--object-scale must be in [0.0625, 16]")
    assert not (tmp_path / "n.onnx").exists()
    with pytest.raises(Exception, match=r"object_scale must be a number in \[0.0625, 16\]"):
        fmt.parse(__import__("json").dumps({**before.manifest.raw, "object_scale": 0}))
