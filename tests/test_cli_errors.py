"""Every remaining traceback or misleading message becomes one clear line
(issue 10, class 6)."""

import signal
import subprocess
import sys
import time

from click.testing import CliRunner

from sinshape.cli.main import cli
from test_cli_train import assert_one_line_error


def sinrun(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_interpolate_refuses_a_range_that_is_not_finite(tiny_model, tmp_path):
    for low, high in (("nan", "nan"), ("-inf", "inf"), ("0", "inf")):
        result = sinrun("interpolate", tiny_model, "--seeds", 0, 1, "--steps", 2, "--range", low, high,
                        "-o", tmp_path / "i.ply")
        assert result.exit_code == 2 and "--range must be two finite numbers" in result.output, result.output
    assert list(tmp_path.iterdir()) == []


def test_output_patterns_fill_plain_fields_only(tiny_model, tmp_path):
    for pattern in ("s_{seed:5}.ply", "s_{seed!r}.ply", "s_{seed.real}.ply", "s_{seed:>{seed}}.ply"):
        result = sinrun("sample", tiny_model, "--seeds", "0-1", "-o", tmp_path / pattern)
        assert result.exit_code == 2 and "only {seed} can be filled in" in result.output, (pattern, result.output)
    assert list(tmp_path.iterdir()) == []
    assert sinrun("sample", tiny_model, "--seeds", "0-1", "-o", tmp_path / "s_{seed}.ply").exit_code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s_0.ply", "s_1.ply", "s_index.jsonl"]


def test_a_directory_is_not_called_missing(tmp_path):
    for folder in (tmp_path / "model.onnx", tmp_path / "plain"):
        folder.mkdir()
        assert_one_line_error(sinrun("sample", folder, "-o", tmp_path / "s.ply"), "a directory, not a model file")


def test_seeds_counting_down_say_so(tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "--seeds", "5-1", "-o", tmp_path / "s.ply")
    assert result.exit_code == 2 and "5-1 counts down; write 1-5" in result.output, result.output


def test_eval_blames_scale_not_the_levels(tiny_model, tmp_path):
    mesh = tmp_path / "box.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    for scale in ("0", "-1", "inf"):
        assert_one_line_error(sinrun("eval", tiny_model, "--reference", mesh, "-n", 2, "--scale", scale),
                              "--scale must be a positive number")


def test_an_empty_sample_is_refused_not_written(tiny_model, tmp_path, monkeypatch):
    import trimesh

    from sinshape.runtime import mesh

    # As --size 0.01 gave with tests/data/tiny.onnx: a 2x2x2 grid, all inside or all outside.
    monkeypatch.setattr(mesh, "extract", lambda *args, **kwargs: trimesh.Trimesh())
    monkeypatch.setattr(mesh, "pieces", lambda *args, **kwargs: iter(()))  # a .ply streams
    for out in (tmp_path / "s.ply", tmp_path / "s.glb"):
        assert_one_line_error(sinrun("sample", tiny_model, "-o", out, "--size", "0.5"), "no surface", "nothing written")
    assert list(tmp_path.iterdir()) == []


def test_clamped_levels_warn(tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "-o", tmp_path / "s.npz", "--size", "0.05")
    assert result.exit_code == 0 and "Warning: --size 0.05,0.05,0.05 shrinks some levels below 2" in result.output
    assert "Warning" not in sinrun("sample", tiny_model, "-o", tmp_path / "t.npz", "--size", "0.5").output


def test_a_clamped_grid_is_written_with_a_warning(tiny_model, tmp_path):
    result = sinrun("sample", tiny_model, "-o", tmp_path / "s.npz", "--scale", "0.0001")
    assert result.exit_code == 0 and "Warning: --scale 0.0001 leaves under 2 grid points" in result.output


def test_ctrl_c_exits_130(tiny_model, tmp_path, monkeypatch):
    """The real signal, in this process. A shell starts a background job
    with Ctrl-C ignored, and Python keeps it so: pytest started that way
    never sees the SIGINT, and the mock returns None. Python's own handler
    is given for the test, as a terminal's foreground job has it."""
    from sinshape.runtime import generate

    def interrupted(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(generate, "sample", interrupted)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        result = sinrun("sample", tiny_model, "-o", tmp_path / "s.ply")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert result.exit_code == 130 and "Traceback" not in result.output and "interrupted" in result.output
    assert not (tmp_path / "s.ply").exists()


def test_the_library_names_alpha(tiny_model):
    import pytest

    from sinshape.runtime import generate, load_model
    from sinshape.core.errors import InputError

    with pytest.raises(InputError, match="alpha must be a number in") as error:
        generate.interpolate(load_model(tiny_model, threads=1), 0, 1, float("nan"))
    assert error.value.parameter == "alpha"


def test_render_refuses_an_empty_sample(tiny_model, tmp_path, monkeypatch):
    import trimesh

    from sinshape.runtime import mesh

    monkeypatch.setattr(mesh, "extract", lambda *args, **kwargs: trimesh.Trimesh())
    out = tmp_path / "r.png"
    assert_one_line_error(sinrun("render", tiny_model, "-o", out), "no surface", "nothing drawn")
    assert not out.exists()


def test_sigterm_during_a_large_sample_leaves_no_temporary_file(tmp_path):
    out = tmp_path / "big.ply"
    process = subprocess.Popen([sys.executable, "-c", "from sinshape.cli.main import main; main()", "sample",
                                "terrain", "--scale", "12", "--threads", "1", "-o", str(out)],
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60  # a hang guard only: the .ply begins within seconds
    while not list(tmp_path.glob(".big.ply*")):  # the streamed .ply has begun
        assert time.monotonic() < deadline and process.poll() is None, process.stderr.read()
        time.sleep(0.02)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143 and "terminated" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_signal_while_a_compiled_module_loads_is_still_the_signal(tiny_model, tmp_path, monkeypatch):
    """onnxruntime's import turns a KeyboardInterrupt raised as it loads into
    ImportError("initialization failed"): Ctrl-C or `kill` in a command's
    first second ended in that traceback, exit 1."""
    from sinshape.cli.main import Terminated
    from sinshape.runtime import generate

    def loading(*args, **kwargs):
        raise ImportError("initialization failed") from Terminated()

    monkeypatch.setattr(generate, "sample", loading)
    result = sinrun("sample", tiny_model, "-o", tmp_path / "s.ply")
    assert result.exit_code == 143 and result.output.strip() == "terminated", result.output
