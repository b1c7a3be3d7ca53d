"""The manifest: the JSON inside every sinshape .onnx file (docs/FORMAT.md).

It holds everything the runtime needs (level sizes, noise amplitudes, tensor
names of each stage, plane order, the input's frame) and how the model was
made. The trainer writes it with `stage_names` and checks it with `parse`;
the runtime reads it with `parse`. This module is the contract in code.
"""

import json
import math
from dataclasses import dataclass

from .errors import InputError

FORMAT_NAME = "sinshape"
FORMAT_VERSION = 1
METADATA_KEY = "sinshape.manifest"  # key of the manifest in the ONNX metadata_props
NOISE_SCHEME = "splitmix64-boxmuller-v1"  # runtime/noise.py
PLANES = ("xy", "xz", "yz")  # plane k drops grid axis 2 - k
PLANE_AXES = ((0, 1), (0, 2), (1, 2))  # the grid axes each plane keeps, in PLANES order
# Initializers of stage decoder_head, (D,), (D, 1), (1,): b1, w2, b2.
HEAD_WEIGHTS = ("decoder_head.bias1", "decoder_head.weight2", "decoder_head.bias2")
MAX_LEVELS = 64
MAX_SIDE = 4096  # a level's side in voxels; far above anything trainable


def plane_sizes(size) -> list:
    """Plane sizes of a grid (X, Y, Z), in PLANES order: [(X, Y), (X, Z), (Y, Z)]."""
    return [(size[a], size[b]) for a, b in PLANE_AXES]


def stage_names(levels: int) -> dict:
    """Input and output tensor names of every stage, as the trainer writes them."""

    def io(stage):
        return {"inputs": [f"{stage}.{p}" for p in PLANES], "outputs": [f"{stage}.{p}.out" for p in PLANES]}

    return {
        "projection": io("projection"),
        "levels": [io(f"level{i}") for i in range(levels)],
        "decoder_planes": io("decoder_planes"),
        "decoder_head": {"inputs": [f"decoder_head.{p}" for p in PLANES], "outputs": ["decoder_head.occupancy"]},
    }


@dataclass(frozen=True)
class Manifest:
    """The parts of the manifest the runtime uses; `raw` keeps all of it."""

    sizes: list  # [(X, Y, Z)] per level, coarsest first
    noise_amps: list  # sigma_i per level; sigma_0 is the std of z0
    channels: int
    pool_bins: int
    hidden: int
    recon_seed: int
    origin: tuple  # input-frame position of the finest level's voxel (0, 0, 0)
    spacing: tuple  # input-frame size of one finest-level voxel, per axis
    stages: dict
    raw: dict


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(f"bad model manifest: {message}")


def _is_int(value, low, high) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def parse(text: str) -> Manifest:
    """Check a manifest's JSON text; raise InputError naming what is wrong."""
    try:
        raw = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        raise InputError("bad model manifest: not valid JSON") from None
    _require(isinstance(raw, dict), "not a JSON object")
    _require(raw.get("format") == FORMAT_NAME, f"format is {raw.get('format')!r}, not {FORMAT_NAME!r}")
    version = raw.get("format_version")
    _require(_is_int(version, 1, 10**6), f"format_version {version!r} is not a positive integer")
    if version > FORMAT_VERSION:
        raise InputError(
            f"model format version {version} is newer than this sinshape reads ({FORMAT_VERSION}); upgrade sinshape"
        )
    _require(list(raw.get("planes", [])) == list(PLANES), f"planes must be {list(PLANES)}")
    _require(raw.get("noise") == NOISE_SCHEME, f"noise scheme {raw.get('noise')!r} is not {NOISE_SCHEME!r}")
    for key in ("channels", "pool_bins", "mlp_hidden"):
        _require(_is_int(raw.get(key), 1, 1024), f"{key} must be an integer in [1, 1024]")
    _require(_is_int(raw.get("recon_seed"), 0, 2**64 - 1), "recon_seed must be an integer in [0, 2**64)")

    levels = raw.get("levels")
    _require(isinstance(levels, list) and 1 <= len(levels) <= MAX_LEVELS, f"levels must be a list of 1..{MAX_LEVELS}")
    sizes, amps = [], []
    for i, level in enumerate(levels):
        _require(isinstance(level, dict), f"level {i} is not an object")
        size = level.get("size")
        _require(isinstance(size, list) and len(size) == 3 and all(_is_int(n, 2, MAX_SIDE) for n in size),
                 f"level {i} size must be 3 integers in [2, {MAX_SIDE}]")
        amp = level.get("noise_amp")
        _require(_is_number(amp) and amp >= 0, f"level {i} noise_amp must be a non-negative number")
        sizes.append(tuple(size))
        amps.append(float(amp))

    frame = raw.get("frame")
    _require(isinstance(frame, dict), "frame is missing")
    origin, spacing = frame.get("origin"), frame.get("spacing")
    _require(isinstance(origin, list) and len(origin) == 3 and all(map(_is_number, origin)), "frame origin must be 3 numbers")
    _require(isinstance(spacing, list) and len(spacing) == 3 and all(_is_number(s) and s > 0 for s in spacing),
             "frame spacing must be 3 positive numbers")

    stages = raw.get("stages")
    _require(stages == stage_names(len(levels)), "stages do not name the standard tensors for this level count")
    return Manifest(
        sizes=sizes,
        noise_amps=amps,
        channels=raw["channels"],
        pool_bins=raw["pool_bins"],
        hidden=raw["mlp_hidden"],
        recon_seed=raw["recon_seed"],
        origin=tuple(float(v) for v in origin),
        spacing=tuple(float(v) for v in spacing),
        stages=stages,
        raw=raw,
    )
