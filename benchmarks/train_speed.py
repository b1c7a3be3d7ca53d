"""Training speed: seconds per iteration and peak memory per level, the
paper's exact method against the default, side by side.

    python benchmarks/train_speed.py                 # a seven-level 128^3 pyramid (24^3 .. 128^3)
    python benchmarks/train_speed.py --sizes paper   # the six level sizes of a paper res-128 pyramid
    python benchmarks/train_speed.py --box 48 64     # also the default with boxes of these sides
    python benchmarks/train_speed.py --train-depth 2 3  # also the default with levels trained together
    python benchmarks/train_speed.py --d-steps 1 2   # also the default with fewer critic steps
    python benchmarks/train_speed.py --port          # also a straightforward port of the authors' step
    python benchmarks/train_speed.py --rounds 9 --levels 5 6
    python benchmarks/train_speed.py --full MESH     # also: the whole default preset on MESH
    python benchmarks/train_speed.py --device cuda   # the same table on a CUDA GPU

An iteration is 3 critic steps, then 3 generator steps, at level i of a
pyramid with the given level sizes (frozen levels below, noise injection).
"paper" is `--preset paper`, "default" the default preset (the same step
with other learning rates, so the same speed), "box N" the default with
`--box N` (only boxes of at most N voxels per side decoded and judged at
large levels), "depth N" the default with `--train-depth N`, "critic N"
the default with `--d-steps N` (N critic steps an iteration); all in the
precision `sinrun train` picks here. The straightforward port (--port)
does what the authors' code does, in float32: the decoder concatenates the
three plane features of every voxel into a (X, Y, Z, 96) tensor and runs
the whole MLP under autograd; every sample goes through the networks on its
own, with PyTorch's own kernel choice. The port and the paper trainer
compute the same losses from the same random draws (a test checks it).

Each trainer has its own process per level (sinshape's with the switches
`sinrun train` sets, the port's without); they run one iteration in turn,
round after round, so a busy machine slows them alike, and the mean of the
rounds is reported (with boxes an iteration's cost varies with where its
boxes fall). Peak memory is the level's process's peak resident memory less
what it held before it built the trainer: what training that level takes
(on CUDA: the peak of what torch allocated on the GPU, less what it held
before). On a CPU, the last column says how the critic's batch-1 and
batch-2 convolutions run at each level in the paper trainer
(trainer/networks.py); on CUDA they are cuDNN's.
"""

import argparse
import multiprocessing
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from sinshape.core.errors import InputError
from sinshape.trainer import device, networks, train
from sinshape.trainer.config import make_config
from sinshape.trainer.networks import Discriminator, TriplaneGenerator
from sinshape.prep.pyramid import Pyramid, level_sizes

# The level sizes of one of the paper's res-128 pyramids, and of a 128^3 shape.
PAPER_SIZES = [(31, 15, 15), (41, 15, 19), (54, 16, 26), (72, 20, 34), (96, 28, 44), (128, 36, 60)]
CUBE_SIZES = level_sizes((128, 128, 128), 7)
SIZES = {"cube": CUBE_SIZES, "paper": PAPER_SIZES}


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
            return super().fake(inputs, [noise_planes], [None])[0]
        planes = gen.levels[0](inputs) if self.level == 0 else gen.step(inputs, self.level, self.sizes[self.level], noise_planes)
        return concat_decode(gen.decoder, planes)

    def gradient_penalty(self, real, fake, alpha):
        """The authors' penalty: the whole grid, padded by the critic itself."""
        mixed = (alpha * real + (1 - alpha) * fake).requires_grad_(True)
        (grad,) = torch.autograd.grad(self.critic(mixed).sum(), mixed, create_graph=True)
        return ((grad.abs() - 1) ** 2).mean()

    def iterate(self, recon_inputs):
        c, level, real = self.config, self.level, self.targets[self.level]
        for _ in range(c.d_steps):
            z0, noises = self.random_noises(level)
            fake = self.fake(self.inputs(z0, noises), noises[level] if level else None)[None, None]
            alpha = self.draw(torch.rand, 1)
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


