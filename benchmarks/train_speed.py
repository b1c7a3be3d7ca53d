"""Training speed: seconds per iteration, ours against a straightforward port.

    python benchmarks/train_speed.py                 # 64^3 and 96^3 levels, side by side
    python benchmarks/train_speed.py --sizes 64      # one size
    python benchmarks/train_speed.py --full MESH     # also: the whole default preset on MESH

An iteration is the paper's: 3 critic steps, then 3 generator steps, at a
level i > 0 (frozen level below, noise injection). The straightforward port
does what the authors' code does: the decoder concatenates the three plane
features of every voxel into a (X, Y, Z, 96) tensor and runs the whole MLP
under autograd; critic steps build the generator's autograd graph and then
detach it; real and fake go through the critic separately. Both trainers
compute the same losses on the same shapes, so the ratio is the speed-up.
"""

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from sinshape.trainer import train
from sinshape.trainer.config import make_config
from sinshape.trainer.networks import TriplaneGenerator
from sinshape.trainer.pyramid import Pyramid


def wavy_terrain(size) -> np.ndarray:
    x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in size], indexing="ij")
    return z < 0.4 * np.sin(3 * x) * np.cos(2 * y)


def concat_decode(decoder, planes) -> torch.Tensor:
    """The authors' decoder: expand and concatenate features, then the MLP."""
    xy, xz, yz = (p[0].permute(1, 2, 0) for p in planes)  # (X, Y, C), (X, Z, C), (Y, Z, C)
    size = (xy.shape[0], xy.shape[1], xz.shape[1])
    features = torch.cat([xy[:, :, None].expand(*size, -1), xz[:, None].expand(*size, -1),
                          yz[None].expand(*size, -1)], dim=-1)  # (X, Y, Z, 3C)
    return torch.sigmoid(decoder.fc2(F.relu(decoder.fc1(features))))[..., 0]


class StraightforwardTrainer(train.Trainer):
    """The same training, computed as the authors' code computes it."""

    def __init__(self, config, pyramid, placement=None):
        super().__init__(config, pyramid, placement)
        self.critic.forward = self.critic.net  # plain PyTorch kernel choice

    def fake(self, inputs, noise_planes):
        gen = self.generator
        if not isinstance(gen, TriplaneGenerator):  # the voxel baseline: no decoder
            return super().fake(inputs, noise_planes)[0]
        planes = gen.levels[0](inputs) if self.level == 0 else gen.step(inputs, self.level, self.sizes[self.level], noise_planes)
        return concat_decode(gen.decoder, planes)

    def iterate(self, recon_inputs):
        c, level, real = self.config, self.level, self.targets[self.level]
        for _ in range(c.d_steps):
            z0, noises = self.random_noises(level)
            fake = self.fake(self.inputs(z0, noises), noises[level] if level else None)[None, None]
            alpha = torch.rand(1, generator=self.rng)
            loss_d = self.critic(fake.detach()).mean() - self.critic(real).mean() \
                + c.gp_weight * self.gradient_penalty(real, fake.detach(), alpha)
            self.opt_d.zero_grad()
            loss_d.backward()
            self.opt_d.step()
        self.critic.requires_grad_(False)
        for _ in range(c.g_steps):
            z0, noises = self.random_noises(level)
            fake = self.fake(self.inputs(z0, noises), noises[level] if level else None)
            loss_adv = -self.critic(fake[None, None]).mean()
            rec_inputs = self.inputs(self.z0_recon, None) if level == 0 else recon_inputs
            loss_rec = F.mse_loss(self.fake(rec_inputs, None), real[0, 0])
            self.opt_g.zero_grad()
            (loss_adv + c.rec_weight * loss_rec).backward()
            self.opt_g.step()
        self.critic.requires_grad_(True)
        return {"D": loss_d.item(), "G": loss_adv.item(), "rec": loss_rec.item()}


def seconds_per_iteration(trainer_class, side: int, iterations: int) -> float:
    """Train level 1 of a two-level cubic pyramid whose finest side is `side`."""
    coarse = math.ceil(side * 0.75)
    pyramid = Pyramid([wavy_terrain((coarse,) * 3), wavy_terrain((side,) * 3)],
                      (0.0,) * 3, (1.0,) * 3, "terrain", "0" * 64, "pyramid")
    trainer = trainer_class(make_config("paper", levels=2), pyramid)
    trainer.begin_level()
    trainer.level = 1
    trainer.begin_level()
    recon_inputs = trainer.inputs(trainer.z0_recon, [None, None])
    trainer.iterate(recon_inputs)  # warm-up: first calls allocate and pick kernels
    started = time.perf_counter()
    for _ in range(iterations):
        trainer.iterate(recon_inputs)
    return (time.perf_counter() - started) / iterations


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 96])
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--full", type=Path, help="also train the default preset on this mesh, end to end")
    args = parser.parse_args()

    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    print("| level | straightforward s/iter | sinshape s/iter | speed-up |")
    print("|---|---|---|---|")
    for side in args.sizes:
        base = seconds_per_iteration(StraightforwardTrainer, side, args.iterations)
        ours = seconds_per_iteration(train.Trainer, side, args.iterations)
        print(f"| {side}^3 | {base:.2f} | {ours:.2f} | {base / ours:.2f}x |", flush=True)

    if args.full:
        with tempfile.TemporaryDirectory() as tmp:
            started = time.perf_counter()
            manifest = train.train(args.full, Path(tmp) / "model.onnx", make_config("default"))
            wall = time.perf_counter() - started
        print(f"\ndefault preset on {args.full.name}: {wall / 60:.1f} min wall time")
        print("| level | grid | s/iter |")
        print("|---|---|---|")
        iters = manifest["config"]["iters"]
        for i, (level, seconds) in enumerate(zip(manifest["levels"], manifest["training"]["level_seconds"])):
            print(f"| {i} | {'x'.join(map(str, level['size']))} | {seconds / iters:.3f} |")


if __name__ == "__main__":
    sys.exit(main())
