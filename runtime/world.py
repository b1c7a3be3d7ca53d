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
  size, one in most cells of a lattice of `spacing` strides, at a place,
  turned and mirrored as drawn from (seed, a, b), standing on a ground; the occupancy
  is the largest of theirs and the ground's. Nothing is blended, so every
  object is whole, and their places follow no period. In a world of
  several models, an object of another model stands at its model's
  `object_scale` against the first's (a voxel of it spans that many of the
  world's): its field is read at the world's points divided by the factor.

A height map (HeightMap: heights in voxels, a pixel a square of the
tiles' longer side, a designer's painting) gives the world its large shape: a blend world's columns are
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
  from its sides straight down to its grid's floor, and a finer one asked
  with `skirt` too, so that the crack is covered from both sides.
"""

import functools
import math
import numbers
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from sinshape.core import noise
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import ARRANGEMENTS, PLANE_AXES, UP_AXIS

from .generate import draw_noise, scaled_sizes, triplane
from .options import DENSITY, MAX_SPACING, MAX_TILE, OPTION, SPACING  # a tile request's range, a scatter world's
from .query import check_scale, head_colour, project, sigmoid
from .world_maps import MAX_MODELS, HeightMap, ModelMap

WORLD_STREAM = 2  # (WORLD_STREAM, a, b): the key of window (a, b)'s noise, absorbed after the world's seed
SCATTER_STREAM = 3  # (SCATTER_STREAM, a, b): the key of scatter cell (a, b)'s draws (presence, place, turn, mirrors)
MIN_STRIDE = 4  # voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
BLEND = 1.0  # the share of a stride, around its middle, over which one window gives way to the next
GROUND = 1.0  # voxels of ground above the map's height under a scatter world's objects
# The ground's logit per voxel: nearly linear across a grid step, so that
# marching cubes places a sloping ground without terraces (4 drew them).
GROUND_SLOPE = 1.0
GROUND_COLOUR = (0.5, 0.5, 0.5)  # sRGB of a scatter world's ground, which no model colours
NORMAL_STEP = 0.25  # voxels: a normal's differences, a power of two (exact steps from a face), under PLATEAU
# Voxels either side of a lattice line where the window whose line it is
# holds the whole weight: a normal's points just past a face need no window
# but the face's own, so a tile's normals make no neighbour's windows.
PLATEAU = 0.5


@dataclass(frozen=True)
class Tiling:
    """How a model's world is cut: which axes are horizontal, the stride S
    per axis (None along up), the windows' size factors."""

    horizontal: tuple  # the two horizontal axes, ascending
    up: int
    stride: tuple  # (3,) voxels per tile along each axis; the up axis's entry is its whole height - 1
    factors: tuple  # a window's size, as factors of the training size


def world_tiling(model) -> Tiling:
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
    return Tiling(horizontal, up, tuple(stride), factors)


def tiles_said(model) -> str:
    """A model's world tiles in words, for a designer painting a map: their
    size, and what a map's pixel covers (map_pixel)."""
    tiling = world_tiling(model)
    (h0, h1), names = tiling.horizontal, "xyz"
    s0, s1 = tiling.stride[h0], tiling.stride[h1]
    return (f"{s0} x {s1} voxels along {names[h0]} and {names[h1]}; a map's pixel is a square of "
            f"{map_pixel(tiling)} voxels a side")


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


