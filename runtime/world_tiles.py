"""A world's tiles as they are asked for: a tile's grid of occupancy (and
colour), and its surface: the grid's mesh, moved by the example's relief
and coloured at its vertices (world_points), a coarser tile's skirt, its
place in the world's frame; and a block of tiles as one mesh."""

import itertools
from dataclasses import dataclass

import numpy as np

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError

from . import cubes
from .bake import vertex_normals
from .generate import check_seed
from .query import sigmoid
from .world import PLAIN, Tiling, WorldOptions, check_tile, coloured, sketch, tile_grid, tile_logits, world_tiling
from .world_points import relief_normals, relieved, tile_colours, tile_normals, tile_relief


# ---- a tile's grid

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
    tiling = world_tiling(model)
    made = tile_logits(model, seed, tile, scale, options, memory_limit, colour, progress)
    logits, colours = made if colour else (made, None)
    order = np.argsort([*tiling.horizontal, tiling.up])  # tile order -> the model's axes
    occupancy = np.ascontiguousarray(sigmoid(logits).transpose(order))
    if not colour:
        return occupancy
    if model.colour_tiles is not None and not sketch(model, options.lod) or options.models:  # as its vertices are
        grid = tile_grid(model, tiling, scale, options)
        points = np.stack(np.meshgrid(*grid.positions, indexing="ij"), axis=-1).reshape(-1, 3)
        return occupancy, tile_colours(model, seed, tile, points, options, 1 / scale)[:, :3].reshape(*occupancy.shape, 3)
    return occupancy, np.round(np.ascontiguousarray(colours.transpose(*order, 3)) * 255).astype(np.uint8)


def tile_heights(model, seed: int, tile, scale: float = 1.0, options: WorldOptions = PLAIN) -> tuple:
    """Tile (i, j)'s height field, seen from above: on its grid's columns,
    the height (voxels from the model's floor) where the occupancy last
    crosses the surface level going up, as its mesh's top vertex there
    lies; NaN over a column with nothing in it. Returns (positions along
    the first horizontal axis, along the second, (n0, n1) heights): what a
    coarser tile is compared with its finer self by, and a border with its
    neighbour's."""
    tiling = world_tiling(model)
    grid = tile_grid(model, tiling, scale, options)
    h0, h1, up = *tiling.horizontal, tiling.up
    columns = np.moveaxis(tile_occupancy(model, seed, tile, scale, options=options), (h0, h1, up), (0, 1, 2))
    columns = np.pad(columns, [(0, 0), (0, 0), (0, 1)])  # empty above the grid, as tile_mesh closes the top
    inside = columns >= cubes.LEVEL
    top = columns.shape[2] - 1 - np.argmax(inside[:, :, ::-1], axis=2)  # the highest point inside
    at, over = (np.take_along_axis(columns, k[..., None], axis=2)[..., 0] for k in (top, np.minimum(top + 1, columns.shape[2] - 1)))
    positions = grid.positions[up]
    heights = positions[0] + (top + (at - cubes.LEVEL) / np.maximum(at - over, 1e-12)) * (positions[1] - positions[0])
    return grid.positions[h0], grid.positions[h1], np.where(inside.any(axis=2), heights, np.nan)


# ---- a tile's surface

