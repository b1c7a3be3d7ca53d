"""`sinrun train` on a coloured example: a coloured model, or one line and
nothing written when the colour cannot be read; --no-colour trains geometry."""

import json
import shutil
from pathlib import Path

import onnx
import pytest
from click.testing import CliRunner

pytest.importorskip("torch")

from sinshape.cli.main import cli  # noqa: E402
from sinshape.core import manifest as fmt  # noqa: E402
from test_cli_train import assert_one_line_error  # noqa: E402

DATA = Path(__file__).parent / "data" / "colour"


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def version(path: Path) -> int:
    props = {p.key: p.value for p in onnx.load(path).metadata_props}
    return json.loads(props[fmt.METADATA_KEY])["format_version"]


@pytest.fixture
def missing_texture(tmp_path) -> Path:
    for name in ("box_texture.obj", "box_texture.mtl"):  # the PNG left behind
        shutil.copy(DATA / name, tmp_path / name)
    return tmp_path / "box_texture.obj"


def test_colour_that_cannot_be_read_stops_training_before_anything_is_written(missing_texture, tmp_path):
    out = tmp_path / "m.onnx"
    assert_one_line_error(sinrun("train", missing_texture, "-o", out, "--preset", "tiny", "--iters", 1),
                          "box_texture.png (named in box_texture.mtl) is missing")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box_texture.mtl", "box_texture.obj"]


def test_no_colour_trains_geometry_only_from_the_same_mesh(missing_texture, tmp_path):
    out = tmp_path / "m.onnx"
    result = sinrun("train", missing_texture, "-o", out, "--preset", "tiny", "--iters", 1, "-q", "--no-colour")
    assert result.exit_code == 0, result.output
    assert "coloured" not in result.output and "with its example's relief" in result.output
    manifest = json.loads({p.key: p.value for p in onnx.load(out).metadata_props}[fmt.METADATA_KEY])
    assert manifest["format_version"] == 5 and "colour" not in manifest and "relief" in manifest


def test_the_voxel_baseline_asks_for_no_colour(tmp_path):
    result = sinrun("train", DATA / "box_vertex.ply", "-o", tmp_path / "b.pt", "--preset", "tiny", "--iters", 1,
                    "--generator", "voxel", "-q")
    assert_one_line_error(result, "geometry only", "--no-colour")
    assert not (tmp_path / "b.pt").exists()


def test_a_coloured_mesh_trains_a_coloured_model(tiny_colour_model):
    assert version(tiny_colour_model) == fmt.TILES_VERSION  # colour read from the example