# ---- the world's options: its arrangement, its maps (world_maps), a tile's detail

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
    skirt: bool = False  # a skirt at lod 0 too (a coarser tile always has one): a finer tile beside a coarser one
    underside: bool = True  # closed underneath (off: open below, for a view from above, which never sees it)
    density: float = DENSITY  # the share of a scattered world's cells that hold an object
    spacing: float = SPACING  # a scattered world's cell side, in tiles (at least its widest object's)

    def __post_init__(self):
        for name in ("detail", "skirt", "underside"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"`{name}` must be true or false, got {getattr(self, name)!r}", name)
        if self.arrange not in ARRANGEMENTS:
            raise InputError(f"unknown `arrange` {self.arrange!r}; choose {' or '.join(ARRANGEMENTS)}", "arrange")
        for name, wanted in (("density", "above 0 and at most 1"), ("spacing", f"1 to {MAX_SPACING:g} tiles")):
            value = getattr(self, name)
            if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and OPTION[name].admits(value)):
                raise InputError(f"`{name}` must be {wanted}, got {value!r}", name)
            object.__setattr__(self, name, float(value))
            if self.arrange != "scatter" and value != OPTION[name].default:
                raise InputError(f"`{name}` places whole objects: it is for a scatter world", name)
        if self.heights is not None and not isinstance(self.heights, HeightMap):
            raise InputError("`heights` must be a world_maps.HeightMap (HeightMap.of(array))", "heights")
        if not (isinstance(self.lod, numbers.Integral) and not isinstance(self.lod, bool) and 0 <= self.lod):
            raise InputError(f"`lod` must be a whole number of levels, 0 or more, got {self.lod!r}", "lod")
        if not isinstance(self.models, tuple) or len(self.models) >= MAX_MODELS:
            raise InputError(f"a world takes at most {MAX_MODELS - 1} `models` after the first", "models")
        if self.models_map is None:
            if self.models:
                raise InputError("several models need a model map saying which goes where", "models_map")
            return
        if not isinstance(self.models_map, ModelMap):
            raise InputError("`models_map` must be a world_maps.ModelMap (ModelMap.of(array))", "models_map")
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
    """The level whose grid a tile of `lod` has."""
    levels = len(model.manifest.sizes)
    if lod >= levels:
        raise InputError(f"`lod` must be 0 to {levels - 1} (the model has {levels} levels), got {lod}", "lod")
    return levels - 1 - lod


def planes_level(model, lod: int) -> int:
    """The level whose planes a tile of `lod` reads: the finest at lod 0, the
    one below it at every lod between (each level adds shape as well as
    detail: a tile two levels down read at its own level correlated 0.87 in
    height with its finest self, read one level down 0.96), and the coarsest
    level's own at the coarsest lod, a sketch at a tenth of a tile's cost
    (a view filled before its tiles come at their levels). A model coloured
    by correspondence reads the finest at every lod between: its coarser
    tiles' colour is matched on planes of the finest size anyway, which is
    most of what a tile costs (read one level down, the coloured terrain's
    lod 1 cost 0.90-0.94 of a full tile; the finest, 1.02-1.09), and the
    level below it drifts (its three levels: 0.92 in height against 0.995,
    and 4 sRGB levels off in colour against 0.8)."""
    level = check_lod(model, lod)
    finest = len(model.manifest.sizes) - 1
    if level == 0:
        return 0
    return finest if model.colour_tiles is not None else max(level, finest - 1)


def sketch(model, lod: int) -> bool:
    """Whether a tile of `lod` is the coarsest level's sketch (planes_level)."""
    return lod > 0 and planes_level(model, lod) == 0


def farthest_lod(model) -> int:
    """The coarsest lod a view's far tiles are made at: the coarsest true to
    its full tile (every lod but the sketch), or the sketch of a model of
    two levels, which has no other."""
    levels = len(model.manifest.sizes)
    return levels - 2 if levels > 2 else levels - 1


def coloured(model, options: WorldOptions = PLAIN) -> bool:
    """Whether a world's tiles carry colour: any of its models has it."""
    return any(each.manifest.colour for each in (model, *options.models))


def hidden_width(model, options: WorldOptions) -> int:
    """The hidden vectors' width a world's points hold: its widest model's."""
    return max(each.manifest.hidden for each in (model, *options.models))


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


def window_sizes(model, tiling: Tiling, arrange: str) -> list:
    """Every level's size of a window (blend: 2S + 1 along each horizontal
    axis) or an object (scatter: the training size)."""
    factors = tiling.factors if arrange == "blend" else (1.0, 1.0, 1.0)
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


