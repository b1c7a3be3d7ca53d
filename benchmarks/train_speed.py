"""Training speed: seconds per iteration, ours against a straightforward port.

    python benchmarks/train_speed.py                 # the six level sizes of a paper res-128 pyramid
    python benchmarks/train_speed.py --rounds 9      # more repetitions (the median is reported)
    python benchmarks/train_speed.py --levels 0 5    # only some of the six levels
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
checks it), so the ratio is the speed-up. Each trainer has its own process
(sinshape's with the switches `sinrun train` sets, the port's without); they
run one iteration in turn, round after round, so a busy machine slows them
alike, and the median of the rounds is reported. sinshape runs in float32
(the same computation) and, where this machine has native bf16, also with
what it picks (--precision auto). The last column says how the critic's
batch-1 and batch-2 convolutions run at each level (trainer/networks.py).
"""

import argparse
import multiprocessing
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from sinshape.trainer import device, networks, train
from sinshape.trainer.config import make_config
from sinshape.trainer.networks import Discriminator, TriplaneGenerator
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
            return super().fake(inputs, noise_planes, [None])[0]
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


def timed_iteration(trainer, recon_inputs) -> float:
    started = time.perf_counter()
    trainer.iterate(recon_inputs)
    return time.perf_counter() - started


def serve_iterations(connection, straightforward: bool, level: int, precision: str, options: dict) -> None:
    """A worker process: one trainer, one timed iteration per request.

    Every trainer has its own process, so each runs as it would alone: the
    straightforward port with the C library's default allocator, as the
    authors' code runs; sinshape with the switches `train` sets.
    """
    placement = device.choose("cpu", precision)
    if not straightforward:
        placement.activate()
    trainer = trainer_at(StraightforwardTrainer if straightforward else train.Trainer, PAPER_SIZES, level,
                         placement, **options)
    connection.send("ready")
    while connection.recv():
        connection.send(timed_iteration(*trainer))


def critic_methods(size: tuple) -> str:
    """How the critic's middle and last convolutions run at a level, for a
    batch of one (generator steps, gradient penalty) and of two (real and fake)."""
    critic = Discriminator(32)
    middle_in = [(n + 1) // 2 for n in size]  # after the stride-2 first layer
    last_in = [n - 2 for n in middle_in]
    picks = []
    for batch in (1, 2):
        middle = networks.valid_conv_method(critic.net[3], torch.empty(batch, 32, *middle_in))
        last = networks.valid_conv_method(critic.net[6], torch.empty(batch, 32, *last_in))
        picks.append(f"B{batch}: {middle}/{last}")
    return ", ".join(picks)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=5, help="iterations each trainer runs per level")
    parser.add_argument("--levels", type=int, nargs="+", default=range(len(PAPER_SIZES)),
                        help="which of the six levels to time (default: all)")
    parser.add_argument("--critic-box", type=int, default=None,
                        help="also time sinshape with this --critic-box (a change of method)")
    parser.add_argument("--full", type=Path, help="also train the default preset on this mesh, end to end")
    args = parser.parse_args()

    picked = device.choose("cpu")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, CPU capability "
          f"{torch.backends.cpu.get_cpu_capability()}, native bf16: {device.native_bf16()}")
    print(f"sinshape picked: {picked.describe()}; allocator keeps freed memory: {device.keep_freed_memory()}")
    # (name, straightforward, precision, options) of each trainer in the table
    runs = [("straightforward", True, "fp32", {}), ("sinshape fp32", False, "fp32", {})]
    if picked.precision != "fp32":
        runs.append((f"sinshape {picked.precision}", False, picked.precision, {}))
    if args.critic_box:
        runs.append((f"crop {args.critic_box}, {picked.precision}", False, picked.precision,
                     {"critic_box": args.critic_box}))
    names = [name for name, *_ in runs]
    print("| level | grid | " + " | ".join(names) + " | " + " | ".join(f"speed-up {n}" for n in names[1:])
          + " | critic's middle/last conv |")
    print("|---" * (2 * len(runs) + 2) + "|")
    sums = np.zeros(len(runs))
    context = multiprocessing.get_context("spawn")
    for level in args.levels:
        size = PAPER_SIZES[level]
        workers = []
        for _, straightforward, precision, options in runs:
            ours, theirs = context.Pipe()
            process = context.Process(target=serve_iterations, args=(theirs, straightforward, level, precision, options))
            process.start()
            workers.append((process, ours))
        for _, connection in workers:
            connection.recv()  # built and warmed up
        seconds = [[] for _ in runs]
        for _ in range(args.rounds):  # the trainers take turns: a busy machine slows them alike
            for (_, connection), times in zip(workers, seconds):
                connection.send(True)
                times.append(connection.recv())
        for process, connection in workers:
            connection.send(False)
            process.join()
        medians = np.array([statistics.median(times) for times in seconds])
        sums += medians
        print(row(f"| {level} | {'x'.join(map(str, size))} ", medians) + f" {critic_methods(size)} |", flush=True)
    print(row("| sum | ", sums) + " |")
    print(f"\nThe paper's setting (2000 iterations per level) at these sizes: "
          + ", ".join(f"{name} {s * 2000 / 3600:.2f} h" for name, s in zip(names, sums)))

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


def row(head: str, seconds) -> str:
    """A table row: every trainer's seconds, then each sinshape one's speed-up."""
    base = seconds[0]
    return head + "| " + " | ".join([f"{s:.3f}" for s in seconds] + [f"{base / s:.2f}x" for s in seconds[1:]]) + " |"


if __name__ == "__main__":
    sys.exit(main())
