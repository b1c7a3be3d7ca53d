"""The voxel pyramid: the example shape at every level, coarsest first.

Sizes follow SSG: the finest grid has `res` voxels along its longest side and
fits the shape's bounding box; each coarser size is ceil(LEVEL_FACTOR * finer)
per axis; an axis shorter than MIN_SIZE voxels is raised to MIN_SIZE (thinner
voxels). Every level is voxelised from the mesh on its own, over the same box,
not downsampled from the finest one.
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

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import check_readable
from sinshape.core.manifest import MAX_LEVEL_SIDE

from . import appearance, colour as colours
from . import meshfiles, voxelize

# The coarsest level's longest side should be 2-3x the discriminator's
# 11-voxel receptive field: levels are added until it is at most this.
COARSEST_MAX = 33
# SSG's pyramid: each level ceil(0.75 x) the finer one per axis, no axis below
# 15 voxels (the critic needs room). TrainConfig's defaults are these.
LEVEL_FACTOR = 0.75
MIN_SIZE = 15
PYRAMID_SUFFIXES = (".h5", ".hdf5")
# Levels an .h5 pyramid may have: far more than any real one (a 4096-voxel
# side brings the coarsest to 33 voxels in 18).
MAX_LEVELS = 32
# An .h5 level's shortest side: the critic's field, one patch. Files are used
# as they are (SSG's have 15 or more; the minimum for meshes is MIN_SIZE).
MIN_H5_SIDE = 11
# Peak bytes voxelising a mesh needs per voxel of its finest level (crossing
# counts, votes, the coarser levels, the blurred targets): 43 measured on
# tests/data/towerruins at res 128 and 256 (docs/RELIABILITY.md).
VOXELIZE_BYTES_PER_VOXEL = 48
GROUND_SHARE = 0.9  # a grid's lowest slice this full is ground (up_axis)


@dataclass(frozen=True)
class Pyramid:
    """The example shape, voxelised at every level, and where it came from."""

    levels: list  # (X_i, Y_i, Z_i) bool arrays, coarsest first
    origin: tuple  # input-frame position of the finest level's voxel (0, 0, 0) centre
    spacing: tuple  # input-frame size of a finest-level voxel, per axis
    source_name: str
    source_sha256: str
    source_kind: str  # "mesh" or "pyramid"
    up: str = "y"  # the input's axis that points up (`up_axis` for an .h5 pyramid)
    # A coloured mesh's colour field per level (prep/colour.py), or None:
    # (3, X_i, Y_i, Z_i) float32 sRGB of the nearest surface point, and
    # (X_i, Y_i, Z_i) float32 weights of the colour loss (the surface band).
    colours: list | None = None
    bands: list | None = None
    # The SHA-256 of the files the mesh names (prep.meshfiles: its textures,
    # material libraries, buffers), which a resumed run compares; what its
    # colour was read from, in words, and warnings about it.
    files_sha256: str = ""
    colour_read: str = ""
    colour_warnings: tuple = ()
    # A mesh's surface at its own detail (a coloured one's colour and depth,
    # else its depth alone), as tiles of the finest level's surface voxels
    # (prep.appearance.Tiles); None for an .h5 pyramid.
    tiles: object = None

    @property
    def sizes(self) -> list:
        return [tuple(int(n) for n in level.shape) for level in self.levels]


def up_axis(grid: np.ndarray) -> str:
    """Which axis of an SSG pyramid points up: y, the convention of SSG's own
    data (a tree stored 60x128x66 is 128 high), unless the grid's lowest z
    slice is solid ground and its lowest y slice is not (a terrain stored z
    up, as the Canyon pyramid is). Holds on every pyramid at hand: Canyon z,
    NaturalArch and SmallTown y."""
    def ground(axis):
        return np.take(grid, 0, axis=axis).mean() >= GROUND_SHARE

    return "z" if ground(2) and not ground(1) else "y"


def level_count(longest: int, factor: float = LEVEL_FACTOR) -> int:
    """How many levels bring the longest side from `longest` to <= 33."""
    count = 1
    while longest > COARSEST_MAX:
        longest = math.ceil(longest * factor)
        count += 1
    return count


def level_sizes(finest: tuple, count: int, factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE) -> list:
    """Grid sizes per level, coarsest first: the ceil(factor * finer) chain
    per axis, every axis raised to at least `min_size`."""
    chain = [tuple(int(n) for n in finest)]
    for _ in range(count - 1):
        chain.append(tuple(math.ceil(n * factor) for n in chain[-1]))
    chain.reverse()
    if max(chain[0]) < min_size:
        raise InputError(
            f"{count} levels shrink the coarsest level's longest side to {max(chain[0])} voxels, "
            f"below the {min_size}-voxel minimum; use fewer levels or a higher `res`", "res"
        )
    return [tuple(max(n, min_size) for n in size) for size in chain]


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
                      factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE, check=None,
                      colour: bool = True, asset_folder: Path | None = None,
                      tile_bytes: int = appearance.MAX_TILE_BYTES, tiles: bool = True) -> Pyramid:
    """Voxelise a mesh file at every level of its pyramid. check(sizes), if
    given, sees the level sizes before any is voxelised (to refuse work up
    front); voxelising that would not fit in memory is refused too. With
    `colour`, a mesh that has colour gets its colour field at every level;
    without, its colour is not read at all (nor its materials and textures).
    The files it names are read from its folder, or `asset_folder`. With
    `tiles`, its surface's tiles are made too (the grids alone without)."""
    try:
        scene, data = voxelize.read_scene(path, materials=colour, asset_folder=asset_folder)
    except InputError as error:  # a texture or material that cannot be read: say what gets past it
        if "no_colour" not in meshfiles.parameters(error):
            raise
        raise type(error)(f"{error.template} (`no_colour` trains geometry only)", error.parameter) from None
    mesh = voxelize.scene_mesh(scene, path)
    corners = mesh.vertices[mesh.faces.reshape(-1)]
    low, high = corners.min(axis=0), corners.max(axis=0)
    extent = high - low
    voxel = extent.max() / res  # cubic voxels at the finest level, before raising short axes
    finest = tuple(max(1, math.ceil(e / voxel - 1e-6)) for e in extent)
    # The finest grid box is centred on the mesh's bounding box; every level
    # spans the same box with its own (slightly anisotropic) voxels. A short
    # axis raised to min_size voxels is voxelised at that size (thinner
    # voxels), and the frame records the voxels as they are.
    box = np.array(finest) * voxel
    box_low = (low + high) / 2 - box / 2
    count = levels if levels is not None else level_count(max(finest), factor)
    sizes = level_sizes(finest, count, factor, min_size)
    check_memory(VOXELIZE_BYTES_PER_VOXEL * math.prod(sizes[-1]),
                 f"voxelising a {'x'.join(map(str, sizes[-1]))} grid")
    if check:
        check(sizes)
    try:
        surface = colours.surface_colour(scene, path, data, voxel) if colour else None
    except InputError as error:  # what to do about it, where it is raised
        raise InputError(f"{error.template} (`no_colour` trains geometry only)", "no_colour") from None
    if surface:
        check_memory(colours.BYTES_PER_VOXEL * sum(math.prod(size) for size in sizes),
                     f"colouring the levels of a {'x'.join(map(str, sizes[-1]))} grid")
    grids = [voxelize.voxelize(mesh, box_low, box / np.array(size), size) for size in sizes]
    for size, grid in zip(sizes, grids):
        if not grid.any():
            raise InputError(f"{path.name}: the mesh gives an empty {size} grid; is it a closed solid?")
    fields = [colours.colour_grid(surface, box_low, box / np.array(size), size) for size in sizes] if surface else None
    spacing = box / np.array(sizes[-1])
    # The example's surface at its own detail: colour and relief, or (geometry only) relief alone.
    detail = appearance.example_tiles(appearance.coloured_surface(scene, path) if surface
                                      else appearance.relief_surface(scene), box_low, spacing, grids[-1],
                                      tile_bytes) if tiles else None
    return Pyramid(
        levels=grids,
        origin=tuple(float(v) for v in box_low + spacing / 2),
        spacing=tuple(float(v) for v in spacing),
        source_name=path.name,
        source_sha256=file_sha256(path),
        source_kind="mesh",
        colours=[rgb for rgb, _ in fields] if fields else None,
        bands=[colours.band(distance) for _, distance in fields] if fields else None,
        files_sha256=scene.metadata[voxelize.REFERENCES].sha256,
        colour_read=surface.read if surface else "",
        colour_warnings=surface.warnings if surface else (),
        tiles=detail,
    )