def window(model, tiling: Tiling, seed: int, a: int, b: int, level: int, arrange: str = "blend") -> Window:
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
    sizes = window_sizes(model, tiling, arrange)
    made = triplane(model, draw_noise(window_seed(seed, a, b), sizes[:level + 1], model.manifest.channels,
                                      first=start[0] + 1 if start else 0), sizes[:level + 1], start=start)
    planes = project(model, made).planes
    means = []
    for plane, axes in zip(planes, PLANE_AXES):
        if tiling.up not in axes:
            means.append(plane.mean(axis=(0, 1)))  # (D,): the same at every height
        else:
            means.append(plane.mean(axis=1 - axes.index(tiling.up)))  # (U, D)
    mean = np.broadcast_to(sum(means), (sizes[level][tiling.up], model.manifest.hidden)).astype(np.float32)
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
    lowest corner, in voxels from the cell's), whether it is turned a
    quarter about the up axis (its two horizontal axes swapped: `extent`
    is its extent along the world's), and whether it is mirrored along
    each of the world's horizontal axes: with the turn, all eight ways an
    object can face."""

    present: bool
    offset: tuple  # (2,) along the two horizontal axes
    mirror: tuple  # (2,) bool
    turned: bool
    extent: tuple  # (2,) E - 1 along the world's two horizontal axes, turned


@functools.lru_cache(maxsize=1024)  # a pure function, asked again for each tile and point group near the cell
def scatter_cell(seed: int, a: int, b: int, extent: tuple, pitch: tuple, density: float = DENSITY) -> Cell:
    """The draws of cell (a, b) of side `pitch` (voxels) for an object of
    `extent` (E - 1 along its own two horizontal axes): present in a share
    `density` of cells, moved inside its cell by as much room as its turned
    extent leaves."""
    mask = (1 << 64) - 1
    key = noise.stream_key(seed, SCATTER_STREAM, a & mask, b & mask)
    draw = [noise.mix64((key + noise.GOLDEN * (n + 1)) & mask) for n in range(4)]
    turned = bool(draw[3] & 4)
    placed = extent[::-1] if turned else extent
    room = (pitch[0] - placed[0], pitch[1] - placed[1])
    return Cell((draw[0] >> 11) < density * 2**53, (draw[1] % (room[0] + 1), draw[2] % (room[1] + 1)),
                (bool(draw[3] & 1), bool(draw[3] & 2)), turned, tuple(placed))


def object_model(model, options: WorldOptions, index: int) -> tuple:
    """A scattered world's model `index` (0 the first, `model`) and its own cut
    (its axes: an object's first horizontal axis lies along the world's)."""
    if not index:
        return model, world_tiling(model)
    other = options.models[index - 1]
    try:
        return other, world_tiling(other)
    except InputError as error:
        raise InputError(f"model {index} of the world: {error.template}", error.parameter) from None


def object_factor(model, each) -> float:
    """How many of a world's voxels (its first model's, `model`) one voxel of
    an object of model `each` spans: the two models' `object_scale`s' ratio."""
    return each.manifest.object_scale / model.manifest.object_scale


def world_extent(voxels: int, factor: float):
    """An object's extent of `voxels` in its model's voxels, in the world's:
    an exact integer wherever it is one (factor 1, 2, ...), so that places
    computed from it far out stay exact."""
    extent = voxels * factor
    return int(extent) if float(extent).is_integer() else extent


def scatter_geometry(model, tiling: Tiling, options: WorldOptions = PLAIN) -> tuple:
    """A scatter world's cell side P per horizontal axis (`spacing` strides, or
    room for its largest model's objects, turned either way, and half a
    stride), and each model's object extent (E - 1) times its object_factor
    (world voxels) along its own two horizontal axes (the world's, unturned)."""
    extents = []
    for index in range(len(options.models) + 1):
        each, own = object_model(model, options, index)
        finest, factor = each.manifest.sizes[-1], object_factor(model, each)
        extents.append(tuple(world_extent(finest[h] - 1, factor) for h in own.horizontal))
    widest = math.ceil(max(max(extent) for extent in extents))  # turned or not, an object fits its cell
    pitch = tuple(max(math.floor(options.spacing * tiling.stride[h] + 0.5), widest + tiling.stride[h] // 2)
                  for h in tiling.horizontal)
    return pitch, extents


@dataclass(frozen=True)
class Placed:
    """An object of a scatter world where a tile sees it: its cell, its
    lowest corner relative to the tile's (integer voxels), its extent
    along the world's axes, mirrors, whether it is turned (its first
    horizontal axis along the world's second), and the height it stands at.
    Its planes are made (`object_window`) only when a point asks for them."""

    cell: tuple  # (a, b)
    corner: tuple  # (2,) ints, relative to the tile's lowest corner
    extent: tuple  # (2,) (E - 1) * factor along the world's horizontal axes
    mirror: tuple
    height: float
    model: int = 0  # which of the world's models it is a sample of
    turned: bool = False
    factor: float = 1.0  # world voxels per voxel of its model (object_factor)

    def axes(self, own: "Tiling") -> tuple:
        """The object's own horizontal axes that lie along the world's first and second."""
        return own.horizontal[::-1] if self.turned else own.horizontal


def object_window(model, options: WorldOptions, seed: int, placed_object: Placed, level: int) -> tuple:
    """An object's model, that model's cut, and the object's planes at the
    first model's `level` (in the object's model, as many levels from its
    finest, or its coarsest)."""
    each, own = object_model(model, options, placed_object.model)
    return each, own, window(each, own, seed, *placed_object.cell, level_in(each, model, level), "scatter")


def level_in(each, model, level: int) -> int:
    """The first model's `level` in another of the world's models: as many
    levels from its finest, or its coarsest."""
    return max(len(each.manifest.sizes) - len(model.manifest.sizes) + level, 0)


def objects_near(model, tiling: Tiling, seed: int, tile: tuple, level: int, options: WorldOptions) -> list:
    """The objects of a scatter world that reach into tile (i, j), in a fixed
    order: each from the model its cell's centre's pixel of the model map names."""
    i, j = tile
    heights = options.heights
    h0, h1 = tiling.horizontal
    (p0, p1), extents = scatter_geometry(model, tiling, options)
    s0, s1 = tiling.stride[h0], tiling.stride[h1]
    pixel = map_pixel(tiling)
    factors = [object_factor(model, object_model(model, options, k)[0]) for k in range(len(extents))]
    found = []
    for a in range((i * s0) // p0 - 1, ((i + 1) * s0) // p0 + 1):
        for b in range((j * s1) // p1 - 1, ((j + 1) * s1) // p1 + 1):
            index = 0 if options.models_map is None else \
                options.models_map.at((2 * a * p0 + p0) // (2 * pixel), (2 * b * p1 + p1) // (2 * pixel))  # exact
            room = tuple(math.ceil(e) for e in extents[index])  # the whole voxels it takes in its cell
            cell = scatter_cell(seed, a, b, room, (p0, p1), options.density)
            e0, e1 = extents[index][::-1] if cell.turned else extents[index]
            low = (a * p0 + cell.offset[0], b * p1 + cell.offset[1])  # world voxels, exact integers
            if not cell.present or low[0] > (i + 1) * s0 or low[0] + e0 < i * s0 or low[1] > (j + 1) * s1 \
                    or low[1] + e1 < j * s1:
                continue
            height = 0.0 if heights is None else object_height(heights, tiling, low, (e0, e1))
            found.append(Placed((a, b), (low[0] - i * s0, low[1] - j * s1), (e0, e1), cell.mirror, height, index,
                                cell.turned, factors[index]))
    return found


# ---- the height map, read anywhere

def spline_weights(t: np.ndarray) -> list:
    """The uniform cubic B-spline's four weights at fractions t (float64)."""
    s = 1 - t
    return [s * s * s / 6, (3 * t * t * t - 6 * t * t + 4) / 6, (-3 * t * t * t + 3 * t * t + 3 * t + 1) / 6,
            t * t * t / 6]


def map_pixel(tiling: Tiling) -> int:
    """The side of a map's pixel in voxels: the tiles' longer side, the same
    along both axes, so that what is painted keeps its aspect (a circle
    stays round) on tiles that are not square."""
    return max(tiling.stride[h] for h in tiling.horizontal)


def map_coordinates(count: int, tile: int, u: np.ndarray, stride: int, pixel: int) -> np.ndarray:
    """Where points u voxels past tile `tile`'s corner fall among a map's
    `count` pixels of `pixel` voxels along one axis (pixel r centred
    (r + 1/2) pixels from the world's origin), clamped where all four of a
    spline's pixels are the edge's: the same float from any tile that
    computes it (a face's points are integers from both)."""
    low, high = -(2 * pixel // stride) - 2, -(-(count + 2) * pixel // stride) + 1  # farther tiles: past the clamp
    near = min(max(tile, low), high)
    return np.clip((near * stride + np.asarray(u, np.float64)) / pixel - 0.5, -2.0, count + 1.0)


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


def map_heights(heights: HeightMap, tiling: Tiling, u0, u1, tile: tuple, outer: bool = True) -> np.ndarray:
    """The map's height (voxels, float64) at points of tile (i, j), u0 and u1
    voxels from its corner along the two horizontal axes: at every pair
    ((len(u0), len(u1))) or, not `outer`, at each point ((n,))."""
    values = heights.array().astype(np.float64)
    h0, h1 = tiling.horizontal
    pixel = map_pixel(tiling)
    return spline(values, map_coordinates(values.shape[0], tile[0], u0, tiling.stride[h0], pixel),
                  map_coordinates(values.shape[1], tile[1], u1, tiling.stride[h1], pixel), outer)


def object_height(heights: HeightMap, tiling: Tiling, low: tuple, extent: tuple) -> float:
    """The map's height under the centre of an object whose lowest corner is
    at world voxels `low` (exact integers, however far): the same for every
    tile that sees it."""
    values = heights.array().astype(np.float64)
    pixel = map_pixel(tiling)
    q = [np.array([min(max((2 * c + e) / (2 * pixel) - 0.5, -2.0), n + 1.0)]) for c, e, n in zip(low, extent, values.shape)]
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


def tile_grid(model, tiling: Tiling, scale: float, options: WorldOptions) -> Grid:
    """The grid of a tile at `scale` and `options.lod`: the finest level's
    grid at lod 0 (m = S scale points per stride), a level's own otherwise."""
    sizes = model.manifest.sizes
    level = check_lod(model, options.lod)
    positions = []
    for axis in range(3):
        ratio = (sizes[level][axis] - 1) / (sizes[-1][axis] - 1)
        stride = tiling.stride[axis]
        if axis == tiling.up:
            m = max(2, round((stride + 1) * scale * ratio))  # as a sample's grid: m points over the height
            step = stride / (m - 1)
            low, high = options.heights.bounds() if options.heights is not None else (0, 0)
            others = [object_model(model, options, k) for k in range(1, len(options.models) + 1)]
            high += max([0] + [cut.stride[cut.up] * object_factor(model, each) - stride
                               for each, cut in others])  # a taller model's objects
            count = m + math.ceil((high - low) / step)
            positions.append(low + np.arange(count) * step)
        else:
            m = max(1, round(stride * scale * ratio))
            positions.append(np.arange(m + 1) * stride / m)  # exact at the faces: m S / m = S
    return Grid(tuple(positions))


MAX_POINTS = 1 << 14  # a tile's grid points per axis, at most


def check_world_scale(tiling: Tiling, scale: float, hidden: int, memory_limit: int | None,
                      points: tuple | None = None) -> None:
    """A tile's grid (`points` per axis; at lod 0 with no map unless given)
    refused where it is too large or needs more memory than there is."""
    check_scale(scale)
    if points is None:
        points = [round(tiling.stride[a] * scale) + 1 if a != tiling.up
                  else max(2, round((tiling.stride[a] + 1) * scale)) for a in range(3)]
    if max(points) > MAX_POINTS:
        raise InputError(f"`scale` {scale:g} makes a tile of {'x'.join(map(str, points))} points; at most "
                         f"{MAX_POINTS} per axis", "scale")
    h0, h1 = tiling.horizontal
    # The grid, a row's sums and gathered planes, and the interpolated horizontal planes.
    row = points[h1] * points[tiling.up] * hidden * 4 * 6
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


def hidden_on_grid(window: Window, tiling: Tiling, c0: np.ndarray, c1: np.ndarray, up_cells: np.ndarray):
    """A window's hidden sum (b1 not added) on a grid in tile order (h0, h1,
    up): c0, c1 its cells along the horizontal axes, up_cells (X, Y, K) or
    (1, 1, K) along up. Returns (hidden (X, Y, K, D), mean at those heights)."""
    h0, h1 = tiling.horizontal
    cells = {h0: c0, h1: c1}
    flat, vertical = None, []
    for plane, (r, c) in zip(window.planes, PLANE_AXES):
        if tiling.up not in (r, c):  # the horizontal plane
            flat = interpolate(plane, cells[r], cells[c])
            flat = flat if r == h0 else flat.transpose(1, 0, 2)
        else:
            h = c if r == tiling.up else r
            read = along(plane, cells[h], 1 if r == tiling.up else 0)
            read = read.transpose(1, 0, 2) if r == tiling.up else read  # (N, U, D)
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


def blend_sources(model, tiling: Tiling, seed: int, tile: tuple, level: int, progress=None) -> list:
    """Tile (i, j)'s four windows in the fixed order of the sum, each with
    its offset (voxels from its lattice point to the tile's) along the two
    horizontal axes and whether it is the one behind along each.
    progress(0, 1) after each window made or found."""
    i, j = tile
    h0, h1 = tiling.horizontal
    sources = []
    for a in (i - 1, i):
        for b in (j - 1, j):
            sources.append((window(model, tiling, seed, a, b, level),
                            (tiling.stride[h0] if a < i else 0, tiling.stride[h1] if b < j else 0), (a == i, b == j)))
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
    tiling = world_tiling(model)
    level = planes_level(model, options.lod)
    grid = tile_grid(model, tiling, scale, options)
    h0, h1, up = *tiling.horizontal, tiling.up
    check_world_scale(tiling, scale, hidden_width(model, options), memory_limit, grid.shape)
    u0, u1, z = grid.positions[h0], grid.positions[h1], grid.positions[up]
    heights = None if options.heights is None else map_heights(options.heights, tiling, u0, u1, (i, j))
    out = np.empty((len(u0), len(u1), len(z)), np.float32)
    colours = np.zeros((*out.shape, 3), np.float32) if colour else None
    if options.arrange == "scatter":
        ground = z[None, None, :] - GROUND if heights is None else z[None, None, :] - heights[:, :, None] - GROUND
        out[...] = -np.float32(GROUND_SLOPE) * ground.astype(np.float32)
        near = objects_near(model, tiling, seed, (i, j), level, options)
        for done, placed_object in enumerate(near, 1):
            if progress:
                progress(done, len(near))
            scatter_into(out, colours, model, options, seed, level, placed_object, u0, u1, z)
        return (out, colours) if colour else out
    sources = blend_sources(model, tiling, seed, (i, j), level, progress)
    rows = max(1, (1 << 21) // (len(u1) * len(z) * model.manifest.hidden))  # ~8 MB a sum
    for x0 in range(0, len(u0), rows):
        x = slice(x0, min(x0 + rows, len(u0)))
        rise = 0 if heights is None else heights[x, :, None]
        levels = np.clip(z[None, None, :] - rise, 0, tiling.stride[up])  # (X, Y, K) or (1, 1, K)
        blend = ContrastSum(model.manifest.contrast)
        for found, offset, behind in sources:
            w0 = window_weight(u0[x], tiling.stride[h0], behind[0])
            w1 = window_weight(u1, tiling.stride[h1], behind[1])
            hidden, mean = hidden_on_grid(found, tiling, (u0[x] + offset[0]) * found.cells[h0],
                                          (u1 + offset[1]) * found.cells[h1], levels * found.cells[up])
            blend.add((w0[:, None] * w1[None, :])[:, :, None, None], hidden, mean)
        total = blend.total()
        out[x] = capped(head_logits(model.head, total), z[None, None, :] - rise - tiling.stride[up])
        if colour:
            colours[x] = head_colour(model.head, total)
        if progress:
            progress(x.stop, len(u0))
    return (out, colours) if colour else out


def scatter_into(out: np.ndarray, colours, model, options: WorldOptions, seed: int, level: int,
                 placed_object: Placed, u0, u1, z) -> None:
    """One object's logits where they are the largest yet, on the part of a tile's grid inside its box
    (its colour there: its own model's, grey for a model without colour)."""
    local, factor = [], placed_object.factor
    for u, low, extent, mirror in zip((u0, u1), placed_object.corner, placed_object.extent, placed_object.mirror):
        inside = np.flatnonzero((u - low >= 0) & (u - low <= extent))
        position = u[inside] - low
        local.append((inside, (extent - position if mirror else position) / factor))  # in its model's voxels
    (x, c0), (y, c1) = local
    if not len(x) or not len(y):
        return
    each, own, found = object_window(model, options, seed, placed_object, level)
    h0, h1, up = *own.horizontal, own.up  # the object's axes
    rise = (z - placed_object.height) / factor
    levels = np.clip(rise, 0, own.stride[up])[None, None, :]
    along0, along1 = (c1, c0) if placed_object.turned else (c0, c1)  # along its own axes, then turned to the world's
    hidden, _ = hidden_on_grid(found, own, along0 * found.cells[h0], along1 * found.cells[h1], levels * found.cells[up])
    if placed_object.turned:
        hidden = hidden.swapaxes(0, 1)
    logits = capped(head_logits(each.head, hidden), (rise - own.stride[up])[None, None, :])
    part = np.ix_(x, y)
    better = logits > out[part]
    out[part] = np.where(better, logits, out[part])
    if colours is not None:
        rgb = head_colour(each.head, hidden) if each.manifest.colour else np.float32(GROUND_COLOUR)
        colours[part] = np.where(better[..., None], rgb, colours[part])
