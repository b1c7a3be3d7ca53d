"""Endless worlds: any tile of an unbounded world of a seed, on its own,
seamless with its neighbours, at the same cost anywhere.

The world spreads along the model's two horizontal axes (the two that are
not `up`), in tiles of S voxels along each (S the stride, half the training
extent). It is made of samples of the model arranged one of two ways:

- blend (landscapes, rock, anything that continues): windows, ordinary
  samples of the training extent (2S + 1 voxels along each horizontal
  axis), one per point (a, b) of the tile lattice, each with its own noise
  keyed by (seed, a, b). A point lies in four windows; its occupancy is the
  decoder's head applied to their hidden vectors (the first layer's
  pre-activations, linear in the planes) blended with weights that sum to
  one (per axis smoothstep(f) and 1 - smoothstep(f), f the point's place
  between lattice points), contrast kept: each window's deviation from its
  own mean at that height is summed with the weights and divided by
  (sum of the squared weights) ** (contrast / 2), the model's own exponent
  (its manifest's `contrast`), so that four windows blended at a tile's
  centre keep the relief one window has.
- scatter (one object: a temple, a tower): whole samples of the training
  size, one in most cells of a lattice of PITCH strides, at a place and
  mirrored as drawn from (seed, a, b), standing on a ground; the occupancy
  is the largest of theirs and the ground's. Nothing is blended, so every
  object is whole, and their places follow no period.

A height map (HeightMap: heights in voxels over the tiles, a designer's
painting) gives the world its large shape: a blend world's columns are
raised by the map's height there (its cubic B-spline, so the landform is
smooth), a scatter world's ground follows it and each object stands at the
map's height under its centre. A tile can be made coarser (`lod`): its
windows' chains stop `lod` levels early and its grid is that level's.

Why this holds:
- A tile (i, j) depends on the windows or objects that reach into it, which
  depend on (model, seed, a, b) only: no state, no order, and no cost that
  grows with the distance (a window's noise is drawn under its own key;
  every position a tile computes with is a small number relative to it).
- Seams: two neighbouring tiles evaluate the points of their shared face
  from the same windows at the same weights (blend: one window at weight
  exactly 1 across the face, the others exactly 0) or the same objects, at
  the same positions (exact: integers relative to each tile), by the same
  element-wise arithmetic in one fixed order (no matrix products, whose
  rounding may depend on an array's shape), so the values there are equal
  to the bit, and marching cubes cuts the same border vertices from both
  sides. A tile's sides are left open (not padded), so the union of any
  block of tiles is one surface. Normals are the field's gradient at the
  vertex (differences of the same field, each point read in the tile it
  falls in), so they too agree across a face.
- Tiles of different `lod` meet with a crack; a coarser tile hangs a skirt
  from its sides (SKIRT of its grid steps straight down) that covers it.
"""

import functools
import io
import itertools
import math
import numbers
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sinshape.core import noise
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import read_regular
from sinshape.core.manifest import ARRANGEMENTS, PLANE_AXES

from . import cubes
from .bake import vertex_normals
from .colour import RELIEF_SCALE, example_palette, nearest_in_palette, planes_colouring
from .generate import check_seed, draw_noise, scaled_sizes, triplane
from .mesh import colour_bytes
from .options import MAX_TILE  # a tile request's range, declared with its options
from .query import bilinear, check_scale, head_colour, project, sigmoid

WORLD_STREAM = 2  # (WORLD_STREAM, a, b): the key of window (a, b)'s noise, absorbed after the world's seed
SCATTER_STREAM = 3  # (SCATTER_STREAM, a, b): the key of scatter cell (a, b)'s draws (presence, place, mirrors)
MIN_STRIDE = 4  # voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
UP_AXIS = {"y": 1, "z": 2}
BLEND = 1.0  # the share of a stride, around its middle, over which one window gives way to the next
PITCH = 3  # a scatter cell's side, in strides: an object (2S + 1) and up to S of room
# The share of scatter cells that hold an object: 0.75 left the temple's
# height field 0.28 correlated at a cell's side (3S), 0.6 under 0.1.
PRESENCE = 0.6
GROUND = 1.0  # voxels of ground above the map's height under a scatter world's objects
# The ground's logit per voxel: nearly linear across a grid step, so that
# marching cubes places a sloping ground without terraces (4 drew them).
GROUND_SLOPE = 1.0
NORMAL_STEP = 0.25  # voxels: a normal's differences, a power of two (exact steps from a face), under PLATEAU
# Voxels either side of a lattice line where the window whose line it is
# holds the whole weight: a normal's points just past a face need no window
# but the face's own, so a tile's normals make no neighbour's windows.
PLATEAU = 0.5
SKIRT = 2.0  # a coarser tile's skirt, in its grid's steps along up
MAX_MAP_SIDE = 1 << 12  # pixels of a height map along each axis
MAX_RELIEF = 1 << 14  # voxels: a height map's values in +-MAX_RELIEF


@dataclass(frozen=True)
class Layout:
    """How a model's world is cut: which axes are horizontal, the stride S
    per axis (None along up), the windows' size factors."""

    horizontal: tuple  # the two horizontal axes, ascending
    up: int
    stride: tuple  # (3,) voxels per tile along each axis; the up axis's entry is its whole height - 1
    factors: tuple  # a window's size, as factors of the training size


def world_layout(model) -> Layout:
    """The world's cut for a model: refused where a world means nothing."""
    finest = model.manifest.sizes[-1]
    up = UP_AXIS[model.manifest.up]
    horizontal = tuple(a for a in range(3) if a != up)
    stride = [0, 0, 0]
    for axis in horizontal:
        stride[axis] = (finest[axis] - 1) // 2
        if stride[axis] < MIN_STRIDE:
            raise InputError(f"the model is {finest[axis]} voxels along {'xyz'[axis]}, a horizontal axis: a world "
                             f"needs windows of at least {2 * MIN_STRIDE + 1} to blend")
    stride[up] = finest[up] - 1
    factors = tuple((2 * stride[a] + 1) / finest[a] if a != up else 1.0 for a in range(3))
    return Layout(horizontal, up, tuple(stride), factors)


def check_tile(tile) -> tuple:
    """(i, j): two integers of magnitude below MAX_TILE."""
    if not (isinstance(tile, (tuple, list)) and len(tile) == 2
            and all(isinstance(t, (int, np.integer)) and not isinstance(t, bool) and -MAX_TILE < t < MAX_TILE
                    for t in tile)):
        raise InputError(f"`tile` must be two integers (i, j) of magnitude below 2**62, got {tile!r}", "tile")
    return int(tile[0]), int(tile[1])


def window_seed(seed: int, a: int, b: int) -> int:
    """The noise seed of window (a, b) of the world of `seed`: a 64-bit key."""
    mask = (1 << 64) - 1
    return noise.stream_key(seed, WORLD_STREAM, a & mask, b & mask)


# ---- the world's options: its arrangement, its height map, a tile's detail

@dataclass(frozen=True)
class HeightMap:
    """A designer's map of the world's large shape: heights in voxels at the
    centres of tiles (r, c), r along the first horizontal axis, from tile
    (0, 0); between them its cubic B-spline (smooth, and within the map's
    lowest and highest values), beyond its edges its edge. Held as bytes,
    so that a request stays a hashable value."""

    shape: tuple
    data: bytes  # float32, little-endian, C order

    @classmethod
    def of(cls, heights) -> "HeightMap":
        try:
            heights = np.asarray(heights, np.float64)
        except (TypeError, ValueError):
            raise InputError("a height map is a 2-D array of heights in voxels", "heights") from None
        if heights.ndim != 2 or not 0 < min(heights.shape) <= max(heights.shape) <= MAX_MAP_SIDE:
            raise InputError(f"a height map is a 2-D array of 1 to {MAX_MAP_SIDE} pixels a side, got shape "
                             f"{heights.shape}", "heights")
        if not (np.isfinite(heights).all() and np.abs(heights).max() <= MAX_RELIEF):
            raise InputError(f"a height map holds values in voxels within +-{MAX_RELIEF}: no NaN or infinities",
                             "heights")
        return cls(tuple(int(n) for n in heights.shape), heights.astype("<f4").tobytes())

    def array(self) -> np.ndarray:
        """(R, C) float32."""
        return np.frombuffer(self.data, "<f4").reshape(self.shape)

    def bounds(self) -> tuple:
        """The lowest and highest heights, rounded out to whole voxels."""
        heights = self.array()
        return math.floor(heights.min()), math.ceil(heights.max())


MAX_MAP_BYTES = 64 << 20  # a map file: 4096 x 4096 16-bit pixels fit


