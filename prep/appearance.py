"""The example's appearance at its own detail, for colour and relief by
correspondence: small tiles of every surface voxel of the finest level.

A coloured model's sample takes its colour from the example
(runtime/appearance.py): each point of a sample is matched to a point of
the example and takes the colour the example's surface has there, at the
example's own resolution whatever the voxel grid. The tiles hold that colour.

A surface voxel has one tile per axis direction that some face through it
looks along (a floor: +z; the corner of a wall: two or three). A tile is a
T x T image across the voxel, seen along its axis: each texel casts a ray
along the axis through its centre and holds the colour of the facing
surface it meets inside the voxel (the texture looked up at that exact
point, or the vertex colours interpolated there), and the depth where it
met it. So a tile keeps a mortar line one texel wide, and a point near the
surface reads the colour of the surface beside it along the axis. T follows
the texture's own density: a power of two from 2 to MAX_TILE, at least
twice its texels across a voxel, halved while all the tiles would exceed
MAX_TILE_BYTES.

A geometry-only example's tiles hold the depth alone (relief_surface): its
samples take the example's relief finer than a voxel the same way, and T
follows how finely its faces are cut.

numpy, scipy and Pillow only (no torch).
"""

import math
from dataclasses import dataclass

import numpy as np

from sinshape.core.budget import check_memory
from sinshape.core.manifest import DEPTH_RANGE, DISTANCE_STEP

from . import colour as colours
from .voxelize import scene_parts

MAX_TILE = 64
MAX_TILE_BYTES = 48 << 20  # tiles above this get coarser (halved sides) until they fit
FACING = 0.2  # a tile along axis a, side s, shows the faces whose normal has s * n_a above this
REACH = 1.5  # a ray that meets no surface inside its voxel takes the nearest it meets this far out
REFERENCE_BLUR = 0.5  # voxels: the trainer's default blur of its targets (trainer/config.py, blur_sigma)


@dataclass(frozen=True)
class Tiles:
    """An example's surface colour as tiles (see the module's docstring)."""

    voxels: np.ndarray  # (N, 3) int32: the finest-level voxel each tile belongs to, sorted
    directions: np.ndarray  # (N,) uint8: 2 * axis + (1 if it looks from + else 0)
    images: np.ndarray  # (N, T, T, 4) uint8: sRGB, and the surface's depth (0..255 for -0.5..0.5 voxel); or depth alone (N, T, T, 1)
    distance: np.ndarray  # (X, Y, Z) int8: signed distance to the surface at voxel centres, DISTANCE_STEP a unit


@dataclass(frozen=True)
class Surface:
    """A scene's triangles (input frame) and the colour at any point of them (None: geometry only)."""

    triangles: np.ndarray  # (F, 3, 3) float64
    colour: object  # (face (n,), weights (n, 3)) -> (n, 3) sRGB float32, or None
    density: float  # colour samples (texels or vertices) per unit of length, typical


def coloured_surface(scene, path) -> Surface | None:
    """A read scene's triangles, their colour and its density; None when
    nothing has colour (colour.painted_parts' rules for mixed scenes)."""
    paint = colours.surface_painter(scene, path)
    if paint is None:
        return None
    parts = scene_parts(scene)
    triangles = np.concatenate([vertices[faces] for _, vertices, faces, _ in parts])
    areas = [triangle_areas(vertices[faces]).sum() for _, vertices, faces, _ in parts]
    densities = [samples_per_length(geometry, vertices) for _, vertices, _, geometry in parts]
    return Surface(triangles, paint, float(np.average(densities, weights=np.maximum(areas, 1e-30))))


