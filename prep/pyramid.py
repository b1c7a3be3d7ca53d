"""The voxel pyramid: the example shape at every level, coarsest first.

Sizes follow SSG: the finest grid has `res` voxels along its longest side and
fits the shape's bounding box; each coarser size is ceil(LEVEL_FACTOR * finer)
per axis; an axis shorter than MIN_SIZE voxels is stretched to MIN_SIZE. Every level is
voxelised from the mesh on its own, not downsampled from the finest one.
An SSG HDF5 pyramid (attribute `n_scales`, datasets `scale0` (coarsest) ..
`scale{n-1}`) is read as it is.

numpy and scipy only: evaluation, which is torch-free, voxelises its
reference the same way, with the model's own settings (`reference_grid`).
"""

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from sinshape.runtime.budget import check_memory
from sinshape.runtime.errors import InputError
from sinshape.runtime.generate import resize_volume

from . import voxelize

# The coarsest level's longest side should be 2-3x the discriminator's
# 11-voxel receptive field: levels are added until it is at most this.
COARSEST_MAX = 33
# SSG's pyramid: each level ceil(0.75 x) the finer one per axis, no axis below
# 15 voxels (the critic needs room). TrainConfig's defaults are these.
LEVEL_FACTOR = 0.75
MIN_SIZE = 15
PYRAMID_SUFFIXES = (".h5", ".hdf5")
# Peak bytes voxelising a mesh needs per voxel of its finest level (crossing
# counts, votes, the coarser levels, the blurred targets): 43 measured on
# tests/data/towerruins at res 128 and 256 (docs/RELIABILITY.md).
VOXELIZE_BYTES_PER_VOXEL = 48


@dataclass(frozen=True)
class Pyramid:
    """The example shape, voxelised at every level, and where it came from."""

    levels: list  # (X_i, Y_i, Z_i) bool arrays, coarsest first
    origin: tuple  # input-frame position of the finest level's voxel (0, 0, 0) centre
    spacing: tuple  # input-frame size of a finest-level voxel, per axis
    source_name: str
    source_sha256: str
    source_kind: str  # "mesh" or "pyramid"

    @property
    def sizes(self) -> list:
        return [tuple(int(n) for n in level.shape) for level in self.levels]


def level_count(longest: int, factor: float = LEVEL_FACTOR) -> int:
    """How many levels bring the longest side from `longest` to <= 33."""
    count = 1
    while longest > COARSEST_MAX:
        longest = math.ceil(longest * factor)
        count += 1
    return count


def level_sizes(finest: tuple, count: int, factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE) -> tuple:
    """Grid sizes per level, coarsest first: (voxelised sizes, stretched sizes).

    The voxelised size is the ceil(factor * finer) chain; the stretched size
    raises every axis to at least `min_size`.
    """
    chain = [tuple(int(n) for n in finest)]
    for _ in range(count - 1):
        chain.append(tuple(math.ceil(n * factor) for n in chain[-1]))
    chain.reverse()
    if max(chain[0]) < min_size:
        raise InputError(
            f"{count} levels shrink the coarsest level's longest side to {max(chain[0])} voxels, "
            f"below the {min_size}-voxel minimum; use fewer levels or a higher res", "res"
        )
    return chain, [tuple(max(n, min_size) for n in size) for size in chain]


def stretch(volume: np.ndarray, shape: tuple) -> np.ndarray:
    """Raise short axes to `shape`: trilinear resize, then threshold at 0.5."""
    if volume.shape == tuple(shape):
        return volume
    return resize_volume(volume, shape) > 0.5


