"""`sinrun train`: help, the missing-torch message, and bad input as one line."""

import os
import signal
import subprocess
import sys

import pytest
from click.testing import CliRunner

from sinshape.cli.main import cli

BLOCK_TORCH = "import sys; sys.modules['torch'] = None; "  # makes `import torch` raise ImportError


def run_sinrun(*args, block_torch=False, **kwargs):
    code = (BLOCK_TORCH if block_torch else "") + "from sinshape.cli.main import main; main()"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, **kwargs)


def assert_one_line_error(result, *fragments):
    assert result.exit_code != 0 if hasattr(result, "exit_code") else result.returncode != 0
    output = result.output if hasattr(result, "output") else result.stderr
    lines = [line for line in output.strip().splitlines() if line]
    assert "Traceback" not in output
    assert len(lines) == 1 and lines[0].startswith("Error:"), output
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_help_explains_every_option():
    result = CliRunner().invoke(cli, ["train", "--help"])
    assert result.exit_code == 0
    for option in ["--res", "--levels", "--iters", "--preset", "--resume", "--seed", "--output"]:
        assert option in result.output
    assert "paper" in result.output and "tiny" in result.output
    top = CliRunner().invoke(cli, ["--help"])
    assert top.exit_code == 0 and "train" in top.output


RUN_OPTIONS = {"input_path", "output", "preset", "device", "no_colour", "asset_folder", "resume", "checkpoint", "quiet"}


def test_every_other_train_option_is_a_training_setting_of_its_name():
    """A new training setting is a TrainConfig field and one option named
    after it: train hands every option but the run's own to make_config."""
    import dataclasses

    from sinshape.trainer.config import TrainConfig

    settings = {param.name for param in cli.commands["train"].params} - RUN_OPTIONS
    assert settings and settings <= {field.name for field in dataclasses.fields(TrainConfig)}, \
        settings - {field.name for field in dataclasses.fields(TrainConfig)}


def test_without_torch_train_says_how_to_install_it(tiny_pyramid, tmp_path):
    result = run_sinrun("train", tiny_pyramid, "-o", tmp_path / "m.onnx", block_torch=True)
    assert result.returncode == 1
    assert_one_line_error(result, "pip install 'sinshape[train]'")
    assert not (tmp_path / "m.onnx").exists()


def write(path, text):
    path.write_text(text)
    return path


@pytest.fixture
def bad_inputs(tmp_path):
    return {
        "missing": (tmp_path / "nothing.obj", "is missing"),
        "format": (write(tmp_path / "notes.txt", "hello"), "notes.txt"),
        "empty": (write(tmp_path / "empty.obj", "# nothing\n"), "empty.obj"),
        "flat": (write(tmp_path / "flat.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"), "flat.obj"),
    }


@pytest.mark.parametrize("case", ["missing", "format", "empty", "flat"])
def test_bad_input_files(case, bad_inputs, tmp_path):
    pytest.importorskip("torch")
    path, fragment = bad_inputs[case]
    out = tmp_path / "m.onnx"
    result = CliRunner().invoke(cli, ["train", str(path), "-o", str(out), "--preset", "tiny"])
    assert_one_line_error(result, fragment)
    assert list(tmp_path.glob("m.*")) == []  # no model, no checkpoint, no temporary file


def test_bad_options_and_outputs(tiny_pyramid, tmp_path):
    pytest.importorskip("torch")
    runner = CliRunner()
    cases = [
        (["--res", "10"], tmp_path / "m.onnx", "--res 10"),
        (["--levels", "6"], tmp_path / "m.onnx", "has 2 levels; --levels 6 asks for more"),
        ([], tmp_path / "no-such-folder" / "m.onnx", "does not exist"),
        ([], tmp_path, "is a directory"),
    ]
    for options, out, fragment in cases:
        result = runner.invoke(cli, ["train", str(tiny_pyramid), "-o", str(out), "--preset", "tiny", *options])
        assert_one_line_error(result, fragment)
    assert list(tmp_path.glob("m.*")) == []
    result = runner.invoke(cli, ["train", str(tiny_pyramid), "-o", str(tmp_path / "m.onnx"), "--resume", "--iters", "5"])
    assert result.exit_code == 2 and "leave out --iters" in result.output


