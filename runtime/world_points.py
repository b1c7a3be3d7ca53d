"""A world's field at any points of a tile, not only at its grid's:
normals, colours and the example's relief at a tile's vertices. Each point
is read from the windows or objects of the tile it falls in (world), as
the grid is, so what two tiles read on their shared face agrees."""

import threading
from collections import OrderedDict

import numpy as np

from sinshape.core.manifest import PLANE_AXES

from .colour import RELIEF_SCALE, example_palette, nearest_in_palette, planes_colouring
from .mesh import colour_bytes
from .generate import resize_plane
from .query import bilinear, head_colour, sigmoid
from .world import (GROUND, GROUND_COLOUR, GROUND_SLOPE, NORMAL_STEP, PLAIN, WINDOWS_KEPT, ContrastSum, Tiling,
                    Window, WorldOptions, along, capped, check_tile, head_logits, hidden_width, map_heights,
                    level_in, object_factor, object_model, object_window, objects_near, planes_level, sketch, window,
                    window_sizes, window_weight, world_tiling)


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
    tiling = world_tiling(model)
    level = planes_level(model, options.lod)
    h0, h1 = tiling.horizontal
    points = np.asarray(points, np.float64).reshape(-1, 3)
    t0, t1 = (np.floor(points[:, axis] / tiling.stride[axis]).astype(np.int64) for axis in (h0, h1))
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
        local[:, h0] -= t0 * tiling.stride[h0]  # exact: a power-of-two step from an integer
        local[:, h1] -= t1 * tiling.stride[h1]
        found = [] if sources is not None else None
        logits[chosen], hidden[chosen], ground[chosen] = point_tile(model, tiling, seed, (i + t0, j + t1), local,
                                                                     level, options, found)
        if sources is not None:
            sources.extend((key, chosen[index], cells, back) for key, index, cells, back in found)
    return logits, hidden, ground


def point_tile(model, tiling: Tiling, seed: int, tile: tuple, points: np.ndarray, level: int,
               options: WorldOptions, sources: list | None = None) -> tuple:
    """point_field for points inside one tile (`sources`: as point_field's,
    with indices into `points`: the window that weighs most, the first of
    equals, or the object a point lies in)."""
    h0, h1, up = *tiling.horizontal, tiling.up
    u0, u1, z = points[:, h0], points[:, h1], points[:, up]
    rise = (np.zeros(len(points)) if options.heights is None
            else map_heights(options.heights, tiling, u0, u1, tile, outer=False))
    if options.arrange == "scatter":
        logits = (-np.float32(GROUND_SLOPE) * (z - rise - GROUND)).astype(np.float32)
        hidden = np.zeros((len(points), hidden_width(model, options)), np.float32)
        ground = np.ones(len(points), bool)
        owner, owner_cells, objects = np.full(len(points), -1), np.zeros((len(points), 3)), []
        for placed_object in objects_near(model, tiling, seed, tile, level, options):
            each, own = object_model(model, options, placed_object.model)
            inside = np.ones(len(points), bool)
            cells = np.empty((len(points), 3))
            back = np.zeros((3, 3))  # its cells' moves -> the world's voxels
            factor = placed_object.factor
            for axis, world_axis, u, low, extent, mirror in zip(placed_object.axes(own), (h0, h1), (u0, u1),
                                                                placed_object.corner, placed_object.extent,
                                                                placed_object.mirror):
                position = u - low
                inside &= (position >= 0) & (position <= extent)
                cells[:, axis] = (extent - position if mirror else position) / factor  # in its model's voxels
                back[axis, world_axis] = -factor if mirror else factor
            if not inside.any():
                continue
            found = object_window(model, options, seed, placed_object, level)[2]
            rise = (z - placed_object.height) / factor
            cells[:, own.up] = np.clip(rise, 0, own.stride[own.up])
            back[own.up, up] = factor
            cells *= np.asarray(found.cells)
            back /= np.asarray(found.cells, np.float64)[:, None]
            hid = point_hidden(found, cells[inside])
            better = np.zeros(len(points), bool)
            candidate = capped(head_logits(each.head, hid), (rise - own.stride[own.up])[inside])
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
    levels = np.clip(z - rise, 0, tiling.stride[up])
    blend = ContrastSum(model.manifest.contrast)
    i, j = tile
    heaviest, owner, owner_cells, keys = np.full(len(points), -1.0), np.zeros(len(points), np.int64), None, []
    for a in (i - 1, i):
        for b in (j - 1, j):
            weight = window_weight(u0, tiling.stride[h0], a == i) * window_weight(u1, tiling.stride[h1], b == j)
            if not weight.any():  # adds exact zeros: its planes are not needed (a point just past a face)
                continue
            found = window(model, tiling, seed, a, b, level)
            cells = np.empty((len(points), 3))
            cells[:, h0] = (u0 + (tiling.stride[h0] if a < i else 0)) * found.cells[h0]
            cells[:, h1] = (u1 + (tiling.stride[h1] if b < j else 0)) * found.cells[h1]
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
    return capped(head_logits(model.head, total), z - rise - tiling.stride[up]), total, np.zeros(len(points), bool)


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
    up[world_tiling(model).up] = 1
    normals = np.where(length > 0, -gradient / np.where(length > 0, length, 1), up)
    return normals.astype(np.float32)