def pyramid_from_h5(path: Path, levels: int | None = None) -> Pyramid:
    """Read an SSG HDF5 pyramid; `levels` keeps only the finest that many.
    Everything in the file is checked before a grid is read: the level
    count, each level's type and shape (growing from coarse to fine) and the
    memory the grids need; then their values."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            datasets = _h5_datasets(f, path.name)
            check_memory(sum(d.size * (d.dtype.itemsize + 1 + 4) for d in datasets),
                         f"reading {path.name} (its grids, as read, as occupancy and as training targets)")
            grids = [_occupancy(np.asarray(d[()]), f"{path.name}: {d.name.lstrip('/')}") for d in datasets]
    except (OSError, RuntimeError) as error:  # RuntimeError: HDF5's own, for a damaged file
        raise InputError(f"{path.name}: cannot read as HDF5 ({str(error).splitlines()[0][:200]})") from None
    if grids[0].size > grids[-1].size:  # some files store the finest level first
        grids.reverse()
    if max(grids[-1].shape) < MIN_SIZE:  # a model's res, its finest longest side, is at least that
        raise InputError(f"{path.name}: the finest level is {grids[-1].shape}, under the {MIN_SIZE}-voxel "
                         "minimum along every axis")
    for i, (coarse, fine) in enumerate(zip(grids, grids[1:])):
        if any(c > n for c, n in zip(coarse.shape, fine.shape)):
            raise InputError(f"{path.name}: its levels do not grow from coarse to fine along every axis "
                             f"(level {i} is {coarse.shape}, level {i + 1} {fine.shape})")
    if levels is not None:
        if levels > len(grids):
            raise InputError(f"{path.name} has {len(grids)} levels; `levels` {levels} asks for more", "levels")
        grids = grids[len(grids) - levels:]
    return Pyramid(
        levels=grids,
        origin=(0.0, 0.0, 0.0),
        spacing=(1.0, 1.0, 1.0),
        source_name=path.name,
        source_sha256=file_sha256(path),
        source_kind="pyramid",
        up=up_axis(grids[-1]),
    )


def _h5_datasets(f, name: str) -> list:
    """The scale0 .. scale{n-1} datasets of an open SSG file, n = n_scales,
    each checked to be a numeric 3-D grid of sides in [MIN_H5_SIDE, MAX_LEVEL_SIDE]
    stored in the file itself (no links, external or virtual storage)."""
    import h5py

    count = f.attrs.get("n_scales")
    if count is None:
        raise InputError(f"{name}: not an SSG pyramid (no 'n_scales' attribute)")
    if not (isinstance(count, (int, np.integer)) and not isinstance(count, (bool, np.bool_))
            and 1 <= count <= MAX_LEVELS):
        shown = count if isinstance(count, (int, float, np.number)) else repr(count)[:60]
        raise InputError(f"{name}: n_scales must be a whole number of levels in [1, {MAX_LEVELS}], got {shown}")
    count = int(count)
    datasets = []
    for i in range(count):
        link = f.get(f"scale{i}", getlink=True)
        if link is None:
            raise InputError(f"{name}: n_scales is {count} but scale{i} is missing")
        if not isinstance(link, h5py.HardLink):  # soft links can loop; external ones read other files
            raise InputError(f"{name}: scale{i} is a link ({type(link).__name__}); an SSG file holds its grids itself")
        item = f.get(f"scale{i}")
        if not hasattr(item, "dtype") or item.dtype.kind not in "biuf":
            raise InputError(f"{name}: scale{i} is not a grid of numbers")
        if item.shape is None or len(item.shape) != 3 or not all(MIN_H5_SIDE <= n <= MAX_LEVEL_SIDE for n in item.shape):
            raise InputError(f"{name}: scale{i} is not a 3-D grid of {MIN_H5_SIDE} to {MAX_LEVEL_SIDE} voxels a side "
                             f"(shape {item.shape})")
        if item.external or item.is_virtual:  # raw data kept in other files
            raise InputError(f"{name}: scale{i} keeps its data in other files; an SSG file holds its grids itself")
        datasets.append(item)
    return datasets


def _occupancy(grid: np.ndarray, name: str) -> np.ndarray:
    """An occupancy grid from the numbers stored: 0 (empty) to 1 (full),
    occupied from 0.5. NaN, infinities and values outside [0, 1] mean the
    file holds something else."""
    if grid.dtype.kind == "b":
        occupied = grid
    else:
        if not np.isfinite(grid).all():
            raise InputError(f"{name} holds NaN or infinite values, not occupancy")
        if grid.min() < 0 or grid.max() > 1:
            raise InputError(f"{name} holds values in [{grid.min():.9g}, {grid.max():.9g}], not occupancy in [0, 1]")
        occupied = grid >= 0.5
    if not occupied.any():
        raise InputError(f"{name} is empty")
    return occupied


def load_pyramid(path, res: int, levels: int | None = None, factor: float = LEVEL_FACTOR, min_size: int = MIN_SIZE,
                 check=None, colour: bool = True, asset_folder: Path | None = None,
                 tile_bytes: int = appearance.MAX_TILE_BYTES, tiles: bool = True) -> Pyramid:
    """The pyramid of a mesh file (voxelised at `res`) or of an SSG .h5 file
    (which has no colour). check(sizes), if given, sees the level sizes
    before a mesh is voxelised, after an .h5 file is read. `colour`: read a
    mesh's colour, if it has any; `asset_folder`: where the files a mesh
    names may lie (default: its own folder); `tile_bytes`: the most its
    tiles may take; `tiles`: make them (a mesh's surface at its detail)."""
    path = check_readable(path, "mesh or .h5 file")
    if path.suffix.lower() in PYRAMID_SUFFIXES:
        pyramid = pyramid_from_h5(path, levels)
        if check:
            check(pyramid.sizes)
        return pyramid
    return pyramid_from_mesh(path, res, levels, factor, min_size, check, colour, asset_folder, tile_bytes, tiles)


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
        raise InputError("`scale` needs a mesh reference: an .h5 pyramid has one resolution", "scale")
    res = round(config.get("res", max(manifest.sizes[-1])) * scale)
    return load_pyramid(path, res=res, levels=1, factor=config.get("level_factor", LEVEL_FACTOR),
                        min_size=config.get("min_size", MIN_SIZE), colour=False, tiles=False).levels[-1]
