"""`sinrun render` and `sinrun shape`: pictures and example meshes from the command line."""

import numpy as np
import trimesh
from PIL import Image

from test_cli_sample import sinrun
from test_cli_train import assert_one_line_error


def background_fraction(path):
    pixels = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3).astype(int)
    return float((np.abs(pixels - pixels[0]).sum(axis=1) < 6).mean())


def test_render_a_mesh_and_samples(tiny_model, tmp_path):
    box = tmp_path / "box.obj"
    trimesh.creation.box((2, 1, 1)).export(box)
    out = tmp_path / "grid.png"
    result = sinrun("render", box, tiny_model, "--seeds", "1-2", "--image-size", 64, "-o", out)
    assert result.exit_code == 0, result.output
    image = Image.open(out)
    assert image.size[0] == 3 * 64 and image.size[1] > 64  # three cells in a row, labels beneath
    assert 0.2 < background_fraction(out) < 0.95  # shapes drawn, not an empty picture


def test_turntable_and_zoom(tiny_model, tmp_path):
    out = tmp_path / "turn.png"
    assert sinrun("render", tiny_model, "--seeds", "4", "--views", 3, "--image-size", 48,
                  "--zoom", 2, "--scale", 2, "-o", out).exit_code == 0
    assert Image.open(out).size == (3 * 48, 48)


def test_render_refuses_bad_input(tmp_path):
    assert_one_line_error(sinrun("render", tmp_path / "none.obj", "-o", tmp_path / "x.png"), "neither")
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    assert_one_line_error(sinrun("render", tmp_path / "a.obj", "-o", tmp_path / "x.png"), "no triangles")
    assert_one_line_error(sinrun("render", tmp_path / "a.obj", "-o", tmp_path / "x.jpg"), ".png")
    assert not (tmp_path / "x.png").exists()


def test_shape_writes_a_closed_example(tmp_path):
    out = tmp_path / "wall.ply"
    result = sinrun("shape", "wall", "--detail", 4, "--seed", 2, "-o", out)
    assert result.exit_code == 0, result.output
    mesh = trimesh.load(out)
    assert mesh.is_watertight and mesh.volume > 0
    assert_one_line_error(sinrun("shape", "castle", "-o", out), "known shapes")


def test_zoom_box_must_hold_part_of_the_shape(tmp_path):
    box, ball = tmp_path / "box.obj", tmp_path / "ball.obj"
    trimesh.creation.box((2, 1, 1)).export(box)
    trimesh.creation.icosphere().export(ball)  # its bounding box's corner is far from its surface
    assert_one_line_error(sinrun("render", ball, "--zoom", 10, "--focus", "0,0,0", "-o", tmp_path / "z.png"),
                          "no part of the shape")
    assert sinrun("render", box, "--zoom", 2, "--focus", "0.5,0.5,1", "-o", tmp_path / "z.png").exit_code == 0
    assert sinrun("render", box, "--focus", "2,0,0", "-o", tmp_path / "z.png").exit_code == 2


def test_pictures_stand_the_way_the_model_says(tmp_path):
    """The acropolis records z as up: drawn so without --up, on its side with --up y."""
    pictures = {}
    for up in (None, "z", "y"):
        out = tmp_path / f"{up}.png"
        assert sinrun("render", "acropolis", "--seeds", "0", "--image-size", 48,
                      *(["--up", up] if up else []), "-o", out).exit_code == 0
        pictures[up] = np.asarray(Image.open(out))
    assert np.array_equal(pictures[None], pictures["z"]) and not np.array_equal(pictures[None], pictures["y"])
