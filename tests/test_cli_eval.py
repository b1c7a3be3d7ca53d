"""`sinrun eval`: the paper's metrics for a model, torch-free."""

import json

import numpy as np

from sinshape.runtime import generate
from test_cli_sample import sinrun
from test_cli_train import assert_one_line_error, run_sinrun


def test_eval_writes_the_metrics(tiny_model, tiny_pyramid, tmp_path):
    out = tmp_path / "e.json"
    result = sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 4, "--json", out)
    assert result.exit_code == 0, result.output
    assert "LP-IoU" in result.output and "diversity" in result.output
    report = json.loads(out.read_text())
    assert report["samples"] == 4 and report["sample_size"] == report["reference_size"] == [20, 18, 15]
    for key in ("lp_iou", "lp_f", "diversity"):
        assert 0 <= report[key] <= 1
    assert len(report["per_sample"]["lp_iou"]) == 4
    assert report["diversity"] > 0  # different seeds, different shapes


def test_eval_needs_no_torch(tiny_model, tiny_pyramid):
    result = run_sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 2, block_torch=True)
    assert result.returncode == 0, result.stderr


def test_eval_refuses_bad_requests(tiny_model, tiny_pyramid, tmp_path):
    assert_one_line_error(sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 2, "--scale", 2),
                          "needs a mesh reference")
    assert_one_line_error(sinrun("eval", tiny_model, "--reference", tmp_path / "none.obj", "-n", 2), "is missing")
    assert sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 1).exit_code == 2


def test_upsampling_baseline_keeps_corners_and_shape():
    volume = np.random.default_rng(0).random((5, 6, 7)).astype(np.float32)
    up = generate.resize_volume(volume, (9, 11, 13))
    assert up.shape == (9, 11, 13)
    assert np.allclose(up[::2, ::2, ::2], volume, atol=1e-6)  # align_corners: every other point is an original
    assert np.allclose(up[1, 0, 0], volume[:2, 0, 0].mean(), atol=1e-6)


def test_eval_reports_what_evaluate_model_returns(tiny_model, tiny_pyramid, tmp_path):
    """The command is a thin wrapper: a tool calling the library gets the same scores."""
    from sinshape.runtime import evaluate, load

    out = tmp_path / "e.json"
    assert sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 3, "--json", out).exit_code == 0
    ours = evaluate.evaluate_model(load.load_model(tiny_model), tiny_pyramid, samples=3)
    cli = json.loads(out.read_text())
    timings = ("seconds_sampling", "seconds_scoring")
    assert {k: v for k, v in cli.items() if k not in timings} == {k: v for k, v in ours.items() if k not in timings}


def test_eval_warns_when_the_reference_is_not_the_training_input(tiny_model, tmp_path):
    from conftest import write_pyramid

    other = write_pyramid(tmp_path / "other.h5", [(20, 18, 14), (20, 18, 15)])
    result = sinrun("eval", tiny_model, "--reference", other, "-n", 2)
    assert result.exit_code == 0, result.output
    assert "Warning: other.h5 is not the file" in result.output and "--force" in result.output
    assert "terrain.h5" in result.output  # the recorded source is named
    forced = sinrun("eval", tiny_model, "--reference", other, "-n", 2, "--force")
    assert forced.exit_code == 0 and "Warning" not in forced.output


def test_eval_is_silent_about_its_own_training_input(tiny_model, tiny_pyramid):
    result = sinrun("eval", tiny_model, "--reference", tiny_pyramid, "-n", 2)
    assert result.exit_code == 0 and "Warning" not in result.output


def test_eval_never_writes_its_json_over_the_model_or_the_reference(tiny_model, tiny_pyramid, tmp_path):
    model, reference = tmp_path / "m.onnx", tmp_path / "r.h5"
    model.write_bytes(tiny_model.read_bytes())
    reference.write_bytes(tiny_pyramid.read_bytes())
    (tmp_path / "link.json").symlink_to(reference)
    for target in (model, reference, tmp_path / "link.json"):
        result = sinrun("eval", model, "--reference", reference, "-n", 2, "--json", target)
        assert_one_line_error(result, "is the input")
    assert model.read_bytes() == tiny_model.read_bytes() and reference.read_bytes() == tiny_pyramid.read_bytes()
