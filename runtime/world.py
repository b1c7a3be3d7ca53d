"""Endless worlds: any tile of an unbounded world of a seed, on its own,
seamless with its neighbours, at the same cost anywhere.

The world spreads along the model's two horizontal axes (the two that are
not `up`). It is covered by windows: ordinary samples of the training
extent (2S + 1 voxels along each horizontal axis, S the stride, the model's
height along up), one per point (a, b) of a lattice of stride S, each with
its own noise, keyed by (seed, a, b). A point of the world lies in four
windows; its occupancy is the decoder's head applied to the four windows'
hidden vectors (the first layer's pre-activations, which are linear in the
planes) blended with weights that sum to one: per axis, the window whose
lattice point lies behind the point by a fraction f of S weighs
smoothstep(f), the one before it 1 - smoothstep(f). A window's weight falls
to zero at its edges, where its content is least like the example.

Why this holds:
- A tile (i, j) is the world between lattice points i, i + 1 and j, j + 1:
  its occupancy depends on its four windows only, which depend on (model,
  seed, a, b) only. No state, no order, and no cost that grows with the
  distance: a window's noise is drawn at its own positions under its own key.
- Seams: two neighbouring tiles evaluate the points of their shared face
  with the same window at weight exactly 1 and the others at exactly 0,
  by the same element-wise arithmetic (no matrix products, whose rounding
  may depend on an array's shape), so the values there are equal to the
  bit, and marching cubes cuts the same border vertices from both sides.
  The faces along the horizontal axes are left open (not padded), so the
  union of any block of tiles is one surface.
- The blend does not repeat: every window has its own noise.

What it costs in quality: where two windows overlap, the shape is a blend
of two independent samples' features, not a sample the generator made;
the decoder keeps it sharp (it sees one hidden vector), but a structure
that is in one window and not the other thins out across the overlap.
A tile's cost is four windows' chains (a sample's) and the decoding of its
points, the same for every (i, j).
"""

import itertools
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from sinshape.core import noise
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES

from . import cubes
from .generate import draw_noise, scaled_sizes, triplane
from .query import check_scale, head_colour, hidden_at, project, sigmoid

WORLD_STREAM = 2  # (WORLD_STREAM, a, b): the key of window (a, b)'s noise, absorbed after the world's seed
MAX_TILE = 1 << 62  # |i|, |j| below this: a window index and its neighbour fit in 64 bits in every runtime
MIN_STRIDE = 4  # voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
UP_AXIS = {"y": 1, "z": 2}
BLEND = 1.0  # the share of a stride, around its middle, over which one window gives way to the next


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
        raise InputError(f"a tile is two integers (i, j) of magnitude below 2**62, got {tile!r}", "tile")
    return int(tile[0]), int(tile[1])


def window_seed(seed: int, a: int, b: int) -> int:
    """The noise seed of window (a, b) of the world of `seed`: a 64-bit key."""
    mask = (1 << 64) - 1
    return noise.stream_key(seed, WORLD_STREAM, a & mask, b & mask)


# Windows kept for the next tiles (a tile shares each of its four with a
# neighbour): the last few made, whatever asked for them. A cache, not state:
# a window is the same array whether it is made or found.
WINDOWS_KEPT = 16
_windows = OrderedDict()  # (id(model), seed, a, b) -> (model, planes)


def window(model, layout: Layout, seed: int, a: int, b: int) -> list:
    """Window (a, b)'s final planes times the decoder's first layer: 3 x (H, W, D)."""
    key = (id(model), seed, a, b)
    if key in _windows:
        _windows.move_to_end(key)
        return _windows[key][1]
    sizes = scaled_sizes(model.manifest.sizes, layout.factors)
    planes = project(model, triplane(model, draw_noise(window_seed(seed, a, b), sizes, model.manifest.channels),
                                     sizes)).planes
    _windows[key] = (model, planes)  # the model is held, so its id names it while the entry lives
    while len(_windows) > WINDOWS_KEPT:
        _windows.popitem(last=False)
    return planes


def smoothstep(f: np.ndarray) -> np.ndarray:
    return f * f * (3 - 2 * f)


@dataclass(frozen=True)
class Axis:
    """A tile's grid along one axis: `points` positions, and for the tile's
    two windows along a horizontal axis (the one before, the one behind)
    their cell positions and weights; along up, one window spanning it all."""

    points: int
    cells: tuple  # per window: (points,) float64 positions in the window's cells
    weights: tuple  # per window: (points,) float32