def relief_surface(scene) -> Surface:
    """A read scene's triangles without colour, for depth tiles. Their
    density is how finely its shape varies: per unit of length, one over
    its faces' shortest edges (the median by area: a ridge's long thin faces
    count across the ridge, slivers hardly at all)."""
    parts = scene_parts(scene)
    triangles = np.concatenate([vertices[faces] for _, vertices, faces, _ in parts])
    edges = np.stack([np.linalg.norm(triangles[:, a] - triangles[:, b], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    finest = 1 / np.maximum(edges.min(axis=0), 1e-30)
    order = np.argsort(finest)
    areas = np.cumsum(triangle_areas(triangles)[order])
    density = float(finest[order][np.searchsorted(areas, areas[-1] / 2)]) if areas[-1] > 0 else 0.0
    return Surface(triangles, None, density)


def triangle_areas(triangles: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)


def samples_per_length(geometry, vertices: np.ndarray) -> float:
    """How finely a geometry's colour varies, per unit of length: for a
    texture, texels per unit along each face's most detailed edge (its
    pixels over the edge's length), averaged by area; else vertex colours
    per unit of length."""
    triangles = vertices[geometry.faces]
    areas = triangle_areas(triangles)
    if areas.sum() <= 0:
        return 0.0
    visual = geometry.visual
    image = None
    if getattr(visual, "kind", None) == "texture" and getattr(visual, "uv", None) is not None:
        image = getattr(visual.material, "baseColorTexture", None)
        image = getattr(visual.material, "image", None) if image is None else image
    if image is not None:
        uv = np.asarray(visual.uv, np.float64)[geometry.faces] * np.array(image.size)  # in pixels
        edges = [(1, 0), (2, 1), (0, 2)]
        texels = np.stack([np.linalg.norm(uv[:, a] - uv[:, b], axis=1) for a, b in edges], axis=1)
        lengths = np.stack([np.linalg.norm(triangles[:, a] - triangles[:, b], axis=1) for a, b in edges], axis=1)
        ratio = np.max(texels / np.maximum(lengths, 1e-30), axis=1)
        return float(np.average(ratio, weights=np.maximum(areas, 1e-30)))
    if getattr(visual, "kind", None) == "vertex":
        return math.sqrt(len(vertices) / areas.sum())
    return math.sqrt(len(geometry.faces) / areas.sum())


def example_tiles(surface: Surface, box_low, spacing, solid: np.ndarray, max_bytes: int = MAX_TILE_BYTES) -> Tiles:
    """The tiles (4 channels, or a colourless surface's 1) of every voxel of
    the finest level `solid` (X, Y, Z) bool (the training grid) the surface
    passes through (voxel (i, j, k) centred at box_low + (i +
    0.5) * spacing, input frame), and the signed distance at every voxel;
    the tiles' side is halved while they would pass `max_bytes`.

    A voxel gets one tile per axis direction that some face through it looks
    along (a floor: +z; a wall's corner: two or three). Each texel casts a ray
    along the tile's axis through its centre and takes the colour and depth
    of the nearest facing surface it meets within DEPTH_RANGE of the voxel's
    centre; texels whose ray meets none take their nearest neighbour's."""
    box_low, spacing, shape = np.asarray(box_low, np.float64), np.asarray(spacing, np.float64), solid.shape
    triangles = (surface.triangles - box_low) / spacing - 0.5  # model units: voxel centres at integers
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    voxel, face = voxel_faces(triangles, shape)
    side = tile_side(surface.density, spacing)
    pairs = []
    for axis in range(3):
        for positive in (False, True):
            facing = normals[face, axis] * (1 if positive else -1) > FACING
            pairs.append((axis, positive, voxel[facing], face[facing]))
    # Each (voxel, direction) with a facing face is a tile; a voxel's tiles are kept together.
    keys = np.concatenate([key_of(v, shape) * 6 + 2 * a + p for a, p, v, _ in pairs])
    unique = np.unique(keys)
    channels = 1 if surface.colour is None else 4
    while len(unique) * side * side * channels > max_bytes and side > 2:
        side //= 2
    check_memory(len(unique) * side * side * 120, f"the tiles of {len(unique)} surface directions")
    images = np.zeros((len(unique), side, side, channels), np.uint8)
    hit_any = np.zeros(len(unique), bool)
    offsets = -0.5 + (np.arange(side) + 0.5) / side
    for axis, positive, v, f in pairs:
        tile = np.searchsorted(unique, key_of(v, shape) * 6 + 2 * axis + positive)
        colour, depth, hit, own = cast(surface, triangles, v, f, tile, len(unique), axis, offsets)
        mine = np.unique(tile)
        if channels == 4:
            images[mine, ..., :3] = np.round(colour[mine] * 255)
        # Depth in 1..254 where the ray met the surface inside the voxel; 0 and 255 say it lies beyond.
        level = np.round((np.clip(depth[mine], -DEPTH_RANGE, DEPTH_RANGE) / DEPTH_RANGE + 1) * 127.5)
        images[mine, ..., -1] = np.where(own[mine], np.clip(level, 1, 254), level)
        images[mine] = fill_misses(images[mine], hit[mine])
        hit_any[mine] = own[mine].any(axis=(1, 2))  # a tile shows a surface inside its voxel
    kept = unique[hit_any]
    direction = (kept % 6).astype(np.uint8)
    flat = kept // 6
    voxels = np.stack([flat // (shape[1] * shape[2]), flat // shape[2] % shape[1], flat % shape[2]], axis=1)
    return Tiles(voxels.astype(np.int32), direction, images[hit_any], signed_distance(solid))


def signed_distance(solid: np.ndarray) -> np.ndarray:
    """The signed distance from each voxel centre to the surface a model can
    learn of the example: the 0.5 level of the training grid `solid`
    blurred as the trainer blurs its targets (REFERENCE_BLUR voxels), which
    has the voxels' shape but neither their staircase on a slope nor
    anything finer (beyond the grid is outside). A sample's surface is one
    of these; relief moves it from there onto the tiles' surface at full
    detail. The level's own surface (marching cubes of the blurred grid,
    padded with outside), 64 samples per voxel face of area, the nearest
    found from each centre; negative where the blurred grid is above 0.5,
    clamped to +-2 voxels: (X, Y, Z) int8 in DISTANCE_STEPs."""
    from scipy import ndimage
    from scipy.spatial import cKDTree
    from skimage import measure

    pad = 3
    blurred = ndimage.gaussian_filter(np.pad(solid, pad).astype(np.float64), REFERENCE_BLUR, mode="constant")
    distance = np.full(solid.shape, 2.0)
    if blurred.max() > 0.5:
        vertices, faces, _, _ = measure.marching_cubes(blurred, 0.5)
        triangles = vertices[faces] - pad
        face, weights = colours.sample_faces(triangles, 64.0, np.random.default_rng(1))
        tree = cKDTree(np.einsum("nk,nkc->nc", weights, triangles[face]))
        centres = np.argwhere(np.ones(solid.shape, bool)).astype(np.float64)
        found, _ = tree.query(centres, distance_upper_bound=3.0, workers=-1)
        distance = np.minimum(found, 2.0).reshape(solid.shape)
    inside = blurred[(slice(pad, -pad),) * 3] > 0.5
    distance[inside] *= -1
    return np.round(distance / DISTANCE_STEP).astype(np.int8)


def key_of(voxels: np.ndarray, shape) -> np.ndarray:
    return (voxels[:, 0] * shape[1] + voxels[:, 1]) * shape[2] + voxels[:, 2]


def voxel_faces(triangles: np.ndarray, shape) -> tuple:
    """Every (surface voxel, face) pair: the faces whose bounding box meets
    the voxel's cube grown by REACH, for the voxels a face passes
    through (its samples land in). ((n, 3) int64, (n,) int64)."""
    rng = np.random.default_rng(0)
    face, weights = colours.sample_faces(triangles, 16.0, rng)  # 16 samples per voxel face of area
    points = np.einsum("nk,nkc->nc", weights, triangles[face])
    voxel = np.floor(points + 0.5).astype(np.int64)  # the runtime's rounding: halves up
    surface = np.unique(np.clip(voxel, 0, np.array(shape) - 1), axis=0)
    low = np.floor(triangles.min(axis=1) - REACH + 0.5).astype(np.int64)
    high = np.ceil(triangles.max(axis=1) + REACH - 0.5).astype(np.int64)
    low, high = np.maximum(low, 0), np.minimum(high, np.array(shape) - 1)
    lookup = np.full(shape, -1, np.int64)
    lookup[tuple(surface.T)] = np.arange(len(surface))
    voxels, faces = [], []
    counts = np.prod(np.maximum(high - low + 1, 0), axis=1)
    for f in np.flatnonzero(counts):
        box = lookup[low[f, 0]:high[f, 0] + 1, low[f, 1]:high[f, 1] + 1, low[f, 2]:high[f, 2] + 1]
        found = box[box >= 0]
        voxels.append(found)
        faces.append(np.full(len(found), f))
    index = np.concatenate(voxels) if voxels else np.zeros(0, np.int64)
    return surface[index], (np.concatenate(faces) if faces else np.zeros(0, np.int64))


def cast(surface: Surface, triangles, voxels, faces, tile, count: int, axis: int, offsets) -> tuple:
    """Rays along `axis` through every texel of the tiles `tile` (one per
    (voxel, face) pair): the colour and depth of the nearest hit inside the
    voxel, or failing that within REACH, per tile texel; which texels were
    hit at all, and which inside the voxel. ((count, T, T, 3), (count, T, T),
    (count, T, T) bool, (count, T, T) bool); colour None for a colourless surface."""
    side = len(offsets)
    b, c = [k for k in range(3) if k != axis]
    depth = np.full((count, side, side), np.inf)
    rank = np.full((count, side, side), np.inf)  # the hit's distance, those outside the voxel after those in it
    best_face = np.zeros((count, side, side), np.int64)
    best_weights = np.zeros((count, side, side, 3))
    chunk = max(1, (1 << 20) // (side * side))
    for start in range(0, len(faces), chunk):
        v, f, t = voxels[start:start + chunk], faces[start:start + chunk], tile[start:start + chunk]
        tri = triangles[f] - v[:, None, :]  # relative to the voxel's centre
        pu = offsets[None, :, None]  # texel rows along b, columns along c
        pv = offsets[None, None, :]
        a2, b2, c2 = (tri[:, k, [b, c]] for k in range(3))
        d = (b2[:, 1] - c2[:, 1]) * (a2[:, 0] - c2[:, 0]) + (c2[:, 0] - b2[:, 0]) * (a2[:, 1] - c2[:, 1])
        ok = np.abs(d) > 1e-12
        d = np.where(ok, d, 1.0)[:, None, None]
        w0 = ((b2[:, 1] - c2[:, 1])[:, None, None] * (pu - c2[:, 0, None, None])
              + (c2[:, 0] - b2[:, 0])[:, None, None] * (pv - c2[:, 1, None, None])) / d
        w1 = ((c2[:, 1] - a2[:, 1])[:, None, None] * (pu - c2[:, 0, None, None])
              + (a2[:, 0] - c2[:, 0])[:, None, None] * (pv - c2[:, 1, None, None])) / d
        w2 = 1 - w0 - w1
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9) & ok[:, None, None]
        z = w0 * tri[:, 0, axis, None, None] + w1 * tri[:, 1, axis, None, None] + w2 * tri[:, 2, axis, None, None]
        inside &= np.abs(z) <= REACH
        pair, row, column = np.nonzero(inside)
        if not len(pair):  # faces smaller than a texel, between the rays: none hit
            continue
        key = (t[pair] * side + row) * side + column
        distance = np.abs(z[pair, row, column])
        distance[distance > DEPTH_RANGE + 1e-9] += 2 * REACH  # a hit inside the voxel first
        order = np.lexsort((distance, key))  # per texel, the nearest hit first
        first = order[np.r_[True, key[order][1:] != key[order][:-1]]]
        key, pair, row, column = key[first], pair[first], row[first], column[first]
        flat_rank = rank.reshape(-1)
        take = distance[first] < flat_rank[key]
        key, pair, row, column = key[take], pair[take], row[take], column[take]
        flat_rank[key] = distance[first][take]
        depth.reshape(-1)[key] = z[pair, row, column]
        best_face.reshape(-1)[key] = f[pair]
        best_weights.reshape(-1, 3)[key] = np.stack([w0[pair, row, column], w1[pair, row, column],
                                                     w2[pair, row, column]], axis=1)
    hit = np.isfinite(depth)
    colour = None
    if surface.colour is not None:
        colour = np.zeros((count, side, side, 3), np.float32)
        colour[hit] = surface.colour(best_face[hit], best_weights[hit])
    return colour, np.where(hit, depth, 0.0), hit, rank <= DEPTH_RANGE + 1e-9


def fill_misses(images: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Texels no ray hit take the values of their nearest hit texel in the
    same tile: the surface ends inside the tile there. (One distance
    transform over all tiles; the tile axis is weighted so that no texel
    reaches into another tile.)"""
    from scipy.ndimage import distance_transform_edt

    if hit.all() or not hit.any():
        return images
    _, nearest = distance_transform_edt(~hit, sampling=(1e6, 1, 1), return_indices=True)
    return images[nearest[0], nearest[1], nearest[2]]


def tile_side(density: float, spacing) -> int:
    """Texels per tile side: a power of two at least twice the surface's
    colour samples across one voxel (a tile resamples the texture: at one
    texel per texel, a texel's colour would spread over two)."""
    wanted = 2 * density * float(np.min(spacing))
    return int(min(MAX_TILE, max(2, 2 ** math.ceil(math.log2(max(wanted, 1))))))