def read_npy_map(data: bytes, name, field: str) -> np.ndarray:
    """A map's 2-D numeric array from .npy bytes, its header checked before its data is read."""
    try:
        stream = io.BytesIO(data)
        header = {(1, 0): np.lib.format.read_array_header_1_0,
                  (2, 0): np.lib.format.read_array_header_2_0}.get(np.lib.format.read_magic(stream))
        if header is None:
            raise ValueError("an unknown .npy version")
        shape, _, dtype = header(stream)
        if dtype.kind not in "fiu" or len(shape) != 2 or max(shape, default=0) > MAX_MAP_SIDE:
            raise ValueError(f"{dtype} of shape {shape}")
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as error:
        raise InputError(f"{name}: not a 2-D numeric .npy array of at most {MAX_MAP_SIDE} a side ({error})",
                         field) from None


def image_pixels(data: bytes, name, what: str, field: str, read):
    """What `read(image)` takes from an image map's bytes, its size checked before its pixels are read."""
    from PIL import Image, UnidentifiedImageError  # pillow: Blender's Python, which makes worlds, has none

    try:
        with Image.open(io.BytesIO(data)) as image:
            if max(image.size) > MAX_MAP_SIDE:
                raise InputError(f"{name}: {image.size[0]}x{image.size[1]} pixels; {what} has at most "
                                 f"{MAX_MAP_SIDE} a side", field)
            return read(image)
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError) as error:
        raise InputError(f"{name}: not a readable image ({error})", field) from None


def parse_height_map(data: bytes, suffix: str, name, relief: float | None = None) -> HeightMap:
    """A height map from a file's bytes: a greyscale image (.png: black 0,
    white `relief` voxels; its columns run along the first horizontal axis,
    its rows from the bottom up along the second, as a map seen from above)
    or an array (.npy: heights in voxels, [i, j] tile (i, j)'s). `name`
    says what the bytes are in messages."""
    if len(data) > MAX_MAP_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a height map")
    suffix = suffix.lower()
    if suffix == ".npy":
        if relief is not None:
            raise InputError(f"{name}: an array holds heights in voxels; `relief` scales an image's", "relief")
        return HeightMap.of(read_npy_map(data, name, "heights"))
    if suffix != ".png":
        raise InputError(f"{name}: a height map is a .png image or a .npy array, got {suffix or 'no extension'!r}",
                         "heights")
    if relief is None or not (isinstance(relief, numbers.Real) and 0 < relief <= MAX_RELIEF):
        raise InputError(f"`relief` must be a number of voxels in (0, {MAX_RELIEF}] for an image, got {relief!r}",
                         "relief")
    wide, pixels = image_pixels(data, name, "a height map", "heights", lambda image: (
        image.mode.startswith("I"), np.asarray(image if image.mode.startswith("I") else image.convert("L"), np.float64)))
    full = 65535.0 if wide else 255.0
    return HeightMap.of(np.flipud(np.clip(pixels, 0, full) / full).T * relief)


RELIEF = 4  # an image map's white, in the model's heights, unless a relief is given


def read_height_map(path, model, relief: float | None = None) -> HeightMap:
    """parse_height_map of a file; an image's white is `relief` voxels
    (default RELIEF times the model's height)."""
    path = Path(path)
    data = read_regular(path, f"the height map {path}", MAX_MAP_BYTES, field="heights")
    if relief is None and path.suffix.lower() == ".png":
        layout = world_layout(model)
        relief = RELIEF * layout.stride[layout.up]
    return parse_height_map(data, path.suffix, path.name, relief)


MAX_MODELS = 256  # models in one world: a model map's pixel is a byte


@dataclass(frozen=True)
class ModelMap:
    """A designer's map of which model goes where in a scattered world: a
    model's index (0 the world's first model) per tile (r, c), r along the
    first horizontal axis, from tile (0, 0), as a height map's pixels lie;
    beyond its edges, its edge. A scatter cell's object comes from the model
    the pixel under the cell's centre names. Held as bytes, as HeightMap."""

    shape: tuple
    data: bytes  # uint8, C order

    @classmethod
    def of(cls, indices) -> "ModelMap":
        try:
            values = np.asarray(indices)
        except (TypeError, ValueError):
            values = np.empty(0)
        if values.ndim != 2 or not 0 < min(values.shape) <= max(values.shape) <= MAX_MAP_SIDE:
            raise InputError(f"a model map is a 2-D array of 1 to {MAX_MAP_SIDE} pixels a side, got shape "
                             f"{values.shape}", "models_map")
        numeric = values.dtype.kind in "iub" or values.dtype.kind == "f" and np.isfinite(values).all()
        if not (numeric and (values == np.round(values)).all() and 0 <= values.min() and values.max() < MAX_MODELS):
            raise InputError(f"a model map holds models' indices, whole numbers 0 to {MAX_MODELS - 1}", "models_map")
        return cls(tuple(int(n) for n in values.shape), values.astype(np.uint8).tobytes())

    @classmethod
    def of_text(cls, text: str) -> "ModelMap":
        """A map written as text, rows (along the first horizontal axis) parted
        by ';' and a row's pixels by ',': '0,1;1,0'."""
        try:
            rows = [[int(pixel) for pixel in row.split(",")] for row in text.split(";")]
        except ValueError:
            rows = None
        if not rows or len({len(row) for row in rows}) != 1:
            raise InputError(f"a model map's text is rows of whole numbers, ',' between pixels and ';' between "
                             f"rows, all rows as long (0,1;1,0), got {text[:40]!r}", "models_map")
        return cls.of(rows)

    def array(self) -> np.ndarray:
        """(R, C) uint8."""
        return np.frombuffer(self.data, np.uint8).reshape(self.shape)

    def at(self, r: int, c: int) -> int:
        """The index at tile (r, c), the edge's beyond the map."""
        return int(self.array()[min(max(r, 0), self.shape[0] - 1), min(max(c, 0), self.shape[1] - 1)])


def parse_model_map(data: bytes, suffix: str, name) -> ModelMap:
    """A model map from a file's bytes: an image (.png: a palette image's
    indices, or a greyscale image's values, laid out as a height map's
    image) or an array (.npy: [i, j] tile (i, j)'s model index). `name` says
    what the bytes are in messages."""
    if len(data) > MAX_MAP_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a model map", "models_map")
    suffix = suffix.lower()
    if suffix == ".npy":
        return ModelMap.of(read_npy_map(data, name, "models_map"))
    if suffix != ".png":
        raise InputError(f"{name}: a model map is a .png image or a .npy array, got {suffix or 'no extension'!r}",
                         "models_map")

    def indices(image) -> np.ndarray:
        if image.mode not in ("P", "L", "I", "I;16", "1"):
            raise InputError(f"{name}: a model map is a palette or greyscale image (a model's index per pixel), "
                             f"got mode {image.mode}", "models_map")
        return np.asarray(image).astype(np.int64)

    return ModelMap.of(np.flipud(image_pixels(data, name, "a model map", "models_map", indices)).T)


def read_model_map(path) -> ModelMap:
    """parse_model_map of a file."""
    path = Path(path)
    data = read_regular(path, f"the model map {path}", MAX_MAP_BYTES, field="models_map")
    return parse_model_map(data, path.suffix, path.name)


@dataclass(frozen=True)
class WorldOptions:
    """How a world is made (its arrangement and height map: every tile of one
    world has the same) and how finely one of its tiles is (`lod`: 0 the
    model's finest level, n that many levels coarser)."""

    arrange: str = "blend"
    heights: HeightMap | None = None
    lod: int = 0
    models: tuple = ()  # a scattered world's models after its first (the `model` its tiles are asked of): 1, 2, ...
    models_map: ModelMap | None = None  # which of them each scatter cell draws its object from
    detail: bool = True  # the example's relief and colour by correspondence (off: the decoder's colour, no relief)

    def __post_init__(self):
        if not isinstance(self.detail, bool):
            raise InputError(f"`detail` must be true or false, got {self.detail!r}", "detail")
        if self.arrange not in ARRANGEMENTS:
            raise InputError(f"unknown `arrange` {self.arrange!r}; choose {' or '.join(ARRANGEMENTS)}", "arrange")
        if self.heights is not None and not isinstance(self.heights, HeightMap):
            raise InputError("`heights` must be a world.HeightMap (HeightMap.of(array))", "heights")
        if not (isinstance(self.lod, numbers.Integral) and not isinstance(self.lod, bool) and 0 <= self.lod):
            raise InputError(f"`lod` must be a whole number of levels, 0 or more, got {self.lod!r}", "lod")
        if not isinstance(self.models, tuple) or len(self.models) >= MAX_MODELS:
            raise InputError(f"a world takes at most {MAX_MODELS - 1} `models` after the first", "models")
        if self.models_map is None:
            if self.models:
                raise InputError("several models need a model map saying which goes where", "models_map")
            return
        if not isinstance(self.models_map, ModelMap):
            raise InputError("`models_map` must be a world.ModelMap (ModelMap.of(array))", "models_map")
        if self.arrange != "scatter":
            raise InputError("a model map places whole objects: it is for a scatter world (blended models' "
                             "tiles, voxels and heights differ)", "models_map")
        named = self.models_map.array()
        if named.max() > len(self.models):
            r, c = np.argwhere(named > len(self.models))[0]
            raise InputError(f"the model map's pixel for tile ({r}, {c}) names model {named[r, c]}, and the world "
                             f"has {len(self.models) + 1} (0 to {len(self.models)})", "models_map")


