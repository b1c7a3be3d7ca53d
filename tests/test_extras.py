"""The runtime install (no extras) does everything but prepare examples and
train: the prep and train extras' modules are blocked in a fresh process, so
a command that still reaches one of them fails here, whatever is installed."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import TINY_ONNX
from sinshape.runtime import mesh
from test_cli_train import assert_one_line_error

# What the prep and train extras install, and the graph engines trimesh would
# fall back on for its own clean-up.
EXTRAS_ONLY = ("scipy", "h5py", "skimage", "onnx", "torch", "networkx")
BLOCK = "import sys\n" + "".join(f"sys.modules[{name!r}] = None\n" for name in EXTRAS_ONLY)


def sinrun_without_extras(*args, cwd):
    code = BLOCK + "from sinshape.cli.main import main\nmain()\n"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("args, output", [
    (["sample", TINY_ONNX, "--seed", "3", "--smooth", "3", "--largest", "-o", "s.obj"], "s.obj"),
    (["sample", TINY_ONNX, "--seed", "3", "--smooth", "4", "--smoother", "taubin", "-o", "t.glb"], "t.glb"),
    (["render", TINY_ONNX, "--seeds", "0-1", "-o", "r.png"], "r.png"),
    (["render", Path(__file__).parent / "data" / "colour" / "box_texture.glb", "-o", "m.png"], "m.png"),  # its texture
    (["layout", TINY_ONNX, "--seed", "3", "-o", "l.vox"], "l.vox"),
    (["export-web", TINY_ONNX, "-o", "site"], "site"),
])
def test_runtime_commands_need_no_extra(tmp_path, args, output):
    result = sinrun_without_extras(*args, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / output).exists()


def test_a_command_that_needs_the_prep_extra_says_so(tmp_path):
    result = sinrun_without_extras("shape", "arch", "-o", "a.obj", cwd=tmp_path)
    assert_one_line_error(result, "this needs", "pip install 'sinshape[prep]'")
    assert not (tmp_path / "a.obj").exists()


def bumpy_sphere(subdivisions, shift=0.0):
    sphere = trimesh.creation.icosphere(subdivisions)
    bumps = 1 + 0.1 * np.sin(7 * sphere.vertices[:, :1]) * np.cos(5 * sphere.vertices[:, 1:2])
    return trimesh.Trimesh(sphere.vertices * bumps + shift, sphere.faces, process=False)


@pytest.mark.parametrize("smoother, reference", [("laplacian", trimesh.smoothing.filter_laplacian),
                                                 ("taubin", trimesh.smoothing.filter_taubin)])
def test_smoothing_is_trimeshs(smoother, reference):
    sphere = bumpy_sphere(3)
    expected = reference(sphere.copy(), iterations=7).vertices
    ours = mesh.smoothed(sphere.vertices, sphere.faces, 7, smoother)
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-12)
    assert np.abs(ours - sphere.vertices).max() > 1e-3  # it moved them


def test_the_largest_part_is_trimeshs():
    # The largest part is neither first nor last; a part of 2 faces sharing only a
    # vertex with the small sphere counts apart from it, as trimesh's split does.
    small, large, far = bumpy_sphere(1), bumpy_sphere(3, shift=5.0), bumpy_sphere(2, shift=-5.0)
    whole = trimesh.util.concatenate([small, large, far])
    n = len(whole.vertices)  # two faces more, the first with a corner at the small sphere's vertex 0
    whole = trimesh.Trimesh(np.concatenate([whole.vertices, [[3, 3, 3], [3, 4, 3], [4, 3, 3]]]),
                            np.concatenate([whole.faces, [[0, n, n + 1], [n, n + 2, n + 1]]]), process=False)
    assert len(whole.split(only_watertight=False)) == 4
    expected = max(whole.split(only_watertight=False), key=lambda part: len(part.faces))
    ours = mesh.largest_part(whole)
    np.testing.assert_array_equal(ours.vertices, expected.vertices)
    # The same faces; trimesh orders them with numpy's unstable sort, whose
    # order differs between numpy 1.x (Blender's, in the blender extra) and 2.x.
    assert sorted(map(tuple, ours.faces.tolist())) == sorted(map(tuple, expected.faces.tolist()))


def test_parts_joined_through_a_long_chain_get_one_label():
    """A path visited in random order needs several rounds of hooking."""
    order = np.random.default_rng(0).permutation(1000)
    a, b = order[:-1], order[1:]
    separate = np.arange(1000, 1010)  # ten nodes on their own
    labels = mesh.connected_parts(np.append(a, separate[:5]), np.append(b, separate[5:]), 1010)
    assert (labels[:1000] == 0).all()
    assert list(labels[1000:]) == [1000, 1001, 1002, 1003, 1004, 1000, 1001, 1002, 1003, 1004]
