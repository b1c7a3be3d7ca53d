"""Checkpoints: one file that holds a run where it stands, written so that a
crash never leaves half of one.

A run saves after every level, every few minutes within one
(`Checkpoints`) and on Ctrl-C. The file is torch.save of `Trainer.state()`,
loadable weights-only; `load_checkpoint` checks it is one of ours before a
resumed run restores it (`Trainer.restore`).
"""

import math
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
    checkpoint, and no temporary file left behind. One that cannot be
    written (a full disk, a file-size limit) is an InputError, and the last
    one written stays as it was."""
    try:
        atomic_write(path, lambda f: torch.save(obj, f))
    except InputError as error:  # the file system's own reason
        raise InputError(f"{error}; the last checkpoint written is kept") from None
    except RuntimeError:  # torch's zip writer says only "unexpected pos" (inline_container.cc)
        raise InputError(f"{path}: cannot write the checkpoint (writing it failed: a full disk, or a file-size "
                         "limit?); the last checkpoint written is kept") from None


def count_levels(generator_state: dict) -> int:
    """How many level generators a TriplaneGenerator state dict holds."""
    return len({key.split(".")[1] for key in generator_state if key.startswith("levels.")})


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint (weights only: tensors and plain values, never
    pickled objects) and check that it is one of ours, field by field."""
    if not path.is_file():
        raise InputError(f"{path}: no checkpoint to resume from")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many kinds for a bad file
        raise InputError(f"{path}: not a readable checkpoint ({type(error).__name__})") from None
    if not (isinstance(state, dict) and isinstance(state.get("format"), str) and state["format"] == CHECKPOINT_FORMAT):
        raise InputError(f"{path}: not a sinshape checkpoint")
    if not (whole(state.get("version")) and state["version"] == CHECKPOINT_VERSION):
        raise InputError(f"{path}: checkpoint version {str(state.get('version'))[:20]!r} is not {CHECKPOINT_VERSION}")
    why = check_fields(state)
    if why:
        raise InputError(f"{path}: a damaged checkpoint ({why})")
    return state


def whole(value, low: int = 0, high: int = 2**63) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value < high


def finite(value) -> bool:
    """A plain finite number (an integer of at most 63 bits: a float's range, and no 10**400)."""
    if isinstance(value, bool):
        return False
    return whole(value, -2**63) or isinstance(value, float) and math.isfinite(value)


def numbers_list(value) -> bool:
    return isinstance(value, list) and all(finite(v) for v in value)


def tensors(value) -> bool:
    return isinstance(value, dict) and all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in value.items())


def check_fields(state: dict) -> str | None:
    """What is wrong with a checkpoint's fields (None: nothing): each of the
    type, sign and range `Trainer.restore` and `TrainConfig` rely on."""
    if not isinstance(state.get("config"), dict):
        return "config is not a table of settings"
    try:
        TrainConfig.from_dict(state["config"])
    except (TypeError, ValueError) as error:  # InputError is a ValueError
        return f"its config: {str(error).splitlines()[0][:200] if str(error) else type(error).__name__}"
    sizes = state.get("sizes")
    if not (isinstance(sizes, list) and 1 <= len(sizes) <= 32
            and all(isinstance(s, list) and len(s) == 3 and all(whole(n, 1, 4097) for n in s) for s in sizes)):
        return "sizes must be 1 to 32 lists of 3 whole numbers in [1, 4096]"
    source = state.get("source")
    if not (isinstance(source, dict) and all(isinstance(source.get(k), str) for k in ("name", "sha256", "kind"))
            and all(isinstance(source.get(k, ""), str) for k in ("files", "colour"))):
        return "source must hold the strings name, sha256 and kind (and files and colour, if any)"
    if not (whole(state.get("level"), 0, len(sizes) + 1) and whole(state.get("iteration"))):
        return f"level must be 0 to {len(sizes)} and iteration a whole number"
    for name in ("noise_amps", "seconds"):
        if not numbers_list(state.get(name)):
            return f"{name} must be a list of finite numbers"
    for name in ("lrs", "rewinds", "plan"):
        if state.get(name) is not None and not numbers_list(state[name]):
            return f"{name} must be a list of finite numbers"
    if not finite(state.get("level_seconds")):
        return "level_seconds must be a finite number"
    if not (tensors(state.get("generator")) and tensors(state.get("critic"))):
        return "generator and critic must be tables of tensors"
    if any(k.startswith("levels.") and not k.split(".")[1].isdigit() for k in state["generator"]):
        return "the generator's levels are not numbered"
    if count_levels(state["generator"]) > len(sizes):
        return f"the generator has {count_levels(state['generator'])} levels for {len(sizes)} sizes"
    if any(state.get(name) is not None and not isinstance(state[name], dict) for name in ("opt_g", "opt_d")):
        return "opt_g and opt_d must be optimiser states"
    rng = state.get("rng")
    if not (isinstance(rng, torch.Tensor) and rng.dtype == torch.uint8 and rng.dim() == 1):
        return "rng must be a generator's state (a tensor of bytes)"
    return None


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