PLAIN = WorldOptions()


def check_lod(model, lod: int) -> int:
    """The level a tile of `lod` reads its detail from."""
    levels = len(model.manifest.sizes)
    if lod >= levels:
        raise InputError(f"`lod` must be 0 to {levels - 1} (the model has {levels} levels), got {lod}", "lod")
    return levels - 1 - lod


# ---- windows and objects: samples whose planes a tile reads

@dataclass(frozen=True)
class Window:
    """One window's (blend) or object's (scatter) planes at the level a tile
    reads: 3 x (H, W, D) float32, its final planes times the decoder's first
    layer; its mean over its horizontal extent at each height, (U, D); per
    axis how many of the level's cells a finest voxel is; and the chain's
    own planes at that level, which a finer level of the window goes on from."""

    planes: list
    mean: np.ndarray
    cells: tuple  # (3,) level cells per finest voxel
    chain: list  # 3 x (C, H, W) float32: the generator's planes at the level


def window_sizes(model, layout: Layout, arrange: str) -> list:
    """Every level's size of a window (blend: 2S + 1 along each horizontal
    axis) or an object (scatter: the training size)."""
    factors = layout.factors if arrange == "blend" else (1.0, 1.0, 1.0)
    return scaled_sizes(model.manifest.sizes, factors)


# Windows kept for the next tiles (a tile shares each of its four with a
# neighbour; a view of 7 x 7 tiles, coarse first and then finer, goes on from
# the coarser windows it kept with 64): the last few made, whatever asked for
# them. A shipped model's window is 0.6 to 2 MB at full detail, a fifth of
# that or less at the coarsest. A cache, not state: a window is the same
# array whether it is made or found. A server makes tiles on several threads
# at once: the lock keeps each look and change whole.
WINDOWS_KEPT = 64
_windows = OrderedDict()  # (id(model), seed, arrange, level, a, b) -> (model, Window)
_windows_lock = threading.Lock()


def window(model, layout: Layout, seed: int, a: int, b: int, level: int, arrange: str = "blend") -> Window:
    """Window (a, b) (or scatter cell (a, b)'s object), its chain stopped at `level`."""
    key = (id(model), seed, arrange, level, a, b)
    with _windows_lock:
        if key in _windows:
            _windows.move_to_end(key)
            return _windows[key][1]
        # A coarser level of the window made before (a far tile come nearer) is gone
        # on from: the same planes as the whole chain, the levels below not run again.
        start = next(((coarser, _windows[key[:3] + (coarser, a, b)][1].chain) for coarser in range(level - 1, -1, -1)
                      if key[:3] + (coarser, a, b) in _windows), None)
    sizes = window_sizes(model, layout, arrange)
    made = triplane(model, draw_noise(window_seed(seed, a, b), sizes[:level + 1], model.manifest.channels,
                                      first=start[0] + 1 if start else 0), sizes[:level + 1], start=start)
    planes = project(model, made).planes
    means = []
    for plane, axes in zip(planes, PLANE_AXES):
        if layout.up not in axes:
            means.append(plane.mean(axis=(0, 1)))  # (D,): the same at every height
        else:
            means.append(plane.mean(axis=1 - axes.index(layout.up)))  # (U, D)
    mean = np.broadcast_to(sum(means), (sizes[level][layout.up], model.manifest.hidden)).astype(np.float32)
    cells = tuple((n - 1) / (f - 1) for n, f in zip(sizes[level], sizes[-1]))
    found = Window(planes, mean, cells, made.planes)
    with _windows_lock:
        _windows[key] = (model, found)  # the model is held, so its id names it while the entry lives
        while len(_windows) > WINDOWS_KEPT:
            _windows.popitem(last=False)
    return found


def smoothstep(f):
    return f * f * (3 - 2 * f)


def behind_weight(u, stride: int):
    """The weight, along one horizontal axis, of the window whose lattice
    point lies behind a point u voxels past it (0 to S): exactly 0 within
    PLATEAU of that point, exactly 1 within PLATEAU of the next, smooth
    between; the window before weighs exactly 1 minus this. float32."""
    f = np.clip((np.asarray(u) - PLATEAU) / (stride - 2 * PLATEAU), 0, 1)
    return np.float32(smoothstep(np.clip((f - 0.5) / BLEND + 0.5, 0, 1)))


@dataclass(frozen=True)
class Cell:
    """Scatter cell (a, b)'s draws: whether it holds an object, where (its
    lowest corner, in voxels from the cell's), and whether it is mirrored
    along each horizontal axis."""

    present: bool
    offset: tuple  # (2,) along the two horizontal axes
    mirror: tuple  # (2,) bool


@functools.lru_cache(maxsize=1024)  # a pure function, asked again for each tile and point group near the cell
def scatter_cell(seed: int, a: int, b: int, room: tuple) -> Cell:
    """The draws of cell (a, b): `room` is how far (voxels) an object may move
    along each horizontal axis inside its cell."""
    mask = (1 << 64) - 1
    key = noise.stream_key(seed, SCATTER_STREAM, a & mask, b & mask)
    draw = [noise.mix64((key + noise.GOLDEN * (n + 1)) & mask) for n in range(4)]
    return Cell((draw[0] >> 11) < PRESENCE * 2**53, (draw[1] % (room[0] + 1), draw[2] % (room[1] + 1)),
                (bool(draw[3] & 1), bool(draw[3] & 2)))


def object_model(model, options: WorldOptions, index: int) -> tuple:
    """A scattered world's model `index` (0 the first, `model`) and its own cut
    (its axes: an object's first horizontal axis lies along the world's)."""
    if not index:
        return model, world_layout(model)
    other = options.models[index - 1]
    try:
        return other, world_layout(other)
    except InputError as error:
        raise InputError(f"model {index} of the world: {error.template}", error.parameter) from None