def test_unwritable_output_folder(tiny_pyramid, tmp_path):
    pytest.importorskip("torch")
    if os.geteuid() == 0:  # root writes through permissions; /proc refuses everyone
        if not os.path.isdir("/proc/self"):
            pytest.skip("no unwritable folder for root")
        target = "/proc/sinshape-test.onnx"
    else:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        target = str(locked / "m.onnx")
    result = CliRunner().invoke(cli, ["train", str(tiny_pyramid), "-o", target, "--preset", "tiny"])
    assert_one_line_error(result, "cannot write")


def test_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(tiny_pyramid, tmp_path):
    pytest.importorskip("torch")
    out = tmp_path / "m.onnx"
    process = subprocess.Popen(
        [sys.executable, "-c", "from sinshape.cli.main import main; main()", "train", str(tiny_pyramid),
         "-o", str(out), "--preset", "tiny", "--iters", "100000"],
        stderr=subprocess.PIPE, text=True,
        # A shell starts background jobs with SIGINT ignored, and Python keeps an
        # ignored SIGINT: give the child the default, as a terminal would.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    for line in process.stderr:  # wait until training is under way
        if "level 1/2" in line and "/100000" in line:
            break
    process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=60)
    assert process.returncode == 130
    assert "; --resume continues from it" in rest and "Traceback" not in rest
    assert train_checkpoint(out).exists() and not out.exists()


def train_checkpoint(out):
    return out.with_name(out.stem + ".ckpt.pt")


def progress_of(stream, iterations, iters=20, interrupt=False):
    """What TrainProgress writes for level 1 of 2 up to `iterations`."""
    from types import SimpleNamespace

    from sinshape.cli.progress import TrainProgress

    try:
        with TrainProgress(stream) as show:
            for i in range(1, iterations + 1):
                show(SimpleNamespace(level=0, levels=2, size=(20, 18, 15), iteration=i, iters=iters,
                                     losses={"d": 0.25}))
            if interrupt:
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    return stream.getvalue()


def test_progress_is_a_line_every_10_percent_in_a_log():
    import io

    lines = progress_of(io.StringIO(), 20).splitlines()
    assert len(lines) == 11 and lines[-1].startswith("level 1/2 20x18x15 20/20  d +0.2500")


def test_progress_is_a_bar_on_a_terminal_and_ends_its_line_on_ctrl_c():
    import io

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    text = progress_of(Terminal(), 5, interrupt=True)
    assert "level 1/2 20x18x15" in text and "5/20" in text and "d +0.2500" in text
    assert text.endswith("\033[?25h\n")  # cursor shown again, the next message on a line of its own


def test_training_never_writes_over_its_input(tmp_path):
    """The model, or the checkpoint derived from it or named, is never the
    input: not by name, nor through a link; and a model is an .onnx file."""
    pytest.importorskip("torch")  # without it, train says so first
    from sinshape.prep import shapes

    source = tmp_path / "s.obj"
    shapes.write_shape("stairs", source, detail=4)
    before = source.read_bytes()
    (tmp_path / "link.onnx").symlink_to(source)
    (tmp_path / "link.ckpt.pt").symlink_to(source)
    cases = [
        (["-o", source], "is the input"),
        (["-o", tmp_path / "s.ply"], "writes a .onnx model"),
        (["-o", tmp_path / "link.onnx"], "is the input"),
        (["-o", tmp_path / "link.onnx", "--checkpoint", tmp_path / "c.pt"], "is the input"),
        (["-o", tmp_path / "m.onnx", "--checkpoint", source], "is the input"),
        (["-o", tmp_path / "link"], "link.ckpt.pt: is the input"),  # the checkpoint derived from -o
        (["-o", tmp_path / "m.onnx", "--checkpoint", tmp_path / "m.onnx"], "would overwrite the model"),
        (["-o", tmp_path / "v.pt", "--generator", "voxel", "--checkpoint", tmp_path / "c.pt"], "give one of them"),
    ]
    for options, fragment in cases:
        result = CliRunner().invoke(cli, ["train", str(source), *map(str, options), "--preset", "tiny"])
        assert_one_line_error(result, fragment)
    assert source.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.ckpt.pt", "link.onnx", "s.obj"]


def test_an_h5_with_too_few_levels_blames_the_preset_not_an_option_never_given(tmp_path):
    pytest.importorskip("torch")
    from conftest import write_pyramid

    one = write_pyramid(tmp_path / "one.h5", [(15, 15, 15)])
    result = CliRunner().invoke(cli, ["train", str(one), "-o", str(tmp_path / "m.onnx"), "--preset", "tiny"])
    assert_one_line_error(result, "one.h5 has 1 levels; the tiny preset's levels 2 asks for more")
    assert "--levels" not in result.output
