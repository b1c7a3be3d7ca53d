"""Checkpoints: one file that holds a run where it stands, written so that a
crash never leaves half of one.

A run saves after every level, every few minutes within one
(`Checkpoints`) and on Ctrl-C. The file is torch.save of `Trainer.state()`,
loadable weights-only; `load_checkpoint` checks it is one of ours before a
resumed run restores it (`Trainer.restore`).
"""

import time
from pathlib import Path

import torch

from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write

from .config import TrainConfig
from .networks import make_generator

CHECKPOINT_FORMAT = "sinshape-checkpoint"
CHECKPOINT_VERSION = 1


def default_checkpoint_path(output: Path) -> Path:
    """model.onnx -> model.ckpt.pt, beside the model. A .pt output (the voxel
    baseline, which has no .onnx form) is its own checkpoint."""
    output = Path(output)
    return output if output.suffix.lower() == ".pt" else output.with_name(output.stem + ".ckpt.pt")


def atomic_save(obj, path: Path) -> None:
    """torch.save through the runtime's atomic writer: never a half-written
    checkpoint, and no temporary file left behind."""
    atomic_write(path, lambda f: torch.save(obj, f))


def count_levels(generator_state: dict) -> int:
    """How many level generators a TriplaneGenerator state dict holds."""
    return len({key.split(".")[1] for key in generator_state if key.startswith("levels.")})


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint and check that it is one of ours."""
    if not path.is_file():
        raise InputError(f"{path}: no checkpoint to resume from")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many kinds for a bad file
        raise InputError(f"{path}: not a readable checkpoint ({type(error).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: not a sinshape checkpoint")
    if state.get("version") != CHECKPOINT_VERSION:
        raise InputError(f"{path}: checkpoint version {state.get('version')} is not {CHECKPOINT_VERSION}")
    return state


def load_generator(checkpoint_path) -> tuple:
    """The trained generator of a checkpoint, with its level sizes and noise
    amplitudes: for sampling with torch (tests, benchmarks)."""
    state = load_checkpoint(Path(checkpoint_path))
    config = TrainConfig.from_dict(state["config"])
    generator = make_generator(config.generator, config.channels, config.pool_bins, config.mlp_hidden,
                               state.get("colour", False))
    for _ in range(count_levels(state["generator"])):
        generator.add_level()
    generator.load_state_dict(state["generator"])
    return generator.eval(), [tuple(s) for s in state["sizes"]], list(state["noise_amps"])


class Checkpoints:
    """Where a run saves, and when within a level: once `every` seconds have
    passed since the last save."""

    def __init__(self, path: Path, every: float):
        self.path, self.every = path, every
        self.saved = time.monotonic()

    def save(self, trainer) -> None:
        atomic_save(trainer.state(), self.path)
        self.saved = time.monotonic()

    def save_if_due(self, trainer) -> None:
        if time.monotonic() - self.saved > self.every:
            self.save(trainer)