def tile_mesh(model, seed: int, tile, scale: float = 1.0, memory_limit: int | None = None,
              closed: tuple = (), options: WorldOptions = PLAIN, progress=None) -> tuple:
    """Tile (i, j)'s surface: (vertices (V, 3) float64 in model units
    relative to the tile's lowest corner along the horizontal axes and to
    the model's floor along up, faces (F, 3) int64). Closed at the top and
    bottom, open on the four sides it shares with its neighbours, whose
    border vertices it shares exactly, except the sides in `closed` ((axis,
    0 or 1) pairs: the low or high side along a horizontal axis), closed as
    a sample's sides are (where a block of tiles ends). Without
    options.underside, open at the bottom too: solid below the grid, so
    that no surface closes under it (and a column empty down to the floor
    ends on a floor half a grid step below, not in a hole).
    progress: as tile_occupancy's."""
    values = tile_occupancy(model, seed, tile, scale, memory_limit, options=options, progress=progress)
    tiling = world_tiling(model)
    grid = tile_grid(model, tiling, scale, options)
    pad = [[0, 0], [0, 0], [0, 0]]
    pad[tiling.up] = [1, 1]
    for axis, side in closed:
        pad[axis][side] = 1
    padded = np.pad(values, pad)
    if not options.underside:
        below = [slice(None)] * 3
        below[tiling.up] = 0
        padded[tuple(below)] = 1.0
    corners = np.stack([padded[dx:padded.shape[0] - 1 + dx, dy:padded.shape[1] - 1 + dy, dz:padded.shape[2] - 1 + dz]
                        < cubes.LEVEL for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)])
    crossing = np.argwhere(corners.any(axis=0) & ~corners.all(axis=0))
    _, vertices, faces = cubes.march(padded, crossing, 1)
    for axis in range(3):
        vertices[:, axis] -= pad[axis][0]
        intervals = values.shape[axis] - 1
        if axis == tiling.up:
            low, step = grid.positions[axis][0], grid.positions[axis][1] - grid.positions[axis][0]
            vertices[:, axis] = low + vertices[:, axis] * step
        else:
            vertices[:, axis] = vertices[:, axis] * tiling.stride[axis] / intervals  # exact at the faces: m S / m = S
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
    """Tile (i, j)'s mesh with its normals (and colours), and at lod > 0 (or
    with options.skirt) a skirt: every edge on the tile's sides extruded
    straight down to the floor of its grid, so that a neighbour of another
    level, whose border its own does not meet, shows no gap from either
    side (the finer side sees the coarser tile's skirt, the coarser side the
    finer tile's). Skirt vertices take the normal and colour of the vertex
    above. progress: as tile_occupancy's."""
    vertices, faces = tile_mesh(model, seed, tile, scale, memory_limit, options=options, progress=progress)
    normals = tile_normals(model, seed, tile, vertices, options)
    if relieved(model, options, scale) and len(vertices):
        tiling = world_tiling(model)
        border = np.any([(vertices[:, h] == 0) | (vertices[:, h] == tiling.stride[h]) for h in tiling.horizontal],
                        axis=0)
        moved = tile_relief(model, seed, tile, vertices, options)
        # The moved mesh's own normals inside; on the border, normals its neighbour gives alike.
        inside = vertex_normals(moved, faces)
        inside[border] = relief_normals(model, seed, tile, vertices[border], normals[border].astype(np.float64),
                                        0.5 / scale, options)
        vertices, normals = moved, inside.astype(np.float32)
    colours = tile_colours(model, seed, tile, vertices, options, 1 / scale) if coloured(model, options) else None
    if (options.lod or options.skirt) and len(faces):
        tiling = world_tiling(model)
        floor = tile_grid(model, tiling, scale, options).positions[tiling.up][0]
        vertices, faces, source = skirted(vertices, faces, tiling, floor)
        normals = normals[source]
        colours = None if colours is None else colours[source]
    return Surface(vertices, faces, normals, colours)


def skirted(vertices: np.ndarray, faces: np.ndarray, tiling: Tiling, floor: float) -> tuple:
    """The mesh with a skirt: each edge lying on one of the tile's four sides
    (an edge of one face only) above `floor` gets a quad hanging from it
    down to `floor`, wound as the face beside it, facing out of the tile.
    The bottom's edges (below the floor) and those climbing to it at a
    side's ends get none, nor does the edge of an overhang, whose quad would
    face into the tile (the edges above it cover the side there). Returns
    (vertices, faces, the vertex each new vertex copies: an index per vertex)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.minimum(edges[:, 0], edges[:, 1]) * len(vertices) + np.maximum(edges[:, 0], edges[:, 1])
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    open_edges = edges[counts[inverse.reshape(-1)] == 1]
    open_edges = open_edges[(vertices[open_edges, tiling.up] > floor).all(axis=1)]
    hung = []
    for axis in tiling.horizontal:
        for at, outward in ((0, -1), (tiling.stride[axis], 1)):
            side = open_edges[(vertices[open_edges, axis] == at).all(axis=1)]
            a, b = vertices[side[:, 0]], vertices[side[:, 1]]
            below = a.copy()
            below[:, tiling.up] = floor
            facing = np.cross(a - b, below - b)[:, axis]  # the quad's first triangle (b, a, a below)
            hung.append(side[facing * outward > 0])
    open_edges = np.concatenate(hung)
    used, index = np.unique(open_edges, return_inverse=True)
    hanging = vertices[used].copy()
    hanging[:, tiling.up] = floor
    base = len(vertices)
    lower = base + index.reshape(-1, 2)
    a, b = open_edges[:, 0], open_edges[:, 1]
    skirt = np.concatenate([np.stack([b, a, lower[:, 0]], axis=1), np.stack([b, lower[:, 0], lower[:, 1]], axis=1)])
    return (np.concatenate([vertices, hanging]), np.concatenate([faces, skirt]),
            np.concatenate([np.arange(base), used]))


def tile_corner(model, tile) -> tuple:
    """Tile (i, j)'s lowest corner in model units (exact integers, for any tile)."""
    i, j = check_tile(tile)
    tiling = world_tiling(model)
    corner = [0, 0, 0]
    corner[tiling.horizontal[0]], corner[tiling.horizontal[1]] = i * tiling.stride[tiling.horizontal[0]], \
        j * tiling.stride[tiling.horizontal[1]]
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
    """A block of tiles (a rectangle of them, all at the request's `lod`) as
    one trimesh mesh in the request's frame ('input' or 'model': placed in
    the world), shared border vertices welded and the block's outer sides
    closed: one closed surface.
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
    if options.skirt or not options.underside:
        name, what = ("skirt", "`skirt`") if options.skirt else ("underside", "a tile open underneath (`underside` off)")
        raise InputError(f"a block is one closed surface, its tiles of one level: {what} is for a streamed view", name)
    h0, h1 = world_tiling(model).horizontal
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
