"""Training speed: seconds per iteration, ours against a straightforward port.

    python benchmarks/train_speed.py                 # the six level sizes of a paper res-128 pyramid
    python benchmarks/train_speed.py --rounds 9      # more repetitions (the median is reported)
    python benchmarks/train_speed.py --full MESH     # also: the whole default preset on MESH

An iteration is the paper's: 3 critic steps, then 3 generator steps, at level
i of a pyramid with the given level sizes (frozen levels below, noise
injection). The straightforward port does what the authors' code does, in
float32: the decoder concatenates the three plane features of every voxel
into a (X, Y, Z, 96) tensor and runs the whole MLP under autograd; every
sample goes through the networks on its own (critic steps build the
generator's autograd graph and then detach it; real, fake and the gradient
penalty's mix go through the critic separately), with PyTorch's own kernel
choice. Both compute the same losses from the same random draws (a test
checks it), so the ratio is the speed-up. The trainers run one iteration in
turn, round after round, so a busy machine slows them alike; the median of
the rounds is reported. sinshape runs twice: in float32 (the same
computation) and with what it picks on this machine (--precision auto).
"""

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from sinshape.trainer import device, train
from sinshape.trainer.config import make_config
from sinshape.trainer.networks import TriplaneGenerator
from sinshape.prep.pyramid import Pyramid

# The level sizes of one of the paper's res-128 pyramids (the training issue's).
PAPER_SIZES = [(31, 15, 15), (41, 15, 19), (54, 16, 26), (72, 20, 34), (96, 28, 44), (128, 36, 60)]


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


def trainer_at(trainer_class, sizes: list, level: int, placement, **options):
    """A trainer at `level` of a wavy terrain with these level sizes, warmed up."""
    pyramid = Pyramid([wavy_terrain(size) for size in sizes[:level + 1]], (0.0,) * 3, (1.0,) * 3,
                      "terrain", "0" * 64, "pyramid")
    trainer = trainer_class(make_config("paper", levels=level + 1, **options), pyramid, placement)
    for trainer.level in range(level + 1):
        trainer.begin_level()
    recon_inputs = trainer.recon_inputs()
    trainer.iterate(recon_inputs)  # warm-up: first calls allocate and pick kernels
    return trainer, recon_inputs


def row(head: str, seconds) -> str:
    """A table row: the seconds of each trainer, then each one's speed-up."""
    base, *ours = seconds
    cells = [f"{base:.3f}", *(f"{s:.3f}" for s in ours[:2]), *(f"{base / s:.2f}x" for s in ours[:2])]
    cells += [f"{ours[2]:.3f}", f"{base / ours[2]:.2f}x"] if len(ours) > 2 else []
    return head + "| " + " | ".join(cells) + " |"


def timed_iteration(trainer, recon_inputs) -> float:
    started = time.perf_counter()
    trainer.iterate(recon_inputs)
    return time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=5, help="iterations each trainer runs per level")
    parser.add_argument("--critic-crop", type=int, default=None,
                        help="also time sinshape with this --critic-crop (a change of method)")
    parser.add_argument("--full", type=Path, help="also train the default preset on this mesh, end to end")
    args = parser.parse_args()

    picked = device.choose("cpu")
    fp32 = device.Placement(torch.device("cpu"), "fp32", "float32 asked for")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, CPU capability "
          f"{torch.backends.cpu.get_cpu_capability()}, native bf16: {device.native_bf16()}")
    print(f"sinshape picked: {picked.describe()}")
    crop = args.critic_crop
    print("| level | grid | straightforward s/iter | sinshape fp32 | sinshape " + picked.precision
          + " | speed-up fp32 | speed-up " + picked.precision + " |"
          + (f" crop {crop}, {picked.precision} | its speed-up |" if crop else ""))
    print("|---|---|---|---|---|---|---|" + ("---|---|" if crop else ""))
    sums = np.zeros(4)
    for level, size in enumerate(PAPER_SIZES):
        runs = [trainer_at(StraightforwardTrainer, PAPER_SIZES, level, fp32),
                trainer_at(train.Trainer, PAPER_SIZES, level, fp32),
                trainer_at(train.Trainer, PAPER_SIZES, level, picked)]
        if crop:
            runs.append(trainer_at(train.Trainer, PAPER_SIZES, level, picked, critic_crop=crop))
        seconds = [[] for _ in runs]
        for _ in range(args.rounds):
            for run, times in zip(runs, seconds):
                times.append(timed_iteration(*run))
        medians = [statistics.median(times) for times in seconds]
        sums[:len(medians)] += medians
        print(row(f"| {level} | {'x'.join(map(str, size))} ", medians), flush=True)
    print(row("| sum | ", sums[:len(runs)]))
    base, ours32, ours = sums[:3]
    print(f"\nThe paper's setting (2000 iterations per level) at these sizes: straightforward "
          f"{base * 2000 / 3600:.2f} h, sinshape fp32 {ours32 * 2000 / 3600:.2f} h, "
          f"sinshape {picked.precision} {ours * 2000 / 3600:.2f} h")

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