def tile_axis(layout: Layout, axis: int, scale: float) -> Axis:
    """Tile-local grid along `axis`: m + 1 points over the stride S (m = S
    scale, rounded), point p at p S / m, the same for every tile."""
    stride = layout.stride[axis]
    if axis == layout.up:
        m = max(2, round((stride + 1) * scale))  # as a sample's grid: m points over the height
        return Axis(m, (np.arange(m) * (stride / (m - 1)),), (np.ones(m, np.float32),))
    m = max(1, round(stride * scale))
    p = np.arange(m + 1)
    behind = smoothstep(np.clip((p / m - 0.5) / BLEND + 0.5, 0, 1)).astype(np.float32)  # window i (p = 0 at its start)
    before = (np.float32(1) - behind).astype(np.float32)  # window i - 1: exactly 1 - behind
    return Axis(m + 1, ((m + p) * stride / m, p * stride / m), (before, behind))


def interpolate(plane: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """A (H, W, D) plane at every (row, col) of two position lists, element-wise
    (bilinear, align_corners): (len(rows), len(cols), D) float32. Two tiles
    asking for the same position get the same bits."""
    def along(values, positions, axis):
        n = values.shape[axis]
        low = np.clip(np.floor(positions).astype(np.int64), 0, max(n - 2, 0))
        high = np.minimum(low + 1, n - 1)
        frac = (positions - low).astype(np.float32)
        shape = [1] * values.ndim
        shape[axis] = len(positions)
        frac = frac.reshape(shape)
        return np.take(values, low, axis) * (np.float32(1) - frac) + np.take(values, high, axis) * frac

    return along(along(plane, rows, 0), cols, 1)


def check_world_scale(layout: Layout, scale: float, hidden: int, memory_limit: int | None) -> None:
    check_scale(scale)
    points = [tile_axis(layout, a, scale).points for a in range(3)]
    if max(points) > 1 << 14:
        raise InputError(f"scale {scale:g} makes a tile of {'x'.join(map(str, points))} points; at most "
                         f"{1 << 14} per axis", "scale")
    h0, h1 = layout.horizontal
    # The grid, a row of four windows' hidden sums, and the interpolated planes.
    row = points[h1] * points[layout.up] * hidden * 4 * 3
    planes = 4 * hidden * 4 * sum(points[a] * points[b] for a, b in PLANE_AXES)
    check_memory(math.prod(points) * 4 * 2 + row + planes, f"a {'x'.join(map(str, points))} tile", memory_limit)


def tile_occupancy(model, seed: int, tile, scale: float = 1.0, memory_limit: int | None = None,
                   colour: bool = False, progress=None):
    """Occupancy on tile (i, j)'s grid: (X, Y, Z) float32, its points along
    each horizontal axis from the tile's lattice point to the next (both
    included: the faces it shares), along up the model's height. With
    `colour` (a coloured model), also its colour there: (occupancy,
    (X, Y, Z, 3) uint8 sRGB). progress(done, total) after each window and
    each slab of rows (a server stops a job there)."""
    from .generate import check_seed

    check_seed(seed)
    i, j = check_tile(tile)
    layout = world_layout(model)
    check_world_scale(layout, scale, model.manifest.hidden, memory_limit)
    axes = [tile_axis(layout, a, scale) for a in range(3)]
    h0, h1 = layout.horizontal
    sources = []  # per window, in a fixed order (the sum's): its interpolated planes and weights
    for a, b in [(a, b) for a in (i - 1, i) for b in (j - 1, j)]:
        index = {h0: a - i + 1, h1: b - j + 1, layout.up: 0}  # which of the axis's windows this is
        cells = [axes[axis].cells[index[axis]] for axis in range(3)]
        planes = [interpolate(plane, cells[r], cells[c])
                  for plane, (r, c) in zip(window(model, layout, seed, a, b), PLANE_AXES)]
        sources.append((planes, [axes[axis].weights[index[axis]] for axis in range(3)]))
        if progress:
            progress(0, axes[0].points)
    out = np.empty([a.points for a in axes], np.float32)
    colours = np.empty((*out.shape, 3), np.uint8) if colour else None
    rows = max(1, (1 << 22) // (out.shape[1] * out.shape[2] * model.manifest.hidden))  # ~16 MB of sums
    for x0 in range(0, out.shape[0], rows):
        x = slice(x0, min(x0 + rows, out.shape[0]))
        total = None
        for (xy, xz, yz), (wx, wy, wz) in sources:
            hidden = xy[x, :, None] + xz[x, None, :] + yz[None]  # (r, Y, Z, D)
            weight = (wx[x, None, None] * wy[None, :, None] * wz[None, None, :])[..., None]
            total = weight * hidden if total is None else total + weight * hidden
        out[x] = head(model.head, total)
        if colour:
            colours[x] = np.round(head_colour(model.head, total) * 255)
        if progress:
            progress(x.stop, out.shape[0])
    return (out, colours) if colour else out


def tile_colours(model, seed: int, tile, vertices: np.ndarray) -> np.ndarray:
    """A coloured model's colour at tile (i, j)'s vertices (model units from
    the tile's corner, as tile_mesh gives them): the four windows' hidden
    sums at the vertices, blended with the weights the tile's grid has
    there (`tile_axis`, continued between its points), then the colour head.
    A vertex on a face two tiles share gets the same colour from both.
    Returns (n, 4) uint8 RGBA."""
    from .mesh import colour_bytes

    return colour_bytes(head_colour(model.head, tile_hidden(model, seed, tile, vertices)))


def tile_hidden(model, seed: int, tile, vertices: np.ndarray) -> np.ndarray:
    """The decoder's hidden pre-activations (b1 not added) at points of tile
    (i, j) (model units from its corner): the four windows' hidden sums
    blended with the weights the tile's grid has there. (n, D)."""
    i, j = check_tile(tile)
    layout = world_layout(model)
    h0, h1 = layout.horizontal
    total = 0
    for a, b in [(a, b) for a in (i - 1, i) for b in (j - 1, j)]:
        cells, weight = [None] * 3, np.ones(len(vertices))
        for axis, before in ((h0, a < i), (h1, b < j)):  # before: the window i - 1 along the axis
            t, stride = vertices[:, axis], layout.stride[axis]
            behind = smoothstep(np.clip((t / stride - 0.5) / BLEND + 0.5, 0, 1))
            cells[axis] = t + stride if before else t
            weight = weight * (1 - behind if before else behind)
        cells[layout.up] = vertices[:, layout.up]
        total = total + weight[:, None] * hidden_at(window(model, layout, seed, a, b), np.stack(cells, axis=1))
    return total


def head(weights, hidden: np.ndarray) -> np.ndarray:
    """sigmoid(w2 . relu(hidden + b1) + b2) element-wise over the hidden
    width, in a fixed order: (..., D) -> (...) float32."""
    biased = np.maximum(hidden + weights.bias1, 0)
    logits = np.full(hidden.shape[:-1], np.float32(weights.bias2), np.float32)
    for d in range(hidden.shape[-1]):
        logits += biased[..., d] * weights.weight2[d]
    return sigmoid(logits)


def tile_mesh(model, seed: int, tile, scale: float = 1.0, memory_limit: int | None = None,
              closed: tuple = (), progress=None) -> tuple:
    """Tile (i, j)'s surface: (vertices (V, 3) float64 in model units
    relative to the tile's lowest corner, faces (F, 3) int64). Closed at the
    top and bottom, open on the four sides it shares with its neighbours,
    whose border vertices it shares exactly, except the sides in `closed`
    ((axis, 0 or 1) pairs: the low or high side along a horizontal axis),
    closed as a sample's sides are (where a block of tiles ends). progress: as tile_occupancy's."""
    values = tile_occupancy(model, seed, tile, scale, memory_limit, progress=progress)
    layout = world_layout(model)
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
        vertices[:, axis] = vertices[:, axis] * layout.stride[axis] / intervals  # exact at the faces: m S / m = S
    return vertices, faces


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
                         "coordinates lose the shape's detail: give frame tile (coordinates from the tile's "
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


def tile_bytes(model, request, name, progress=None) -> tuple:
    """A tile request (request.SampleRequest with `tile`) as the bytes of the
    file `name` names, and its mesh (None for an .npz grid). progress: as
    tile_occupancy's."""
    from pathlib import Path

    from . import write

    suffix = Path(name).suffix.lower()
    if write.output_kind(name) == "grid":
        grids = tile_occupancy(model, request.sample_seed, request.tile, request.scale, colour=model.manifest.colour,
                               progress=progress)
        grids = dict(zip(("occupancy", "colour"), grids)) if model.manifest.colour else {"occupancy": grids}
        return write.grid_bytes(**grids, tile=request.tile, corner=tile_corner(model, request.tile),
                                scale=request.scale), None
    import trimesh

    vertices, faces = tile_mesh(model, request.sample_seed, request.tile, request.scale, progress=progress)
    if not len(faces):
        raise write.no_surface(Path(name))
    mesh = trimesh.Trimesh(placed(model, request.tile, vertices, request.frame), faces, process=False)
    if model.manifest.colour:
        mesh.visual.vertex_colors = tile_colours(model, request.sample_seed, request.tile, vertices)
    return write.mesh_bytes(mesh, suffix), mesh


def write_tiles(model_path, tiles, pattern, request, engine: str = "local", workers: int | None = None,
                threads: int | None = None, address: str | None = None, progress=None,
                restart: bool = False, asset=None) -> dict:
    """Write one file per tile of `tiles` ((i, j) pairs, read lazily), `pattern`
    with {tile} filled in as I_J: the world of `request` (a
    request.SampleRequest with a seed and no tile), resumably, on the cores
    or a Ray cluster as runtime.many's jobs (an index of another job is
    refused unless `restart`); with `asset` (an asset.AssetOptions), each
    tile's game asset (.glb), whose levels keep the tile's whole border.
    Returns {"written", "skipped", "index"}."""
    import dataclasses

    from . import many

    from pathlib import Path

    from .load import load_model

    if request.tile is not None:
        raise InputError("give the tiles to write, not one tile in the request", "tile")
    tiles = iter(tiles)
    first = next(tiles, None)
    if first is None:
        raise InputError("no tiles to write", "tile")
    dataclasses.replace(request, tile=first)  # what a tile refuses, refused before the first is made
    if request.frame != "tile":
        check_placement(load_model(model_path, threads=1), first, request.frame)
    tiles = itertools.chain([first], tiles)
    folder = Path(pattern).parent
    if not folder.exists():
        try:
            folder.mkdir(parents=True)
        except OSError as error:
            raise InputError(f"{folder}: cannot make the folder ({error.strerror})") from None
    return many.run_job(model_path, tiles, pattern, many.TILES, request, engine, workers, threads, address,
                        progress, restart, asset)


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
    import trimesh

    sized = hasattr(tiles, "__len__")
    count = len(tiles) if sized else None  # a block's count is checked before its tiles are listed
    tiles = list(itertools.islice(tiles, MAX_BLOCK_TILES + 1)) if not sized or count <= MAX_BLOCK_TILES else []
    count = count if sized else len(tiles)
    if not 0 < count <= MAX_BLOCK_TILES:
        got = count if sized else f"more than {MAX_BLOCK_TILES}"
        raise InputError(f"a block is 1 to {MAX_BLOCK_TILES} tiles, got {got}; write more as a folder of tiles",
                         "tile")
    if request.frame == "tile":
        raise InputError("a block is placed in the world: give frame input or model", "frame")
    h0, h1 = world_layout(model).horizontal
    low, high = np.min(tiles, axis=0), np.max(tiles, axis=0)
    vertices, faces, colours, count = [], [], [], 0
    for done, tile in enumerate(tiles, 1):
        check_placement(model, tile, request.frame)
        ends = [(axis, side) for n, axis in enumerate((h0, h1)) for side, end in enumerate((low, high))
                if tile[n] == end[n]]
        v, f = tile_mesh(model, request.sample_seed, tile, request.scale, memory_limit, closed=ends)
        if done == 1:
            check_memory(BLOCK_BYTES_PER_VERTEX * max(len(v), 1) * len(tiles),
                         f"a block of {len(tiles)} tiles at scale {request.scale:g} (about {len(v)} vertices each)",
                         memory_limit)
        if model.manifest.colour:
            colours.append(tile_colours(model, request.sample_seed, tile, v))
        vertices.append(np.array(tile_corner(model, tile), np.float64) + v)  # exact on shared borders
        faces.append(f + count)
        count += len(v)
        if progress:
            progress(done, len(tiles))
    unique, index = np.unique(np.concatenate(vertices), axis=0, return_inverse=True)
    faces = index.reshape(-1)[np.concatenate(faces)]
    if request.frame == "input":
        unique = np.asarray(model.manifest.origin) + unique * np.asarray(model.manifest.spacing)
    mesh = trimesh.Trimesh(unique, faces, process=False)
    if colours:  # a welded vertex's tiles gave it the same colour
        welded = np.empty((len(unique), 4), np.uint8)
        welded[index.reshape(-1)] = np.concatenate(colours)
        mesh.visual.vertex_colors = welded
    return mesh