def tile_colours(model, seed: int, tile, vertices: np.ndarray, options: WorldOptions = PLAIN,
                 footprint: float | None = None) -> np.ndarray:
    """A coloured model's colour at tile (i, j)'s vertices (model units from
    the tile's corner, as tile_mesh gives them): a format-5 model's, read
    from the example by correspondence in the window that weighs most there
    (a scatter world's: in the object there), each the colour around it
    (`footprint` voxels), a coarser tile's in its windows at the level it
    reads (window_colouring); a format-4 model's (and the coarsest lod's
    sketch, or any without `detail`), the colour head of the hidden vector
    there, blended as the occupancy is; a format-5 model's sketch then takes
    the example's nearest colour (colour.example_palette: its tiles' means),
    so that no hue the example lacks shows in the distance either (and
    without `detail`). A scatter world's ground is
    grey. A vertex on a face two tiles share gets the same colour from
    both. Returns (n, 4) uint8 RGBA."""
    by_correspondence = options.detail and not sketch(model, options.lod)
    level = planes_level(model, options.lod)
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
                own_level = level_in(each, model, level)
                finest = cells / np.asarray(window(each, own, seed, a, b, own_level, arrange).cells)
                within = None if footprint is None else footprint / object_factor(model, each)  # its own voxels
                rgb[index] = window_colouring(each, own, seed, a, b, arrange, own_level)(finest, within)
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
        if each.example_tiles is None or not len(index):
            continue
        surface = window_colouring(each, own, seed, a, b, arrange)
        moved[index] += (surface.relief(cells) - cells) @ back
    return moved


def relieved(model, options: WorldOptions, scale: float) -> bool:
    """Whether a tile's mesh takes its example's relief: at full detail, on
    a mesh fine enough to carry it (colour.RELIEF_SCALE), a model with relief
    tiles among the world's."""
    return (options.detail and not options.lod and scale >= RELIEF_SCALE
            and any(each.example_tiles is not None for each in (model, *options.models)))


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


# Windows' colourings kept for the next tiles, as their planes are (`window`).
_colourings = OrderedDict()  # (id(model), seed, arrange, a, b, level) -> (model, colouring)
_colourings_lock = threading.Lock()


def window_colouring(model, tiling: Tiling, seed: int, a: int, b: int, arrange: str, level: int | None = None):
    """A format-5 window's (or object's) colour at points in its finest
    cells: its own sample's colour by correspondence (colour.planes_colouring),
    matched once and kept. A window's matches follow its content only, so a
    tile and its neighbour read a window they share alike. At a `level`
    below the finest (a coarser tile's), its planes there, resized to the
    finest size and matched as the finest are: the example's colours as
    they lie on the shape the tile shows, which from afar look as the
    finer tile's do (the colour head's differ by up to 40 sRGB levels)."""
    finest = len(model.manifest.sizes) - 1
    level = finest if level is None else level
    key = (id(model), seed, arrange, a, b, level)
    with _colourings_lock:
        if key in _colourings:
            _colourings.move_to_end(key)
            return _colourings[key][1]
    size = window_sizes(model, tiling, arrange)[-1]
    planes = window(model, tiling, seed, a, b, level, arrange).planes
    if level < finest:
        planes = [np.ascontiguousarray(resize_plane(plane.transpose(2, 0, 1), [size[axis] for axis in axes])
                                       .transpose(1, 2, 0)) for plane, axes in zip(planes, PLANE_AXES)]
    made = planes_colouring(model, planes, size)
    with _colourings_lock:
        _colourings[key] = (model, made)
        while len(_colourings) > WINDOWS_KEPT:
            _colourings.popitem(last=False)
    return made


def tile_points(model, seed: int, tile, points: np.ndarray, options: WorldOptions = PLAIN) -> np.ndarray:
    """The world's occupancy at any points of tile (i, j) (model units from
    its corner along the horizontal axes, from the floor along up): (n,)
    float32, what its grid holds where a point is one of the grid's."""
    return sigmoid(point_field(model, seed, tile, points, options)[0])
