"""The fast training step computes the paper's step; budgets and crops behave."""

import sys
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from sinshape.trainer import device, steps, train  # noqa: E402
from sinshape.trainer.networks import Discriminator, TriplaneGenerator  # noqa: E402
from sinshape.trainer.config import make_config  # noqa: E402
from sinshape.prep.pyramid import Pyramid, load_pyramid  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from train_speed import StraightforwardTrainer  # noqa: E402

FP32 = device.Placement(torch.device("cpu"), "fp32", "test")


def trainer_at_level(cls, pyramid, level, **overrides):
    trainer = cls(make_config("tiny", **overrides), pyramid, FP32)
    trainer.begin_level()
    for _ in range(level):
        trainer.finish_level()
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


def test_boxes_fall_anywhere_and_reach_the_edges():
    """A box hangs over the grid's edge by up to half its side, clipped: the
    outermost voxels are seen at least a third as often as the middle ones
    (boxes kept inside would see them 1 time in 9 here)."""
    pyramid = Pyramid([torch.zeros(48, 20, 30).numpy() > 0], (0.0,) * 3, (1.0,) * 3, "x", "0" * 64, "pyramid")
    trainer = train.Trainer(make_config("tiny", levels=1, box=32), pyramid, FP32)
    seen = torch.zeros(48)
    for _ in range(400):
        x, y, z = trainer.draw_box()
        assert 16 <= x.stop - x.start <= 32 and 0 <= x.start and x.stop <= 48
        assert (y, z) == (slice(0, 20), slice(0, 30))  # axes no longer than the box are seen whole
        seen[x] += 1
    assert seen[0] > seen[24] / 3 and seen[47] > seen[24] / 3
    # A level that fits in the box is seen whole, and draws nothing.
    state = trainer.rng.get_state()
    whole = train.Trainer(make_config("tiny", levels=1, box=48), pyramid, FP32)
    whole.rng.set_state(state)
    assert whole.draw_box() is None and torch.equal(whole.rng.get_state(), state)


def test_the_critic_is_not_shown_a_box_where_the_example_is_all_one():
    """A floor under empty air: many boxes are all air, and the
    critic's boxes (which its instance norms would blow up on) never are;
    the reconstruction's boxes still may be."""
    grid = torch.zeros(48, 40, 40)
    grid[:, :, :10] = 1
    pyramid = Pyramid([grid.numpy() > 0], (0.0,) * 3, (1.0,) * 3, "x", "0" * 64, "pyramid")
    trainer = train.Trainer(make_config("tiny", levels=1, box=16), pyramid, FP32)
    real = trainer.targets[0][0, 0]

    def share(box):
        return float(real[box].mean())

    shares = [share(trainer.draw_box()) for _ in range(100)]
    assert min(shares) == 0.0
    assert all(0.01 <= share(trainer.critic_box()) <= 0.99 for _ in range(100))


def test_a_box_decodes_what_the_whole_grid_has_there():
    generator = TriplaneGenerator(8, 4, 8)
    planes = [torch.randn(1, 8, *size) for size in ((20, 12), (20, 14), (12, 14))]
    box = (slice(3, 19), slice(0, 12), slice(5, 14))
    whole = generator.decoder.grid(planes)[0]
    torch.testing.assert_close(generator.decoder.grid(planes, box)[0], whole[box])


def test_the_critic_compares_the_same_box_of_real_and_fake(tiny_pyramid, monkeypatch):
    """Every critic step sees a box of the real grid, with the voxel around it
    (zeros only beyond the grid's faces), beside a fake of the same size; the
    reconstruction is scored in a box of the real grid too."""
    trainer = trainer_at_level(train.Trainer, load_pyramid(tiny_pyramid, 32), 1, box=16)
    boxes = iter([(slice(i, i + 16), slice(1, 17), slice(0, 15)) for i in range(4)] * 3)
    monkeypatch.setattr(trainer, "draw_box", lambda: next(boxes))
    shown = []
    critic_forward = trainer.critic.forward
    monkeypatch.setattr(trainer.critic, "forward",
                        lambda volume, framed: shown.append(volume.detach()) or critic_forward(volume, framed))
    trainer.iterate(trainer.recon_inputs())
    real = trainer.targets[1][0, 0]
    assert real.shape[2] == 15  # so the z box reaches both of the grid's faces
    padded = torch.nn.functional.pad(real, (1,) * 6)  # the whole grid as the critic reads it
    pairs = [v for v in shown if v.shape[0] == 2]
    assert len(pairs) == 3  # one per critic step (the gradient penalty's mix is a batch of one)
    for step, pair in enumerate(pairs):
        torch.testing.assert_close(pair[0, 0], padded[step:step + 18, 1:19, 0:17])
        assert not torch.equal(pair[1, 0], pair[0, 0])


def test_a_framed_box_scores_as_the_whole_grid_does_there():
    """With the instance norms out of the way (they see only the box, by
    design), the critic scores a framed box as it scores the whole grid
    there; a box padded with zeros instead differs at its faces inside the
    grid, where it looks like the grid's own faces."""
    critic = Discriminator(4)
    critic.net[1] = critic.net[4] = torch.nn.Identity()
    grid = torch.rand(1, 1, 24, 20, 18)
    box = (slice(4, 20), slice(0, 12), slice(2, 18))  # even starts keep the stride-2 patches aligned
    taken, pad = steps.framed(box, grid.shape[2:])
    with torch.no_grad():
        whole = critic(grid)
        scores = critic(torch.nn.functional.pad(grid[(..., *taken)], pad), framed=True)
        unframed = critic(grid[(..., *box)])
    there = whole[(..., *[slice(s.start // 2, s.start // 2 + n) for s, n in zip(box, scores.shape[2:])])]
    torch.testing.assert_close(scores, there)
    assert (unframed - there).abs().max() > 1e-3
