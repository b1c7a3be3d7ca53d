"""Bake a sample's full-resolution surface into one level of detail's texture
maps: for every texel of the level's atlas, the point of the full surface it
stands for, the surface's normal there (a tangent-space normal map), a
coloured model's colour there (a base-colour map) and, if asked, how open
the surface is around it (ambient occlusion).

The full-resolution surface is the model's own: the 0.5 level set of its
occupancy field (`Field`), which every mesh of the sample (at any --scale)
samples. Baking from the field rather than from the dense mesh needs no ray
casting against a million triangles, gives the same maps whatever scale the
dense mesh was cut at, and its gradient is the surface's normal at any point.

Where a texel's surface point is: the level's triangles are cut into a
lattice of points about LATTICE voxels apart (and never much coarser than a
texel); from each, along the level's interpolated normal, the field's 0.5
crossing nearest the level's surface is found (bracketed, then refined by
regula falsi) and, unless the example's relief gives the normal, the
field's gradient there taken (central differences: six queries a point).
The model's detail is a voxel's (its planes are bilinear within one), so a
texel's surface point and normal are interpolated from its lattice triangle;
its colour is then asked of the model at that point, texel by texel, so that
colour detail finer than a voxel (a texture) is kept.

A model carrying its example's relief (detail finer than a voxel: bricks
standing out of their mortar) moves each texel's point onto the example's
surface, texel by texel, and the normal map takes the normal of the moved
surface: the cross product of the moved points' differences to the texels
beside it in the map (those of the same chart), so that the relief shades
on any level, however few its triangles; the field's gradient is not
needed then (the side the surface faces is the bracket's), and its lattice
is RELIEF_LATTICE voxels apart. Its colour is read at the moved point, as
a sample's vertices are.
"""

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .raster import cross as flat_cross, rasterise

LATTICE = 0.75  # voxels between lattice points: the model's detail is a voxel's
# ... where the example's relief gives each texel its point and normal, the
# lattice gives only the points it moves from: the tower's asset at 1 voxel
# drew as close to its dense mesh as at 0.75 (within 0.01 points of
# brightness), its bake 0.7 s faster; at 1.5, 0.1 points further.
RELIEF_LATTICE = 1.0
MAX_SPLIT = 64  # lattice intervals along a level's triangle side, at most
BRACKET = 7  # field samples along a lattice point's ray before refining
REFINE = 2  # regula falsi steps inside the bracket
GRADIENT_STEP = 0.25  # voxels either side of a point its gradient is taken over
CHUNK = 1 << 14  # points asked of the model at once: 1.6x faster than 1 << 16 (cache-sized temporaries)
# Ambient occlusion: directions around the normal, and the distances (voxels)
# at which each looks for solid.
AO_DIRECTIONS = 12
AO_REACH = (0.75, 1.5, 3.0, 6.0)
# A ray is blocked by degrees, as the occupancy it meets rises from the
# first to the second (not at once where it passes 0.5): occlusion in
# shades, not in AO_DIRECTIONS + 1 bands. From 0.2 the rays grazing the
# surface read its own voxel-wide kinks, which drew faint lines a voxel
# apart on the terrain's map; up to 0.9 a lightly trained model's solid,
# which does not reach it, hardly occluded.
AO_BLOCKED = (0.4, 0.7)


@dataclass(frozen=True)
class Field:
    """A sample's surface as the model defines it, in model coordinates:
    occupancy (n, 3) -> (n,) float32 in [0, 1]; for a coloured model
    colour (n, 3) -> (n, 3) uint8 sRGB (None for geometry only); for a model
    carrying its example's relief, relief (n, 3) -> (n, 3): points of the
    field's surface moved onto the example's surface at full detail
    (colour.SampleSurface.relief; None without)."""

    occupancy: Callable
    colour: Callable | None
    relief: Callable | None = None


