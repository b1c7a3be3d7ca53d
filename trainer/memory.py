"""What a training iteration needs in memory, and the check that refuses a
pyramid whose largest level would not fit, before any level trains."""

import math

import torch

from sinshape.core.budget import check_memory
from sinshape.core.manifest import plane_sizes

from .config import TrainConfig

# Peak memory one iteration adds, with 32 channels and 3 + 3 steps in float32:
# per voxel the generator decodes (a batch of samples) and the critic sees
# (with its gradient penalty's double backward), the whole level or its
# boxes; per cell of the three planes, the generator's convolutions (the
# planes are whole either way). Fitted to the peaks benchmarks/train_speed.py
# measures (24^3 to 128^3 levels, whole and in boxes; docs/RELIABILITY.md).
GENERATOR_BYTES_PER_VOXEL = 364
CRITIC_BYTES_PER_VOXEL = 230
PLANE_BYTES_PER_CELL = 12_500
LEVEL_BYTES = 17 << 20  # what a level adds whatever its size


def level_extent(size, box: int | None) -> tuple:
    """(voxels, plane cells) one iteration at a level of `size` (X, Y, Z)
    works on: with boxes, only the voxels of a box are decoded and judged;
    the planes are whole either way."""
    box = box or max(size)
    return math.prod(min(n, box) for n in size), sum(math.prod(plane) for plane in plane_sizes(size))


def level_memory(size, config: TrainConfig) -> int:
    """Bytes one training iteration at a level of `size` (X, Y, Z) needs
    beyond the data and the networks. Activations grow with the channels."""
    seen, cells = level_extent(size, config.box)
    activations = (GENERATOR_BYTES_PER_VOXEL + CRITIC_BYTES_PER_VOXEL) * seen + PLANE_BYTES_PER_CELL * cells
    return LEVEL_BYTES + activations * config.channels // 32


def check_training_memory(sizes: list, config: TrainConfig, placement) -> None:
    """Refuse, before any level trains, a pyramid whose largest level would
    not fit: in the GPU's free memory on CUDA, else in the memory available."""
    if not sizes:
        return
    largest = max(sizes, key=math.prod)
    limit = torch.cuda.mem_get_info(placement.device)[0] if placement.device.type == "cuda" else None
    check_memory(level_memory(largest, config),
                 f"training a level of {'x'.join(map(str, largest))} voxels", limit)