def scatter_geometry(model, layout: Layout, options: WorldOptions = PLAIN) -> tuple:
    """A scatter world's cell side P per horizontal axis (PITCH strides, or
    room for its largest model's objects and half a stride), and each
    model's object extent E - 1 (voxels) along the world's two horizontal axes."""
    extents = []
    for index in range(len(options.models) + 1):
        each, own = object_model(model, options, index)
        finest = each.manifest.sizes[-1]
        extents.append((finest[own.horizontal[0]] - 1, finest[own.horizontal[1]] - 1))
    pitch = tuple(max(PITCH * layout.stride[h], max(extent[n] for extent in extents) + layout.stride[h] // 2)
                  for n, h in enumerate(layout.horizontal))
    return pitch, extents


@dataclass(frozen=True)
class Placed:
    """An object of a scatter world where a tile sees it: its cell, its
    lowest corner relative to the tile's (integer voxels), mirrors, and the
    height it stands at. Its planes are made (`object_window`) only when a
    point asks for them."""

    cell: tuple  # (a, b)
    corner: tuple  # (2,) ints, relative to the tile's lowest corner
    extent: tuple  # (2,) E - 1 per horizontal axis
    mirror: tuple
    height: float
    model: int = 0  # which of the world's models it is a sample of


def object_window(model, options: WorldOptions, seed: int, placed_object: Placed, level: int) -> tuple:
    """An object's model, that model's cut, and the object's planes at the
    first model's `level` (in the object's model, as many levels from its
    finest, or its coarsest)."""
    each, own = object_model(model, options, placed_object.model)
    level = max(len(each.manifest.sizes) - len(model.manifest.sizes) + level, 0)
    return each, own, window(each, own, seed, *placed_object.cell, level, "scatter")


def objects_near(model, layout: Layout, seed: int, tile: tuple, level: int, options: WorldOptions) -> list:
    """The objects of a scatter world that reach into tile (i, j), in a fixed
    order: each from the model its cell's centre's pixel of the model map names."""
    i, j = tile
    heights = options.heights
    h0, h1 = layout.horizontal
    (p0, p1), extents = scatter_geometry(model, layout, options)
    s0, s1 = layout.stride[h0], layout.stride[h1]
    found = []
    for a in range((i * s0) // p0 - 1, ((i + 1) * s0) // p0 + 1):
        for b in range((j * s1) // p1 - 1, ((j + 1) * s1) // p1 + 1):
            index = 0 if options.models_map is None else \
                options.models_map.at((2 * a * p0 + p0) // (2 * s0), (2 * b * p1 + p1) // (2 * s1))  # exact, anywhere
            e0, e1 = extents[index]
            cell = scatter_cell(seed, a, b, (p0 - e0, p1 - e1))
            low = (a * p0 + cell.offset[0], b * p1 + cell.offset[1])  # world voxels, exact integers
            if not cell.present or low[0] > (i + 1) * s0 or low[0] + e0 < i * s0 or low[1] > (j + 1) * s1 \
                    or low[1] + e1 < j * s1:
                continue
            height = 0.0 if heights is None else object_height(heights, layout, low, (e0, e1))
            found.append(Placed((a, b), (low[0] - i * s0, low[1] - j * s1), (e0, e1), cell.mirror, height, index))
    return found


# ---- the height map, read anywhere

def spline_weights(t: np.ndarray) -> list:
    """The uniform cubic B-spline's four weights at fractions t (float64)."""
    s = 1 - t
    return [s * s * s / 6, (3 * t * t * t - 6 * t * t + 4) / 6, (-3 * t * t * t + 3 * t * t + 3 * t + 1) / 6,
            t * t * t / 6]


def map_coordinates(count: int, tile: int, u: np.ndarray, stride: int) -> np.ndarray:
    """Where points u voxels past tile `tile`'s corner fall among a map's
    `count` pixels along one axis (pixel r at the centre of tile r), clamped
    where all four of a spline's pixels are the edge's: the same float from
    any tile that computes it (a face's points are integers from both)."""
    near = min(max(tile, -4), count + 4)  # farther tiles are all past the clamp
    return np.clip((near - 0.5) + np.asarray(u, np.float64) / stride, -2.0, count + 1.0)


def spline(values: np.ndarray, q0: np.ndarray, q1: np.ndarray, outer: bool) -> np.ndarray:
    """The map's cubic B-spline at map coordinates: every (q0, q1) pair
    ((len(q0), len(q1))) when `outer`, else each q0[k] with q1[k] ((n,)).
    float64, the terms summed in a fixed order."""
    base = [np.floor(q).astype(np.int64) for q in (q0, q1)]
    weights = [spline_weights(q - b) for q, b in zip((q0, q1), base)]
    rows, cols = values.shape
    out = 0
    for m in range(4):
        r = np.clip(base[0] + m - 1, 0, rows - 1)
        if outer:
            row = sum(weights[1][n][None, :] * values[r][:, np.clip(base[1] + n - 1, 0, cols - 1)] for n in range(4))
            out = out + weights[0][m][:, None] * row
        else:
            row = sum(weights[1][n] * values[r, np.clip(base[1] + n - 1, 0, cols - 1)] for n in range(4))
            out = out + weights[0][m] * row
    return out


def map_heights(heights: HeightMap, layout: Layout, u0, u1, tile: tuple, outer: bool = True) -> np.ndarray:
    """The map's height (voxels, float64) at points of tile (i, j), u0 and u1
    voxels from its corner along the two horizontal axes: at every pair
    ((len(u0), len(u1))) or, not `outer`, at each point ((n,))."""
    values = heights.array().astype(np.float64)
    h0, h1 = layout.horizontal
    return spline(values, map_coordinates(values.shape[0], tile[0], u0, layout.stride[h0]),
                  map_coordinates(values.shape[1], tile[1], u1, layout.stride[h1]), outer)


def object_height(heights: HeightMap, layout: Layout, low: tuple, extent: tuple) -> float:
    """The map's height under the centre of an object whose lowest corner is
    at world voxels `low` (exact integers, however far): the same for every
    tile that sees it."""
    values = heights.array().astype(np.float64)
    q = [np.array([min(max((2 * c + e) / (2 * layout.stride[h]) - 0.5, -2.0), n + 1.0)])
         for c, e, h, n in zip(low, extent, layout.horizontal, values.shape)]
    return float(spline(values, q[0], q[1], False)[0])


# ---- a tile's grid

@dataclass(frozen=True)
class Grid:
    """A tile's points: along each horizontal axis m + 1 over its stride
    (voxels from the tile's corner, the faces it shares included), along up
    the world's heights (voxels from the model's floor), the same for
    every tile of the world."""

    positions: tuple  # per model axis, (n,) float64

    @property
    def shape(self) -> tuple:
        return tuple(len(p) for p in self.positions)


def tile_grid(model, layout: Layout, scale: float, options: WorldOptions) -> Grid:
    """The grid of a tile at `scale` and `options.lod`: the finest level's
    grid at lod 0 (m = S scale points per stride), a level's own otherwise."""
    sizes = model.manifest.sizes
    level = check_lod(model, options.lod)
    positions = []
    for axis in range(3):
        ratio = (sizes[level][axis] - 1) / (sizes[-1][axis] - 1)
        stride = layout.stride[axis]
        if axis == layout.up:
            m = max(2, round((stride + 1) * scale * ratio))  # as a sample's grid: m points over the height
            step = stride / (m - 1)
            low, high = options.heights.bounds() if options.heights is not None else (0, 0)
            cuts = [object_model(model, options, k)[1] for k in range(1, len(options.models) + 1)]
            high += max([0] + [cut.stride[cut.up] - stride for cut in cuts])  # a taller model's objects
            count = m + math.ceil((high - low) / step)
            positions.append(low + np.arange(count) * step)
        else:
            m = max(1, round(stride * scale * ratio))
            positions.append(np.arange(m + 1) * stride / m)  # exact at the faces: m S / m = S
    return Grid(tuple(positions))


MAX_POINTS = 1 << 14  # a tile's grid points per axis, at most


def check_world_scale(layout: Layout, scale: float, hidden: int, memory_limit: int | None,
                      points: tuple | None = None) -> None:
    """A tile's grid (`points` per axis; at lod 0 with no map unless given)
    refused where it is too large or needs more memory than there is."""
    check_scale(scale)
    if points is None:
        points = [round(layout.stride[a] * scale) + 1 if a != layout.up
                  else max(2, round((layout.stride[a] + 1) * scale)) for a in range(3)]
    if max(points) > MAX_POINTS:
        raise InputError(f"`scale` {scale:g} makes a tile of {'x'.join(map(str, points))} points; at most "
                         f"{MAX_POINTS} per axis", "scale")
    h0, h1 = layout.horizontal
    # The grid, a row's sums and gathered planes, and the interpolated horizontal planes.
    row = points[h1] * points[layout.up] * hidden * 4 * 6
    planes = 4 * hidden * 4 * sum(points[a] * points[b] for a, b in PLANE_AXES)
    check_memory(math.prod(points) * 4 * 3 + row + planes, f"a {'x'.join(map(str, points))} tile", memory_limit)


# ---- the field on a tile's grid

def interpolate(plane: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """A (H, W, D) plane at every (row, col) of two position lists, element-wise
    (bilinear, align_corners): (len(rows), len(cols), D) float32. Two tiles
    asking for the same position get the same bits."""
    return along(along(plane, rows, 0), cols, 1)


def along(values: np.ndarray, positions: np.ndarray, axis: int) -> np.ndarray:
    """Linear interpolation of `values` along `axis` at `positions` (cells), element-wise."""
    n = values.shape[axis]
    low = np.clip(np.floor(positions).astype(np.int64), 0, max(n - 2, 0))
    high = np.minimum(low + 1, n - 1)
    frac = (positions - low).astype(np.float32)
    shape = [1] * values.ndim
    shape[axis] = len(positions)
    frac = frac.reshape(shape)
    return np.take(values, low, axis) * (np.float32(1) - frac) + np.take(values, high, axis) * frac


def along_up(values: np.ndarray, runs_along: int, up_cells: np.ndarray) -> np.ndarray:
    """A vertical plane already interpolated along its horizontal axis,
    (N, U, D), read at per-point heights: up_cells (X, Y, K) (or broadcasting
    to it) in the plane's cells, N running along the grid's axis `runs_along`
    (0 or 1). -> (X or 1, Y or 1, K, D), element-wise."""
    count = values.shape[1]
    low = np.clip(np.floor(up_cells).astype(np.int64), 0, max(count - 2, 0))
    high = np.minimum(low + 1, count - 1)
    frac = (up_cells - low).astype(np.float32)[..., None]
    index = np.arange(len(values)).reshape((-1, 1, 1) if runs_along == 0 else (1, -1, 1))
    return values[index, low] * (np.float32(1) - frac) + values[index, high] * frac


def hidden_on_grid(window: Window, layout: Layout, c0: np.ndarray, c1: np.ndarray, up_cells: np.ndarray):
    """A window's hidden sum (b1 not added) on a grid in tile order (h0, h1,
    up): c0, c1 its cells along the horizontal axes, up_cells (X, Y, K) or
    (1, 1, K) along up. Returns (hidden (X, Y, K, D), mean at those heights)."""
    h0, h1 = layout.horizontal
    cells = {h0: c0, h1: c1}
    flat, vertical = None, []
    for plane, (r, c) in zip(window.planes, PLANE_AXES):
        if layout.up not in (r, c):  # the horizontal plane
            flat = interpolate(plane, cells[r], cells[c])
            flat = flat if r == h0 else flat.transpose(1, 0, 2)
        else:
            h = c if r == layout.up else r
            read = along(plane, cells[h], 1 if r == layout.up else 0)
            read = read.transpose(1, 0, 2) if r == layout.up else read  # (N, U, D)
            vertical.append(along_up(read, 0 if h == h0 else 1, up_cells))
    hidden = flat[:, :, None] + vertical[0] + vertical[1]
    mean = along_up(window.mean[None], 0, up_cells)
    return hidden, mean


def head_logits(weights, hidden: np.ndarray) -> np.ndarray:
    """w2 . relu(hidden + b1) + b2 element-wise over the hidden width, in a
    fixed order: (..., D) -> (...) float32."""
    biased = np.maximum(hidden + weights.bias1, 0)
    logits = np.full(hidden.shape[:-1], np.float32(weights.bias2), np.float32)
    for d in range(hidden.shape[-1]):
        logits += biased[..., d] * weights.weight2[d]
    return logits


def capped(logits: np.ndarray, above) -> np.ndarray:
    """Logits read above a window's top (`above`: voxels past it, where the
    window's own top layer is read again) cut by a ceiling half a voxel up,
    as a sample's padding closes it: a raised window does not stretch its
    top layer upwards. Below the top, unchanged."""
    ceiling = (-np.float32(GROUND_SLOPE) * (np.asarray(above, np.float32) - np.float32(0.5))).astype(np.float32)
    return np.where(np.asarray(above) > 0, np.minimum(logits, ceiling), logits)


def head(weights, hidden: np.ndarray) -> np.ndarray:
    """The occupancy sigmoid(head_logits): (..., D) -> (...) float32."""
    return sigmoid(head_logits(weights, hidden))


def window_weight(u, stride: int, behind: bool):
    """A window's weight along one horizontal axis at points u voxels past
    the tile's corner: behind_weight, or exactly 1 minus it for the window
    before. float32."""
    weight = behind_weight(u, stride)
    return weight if behind else np.float32(1) - weight


class ContrastSum:
    """The blend of windows' hidden vectors that keeps their contrast: the
    weighted means plus the weighted deviations over (sum of squared
    weights) ** (contrast / 2), summed element-wise in the order added."""

    def __init__(self, contrast: float):
        self.contrast = contrast
        self.mean = self.deviation = self.squares = None

    def add(self, weight, hidden, mean) -> None:
        terms = (weight * mean, weight * (hidden - mean), weight * weight)
        if self.mean is None:
            self.mean, self.deviation, self.squares = terms
        else:
            self.mean, self.deviation, self.squares = (self.mean + terms[0], self.deviation + terms[1],
                                                       self.squares + terms[2])

    def total(self):
        return self.mean + self.deviation * np.power(self.squares, np.float32(-self.contrast / 2))


def blend_sources(model, layout: Layout, seed: int, tile: tuple, level: int, progress=None) -> list:
    """Tile (i, j)'s four windows in the fixed order of the sum, each with
    its offset (voxels from its lattice point to the tile's) along the two
    horizontal axes and whether it is the one behind along each.
    progress(0, 1) after each window made or found."""
    i, j = tile
    h0, h1 = layout.horizontal
    sources = []
    for a in (i - 1, i):
        for b in (j - 1, j):
            sources.append((window(model, layout, seed, a, b, level),
                            (layout.stride[h0] if a < i else 0, layout.stride[h1] if b < j else 0), (a == i, b == j)))
            if progress:
                progress(0, 1)
    return sources


def tile_logits(model, seed: int, tile, scale: float = 1.0, options: WorldOptions = PLAIN,
                memory_limit: int | None = None, colour: bool = False, progress=None):
    """The head's logits on tile (i, j)'s grid (tile_grid), in tile order (h0,
    h1, up): (X, Y, K) float32; with `colour`, also the colour there ((X, Y,
    K, 3) float32 sRGB, from the blended hidden vector or the object's).
    progress(done, total) after each window and each slab of rows."""
    i, j = check_tile(tile)
    layout = world_layout(model)
    level = check_lod(model, options.lod)
    grid = tile_grid(model, layout, scale, options)
    h0, h1, up = *layout.horizontal, layout.up
    check_world_scale(layout, scale, hidden_width(model, options), memory_limit, grid.shape)
    u0, u1, z = grid.positions[h0], grid.positions[h1], grid.positions[up]
    heights = None if options.heights is None else map_heights(options.heights, layout, u0, u1, (i, j))
    out = np.empty((len(u0), len(u1), len(z)), np.float32)
    colours = np.zeros((*out.shape, 3), np.float32) if colour else None
    if options.arrange == "scatter":
        ground = z[None, None, :] - GROUND if heights is None else z[None, None, :] - heights[:, :, None] - GROUND
        out[...] = -np.float32(GROUND_SLOPE) * ground.astype(np.float32)
        near = objects_near(model, layout, seed, (i, j), level, options)
        for done, placed_object in enumerate(near, 1):
            if progress:
                progress(done, len(near))
            scatter_into(out, colours, model, options, seed, level, placed_object, u0, u1, z)
        return (out, colours) if colour else out
    sources = blend_sources(model, layout, seed, (i, j), level, progress)
    rows = max(1, (1 << 21) // (len(u1) * len(z) * model.manifest.hidden))  # ~8 MB a sum
    for x0 in range(0, len(u0), rows):
        x = slice(x0, min(x0 + rows, len(u0)))
        rise = 0 if heights is None else heights[x, :, None]
        levels = np.clip(z[None, None, :] - rise, 0, layout.stride[up])  # (X, Y, K) or (1, 1, K)
        blend = ContrastSum(model.manifest.contrast)
        for found, offset, behind in sources:
            w0 = window_weight(u0[x], layout.stride[h0], behind[0])
            w1 = window_weight(u1, layout.stride[h1], behind[1])
            hidden, mean = hidden_on_grid(found, layout, (u0[x] + offset[0]) * found.cells[h0],
                                          (u1 + offset[1]) * found.cells[h1], levels * found.cells[up])
            blend.add((w0[:, None] * w1[None, :])[:, :, None, None], hidden, mean)
        total = blend.total()
        out[x] = capped(head_logits(model.head, total), z[None, None, :] - rise - layout.stride[up])
        if colour:
            colours[x] = head_colour(model.head, total)
        if progress:
            progress(x.stop, len(u0))
    return (out, colours) if colour else out


def scatter_into(out: np.ndarray, colours, model, options: WorldOptions, seed: int, level: int,
                 placed_object: Placed, u0, u1, z) -> None:
    """One object's logits where they are the largest yet, on the part of a tile's grid inside its box
    (its colour there: its own model's, grey for a model without colour)."""
    local = []
    for u, low, extent, mirror in zip((u0, u1), placed_object.corner, placed_object.extent, placed_object.mirror):
        inside = np.flatnonzero((u - low >= 0) & (u - low <= extent))
        position = u[inside] - low
        local.append((inside, extent - position if mirror else position))
    (x, c0), (y, c1) = local
    if not len(x) or not len(y):
        return
    each, own, found = object_window(model, options, seed, placed_object, level)
    h0, h1, up = *own.horizontal, own.up  # the object's axes, along the world's
    levels = np.clip(z - placed_object.height, 0, own.stride[up])[None, None, :]
    hidden, _ = hidden_on_grid(found, own, c0 * found.cells[h0], c1 * found.cells[h1], levels * found.cells[up])
    logits = capped(head_logits(each.head, hidden), (z - placed_object.height - own.stride[up])[None, None, :])
    part = np.ix_(x, y)
    better = logits > out[part]
    out[part] = np.where(better, logits, out[part])
    if colours is not None:
        rgb = head_colour(each.head, hidden) if each.manifest.colour else np.float32(GROUND_COLOUR)
        colours[part] = np.where(better[..., None], rgb, colours[part])


def tile_occupancy(model, seed: int, tile, scale: float = 1.0, memory_limit: int | None = None,
                   colour: bool = False, options: WorldOptions = PLAIN, progress=None):
    """Occupancy on tile (i, j)'s grid: (X, Y, Z) float32, its points along
    each horizontal axis from the tile's lattice point to the next (both
    included: the faces it shares), along up the world's heights. With
    `colour` (a coloured model), also its colour there, tile_colours' at a
    format-5 model's full-detail tile: (occupancy, (X, Y, Z, 3) uint8
    sRGB). progress(done, total) after each window and
    each slab of rows (a server stops a job there)."""
    check_seed(seed)
    layout = world_layout(model)
    made = tile_logits(model, seed, tile, scale, options, memory_limit, colour, progress)
    logits, colours = made if colour else (made, None)
    order = np.argsort([*layout.horizontal, layout.up])  # tile order -> the model's axes
    occupancy = np.ascontiguousarray(sigmoid(logits).transpose(order))
    if not colour:
        return occupancy
    if model.colour_tiles is not None and not options.lod or options.models:  # as the tile's vertices are coloured
        grid = tile_grid(model, layout, scale, options)
        points = np.stack(np.meshgrid(*grid.positions, indexing="ij"), axis=-1).reshape(-1, 3)
        return occupancy, tile_colours(model, seed, tile, points, options, 1 / scale)[:, :3].reshape(*occupancy.shape, 3)
    return occupancy, np.round(np.ascontiguousarray(colours.transpose(*order, 3)) * 255).astype(np.uint8)


# ---- the field at any points of a tile (normals, colours)

def point_field(model, seed: int, tile, points: np.ndarray, options: WorldOptions = PLAIN,
                sources: list | None = None) -> tuple:
    """The logits and hidden vectors at points of tile (i, j) ((n, 3), voxels
    from the tile's corner along the horizontal axes, from the model's floor
    along up), each read in the tile it falls in (a point just past a face,
    in the neighbour's): (logits (n,) float32, hidden (n, D) float32, on the
    ground (n,) bool: a scatter world's points outside every object). With a
    list `sources`, also what each point reads most: the list gets, per
    window or object, (its key for `window`, point indices, their cells in
    it, back: the (3, 3) map of a move in its cells to one of the points, a
    row per cell axis)."""
    i, j = check_tile(tile)
    layout = world_layout(model)
    level = check_lod(model, options.lod)
    h0, h1 = layout.horizontal
    points = np.asarray(points, np.float64).reshape(-1, 3)
    t0, t1 = (np.floor(points[:, axis] / layout.stride[axis]).astype(np.int64) for axis in (h0, h1))
    low0, low1 = (int(t0.min()), int(t1.min())) if len(points) else (0, 0)
    span = int(t1.max()) - low1 + 1 if len(points) else 1
    keys = (t0 - low0) * span + (t1 - low1)  # the tile each point falls in, as one number
    codes, which = np.unique(keys, return_inverse=True)
    groups = np.stack([codes // span + low0, codes % span + low1], axis=1)
    if len(groups) == 1:
        order, starts = np.arange(len(points)), np.array([0, len(points)])
    else:
        order = np.argsort(which, kind="stable")
        starts = np.searchsorted(which[order], np.arange(len(groups) + 1))
    logits = np.empty(len(points), np.float32)
    hidden = np.empty((len(points), hidden_width(model, options)), np.float32)
    ground = np.empty(len(points), bool)
    for group, (t0, t1) in enumerate(groups.tolist()):
        chosen = order[starts[group]:starts[group + 1]]
        local = points[chosen]
        local[:, h0] -= t0 * layout.stride[h0]  # exact: a power-of-two step from an integer
        local[:, h1] -= t1 * layout.stride[h1]
        found = [] if sources is not None else None
        logits[chosen], hidden[chosen], ground[chosen] = point_tile(model, layout, seed, (i + t0, j + t1), local,
                                                                     level, options, found)
        if sources is not None:
            sources.extend((key, chosen[index], cells, back) for key, index, cells, back in found)
    return logits, hidden, ground


def point_tile(model, layout: Layout, seed: int, tile: tuple, points: np.ndarray, level: int,
               options: WorldOptions, sources: list | None = None) -> tuple:
    """point_field for points inside one tile (`sources`: as point_field's,
    with indices into `points`: the window that weighs most, the first of
    equals, or the object a point lies in)."""
    h0, h1, up = *layout.horizontal, layout.up
    u0, u1, z = points[:, h0], points[:, h1], points[:, up]
    rise = (np.zeros(len(points)) if options.heights is None
            else map_heights(options.heights, layout, u0, u1, tile, outer=False))
    if options.arrange == "scatter":
        logits = (-np.float32(GROUND_SLOPE) * (z - rise - GROUND)).astype(np.float32)
        hidden = np.zeros((len(points), hidden_width(model, options)), np.float32)
        ground = np.ones(len(points), bool)
        owner, owner_cells, objects = np.full(len(points), -1), np.zeros((len(points), 3)), []
        for placed_object in objects_near(model, layout, seed, tile, level, options):
            each, own = object_model(model, options, placed_object.model)
            inside = np.ones(len(points), bool)
            cells = np.empty((len(points), 3))
            back = np.zeros((3, 3))
            for axis, world_axis, u, low, extent, mirror in zip(own.horizontal, (h0, h1), (u0, u1),
                                                                placed_object.corner, placed_object.extent,
                                                                placed_object.mirror):
                position = u - low
                inside &= (position >= 0) & (position <= extent)
                cells[:, axis] = extent - position if mirror else position
                back[axis, world_axis] = -1.0 if mirror else 1.0
            if not inside.any():
                continue
            found = object_window(model, options, seed, placed_object, level)[2]
            cells[:, own.up] = np.clip(z - placed_object.height, 0, own.stride[own.up])
            back[own.up, up] = 1.0
            cells *= np.asarray(found.cells)
            back /= np.asarray(found.cells, np.float64)[:, None]
            hid = point_hidden(found, cells[inside])
            better = np.zeros(len(points), bool)
            candidate = capped(head_logits(each.head, hid), (z - placed_object.height - own.stride[own.up])[inside])
            better[inside] = candidate > logits[inside]
            logits[better] = candidate[better[inside]]
            hidden[better] = 0  # a narrower model's vector leaves the rest zero
            hidden[better, :hid.shape[1]] = hid[better[inside]]
            ground[better] = False
            if sources is not None:
                owner[better] = len(objects)
                owner_cells[better] = cells[better]
                objects.append(((*placed_object.cell, "scatter", placed_object.model), back))
        if sources is not None:
            sources.extend((key, np.flatnonzero(owner == k), owner_cells[owner == k], back)
                           for k, (key, back) in enumerate(objects))
        return logits, hidden, ground
    levels = np.clip(z - rise, 0, layout.stride[up])
    blend = ContrastSum(model.manifest.contrast)
    i, j = tile
    heaviest, owner, owner_cells, keys = np.full(len(points), -1.0), np.zeros(len(points), np.int64), None, []
    for a in (i - 1, i):
        for b in (j - 1, j):
            weight = window_weight(u0, layout.stride[h0], a == i) * window_weight(u1, layout.stride[h1], b == j)
            if not weight.any():  # adds exact zeros: its planes are not needed (a point just past a face)
                continue
            found = window(model, layout, seed, a, b, level)
            cells = np.empty((len(points), 3))
            cells[:, h0] = (u0 + (layout.stride[h0] if a < i else 0)) * found.cells[h0]
            cells[:, h1] = (u1 + (layout.stride[h1] if b < j else 0)) * found.cells[h1]
            cells[:, up] = levels * found.cells[up]
            blend.add(weight[:, None], point_hidden(found, cells), along(found.mean, cells[:, up], 0))
            if sources is not None:
                heavier = weight > heaviest
                heaviest[heavier], owner[heavier] = weight[heavier], len(keys)
                owner_cells = cells.copy() if owner_cells is None else np.where(heavier[:, None], cells, owner_cells)
                keys.append((a, b, "blend", 0))
    if sources is not None:  # a window's cells run along the world's axes
        sources.extend((key, np.flatnonzero(owner == k), owner_cells[owner == k],
                        np.diag(1 / np.asarray(found.cells, np.float64))) for k, key in enumerate(keys))
    total = blend.total()
    return capped(head_logits(model.head, total), z - rise - layout.stride[up]), total, np.zeros(len(points), bool)


def point_hidden(window: Window, cells: np.ndarray) -> np.ndarray:
    """A window's hidden sum at points given in its level's cells: (n, D) float32."""
    return sum(bilinear(plane, cells[:, a], cells[:, b]) for plane, (a, b) in zip(window.planes, PLANE_AXES))


def tile_normals(model, seed: int, tile, vertices: np.ndarray, options: WorldOptions = PLAIN) -> np.ndarray:
    """Unit normals at a tile's vertices (model units from its corner, as
    tile_mesh gives them): the field's gradient, by differences over
    NORMAL_STEP voxels along each axis from the vertex, pointing out of the
    solid. A vertex on a face two tiles share gets the same normal from both
    (the same points, each read in the tile it falls in: just past a face,
    only the face's own windows count, so none of the neighbour's is made).
    (V, 3) float32."""
    step = NORMAL_STEP
    vertices = np.asarray(vertices, np.float64)
    offsets = np.concatenate([np.zeros((1, 3)), np.eye(3) * step])  # (4, 3): the vertex, then a step along each axis
    probes = (vertices[:, None, :] + offsets[None]).reshape(-1, 3)
    logits = point_field(model, seed, tile, probes, options)[0].astype(np.float64).reshape(-1, 4)
    gradient = logits[:, 1:] - logits[:, :1]
    length = np.linalg.norm(gradient, axis=1, keepdims=True)
    up = np.zeros(3)
    up[world_layout(model).up] = 1
    normals = np.where(length > 0, -gradient / np.where(length > 0, length, 1), up)
    return normals.astype(np.float32)


GROUND_COLOUR = (0.5, 0.5, 0.5)  # sRGB of a scatter world's ground, which no model colours


def tile_colours(model, seed: int, tile, vertices: np.ndarray, options: WorldOptions = PLAIN,
                 footprint: float | None = None) -> np.ndarray:
    """A coloured model's colour at tile (i, j)'s vertices (model units from
    the tile's corner, as tile_mesh gives them): a format-5 model's, read
    from the example by correspondence in the window that weighs most there
    (a scatter world's: in the object there), each the colour around it
    (`footprint` voxels); a format-4 model's (and a coarser tile's, `lod`,
    or any without `detail`), the colour head of the hidden vector there, blended as the occupancy
    is; a format-5 model's coarser tile then takes the example's nearest
    colour (colour.example_palette: its tiles' means), so that no hue the
    example lacks shows in the distance either (and without `detail`). A scatter world's ground is
    grey. A vertex on a face two tiles share gets the same colour from
    both. Returns (n, 4) uint8 RGBA."""
    by_correspondence = options.detail and not options.lod
    if not options.models and (model.colour_tiles is None or not by_correspondence):
        _, hidden, ground = point_field(model, seed, tile, vertices, options)
        rgb = head_colour(model.head, hidden)
    else:  # each vertex its heaviest window's (or its object's) colour, read from the example or its model's head
        sources = []
        _, hidden, ground = point_field(model, seed, tile, vertices, options, sources)
        rgb = np.empty((len(vertices), 3), np.float32)
        palettes = []
        for (a, b, arrange, k), index, cells, _ in sources:
            each, own = object_model(model, options, k)
            if not len(index):
                continue
            if each.colour_tiles is not None and by_correspondence:
                rgb[index] = window_colouring(each, own, seed, a, b, arrange)(cells, footprint)
            elif each.manifest.colour:
                rgb[index] = head_colour(each.head, hidden[index, :each.manifest.hidden])
                if each.colour_tiles is not None:
                    palettes.append((index, each.colour_tiles))
            else:
                rgb[index] = GROUND_COLOUR
    rgb[ground] = GROUND_COLOUR
    out = colour_bytes(rgb)
    if options.models:
        for index, tiles in palettes:
            out[index, :3] = nearest_in_palette(out[index, :3], example_palette(tiles))
    elif model.colour_tiles is not None and not by_correspondence:
        out[~ground, :3] = nearest_in_palette(out[~ground, :3], example_palette(model.colour_tiles))
    return out


def tile_relief(model, seed: int, tile, points: np.ndarray, options: WorldOptions = PLAIN) -> np.ndarray:
    """Points of tile (i, j)'s surface (model units from its corner, as
    tile_mesh gives them) moved by the example's relief under them (as a
    sample's vertices are: colour.SampleSurface.relief), read in the window
    that weighs most at each (a scatter world's: in its object), as its
    colour is; points of a model without relief tiles (or a scatter world's
    ground) stay. A point on a face two tiles share moves alike in both.
    (n, 3) float64."""
    sources = []
    point_field(model, seed, tile, points, options, sources)
    moved = np.array(points, np.float64).reshape(-1, 3)
    for (a, b, arrange, k), index, cells, back in sources:
        each, own = object_model(model, options, k)
        if each.tiles is None or not len(index):
            continue
        surface = window_colouring(each, own, seed, a, b, arrange)
        moved[index] += (surface.relief(cells) - cells) @ back
    return moved


def relieved(model, options: WorldOptions, scale: float) -> bool:
    """Whether a tile's mesh takes its example's relief: at full detail, on
    a mesh fine enough to carry it (colour.RELIEF_SCALE), a model with relief
    tiles among the world's."""
    return (options.detail and not options.lod and scale >= RELIEF_SCALE
            and any(each.tiles is not None for each in (model, *options.models)))


def relief_normals(model, seed: int, tile, points: np.ndarray, normals: np.ndarray, step: float,
                   options: WorldOptions = PLAIN) -> np.ndarray:
    """The unit normals (n, 3) of the relief surface (tile_relief) at a tile's
    points (before they moved), whatever mesh they belong to: the cross
    product of the moved points' differences `step` voxels either side
    along two directions across the field's `normals` there (so that two
    tiles give a vertex they share the same normal)."""
    across = np.cross(normals, np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    other = np.cross(normals, across)
    probes = np.concatenate([points + sign * step * d for d in (across, other) for sign in (1, -1)])
    moved = tile_relief(model, seed, tile, probes, options).reshape(4, len(points), 3)
    out = np.cross(moved[0] - moved[1], moved[2] - moved[3])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    out = np.where(length > 0, out / np.where(length > 0, length, 1), normals)
    return out * np.where(np.einsum("nc,nc->n", out, normals) < 0, -1.0, 1.0)[:, None]


def coloured(model, options: WorldOptions = PLAIN) -> bool:
    """Whether a world's tiles carry colour: any of its models has it."""
    return any(each.manifest.colour for each in (model, *options.models))


def hidden_width(model, options: WorldOptions) -> int:
    """The hidden vectors' width a world's points hold: its widest model's."""
    return max(each.manifest.hidden for each in (model, *options.models))


# Windows' colourings kept for the next tiles, as their planes are (`window`).
_colourings = OrderedDict()  # (id(model), seed, arrange, a, b) -> (model, colouring)


def window_colouring(model, layout: Layout, seed: int, a: int, b: int, arrange: str):
    """A format-5 window's (or object's) colour at points in its finest
    cells: its own sample's colour by correspondence (colour.planes_colouring),
    matched once and kept. A window's matches follow its content only, so a
    tile and its neighbour read a window they share alike."""
    key = (id(model), seed, arrange, a, b)
    with _windows_lock:
        if key in _colourings:
            _colourings.move_to_end(key)
            return _colourings[key][1]
    found = window(model, layout, seed, a, b, len(model.manifest.sizes) - 1, arrange)
    made = planes_colouring(model, found.planes, window_sizes(model, layout, arrange)[-1])
    with _windows_lock:
        _colourings[key] = (model, made)
        while len(_colourings) > WINDOWS_KEPT:
            _colourings.popitem(last=False)
    return made


def tile_points(model, seed: int, tile, points: np.ndarray, options: WorldOptions = PLAIN) -> np.ndarray:
    """The world's occupancy at any points of tile (i, j) (model units from
    its corner along the horizontal axes, from the floor along up): (n,)
    float32, what its grid holds where a point is one of the grid's."""
    return sigmoid(point_field(model, seed, tile, points, options)[0])


# ---- a tile's surface

def tile_mesh(model, seed: int, tile, scale: float = 1.0, memory_limit: int | None = None,
              closed: tuple = (), options: WorldOptions = PLAIN, progress=None) -> tuple:
    """Tile (i, j)'s surface: (vertices (V, 3) float64 in model units
    relative to the tile's lowest corner along the horizontal axes and to
    the model's floor along up, faces (F, 3) int64). Closed at the top and
    bottom, open on the four sides it shares with its neighbours, whose
    border vertices it shares exactly, except the sides in `closed` ((axis,
    0 or 1) pairs: the low or high side along a horizontal axis), closed as
    a sample's sides are (where a block of tiles ends). progress: as tile_occupancy's."""
    values = tile_occupancy(model, seed, tile, scale, memory_limit, options=options, progress=progress)
    layout = world_layout(model)
    grid = tile_grid(model, layout, scale, options)
    pad = [[0, 0], [0, 0], [0, 0]]
    pad[layout.up] = [1, 1]
    for axis, side in closed:
        pad[axis][side] = 1
    padded = np.pad(values, pad)
    corners = np.stack([padded[dx:padded.shape[0] - 1 + dx, dy:padded.shape[1] - 1 + dy, dz:padded.shape[2] - 1 + dz]
                        < cubes.LEVEL for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)])
    crossing = np.argwhere(corners.any(axis=0) & ~corners.all(axis=0))
    _, vertices, faces = cubes.march(padded, crossing, 1)
    for axis in range(3):
        vertices[:, axis] -= pad[axis][0]
        intervals = values.shape[axis] - 1
        if axis == layout.up:
            low, step = grid.positions[axis][0], grid.positions[axis][1] - grid.positions[axis][0]
            vertices[:, axis] = low + vertices[:, axis] * step
        else:
            vertices[:, axis] = vertices[:, axis] * layout.stride[axis] / intervals  # exact at the faces: m S / m = S
    return vertices, faces


@dataclass(frozen=True)
class Surface:
    """A tile as its file holds it: vertices and faces (tile_mesh's, then a
    coarser tile's skirt), unit normals, and a coloured model's colours."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray  # (V, 3) float32
    colours: np.ndarray | None  # (V, 4) uint8


def tile_surface(model, seed: int, tile, scale: float = 1.0, options: WorldOptions = PLAIN,
                 memory_limit: int | None = None, progress=None) -> Surface:
    """Tile (i, j)'s mesh with its normals (and colours), and at lod > 0 a
    skirt: every edge on the tile's sides extruded SKIRT grid steps down, so
    that a finer neighbour's border, which its own does not meet, shows no
    gap. Skirt vertices take the normal and colour of the vertex above.
    progress: as tile_occupancy's."""
    vertices, faces = tile_mesh(model, seed, tile, scale, memory_limit, options=options, progress=progress)
    normals = tile_normals(model, seed, tile, vertices, options)
    if relieved(model, options, scale) and len(vertices):
        layout = world_layout(model)
        border = np.any([(vertices[:, h] == 0) | (vertices[:, h] == layout.stride[h]) for h in layout.horizontal],
                        axis=0)
        moved = tile_relief(model, seed, tile, vertices, options)
        # The moved mesh's own normals inside; on the border, normals its neighbour gives alike.
        inside = vertex_normals(moved, faces)
        inside[border] = relief_normals(model, seed, tile, vertices[border], normals[border].astype(np.float64),
                                        0.5 / scale, options)
        vertices, normals = moved, inside.astype(np.float32)
    colours = tile_colours(model, seed, tile, vertices, options, 1 / scale) if coloured(model, options) else None
    if options.lod and len(faces):
        layout = world_layout(model)
        grid = tile_grid(model, layout, scale, options)
        depth = SKIRT * (grid.positions[layout.up][1] - grid.positions[layout.up][0])
        vertices, faces, source = skirted(vertices, faces, layout, depth)
        normals = normals[source]
        colours = None if colours is None else colours[source]
    return Surface(vertices, faces, normals, colours)


def skirted(vertices: np.ndarray, faces: np.ndarray, layout: Layout, depth: float) -> tuple:
    """The mesh with a skirt: each edge lying on one of the tile's four sides
    (an edge of one face only) gets a quad hanging `depth` below it, wound as
    the face beside it. Returns (vertices, faces, the vertex each new vertex
    copies: an index per vertex)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.minimum(edges[:, 0], edges[:, 1]) * len(vertices) + np.maximum(edges[:, 0], edges[:, 1])
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    open_edges = edges[counts[inverse.reshape(-1)] == 1]
    on_side = np.zeros(len(open_edges), bool)
    for axis in layout.horizontal:
        for at in (0, layout.stride[axis]):
            on_side |= (vertices[open_edges, axis] == at).all(axis=1)
    open_edges = open_edges[on_side]
    used, index = np.unique(open_edges, return_inverse=True)
    hanging = vertices[used].copy()
    hanging[:, layout.up] -= depth
    base = len(vertices)
    lower = base + index.reshape(-1, 2)
    a, b = open_edges[:, 0], open_edges[:, 1]
    skirt = np.concatenate([np.stack([b, a, lower[:, 0]], axis=1), np.stack([b, lower[:, 0], lower[:, 1]], axis=1)])
    return (np.concatenate([vertices, hanging]), np.concatenate([faces, skirt]),
            np.concatenate([np.arange(base), used]))


def tile_corner(model, tile) -> tuple:
    """Tile (i, j)'s lowest corner in model units (exact integers, for any tile)."""
    i, j = check_tile(tile)
    layout = world_layout(model)
    corner = [0, 0, 0]
    corner[layout.horizontal[0]], corner[layout.horizontal[1]] = i * layout.stride[layout.horizontal[0]], \
        j * layout.stride[layout.horizontal[1]]
    return tuple(corner)


# Beyond this many voxels from the world's origin, absolute float32
# coordinates keep less than 1/64 of a voxel: a tile there is written in its
# own frame ('tile').
MAX_ABSOLUTE = 1 << 18


def check_placement(model, tile, frame: str) -> None:
    """A tile far from the world's origin is written in its own frame only."""
    far = max(abs(c) for c in tile_corner(model, tile))
    if frame != "tile" and far > MAX_ABSOLUTE:
        raise InputError(f"tile {tuple(tile)} lies {far} voxels from the world's origin, where float32 "
                         "coordinates lose the shape's detail: give `frame` tile (coordinates from the tile's "
                         "corner)", "frame")


def placed(model, tile, vertices: np.ndarray, frame: str) -> np.ndarray:
    """Tile-relative model units -> the request's frame: 'tile' (input units
    from the tile's corner), 'model' (voxels) or 'input' (the training mesh's
    frame), the last two from the world's origin."""
    manifest = model.manifest
    check_placement(model, tile, frame)
    if frame == "tile":
        return vertices * np.asarray(manifest.spacing)
    absolute = np.array(tile_corner(model, tile), np.float64) + vertices  # exact on shared borders: integers plus the same offsets
    return absolute if frame == "model" else np.asarray(manifest.origin) + absolute * np.asarray(manifest.spacing)


def frame_normals(model, normals: np.ndarray) -> np.ndarray:
    """Normals in voxel units -> the input's frame (its spacing may differ per axis)."""
    scaled = normals / np.asarray(model.manifest.spacing)
    return (scaled / np.linalg.norm(scaled, axis=1, keepdims=True)).astype(np.float32)


MAX_BLOCK_TILES = 4096  # tiles written as one mesh; more is a folder of tiles (write_tiles)
# Peak bytes a block holds per vertex of its tiles (their arrays, the joined
# ones, welding's sort, the mesh and its file's bytes): 296 to 422 measured
# on blocks of 144 and 256 terrain tiles at scales 2 and 1, counting the
# first tile's vertices for every tile; it stands for the others, which may
# hold more.
BLOCK_BYTES_PER_VERTEX = 500


def block_mesh(model, request, tiles, progress=None, memory_limit: int | None = None):
    """A block of tiles (a rectangle of them) as one trimesh mesh in the
    request's frame ('input' or 'model': placed in the world), shared border
    vertices welded and the block's outer sides closed: one closed surface.
    Its count is bounded before a tile is listed, and its memory (the first
    tile's surface times the count) before the second is made.
    progress(done, total) after each tile."""
    import trimesh  # half a second to import, for a block's whole mesh only (runtime/mesh.py's tiles stream)

    sized = hasattr(tiles, "__len__")
    count = len(tiles) if sized else None  # a block's count is checked before its tiles are listed
    tiles = list(itertools.islice(tiles, MAX_BLOCK_TILES + 1)) if not sized or count <= MAX_BLOCK_TILES else []
    count = count if sized else len(tiles)
    if not 0 < count <= MAX_BLOCK_TILES:
        got = count if sized else f"more than {MAX_BLOCK_TILES}"
        raise InputError(f"a block is 1 to {MAX_BLOCK_TILES} tiles, got {got}; write more as a folder of tiles",
                         "tile")
    if request.frame == "tile":
        raise InputError("a block is placed in the world: give `frame` input or model", "frame")
    options = request.world_options()
    if options.lod:
        raise InputError("a block is one closed surface, at one level of detail: give `lod` 0", "lod")
    h0, h1 = world_layout(model).horizontal
    low, high = np.min(tiles, axis=0), np.max(tiles, axis=0)
    vertices, faces, colours, count = [], [], [], 0
    for done, tile in enumerate(tiles, 1):
        check_placement(model, tile, request.frame)
        ends = [(axis, side) for n, axis in enumerate((h0, h1)) for side, end in enumerate((low, high))
                if tile[n] == end[n]]
        v, f = tile_mesh(model, request.sample_seed, tile, request.scale, memory_limit, closed=ends, options=options)
        if done == 1:
            check_memory(BLOCK_BYTES_PER_VERTEX * max(len(v), 1) * len(tiles),
                         f"a block of {len(tiles)} tiles at scale {request.scale:g} (about {len(v)} vertices each)",
                         memory_limit)
        if coloured(model, options):
            colours.append(tile_colours(model, request.sample_seed, tile, v, options, 1 / request.scale))
        vertices.append(np.array(tile_corner(model, tile), np.float64) + v)  # exact on shared borders
        faces.append(f + count)
        count += len(v)
        if progress:
            progress(done, len(tiles))
    unique, index = np.unique(np.concatenate(vertices), axis=0, return_inverse=True)
    index = index.reshape(-1)
    faces = index[np.concatenate(faces)]
    # A grid value exactly at the level (a scatter world's ground has them)
    # puts several of a cell's vertices on one grid point: welded, their
    # faces have no area and would share edges thrice. Dropped, the block is closed.
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    if request.frame == "input":
        unique = np.asarray(model.manifest.origin) + unique * np.asarray(model.manifest.spacing)
    mesh = trimesh.Trimesh(unique, faces, process=False)
    if colours:  # a welded vertex's tiles gave it the same colour
        painted = np.empty((len(unique), 4), np.uint8)
        painted[index] = np.concatenate(colours)
        mesh.visual.vertex_colors = painted
    return mesh
