"""The fast training step computes the paper's step; budgets and crops behave."""

import sys
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from sinshape.trainer import device, train  # noqa: E402
from sinshape.trainer.config import make_config  # noqa: E402
from sinshape.prep.pyramid import Pyramid, load_pyramid  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from train_speed import StraightforwardTrainer  # noqa: E402

FP32 = device.Placement(torch.device("cpu"), "fp32", "test")


def trainer_at_level(cls, pyramid, level, **overrides):
    trainer = cls(make_config("tiny", **overrides), pyramid, FP32)
    for trainer.level in range(level + 1):
        trainer.begin_level()
    return trainer


@pytest.mark.parametrize("generator", ["triplane", "voxel"])
@pytest.mark.parametrize("level", [0, 1])
def test_batched_iterations_equal_the_straightforward_ones(tiny_pyramid, generator, level, monkeypatch):
    """Same seed, same random draws: two iterations of the batched trainer
    give the losses and weights of the authors' one-sample-at-a-time order.

    Plain SGD stands in for Adam here: Adam turns a gradient that is zero up
    to float noise (the critic's last bias) into a full step of either sign.
    """
    monkeypatch.setattr(torch.optim, "Adam", lambda params, lr, betas, **_: torch.optim.SGD(params, lr=1e-3))
    pyramid = load_pyramid(tiny_pyramid, 32)
    ours = trainer_at_level(train.Trainer, pyramid, level, generator=generator)
    plain = trainer_at_level(StraightforwardTrainer, pyramid, level, generator=generator)
    for _ in range(2):
        ours_losses = ours.iterate(ours.recon_inputs())
        plain_losses = plain.iterate(plain.recon_inputs())
        for key in ours_losses:
            assert ours_losses[key] == pytest.approx(plain_losses[key], rel=1e-3, abs=1e-4), key
    for ours_module, plain_module in ((ours.generator, plain.generator), (ours.critic, plain.critic)):
        for a, b in zip(ours_module.parameters(), plain_module.parameters()):
            torch.testing.assert_close(a, b, rtol=1e-2, atol=2e-4)  # weights move by up to 5e-3
    # Training moved the weights: the comparison is not of two untouched copies.
    fresh = trainer_at_level(train.Trainer, pyramid, level, generator=generator)
    moved = [(a - b).abs().max() for a, b in zip(ours.critic.parameters(), fresh.critic.parameters())]
    assert max(moved) > 1e-5


class FakeTrainer:
    """What Budget reads of a trainer."""

    def __init__(self, levels):
        self.level, self.iteration, self.seconds, self.plan = 0, 0, [], [0] * levels


def test_budget_plans_equal_iterations_and_corrects_for_drift(monkeypatch):
    now = [1000.0]
    monkeypatch.setattr(train.time, "monotonic", lambda: now[0])
    costs = [0.5, 1.0, 2.5]  # seconds per iteration per level
    budget = train.Budget(100 + train.Budget.RESERVE, now[0], costs)
    trainer = FakeTrainer(3)
    trainer.plan[0] = budget.iterations(trainer)
    assert trainer.plan[0] == 25  # 100 s / 4 s per round of the three levels
    # Level 0 took twice its prediction: the rest is planned at double cost.
    now[0] += 25
    trainer.seconds.append(25.0)
    trainer.level = 1
    trainer.plan[1] = budget.iterations(trainer)
    assert trainer.plan[1] == 10  # 75 s left / (2 x 3.5 s)
    # Level 1's share of the time: 10 iterations at twice the measured 1 s.
    assert budget.level_end(trainer) == pytest.approx(now[0] + 20)
    trainer.iteration = 4
    assert budget.level_end(trainer) == pytest.approx(now[0] + 12)
    # The last level runs to the deadline, while one more iteration fits.
    trainer.level, trainer.iteration, trainer.level_seconds = 2, 10, 20.0
    assert budget.level_end(trainer) == pytest.approx(1100.0)
    now[0] = 1098.5  # at 2 s per iteration, one more would end at 1100.5
    assert budget.room_for_another(trainer) is False
    now[0] = 1090.0
    assert budget.room_for_another(trainer) is True
    with pytest.raises(train.InputError, match="give more --minutes"):
        train.Budget(1, now[0], costs).iterations(FakeTrainer(3))


def test_a_budgeted_run_records_its_plan(tmp_path, tiny_pyramid, monkeypatch):
    # Measured costs vary with the machine's load: fixed ones keep the first
    # level's plan small; the second re-plans from how long the first took.
    monkeypatch.setattr(train, "time_levels", lambda *args: [1.0, 2.0])
    out = tmp_path / "m.onnx"
    log = []
    manifest = train.train(tiny_pyramid, out, make_config("tiny", minutes=0.2), log=log.append)
    planned = manifest["config"]["level_iters"]
    assert 1 <= planned[0] <= 3 and planned[1] >= 1  # (12 s - 2 s reserve - start-up) / 3 s
    assert manifest["training"]["iterations_per_level"] == list(planned)
    assert any(line.startswith("plan: ") for line in log)
    assert manifest["config"]["minutes"] == 0.2


def test_critic_crop_shows_random_boxes_of_the_given_side():
    pyramid = Pyramid([torch.zeros(40, 20, 30).numpy() > 0], (0.0,) * 3, (1.0,) * 3, "x", "0" * 64, "pyramid")
    trainer = train.Trainer(make_config("tiny", levels=1, critic_crop=16), pyramid, FP32)
    volume = torch.arange(40 * 20 * 30, dtype=torch.float32).reshape(1, 1, 40, 20, 30)
    corners = set()
    for _ in range(20):
        box = trainer.critic_view(volume)
        assert box.shape == (1, 1, 16, 16, 16)
        corner = box[0, 0, 0, 0, 0].item()
        x, y, z = int(corner // 600), int(corner // 30 % 20), int(corner % 30)
        assert torch.equal(box, volume[:, :, x:x + 16, y:y + 16, z:z + 16])
        corners.add((x, y, z))
    assert len(corners) > 10  # placed at random
    whole = train.Trainer(make_config("tiny", levels=1), pyramid, FP32)
    assert whole.critic_view(volume) is volume