def trainer_at(trainer_class, sizes: list, level: int, placement, preset: str = "paper", **options):
    """A trainer at `level` of a wavy terrain with these level sizes, warmed up."""
    pyramid = Pyramid([wavy_terrain(size) for size in sizes[:level + 1]], (0.0,) * 3, (1.0,) * 3,
                      "terrain", "0" * 64, "pyramid")
    trainer = trainer_class(make_config(preset, levels=level + 1, **options), pyramid, placement)
    trainer.begin_level()
    for _ in range(level):
        trainer.finish_level()
        trainer.begin_level()
    recon_inputs = trainer.recon_inputs()
    trainer.iterate(recon_inputs)  # warm-up: first calls allocate and pick kernels
    return trainer, recon_inputs


def timed_iteration(trainer, recon_inputs) -> float:
    synchronize(trainer.placement.device)
    started = time.perf_counter()
    trainer.iterate(recon_inputs)
    synchronize(trainer.placement.device)  # a GPU runs behind the host: wait for the last kernel
    return time.perf_counter() - started


def synchronize(on: torch.device) -> None:
    if on.type == "cuda":
        torch.cuda.synchronize(on)


def serve_iterations(connection, straightforward: bool, sizes: list, level: int, where: str, precision: str,
                     preset: str, options: dict) -> None:
    """A worker process: one trainer, one timed iteration per request, then
    its peak memory.

    Every trainer has its own process, so each runs as it would alone: the
    straightforward port with the C library's default allocator, as the
    authors' code runs; sinshape with the switches `train` sets.
    """
    placement = device.choose(where, precision)
    on_gpu = placement.device.type == "cuda"
    if not straightforward or on_gpu:  # on CUDA the port too gets cuDNN's autotuner
        placement.activate(shapes_vary=bool(options.get("box")))
    before = torch.cuda.memory_allocated(placement.device) if on_gpu else resident_bytes()
    trainer = trainer_at(StraightforwardTrainer if straightforward else train.Trainer, sizes, level,
                         placement, preset, **options)
    connection.send("ready")
    while connection.recv():
        connection.send(timed_iteration(*trainer))
    peak = (torch.cuda.max_memory_allocated(placement.device) if on_gpu
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
    connection.send(peak - before)


def resident_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize()


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
    parser.add_argument("--sizes", choices=SIZES, default="cube", help="cube: 24^3 .. 128^3 in seven levels; "
                        "paper: 31x15x15 .. 128x36x60 in six")
    parser.add_argument("--rounds", type=int, default=5, help="iterations each trainer runs per level")
    parser.add_argument("--levels", type=int, nargs="+", default=None, help="which levels to time (default: all)")
    parser.add_argument("--box", type=int, nargs="*", default=[], help="also the default with --box N")
    parser.add_argument("--train-depth", type=int, nargs="*", default=[],
                        help="also the default with --train-depth N")
    parser.add_argument("--d-steps", type=int, nargs="*", default=[], help="also the default with --d-steps N")
    parser.add_argument("--port", action="store_true", help="also the straightforward port (float32)")
    parser.add_argument("--full", type=Path, help="also train the default preset on this mesh, end to end")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (default: cpu)")
    args = parser.parse_args()

    sizes = SIZES[args.sizes]
    try:
        picked = device.choose(args.device)
    except InputError as error:
        parser.error(str(error))
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, CPU capability "
          f"{torch.backends.cpu.get_cpu_capability()}, native bf16: {device.native_bf16()}"
          + (f", GPU {torch.cuda.get_device_name(picked.device)}" if picked.device.type == "cuda" else ""))
    print(f"sinshape picked: {picked.describe()}; allocator keeps freed memory: {device.keep_freed_memory()}")
    print("; ".join(f"{name} preset: box {config.box}, " + (
        f"lr {config.lr:g}" if config.lr_total is None else
        f"lr {config.lr_total:g} / iterations, {config.lr:g} to {config.lr_max:g}")
        for name, config in (("default", make_config("default")), ("paper", make_config("paper")))))
    # (name, straightforward, precision, preset, options) of each trainer in the table
    runs = [("paper", False, "auto", "paper", {}), ("default", False, "auto", "default", {})]
    runs += [(f"box {side}", False, "auto", "default", {"box": side}) for side in args.box]
    runs += [(f"depth {n}", False, "auto", "default", {"train_depth": n}) for n in args.train_depth]
    runs += [(f"critic {n}", False, "auto", "default", {"d_steps": n}) for n in args.d_steps]
    if args.port:
        runs = [("straightforward", True, "fp32", "paper", {}), ("paper fp32", False, "fp32", "paper", {})] + runs
    names = [name for name, *_ in runs]
    base = names.index("paper")
    faster = [i for i, name in enumerate(names) if i > base]  # speed-ups over the paper trainer
    print("| level | grid | " + " | ".join(f"{n} s" for n in names) + " | "
          + " | ".join(f"{names[i]} speed-up" for i in faster) + " | "
          + " | ".join(f"{n} peak MB" for n in names) + " | critic's middle/last conv |")
    print("|---" * (2 * len(runs) + len(faster) + 3) + "|")
    sums = np.zeros(len(runs))
    context = multiprocessing.get_context("spawn")
    for level in args.levels if args.levels is not None else range(len(sizes)):
        workers = []
        for _, straightforward, precision, preset, options in runs:
            ours, theirs = context.Pipe()
            process = context.Process(target=serve_iterations, args=(theirs, straightforward, sizes, level,
                                                                     args.device, precision, preset, options))
            process.start()
            workers.append((process, ours))
        for _, connection in workers:
            connection.recv()  # built and warmed up
        seconds = [[] for _ in runs]
        for _ in range(args.rounds):  # the trainers take turns: a busy machine slows them alike
            for (_, connection), times in zip(workers, seconds):
                connection.send(True)
                times.append(connection.recv())
        peaks = []
        for process, connection in workers:
            connection.send(False)
            peaks.append(connection.recv())
            process.join()
        means = np.array([statistics.mean(times) for times in seconds])
        sums += means
        print(f"| {level} | {'x'.join(map(str, sizes[level]))} | " + " | ".join(f"{s:.3f}" for s in means)
              + " | " + " | ".join(f"{means[base] / means[i]:.2f}x" for i in faster) + " | "
              + " | ".join(f"{p / 2**20:.0f}" for p in peaks) + " | "
              + (critic_methods(sizes[level]) if picked.device.type == "cpu" else "cuDNN") + " |", flush=True)
    print("| sum | | " + " | ".join(f"{s:.2f}" for s in sums) + " | "
          + " | ".join(f"{sums[base] / sums[i]:.2f}x" for i in faster) + " |")
    print("\n2000 iterations per level at these sizes: "
          + ", ".join(f"{name} {s * 2000 / 3600:.2f} h" for name, s in zip(names, sums)))

    if args.full:
        with tempfile.TemporaryDirectory() as tmp:
            started = time.perf_counter()
            manifest = train.train(args.full, Path(tmp) / "model.onnx", make_config("default"), device=args.device,
                                   colour=False)
            wall = time.perf_counter() - started
        print(f"\ndefault preset on {args.full.name}: {wall / 60:.1f} min wall time")
        print("| level | grid | s/iter |")
        print("|---|---|---|")
        iters = manifest["config"]["iters"]
        for i, (level, seconds) in enumerate(zip(manifest["levels"], manifest["training"]["level_seconds"])):
            print(f"| {i} | {'x'.join(map(str, level['size']))} | {seconds / iters:.3f} |")


if __name__ == "__main__":
    sys.exit(main())
