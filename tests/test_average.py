"""The weights a level keeps are the running average of what it trained
(config.ema): the model holds the average, later levels build on it, and a
resumed run continues the same average."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")

from sinshape.core import manifest as fmt  # noqa: E402
from sinshape.trainer import train  # noqa: E402
from sinshape.trainer.average import WeightAverage  # noqa: E402
from sinshape.trainer.config import make_config  # noqa: E402


def test_the_average_is_the_mean_then_an_exponential_one():
    param = torch.nn.Parameter(torch.zeros(2))
    average = WeightAverage([param], iterations=40, share=0.1)  # over 4 iterations
    values = [4.0, 8.0, 0.0, 4.0, 12.0, 12.0]
    for value in values:
        param.data.fill_(value)
        average.update()
    expected = np.mean(values[:4])  # the plain mean until the horizon: the untrained start weighs nothing
    for value in values[4:]:
        expected += (value - expected) / 4
    assert average.average[0].tolist() == pytest.approx([expected] * 2)
    average.apply()
    assert param.tolist() == pytest.approx([expected] * 2)


def head_weight(model_path) -> np.ndarray:
    """fc2's weight as the model file holds it (transposed)."""
    from onnx import numpy_helper

    name = fmt.HEAD_WEIGHTS[1]
    return next(numpy_helper.to_array(t) for t in onnx.load(model_path).graph.initializer if t.name == name)


def test_the_model_holds_the_average_not_the_last_weights(tmp_path, tiny_pyramid, monkeypatch):
    kept = []
    apply = WeightAverage.apply

    def recording_apply(self):
        fc2 = next(i for i, p in enumerate(self.params) if p.shape == (1, 32))  # the decoder's last layer
        kept.append((self.params[fc2].detach().clone(), self.average[fc2].clone()))
        apply(self)

    monkeypatch.setattr(WeightAverage, "apply", recording_apply)
    out = tmp_path / "m.onnx"
    manifest = train.train(tiny_pyramid, out, make_config("tiny", iters=6, ema=0.5))
    assert manifest["config"]["ema"] == 0.5 and len(kept) == 2  # one average per level
    last, average = kept[-1]
    assert not torch.allclose(last, average)  # training moved the weights past their average
    np.testing.assert_array_equal(head_weight(out), average.numpy().T)


def test_a_resumed_run_continues_the_same_average(tmp_path, tiny_pyramid):
    config = make_config("tiny", iters=4, ema=0.5)
    whole = train.train(tiny_pyramid, tmp_path / "whole.onnx", config)
    with pytest.raises(train.Interrupted):
        train.train(tiny_pyramid, tmp_path / "cut.onnx", config, progress=interrupt_at(1, 2))
    train.train(tiny_pyramid, tmp_path / "cut.onnx", None, resume=True)
    assert whole["config"]["ema"] == 0.5
    np.testing.assert_array_equal(head_weight(tmp_path / "cut.onnx"), head_weight(tmp_path / "whole.onnx"))


def interrupt_at(level, iteration):
    def progress(p):
        if (p.level, p.iteration) == (level, iteration):
            raise KeyboardInterrupt

    return progress


def test_a_rewind_takes_the_average_back_too(tiny_pyramid):
    trainer = train.Trainer(make_config("tiny", ema=0.5), train.load_pyramid(tiny_pyramid, 32))
    trainer.begin_level()
    recon_inputs = trainer.recon_inputs()
    trainer.iterate(recon_inputs)
    trainer.count_iteration()
    kept = trainer.keep()
    before = [a.clone() for a in trainer.average.average]
    for _ in range(2):
        trainer.iterate(recon_inputs)
        trainer.count_iteration()
    assert trainer.average.count == 3 and not torch.equal(before[0], trainer.average.average[0])
    trainer.rewind(kept)
    assert trainer.average.count == 1
    assert all(torch.equal(a, b) for a, b in zip(before, trainer.average.average))
