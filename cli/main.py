"""The `sinrun` command: parse, call one library function, report.

Heavy imports (torch, onnxruntime, trimesh) happen inside the commands, so
`--help` is instant and everything but `train` works without torch.
"""

import importlib.metadata
import sys
from pathlib import Path

import click

from sinshape.runtime.errors import InputError


class Sinrun(click.Group):
    """Turns InputError (bad user input) into one line and exit code 1."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as error:
            raise click.ClickException(str(error)) from None


@click.group(cls=Sinrun, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(importlib.metadata.version("sinshape"), prog_name="sinrun")
def cli():
    """Learn to generate new 3D shapes from one example shape.

    Train a model on one mesh (needs the train extra: pip install
    'sinshape[train]'), then sample new shapes from it anywhere, without torch.
    """


def import_torch():
    """torch, or a one-line explanation of how to get it."""
    try:
        import torch
    except ImportError:
        raise click.ClickException(
            "training needs PyTorch, which is not installed: pip install 'sinshape[train]'"
        ) from None
    return torch


class TrainProgress:
    """One line per level: a bar on a terminal, a line every 10% otherwise."""

    def __init__(self, stream=sys.stderr):
        self.stream = stream
        self.tty = stream.isatty()
        self.level = None
        self.started = 0.0
        self.reported = -1

    def __call__(self, p) -> None:
        import time

        if p.level != self.level:
            self.level, self.started, self.reported = p.level, time.monotonic(), -1
        elapsed = time.monotonic() - self.started
        left = elapsed / p.iteration * (p.iters - p.iteration)
        losses = "  ".join(f"{k} {v:+.4f}" for k, v in p.losses.items())
        head = f"level {p.level + 1}/{p.levels} {'x'.join(map(str, p.size))}"
        tail = f"{p.iteration}/{p.iters}  {losses}  {format_seconds(left)} left"
        if self.tty:
            filled = int(20 * p.iteration / p.iters)
            self.stream.write(f"\r{head} [{'#' * filled}{'.' * (20 - filled)}] {tail}\033[K")
            if p.iteration == p.iters:
                self.stream.write("\n")
        elif p.iteration * 10 // p.iters != self.reported or p.iteration == p.iters:
            self.reported = p.iteration * 10 // p.iters
            self.stream.write(f"{head} {tail}\n")
        self.stream.flush()


def raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def format_seconds(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


@cli.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Where to write the model (.onnx). A checkpoint MODEL.ckpt.pt is kept beside it.")
@click.option("--preset", type=click.Choice(["default", "paper", "tiny"]), default=None,
              help="Named settings: 'default' (res 64, 1000 iterations per level: a CPU-friendly "
                   "run), 'paper' (res 128, 2000 iterations, as Wu & Zheng 2022), 'tiny' "
                   "(res 32, 2 levels, 10 iterations: a smoke test). Default: default.")
@click.option("--res", type=int, default=None,
              help="Voxels along the longest side of the finest level (meshes only; an .h5 "
                   "pyramid has its own).")
@click.option("--levels", type=int, default=None,
              help="Number of levels. Default: enough that the coarsest longest side is at most 33 voxels.")
@click.option("--iters", type=int, default=None, help="Training iterations per level (3 D + 3 G steps each).")
@click.option("--seed", type=int, default=None, help="Seed of the training run (weights, noise draws). Default 0.")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted run from its checkpoint, skipping finished levels, "
                   "with the checkpoint's settings.")
@click.option("--checkpoint", type=click.Path(path_type=Path), default=None,
              help="Checkpoint file. Default: MODEL.ckpt.pt beside the output.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def train(input_path, output, preset, res, levels, iters, seed, resume, checkpoint, quiet):
    """Train a model on one example shape and export it as one .onnx file.

    INPUT is a mesh (.obj, .ply, .stl, .off, .glb; not necessarily watertight)
    or an SSG voxel pyramid (.h5). The mesh is voxelised at every level of a
    pyramid; one tri-plane generator per level is trained, coarse to fine.
    Checkpoints are written after every level and every 5 minutes; Ctrl-C
    saves one and stops; --resume continues.
    """
    import_torch()
    import signal

    from sinshape.trainer import config as configs
    from sinshape.trainer import train as training

    overrides = dict(preset=preset, res=res, levels=levels, iters=iters, seed=seed)
    given = [f"--{name}" for name, value in overrides.items() if value is not None]
    if resume and given:
        raise click.UsageError(f"--resume continues with the checkpoint's settings; leave out {', '.join(given)}")
    config = None if resume else configs.make_config(**{**overrides, "preset": preset or "default"})
    report = (lambda message: None) if quiet else (lambda message: click.echo(message, err=True))
    signal.signal(signal.SIGTERM, raise_interrupt)  # `kill` saves a checkpoint too, like Ctrl-C
    try:
        manifest = training.train(
            input_path, output, config, resume=resume, checkpoint_path=checkpoint,
            progress=None if quiet else TrainProgress(), log=report,
        )
    except training.Interrupted as error:
        click.echo(str(error), err=True)
        sys.exit(130)
    except training.TrainingDiverged as error:
        raise click.ClickException(str(error)) from None
    sizes = ", ".join("x".join(map(str, level["size"])) for level in manifest["levels"])
    click.echo(f"wrote {output} ({len(manifest['levels'])} levels: {sizes}; "
               f"trained in {format_seconds(manifest['training']['seconds'])})")


def main():
    cli(prog_name="sinrun")