def training_targets(pyramid: Pyramid, sigma: float = 0.5) -> list:
    """Each level blurred by a Gaussian of `sigma` voxels and clipped to [0, 1]:
    the soft targets the networks are trained on. List of float32 arrays."""
    return [
        np.clip(ndimage.gaussian_filter(level.astype(np.float32), sigma=sigma), 0.0, 1.0)
        for level in pyramid.levels
    ]


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def pyramid_from_mesh(path: Path, res: int, levels: int | None = None,
                      factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE, check=None) -> Pyramid:
    """Voxelise a mesh file at every level of its pyramid. check(sizes), if
    given, sees the level sizes before any is voxelised (to refuse work up
    front); voxelising that would not fit in memory is refused too."""
    mesh = voxelize.load_mesh(path)
    corners = mesh.vertices[mesh.faces.reshape(-1)]
    low, high = corners.min(axis=0), corners.max(axis=0)
    extent = high - low
    voxel = extent.max() / res  # cubic voxels at the finest level
    finest = tuple(max(1, math.ceil(e / voxel - 1e-6)) for e in extent)
    # The finest grid box is centred on the mesh's bounding box; every level
    # spans the same box with its own (slightly anisotropic) voxels.
    box = np.array(finest) * voxel
    box_low = (low + high) / 2 - box / 2
    count = levels if levels is not None else level_count(max(finest), factor)
    voxelised, stretched = level_sizes(finest, count, factor, min_size)
    check_memory(VOXELIZE_BYTES_PER_VOXEL * math.prod(finest), f"voxelising a {'x'.join(map(str, finest))} grid")
    if check:
        check(stretched)
    grids = [
        stretch(voxelize.voxelize(mesh, box_low, box / np.array(size), size), target)
        for size, target in zip(voxelised, stretched)
    ]
    for size, grid in zip(stretched, grids):
        if not grid.any():
            raise InputError(f"{path.name}: the mesh gives an empty {size} grid; is it a closed solid?")
    return Pyramid(
        levels=grids,
        origin=tuple(float(v) for v in box_low + voxel / 2),
        spacing=(float(voxel),) * 3,
        source_name=path.name,
        source_sha256=file_sha256(path),
        source_kind="mesh",
    )


def pyramid_from_h5(path: Path, levels: int | None = None) -> Pyramid:
    """Read an SSG HDF5 pyramid; `levels` keeps only the finest that many."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            count = int(f.attrs["n_scales"]) if "n_scales" in f.attrs else None
            if count is None or count < 1:
                raise InputError(f"{path.name}: not an SSG pyramid (no positive 'n_scales' attribute)")
            missing = [f"scale{i}" for i in range(count) if f"scale{i}" not in f]
            if missing:
                raise InputError(f"{path.name}: n_scales is {count} but {', '.join(missing)} is missing")
            grids = [np.asarray(f[f"scale{i}"][()]) for i in range(count)]
    except OSError as error:
        raise InputError(f"{path.name}: cannot read as HDF5 ({error})") from None
    for i, grid in enumerate(grids):
        if grid.ndim != 3 or grid.size == 0:
            raise InputError(f"{path.name}: scale{i} is not a 3-D grid (shape {grid.shape})")
        if not grid.any():
            raise InputError(f"{path.name}: scale{i} is empty")
    if grids[0].size > grids[-1].size:  # some files store the finest level first
        grids.reverse()
    if levels is not None:
        if levels > len(grids):
            raise InputError(f"{path.name} has {len(grids)} levels; levels {levels} asks for more", "levels")
        grids = grids[len(grids) - levels:]
    return Pyramid(
        levels=[grid.astype(bool) for grid in grids],
        origin=(0.0, 0.0, 0.0),
        spacing=(1.0, 1.0, 1.0),
        source_name=path.name,
        source_sha256=file_sha256(path),
        source_kind="pyramid",
    )


def load_pyramid(path, res: int, levels: int | None = None,
                 factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE, check=None) -> Pyramid:
    """The pyramid of a mesh file (voxelised at `res`) or of an SSG .h5 file.
    check(sizes), if given, sees the level sizes before a mesh is voxelised,
    after an .h5 file is read."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.suffix.lower() in PYRAMID_SUFFIXES:
        pyramid = pyramid_from_h5(path, levels)
        if check:
            check(pyramid.sizes)
        return pyramid
    return pyramid_from_mesh(path, res, levels, factor, min_size, check)


def reference_grid(path, manifest, scale: float = 1.0) -> np.ndarray:
    """The finest level of a model's training input, made with the model's
    settings (res, level factor, minimum side from its manifest's config), so
    that a model trained with non-default settings is scored against its own
    grid. `manifest` is a runtime Manifest; `scale` voxelises a mesh that much
    finer. Returns (X, Y, Z) bool.
    """
    path = Path(path)
    config = manifest.raw.get("config", {})
    if scale != 1 and path.suffix.lower() in PYRAMID_SUFFIXES:
        raise InputError("scale needs a mesh reference: an .h5 pyramid has one resolution", "scale")
    res = round(config.get("res", max(manifest.sizes[-1])) * scale)
    return load_pyramid(path, res=res, levels=1, factor=config.get("level_factor", LEVEL_FACTOR),
                        min_size=config.get("min_size", MIN_SIZE)).levels[-1]