@dataclass(frozen=True)
class Frame:
    """The affine map from model coordinates to the asset's: p = offset + v * scale."""

    offset: np.ndarray  # (3,)
    scale: np.ndarray  # (3,)

    def to_model(self, points: np.ndarray) -> np.ndarray:
        return (points - self.offset) / self.scale

    def from_model(self, points: np.ndarray) -> np.ndarray:
        return self.offset + points * self.scale

    def normals_out(self, normals: np.ndarray) -> np.ndarray:
        """Model-frame normals as the asset frame's (the inverse transpose), unit."""
        return unit(normals / self.scale)


@dataclass
class Maps:
    """One level's baked maps, (size, size, channels) uint8 each; colour None
    for a geometry-only model, occlusion None unless asked for."""

    normal: np.ndarray
    colour: np.ndarray | None
    occlusion: np.ndarray | None
    found: float  # the share of lattice points whose ray met the surface


def unit(v: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(length > 0, length, 1)


def in_chunks(function, points: np.ndarray, threads: int) -> np.ndarray:
    """function over (n, 3) points, CHUNK at a time on `threads` threads (numpy
    lets go of the interpreter in the work); the same result for any count."""
    parts = [points[start:start + CHUNK] for start in range(0, len(points), CHUNK)]
    if not parts:
        return function(points)
    if threads > 1 and len(parts) > 1:
        return np.concatenate(list(bakers(threads).map(function, parts)))
    return np.concatenate([function(part) for part in parts])


@functools.lru_cache(maxsize=None)
def bakers(threads: int) -> ThreadPoolExecutor:
    """The `threads` threads every bake's chunks share, made once per count:
    a pool per call started 28 threads for a tower's asset at scale 1, 0.08
    s of it. (The functions run on it never run in_chunks themselves, so no
    chunk waits on another queued behind it.)"""
    return ThreadPoolExecutor(threads, thread_name_prefix="sinshape-bake")


def rasterise_uv(uvs: np.ndarray, faces: np.ndarray, size: int) -> tuple:
    """Which face covers each texel's centre, and where: (texel indices (k,)
    into the flat size x size image, faces (k,), barycentric weights (k, 3)
    float32). uvs (V, 2) in [0, 1], glTF's: u right, v down the image."""
    owner, _, found = rasterise(uvs[faces] * size, np.zeros(faces.shape), (size, size), weights=True)
    texels = np.flatnonzero(owner.ravel() >= 0)
    w12 = np.clip(found.reshape(-1, 2)[texels], 0, 1)
    weights = np.concatenate([np.clip(1 - w12.sum(axis=1, keepdims=True), 0, 1), w12], axis=1)
    return texels, owner.ravel()[texels], weights / weights.sum(axis=1, keepdims=True)


@dataclass
class Lattice:
    """Points on a level's triangles, about LATTICE voxels apart, and the
    small triangles between them: triangle t is cut `split` times along each
    side; its points (i, j), i + j <= split, weigh its corners (1 - i/s -
    j/s, i/s, j/s)."""

    face: np.ndarray  # (P,) the level's triangle of each point
    weights: np.ndarray  # (P, 3) the point's weights of that triangle's corners
    triangles: np.ndarray  # (T, 3) points

    @classmethod
    def of(cls, corners: np.ndarray, voxel: float, texel: float, spacing: float = LATTICE) -> "Lattice":
        """corners (F, 3, 3) in the asset frame; voxel: a voxel's size there;
        texel: a texel's size there, about; spacing: voxels between points."""
        side = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
        split = np.clip(np.ceil(side / max(spacing * voxel, texel)), 1, MAX_SPLIT).astype(np.int64)
        faces, weights, triangles, count = [], [], [], 0
        for s in np.unique(split):
            where = np.flatnonzero(split == s)
            i, j = (a.ravel() for a in np.meshgrid(np.arange(s + 1), np.arange(s + 1), indexing="ij"))
            i, j = i[i + j <= s], j[i + j <= s]
            number = np.full((s + 2, s + 2), -1)
            number[i, j] = np.arange(len(i))
            low = (i + j <= s - 1)
            high = (i + j <= s - 2)
            local = np.concatenate([
                np.stack([number[i[low], j[low]], number[i[low] + 1, j[low]], number[i[low], j[low] + 1]], 1),
                np.stack([number[i[high] + 1, j[high]], number[i[high] + 1, j[high] + 1],
                          number[i[high], j[high] + 1]], 1)])
            firsts = count + np.arange(len(where))[:, None] * len(i)
            faces.append(np.repeat(where, len(i)))
            weights.append(np.tile(np.stack([1 - (i + j) / s, i / s, j / s], axis=1), (len(where), 1)))
            triangles.append((firsts[:, :, None] + local[None]).reshape(-1, 3))
            count += len(where) * len(i)
        return cls(np.concatenate(faces), np.concatenate(weights), np.concatenate(triangles))


def surface_points(field: Field, frame: Frame, starts: np.ndarray, rays: np.ndarray, near: float, reach: float,
                   threads: int) -> tuple:
    """Where each ray (asset frame: starts (n, 3), unit directions (n, 3))
    crosses the field's 0.5 level within `reach` either side of its start,
    the crossing nearest the start: (points (n, 3), found (n,) bool,
    outward (n,): +1 where the ray leaves the solid there, -1 where it
    enters it, the side the surface faces). A ray that meets no crossing
    keeps its start (and +1).

    Most starts lie within a voxel of the surface: the first bracket is
    `near` either side; only the rays it misses are sampled along their
    whole reach (BRACKET points). Then REFINE steps of regula falsi."""
    def occupancy(points):
        return in_chunks(field.occupancy, frame.to_model(points), threads).astype(np.float64) - 0.5

    n = len(starts)
    low, high = np.zeros(n), np.zeros(n)
    f_low, f_high = np.zeros(n), np.zeros(n)
    found = np.zeros(n, bool)
    near = min(near, reach)
    for steps, rows in ((np.array([-near, 0.0, near]), np.arange(n)), (np.linspace(-reach, reach, BRACKET), None)):
        rows = np.flatnonzero(~found) if rows is None else rows
        if not len(rows):
            break
        values = np.stack([occupancy(starts[rows] + t * rays[rows]) for t in steps], axis=1)
        change = np.sign(values[:, :-1]) != np.sign(values[:, 1:])
        nearest = np.argmin(np.where(change, np.abs((steps[:-1] + steps[1:]) / 2), np.inf), axis=1)
        hit = change.any(axis=1)
        rows, nearest, values = rows[hit], nearest[hit], values[hit]
        low[rows], high[rows] = steps[nearest], steps[nearest + 1]
        f_low[rows], f_high[rows] = values[np.arange(len(rows)), nearest], values[np.arange(len(rows)), nearest + 1]
        found[rows] = True
    rows = np.flatnonzero(found)
    low, high, f_low, f_high = low[rows], high[rows], f_low[rows], f_high[rows]

    def secant():
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(f_high != f_low, low - f_low * (high - low) / (f_high - f_low), (low + high) / 2)
        return np.clip(np.nan_to_num(t), np.minimum(low, high), np.maximum(low, high))

    for _ in range(REFINE):
        t = secant()
        value = occupancy(starts[rows] + t[:, None] * rays[rows])
        below = np.sign(value) == np.sign(f_low)
        low, f_low = np.where(below, t, low), np.where(below, value, f_low)
        high, f_high = np.where(below, high, t), np.where(below, f_high, value)
    points = starts.copy()
    points[rows] += secant()[:, None] * rays[rows]
    outward = np.ones(n)
    outward[rows] = np.where(f_low > 0, 1.0, -1.0)  # solid (above 0.5) before the crossing: the ray leaves it
    return points, found, outward


def field_normals(field: Field, frame: Frame, points: np.ndarray, threads: int) -> np.ndarray:
    """The surface's outward unit normal at points (asset frame): minus the
    field's gradient by central differences GRADIENT_STEP voxels either side
    (symmetric, so the field's curvature cancels; a tetrahedron's four
    points, tried, leave it in: 4 degrees off on a bumpy ball), in the asset
    frame. (0, 0, 0) where the field is flat."""
    model = frame.to_model(points)
    gradient = np.empty_like(model)
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = GRADIENT_STEP
        gradient[:, axis] = in_chunks(field.occupancy, model + step, threads) - in_chunks(field.occupancy, model - step,
                                                                                         threads)
    return frame.normals_out(-gradient)


def occlusion(field: Field, frame: Frame, points: np.ndarray, normals: np.ndarray, voxel: float,
              threads: int) -> np.ndarray:
    """How open the surface is around each point: the share of AO_DIRECTIONS
    rays over the normal's hemisphere (cosine-weighted) that meet no solid
    within AO_REACH voxels, each ray blocked by degrees (AO_BLOCKED).
    (n,) in [0, 1]."""
    # A fixed spiral of directions about +z, cosine-distributed, turned onto each normal.
    k = np.arange(AO_DIRECTIONS) + 0.5
    radius, angle = np.sqrt(k / AO_DIRECTIONS), k * np.pi * (3 - np.sqrt(5))
    local = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.sqrt(1 - radius ** 2)], axis=1)
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    tangent = unit(np.cross(helper, normals))
    bitangent = np.cross(normals, tangent)
    low, high = AO_BLOCKED
    open_ = np.zeros(len(points))
    for direction in local:
        ray = direction[0] * tangent + direction[1] * bitangent + direction[2] * normals
        met = np.zeros(len(points))  # the most occupancy the ray meets
        for reach in AO_REACH:
            probe = frame.to_model(points + ray * (reach * voxel))
            met = np.maximum(met, in_chunks(field.occupancy, probe, threads))
        open_ += 1 - np.clip((met - low) / (high - low), 0, 1)
    return open_ / AO_DIRECTIONS


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-vertex unit normals: the area-weighted mean of their faces'. A
    vertex whose faces have no area (or cancel) takes the mean of the
    normals of the vertices it shares a face with, spread until every vertex
    has one (a lone one: +z), so that every normal is of unit length, as
    glTF requires."""
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    face_normals = np.cross(p1 - p0, p2 - p0)  # length: twice the area
    normals = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    normals = unit(normals)
    flat = np.linalg.norm(normals, axis=1) < 0.5
    while flat.any():
        spread = np.zeros_like(normals)
        for k in range(3):
            for other in ((k + 1) % 3, (k + 2) % 3):
                np.add.at(spread, faces[:, k], normals[faces[:, other]])
        filled = flat & (np.linalg.norm(spread, axis=1) > 0)
        if not filled.any():
            normals[flat] = (0.0, 0.0, 1.0)
            break
        normals[filled] = unit(spread[filled])
        flat &= ~filled
    return normals


def vertex_tangents(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """glTF tangents (V, 4) of a mesh with UVs and unit vertex normals: xyz
    along increasing u, orthogonal to the normal; w the handedness, +1 where
    the bitangent cross(normal, tangent) runs up the image (decreasing v,
    glTF's +Y of a normal map)."""
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    t0, t1, t2 = (uvs[faces[:, k]] for k in range(3))
    e1, e2, d1, d2 = p1 - p0, p2 - p0, t1 - t0, t2 - t0
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    r = np.where(np.abs(det) > 1e-20, 1 / np.where(det == 0, 1, det), 0)[:, None]
    along_u = (e1 * d2[:, 1:] - e2 * d1[:, 1:]) * r
    along_v = (e2 * d1[:, :1] - e1 * d2[:, :1]) * r
    tangents, bitangents = np.zeros_like(vertices), np.zeros_like(vertices)
    for k in range(3):
        np.add.at(tangents, faces[:, k], along_u)
        np.add.at(bitangents, faces[:, k], along_v)
    tangents = tangents - normals * (tangents * normals).sum(axis=1, keepdims=True)
    flat = np.linalg.norm(tangents, axis=1) < 1e-12  # no UV gradient: any direction across the normal
    if flat.any():
        helper = np.where(np.abs(normals[flat, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        tangents[flat] = np.cross(helper, normals[flat])
    tangents = unit(tangents)
    w = np.where((np.cross(normals, tangents) * -bitangents).sum(axis=1) < 0, -1.0, 1.0)
    return np.concatenate([tangents, w[:, None]], axis=1)


def tangent_space(normals: np.ndarray, tangents: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """Surface normals (k, 3) in the tangent frames (tangent, bitangent, normal)
    a shader rebuilds from the interpolated vertex normals (k, 3) and
    tangents (k, 4), each normalised: the frame's coordinates of each normal,
    unit. A shader's normalize(T x + B y + N z) then gives the surface's."""
    n = unit(normals)
    t = unit(tangents[:, :3])
    b = unit(cross(n, t) * np.sign(tangents[:, 3:]))
    # Solve [t b n] c = surface by Cramer's rule, per texel.
    det = (t * cross(b, n)).sum(axis=1, keepdims=True)
    c = np.stack([(surface * cross(b, n)).sum(1), (t * cross(surface, n)).sum(1),
                  (t * cross(b, surface)).sum(1)], axis=1) / np.where(np.abs(det) > 1e-12, det, 1)
    c = np.where(np.abs(det) > 1e-12, c, [0.0, 0.0, 1.0])
    c[:, 2] = np.maximum(c[:, 2], 0)  # a normal facing away from the level is bent back to its horizon
    return unit(np.where(np.linalg.norm(c, axis=1, keepdims=True) > 0, c, [0.0, 0.0, 1.0]))


def dilate(image: np.ndarray, filled: np.ndarray, steps: int) -> tuple:
    """Grow each chart's texels `steps` texels into the empty ones around it
    (each the mean of its filled neighbours, 8-connected), so that filtering
    and mip-maps read the chart's own values at its edges; only the ring
    around the charts is touched. image (H, W, C) float32, filled (H, W)
    bool: (image, filled), changed."""
    height, width = filled.shape
    flat, known = image.reshape(height * width, -1), filled.ravel()
    shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    across = np.empty_like(filled)
    for _ in range(steps):
        # The 8-neighbourhood's any(), as a row's then a column's (separable).
        across[:] = filled
        across[:, 1:] |= filled[:, :-1]
        across[:, :-1] |= filled[:, 1:]
        near = across.copy()
        near[1:] |= across[:-1]
        near[:-1] |= across[1:]
        ring = np.flatnonzero((near & ~filled).ravel())
        if not len(ring):
            break
        y, x = np.divmod(ring, width)
        total = np.zeros((len(ring), flat.shape[1]), np.float32)
        count = np.zeros(len(ring), np.float32)
        for dy, dx in shifts:
            inside = (y + dy >= 0) & (y + dy < height) & (x + dx >= 0) & (x + dx < width)
            index = np.where(inside, (y + dy) * width + x + dx, 0)
            use = inside & known[index]
            total[use] += flat[index[use]]
            count += use
        flat[ring] = total / count[:, None]
        known[ring] = True
    return image, filled


def bake(field: Field, frame: Frame, vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
         normals: np.ndarray, tangents: np.ndarray, size: int, voxel: float, reach: float,
         padding: int, ao: bool = False, threads: int | None = None) -> Maps:
    """One level's maps: vertices (V, 3) in the asset frame, faces (F, 3),
    uvs (V, 2), its unit vertex normals (V, 3) and tangents (V, 4);
    size: texels per side; voxel: a voxel's size in the asset frame; reach:
    how far (asset frame) the full surface may lie from the level's; padding:
    texels each chart is grown by."""
    threads = threads or os.cpu_count() or 1
    corners = vertices[faces]
    texel = np.sqrt(area(corners).sum() / max(area(uvs[faces]).sum() * size * size, 1e-30))
    lattice = Lattice.of(corners, voxel, texel, LATTICE if field.relief is None else RELIEF_LATTICE)
    at, w = faces[lattice.face], lattice.weights
    starts = np.einsum("pk,pkc->pc", w, vertices[at])
    level_normals = np.einsum("pk,pkc->pc", w, normals[at])  # as a shader interpolates them
    level_tangents = np.concatenate([np.einsum("pk,pkc->pc", w, tangents[at][..., :3]), tangents[at[:, 0], 3:]], 1)
    rays = unit(level_normals)
    # The triangles around a vertex share its lattice point (a corner's one-hot weights copy the vertex and
    # its normal exactly): each distinct start and ray is searched once, its results the same for every copy.
    # On a level of small triangles, a lattice point a corner, that is a sixth of the searches.
    ray_rows = np.ascontiguousarray(np.concatenate([starts, rays], axis=1))
    _, first, copies = np.unique(ray_rows.view(np.dtype((np.void, ray_rows.strides[0]))).ravel(),
                                 return_index=True, return_inverse=True)
    copies = copies.ravel()
    searched = surface_points(field, frame, starts[first], rays[first], voxel, reach, threads)
    points, found, outward = (values[copies] for values in searched)
    named = {}  # what each texel interpolates from its lattice triangle, by name: (values (P, C), its columns)
    # The field's own normal, six queries of the model a point: the normal map's, unless the example's relief
    # gives it (from the moved texels themselves); occlusion's, if asked.
    if field.relief is None or ao:
        surface = field_normals(field, frame, searched[0], threads)
        surface = np.where(np.linalg.norm(surface, axis=1, keepdims=True) > 0, surface, rays[first])
    if field.relief is None:
        named["normal"] = tangent_space(level_normals, level_tangents, surface[copies])
    if field.colour is not None or field.relief is not None:
        named["point"] = points
    if field.relief is not None:  # the frame a texel's own normal is put in, and the side it faces
        named.update(level_normal=level_normals, level_tangent=level_tangents, outward=outward[:, None])
    if ao:
        named["occlusion"] = occlusion(field, frame, searched[0], surface, voxel, threads)[copies, None]
    columns, start = {}, 0
    for name, value in named.items():
        columns[name] = slice(start, start + value.shape[1])
        start += value.shape[1]
    values = np.concatenate(list(named.values()), axis=1).astype(np.float32)

    # Texels: each interpolates the lattice triangle it falls in, then asks for its own relief and colour.
    texels, small, weights = rasterise_uv(np.einsum("pk,pkc->pc", w, uvs[at]), lattice.triangles, size)

    def per_texel(function):
        """function(rows) (k',) -> (k', C) over all the texels' rows, CHUNK at a time on the threads."""
        return in_chunks(function, np.arange(len(texels)), threads)

    texel_values = per_texel(lambda rows: np.einsum("tk,tkc->tc", weights[rows], values[lattice.triangles[small[rows]]]))
    if field.colour is not None or field.relief is not None:
        point = texel_values[:, columns["point"]].astype(np.float64)
    if field.relief is None:
        normal = unit(texel_values[:, columns["normal"]])
    else:
        moved = frame.from_model(in_chunks(field.relief, frame.to_model(point), threads))
        neighbours = TexelNeighbours(point, texels, size, texel)

        def relief_normal(rows):
            level_normal = texel_values[rows, columns["level_normal"]].astype(np.float64)
            facing = unit(level_normal) * np.where(texel_values[rows, columns["outward"]] < 0, -1.0, 1.0)
            return tangent_space(level_normal, texel_values[rows, columns["level_tangent"]].astype(np.float64),
                                 neighbours.relief_normals(moved, facing, rows))
        normal = per_texel(relief_normal)
        point = moved
    channels = [normal * 0.5 + 0.5]
    if field.colour is not None:
        channels.append(texel_colours(field, frame, point, threads) / 255)
    if ao:
        channels.append(texel_values[:, columns["occlusion"]])
    image = np.zeros((size * size, sum(c.shape[1] for c in channels)), np.float32)
    image[texels] = np.concatenate(channels, axis=1)
    filled = np.zeros(size * size, bool)
    filled[texels] = True
    image, filled = dilate(image.reshape(size, size, -1), filled.reshape(size, size), padding)
    # Texels no chart reaches: the mean, so that the smallest mip-maps stay near the charts' values.
    image[~filled] = image[filled].mean(axis=0) if filled.any() else 0.5
    maps = np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)
    colour = maps[..., 3:6] if field.colour is not None else None
    return Maps(maps[..., :3], colour, maps[..., -1:] if ao else None, float(found.mean()) if len(found) else 1.0)


# Texels beside each other in the map belong to one chart when their points
# are at most this many texels apart on the surface (their own spacing is about one).
SAME_CHART = 3.0


class TexelNeighbours:
    """The texels beside each texel in a size x size map, along its columns
    and its rows, where they are of its chart: texels (k,) at flat map
    indices, their surface points (k, 3) (asset frame, before relief moves
    them); texel: a texel's size on the surface, about."""

    def __init__(self, points: np.ndarray, texels: np.ndarray, size: int, texel: float):
        self.points, self.texels, self.size, self.reach = points, texels, size, SAME_CHART * texel
        self.grid = np.full(size * size, -1, np.int64)
        self.grid[texels] = np.arange(len(texels))

    def beside(self, rows: np.ndarray, d_row: int, d_col: int) -> np.ndarray:
        """The texel (k',) one step (d_row, d_col) from each of texels[rows]
        if it is of the same chart (its point at most SAME_CHART texels
        away), else the texel itself."""
        r, c = np.divmod(self.texels[rows], self.size)
        r, c = r + d_row, c + d_col
        inside = (r >= 0) & (r < self.size) & (c >= 0) & (c < self.size)
        other = np.where(inside, self.grid[np.where(inside, r * self.size + c, 0)], -1)
        apart = self.points[np.maximum(other, 0)] - self.points[rows]
        near = (other >= 0) & (np.einsum("kc,kc->k", apart, apart) <= self.reach ** 2)
        return np.where(near, other, rows)

    def relief_normals(self, moved: np.ndarray, facing: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The unit normal of the surface through the texels' moved points
        (k, 3) at texels[rows]: the cross product of the moved points'
        differences along the map's columns and rows (central where both
        neighbours are of the texel's chart, else one-sided), turned to the
        side of `facing` (k', 3), unit (the level's normal turned to the side
        the surface faces), which a texel with no neighbour on either axis
        keeps. (Turned instead to the side the unmoved points' cross product
        has, the map's handedness, the tower's normal-mapped levels drew
        0.1-0.4 points further from its dense mesh.)"""
        along = [moved[self.beside(rows, d_row, d_col)] - moved[self.beside(rows, -d_row, -d_col)]
                 for d_row, d_col in ((0, 1), (1, 0))]
        normal = cross(along[0], along[1])
        normal *= np.where(np.einsum("kc,kc->k", normal, facing) < 0, -1.0, 1.0)[:, None]
        flat = np.einsum("kc,kc->k", normal, normal) < 1e-40
        normal[flat] = facing[flat]
        return unit(normal)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (k, 3) arrays: np.cross's, several times faster on long arrays."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def texel_colours(field: Field, frame: Frame, points: np.ndarray, threads: int) -> np.ndarray:
    """The model's colour at texels' surface points (asset frame): the one
    place an asset asks the model for colour. (k, 3) uint8 sRGB."""
    return in_chunks(field.colour, frame.to_model(points), threads)


def area(corners: np.ndarray) -> np.ndarray:
    """Areas of triangles (F, 3, 3) or (F, 3, 2) (numpy's cross of 2-D vectors is deprecated)."""
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    if corners.shape[-1] == 2:
        return np.abs(flat_cross(u, v)) / 2
    return np.linalg.norm(cross(u, v), axis=1) / 2
