"""A sample as a game-ready asset: levels of detail simplified from its
full-resolution surface, UVs per level, and maps baked from the model onto
each level, in one glTF binary (.glb).

    sample request --make/tile_mesh--> dense mesh --simplify--> levels --unwrap--> UVs --bake--> maps --gltf--> .glb

Simplification is meshoptimizer's (the simplifier behind gltfpack; compared
with fast-simplification in docs/ASSETS.md), with a world tile's border
locked so that every level of a tile meets every level of its neighbours.
UVs are charts of the faces that face along one axis, packed by xatlas,
padded so that mip-maps do not bleed. The maps
are baked from the model itself (bake.py): the normal from its field's
gradient, or from its example's relief where the model carries it, the colour from the one function that colours a sample's
vertices (colour.colouring; a world tile's blend, world_points.tile_colours).
"""

import math
import os
import time
from dataclasses import dataclass, replace

import numpy as np
from threadpoolctl import threadpool_limits

from sinshape.core.budget import check_memory
from sinshape.core.errors import ConflictError, InputError, named
from sinshape.core.manifest import UP_AXIS

from . import bake, colour as colouring, gltf, ktx2, mesh, query, world, world_points, world_tiles
from .options import ASSET_OPTION, NAMINGS
from .raster import fragments, keep_nearest
from .request import make

MAX_LODS = 8
MIN_TRIANGLES = ASSET_OPTION["lods"].low  # the fewest a closed surface has
MIN_TEXTURE, MAX_TEXTURE = ASSET_OPTION["texture"].low, ASSET_OPTION["texture"].high
MIN_HEIGHT, MAX_HEIGHT = ASSET_OPTION["height"].low, ASSET_OPTION["height"].high  # metres: a pebble to a mountain
MAX_HULLS = ASSET_OPTION["hulls"].high  # convex hulls of one asset's collision: engines step each every frame
HULL_SOURCE = 2000  # triangles of the surface the hulls are decomposed from (CoACD's time grows with them)
# CoACD's concavity thresholds, tried in turn until its hulls keep to the count
# asked: 0.1 held every shipped model's solid as closely as 0.05 in a third of
# the time, where 0.05 left the temple 16 hulls for 8, 1.5 times its volume over.
HULL_THRESHOLDS = (0.1, 0.2, 0.4, 0.8)
STAGE, STAGE_FROM = 4, 16  # levels come through a stage of 4x the finest's triangles from a full mesh of 16x (staged)
UNSEEN_SCALE = 1 / 16  # how much smaller a side the charts of faces nobody sees are (a base: unwrap)
BASE_ANGLE = 30  # degrees from straight down within which a face at a sample's base faces the ground
FILL = 0.6  # the share of an atlas the charts are expected to cover, for their scale (the atlas is then fitted)
SIZED_TEXTURE = (16, 2048)  # the range of a map side sized to the sample (sized_texture)
BAKE_BYTES_PER_TEXEL = 160  # peak bytes per texel of one level's bake and file: 118-138 measured (tracemalloc, 1024 and 2048)


@dataclass(frozen=True)
class AssetOptions:
    """How a sample is packed as an asset.

    lods: the levels' triangle counts, finest first (each at most its
      predecessor's; those above the full mesh's triangles are capped to
      it: capped_lods);
    texture: texels per side of the finest level's maps, a power of two up
      to MAX_TEXTURE, halved level by level (level_texture); None: sized
      to the sample (sized_texture); ao: bake ambient occlusion too (an occlusion map);
    height: the asset's height in metres (glTF's unit), base to top, as the
      file's nodes scale it (None: one unit of the frame is a metre);
    collision: the triangles of a collision mesh (no maps) simplified from
      the full one, 0 for none; None: the coarsest level's own triangles,
      sharing its vertices (no bytes added);
    hulls: at most this many convex hulls of the surface (CoACD's
      decomposition), 0 for none: the collision most engines simulate
      fastest, and the only kind Unreal reads from a file;
    naming: where the collision goes (gltf.glb_bytes; every naming
      carries Godot's import hints, which Godot 3 reads: one level shown,
      the collision a static body's shapes): "gltf" (outside the scene,
      for engines that read MSFT_lod or pick meshes by name), "godot" (in
      the scene too, for Godot 4, which imports the scene alone) or
      "unreal" (the hulls `UCX_NAME_LOD0_NN` in the scene, which Unreal's
      importer makes the finest level's convex collision);
    quantise: store the vertices as 8- and 16-bit integers
      (KHR_mesh_quantization, then a required extension: Blender, three.js,
      Babylon.js and glTFast read it; Godot 3 ignores it and reads the
      integers unscaled, so it is refused with naming "godot");
    compress: quantise, and store every vertex and index view compressed by
      meshoptimizer's codecs (EXT_meshopt_compression, required too; Godot 3
      cannot read it either);
    ktx2: the maps as KTX2 files of Basis Universal (KHR_texture_basisu,
      required; made by its `basisu` encoder: ktx2.py), which a GPU keeps
      compressed; Godot 3 reads no KTX2.
    """

    lods: tuple = (20000, 5000, 1200)
    texture: int | None = ASSET_OPTION["texture"].default  # None: sized to the sample (sized_texture)
    ao: bool = ASSET_OPTION["ao"].default
    height: float | None = ASSET_OPTION["height"].default  # metres, base to top; None: a frame unit is a metre
    collision: int | None = ASSET_OPTION["collision"].default  # a collision mesh's triangles; None: the coarsest level
    hulls: int = ASSET_OPTION["hulls"].default  # convex hulls of a collision decomposition, at most
    naming: str = ASSET_OPTION["naming"].default  # how levels and collision are named: options.NAMINGS
    quantise: bool = ASSET_OPTION["quantise"].default  # vertices as integers (KHR_mesh_quantization)
    compress: bool = ASSET_OPTION["compress"].default  # quantised, and compressed (EXT_meshopt_compression)
    ktx2: bool = ASSET_OPTION["ktx2"].default  # the maps as KTX2 of Basis Universal (KHR_texture_basisu)

    def __post_init__(self):
        lods = (self.lods,) if isinstance(self.lods, int) else self.lods
        try:
            lods = tuple(lods)
        except TypeError:
            lods = ()
        if not (1 <= len(lods) <= MAX_LODS and all(isinstance(n, (int, np.integer)) and not isinstance(n, bool)
                                                    for n in lods)):
            raise InputError(f"`lods` must be 1 to {MAX_LODS} triangle counts, finest first, got {self.lods!r}",
                             "lods")
        low = [n for n in lods if n < MIN_TRIANGLES]
        if low:
            raise InputError(f"`lods` asks for {low[0]} triangles; a level needs at least {MIN_TRIANGLES}", "lods")
        if any(b >= a for a, b in zip(lods, lods[1:])):
            raise InputError(f"`lods` must fall level by level, finest first, got {','.join(map(str, lods))}", "lods")
        object.__setattr__(self, "lods", tuple(int(n) for n in lods))
        size = self.texture
        if size is not None:
            if not (isinstance(size, (int, np.integer)) and not isinstance(size, bool)
                    and MIN_TEXTURE <= size <= MAX_TEXTURE and size & (size - 1) == 0):
                raise InputError(f"`texture` must be a power of two from {MIN_TEXTURE} to {MAX_TEXTURE} texels, "
                                 f"got {size!r}", "texture")
            object.__setattr__(self, "texture", int(size))
        if self.height is not None:
            if not (isinstance(self.height, (int, float, np.number)) and not isinstance(self.height, bool)
                    and MIN_HEIGHT <= self.height <= MAX_HEIGHT):
                raise InputError(f"`height` must be metres from {MIN_HEIGHT:g} to {MAX_HEIGHT:g}, got {self.height!r}",
                                 "height")
            object.__setattr__(self, "height", float(self.height))
        if self.collision is not None:
            if not (isinstance(self.collision, (int, np.integer)) and not isinstance(self.collision, bool)
                    and (self.collision == 0 or MIN_TRIANGLES <= self.collision <= self.lods[0])):
                raise InputError(f"`collision` must be 0 (none) or {MIN_TRIANGLES} to {self.lods[0]} triangles (the "
                                 f"finest level's), got {self.collision!r}", "collision")
            object.__setattr__(self, "collision", int(self.collision))
        if not (isinstance(self.hulls, (int, np.integer)) and not isinstance(self.hulls, bool)
                and 0 <= self.hulls <= MAX_HULLS):
            raise InputError(f"`hulls` must be 0 (none) to {MAX_HULLS} convex hulls, got {self.hulls!r}", "hulls")
        object.__setattr__(self, "hulls", int(self.hulls))
        if self.naming not in NAMINGS:
            raise InputError(f"unknown `naming` {self.naming!r}; choose {', '.join(NAMINGS[:-1])} or {NAMINGS[-1]}",
                             "naming")
        if self.quantise and self.naming == "godot":
            raise ConflictError("`quantise` and `naming` godot do not go together: Godot 3 reads quantised vertices "
                                "as whole numbers, an asset 32767 times its size", ("quantise", "naming"))
        for name, extension in (("compress", "EXT_meshopt_compression"), ("ktx2", "KHR_texture_basisu")):
            if getattr(self, name) and self.naming == "godot":
                raise ConflictError(f"`{name}` and `naming` godot do not go together: Godot 3 cannot read "
                                    f"{extension}", (name, "naming"))

    def level_texture(self, k: int) -> int:
        """Level k's maps' texels per side: `texture` halved level by level
        (at least MIN_TEXTURE), as its screen coverage halves (gltf.screen_coverage):
        a level shown half as large needs half the texels a side."""
        return max(MIN_TEXTURE, self.texture >> k)


def sized_texture(dense_vertices: int) -> int:
    """The finest level's maps' side when none is asked: the least power of
    two whose square holds the full mesh's vertices, at most 2048 (SIZED_TEXTURE).
    The maps then hold a texel for each of the full mesh's vertices or
    more (its detail, relief included, is a vertex apart at its scale), and
    weigh less than it: 2-4 bytes a texel as PNG, where a vertex costs the
    full mesh's .glb about 36 (its position, normal and two triangles)."""
    low, high = SIZED_TEXTURE
    return int(min(max(low, 1 << max(0, math.ceil(math.log2(max(dense_vertices, 1)) / 2))), high))


def padding(size: int) -> int:
    """Texels between charts (and grown around each) in maps of `size`: four
    at 1024, so that mip-maps to an eighth of the size still read a chart's own."""
    return max(2, size // 256)


def parse_lods(text: str) -> tuple:
    """'20000,5000,1200' -> (20000, 5000, 1200): the command line's and the
    web API's spelling of AssetOptions.lods."""
    try:
        return tuple(int(part) for part in str(text).split(","))
    except ValueError:
        raise InputError(f"`lods` must be triangle counts like 20000,5000,1200, got {text!r}", "lods") from None


def check_asset_memory(options: AssetOptions, memory_limit: int | None = None) -> None:
    """Refuse up front a bake that needs more than memory_limit bytes."""
    size = options.texture or SIZED_TEXTURE[1]  # sized to the sample: at most the largest
    check_memory(size * size * BAKE_BYTES_PER_TEXEL, f"baking {size}x{size} maps", memory_limit)


@dataclass(frozen=True)
class Dense:
    """A sample's full-resolution surface and what the bake reads: vertices
    (V, 3) and faces (F, 3) in the asset's frame, the model's field, the
    frame's map, a voxel's size in the frame, whether borders are locked
    (a world tile's), and the up axis of a sample standing on its base
    (None for a tile, which has no base)."""

    vertices: np.ndarray
    faces: np.ndarray
    field: bake.Field
    frame: bake.Frame
    voxel: float
    lock_border: bool
    up: int | None


def surface_read(model, detail: bool) -> bool:
    """Whether a sample's maps read its surface by correspondence: its colour, or (with `detail`) its example's relief."""
    return bool(model.manifest.colour or (detail and model.example_tiles is not None))


def sample_field(model, triplane, detail: bool = True, surface=None) -> bake.Field:
    """The field of a sample (or an edit's composed tri-plane), its colour
    at full detail (a format-5 model's tiles, read at each texel's point;
    without `detail`, its colour head's) and its example's relief (a model
    with tiles, with `detail`). `surface`: colour.matching's Future, begun
    before the mesh was made (None: begun here). It is waited for at the
    first read, the bake's, so that the levels are simplified and
    unwrapped while it runs."""
    if not surface_read(model, detail):
        return bake.Field(query.occupying(model, triplane), None)
    surface = colouring.matching(model, triplane, detail) if surface is None else surface

    def colour(points):
        return mesh.colour_bytes(surface.result()(points))[:, :3]

    def relief(points):
        return surface.result().relief(points)
    return bake.Field(query.occupying(model, triplane), colour if model.manifest.colour else None,
                      relief if detail and model.example_tiles is not None else None)


def tile_field(model, seed: int, tile, options) -> bake.Field:
    """The field of world tile (i, j) (its world made as world.WorldOptions
    `options` say), in model units from its corner, its colour and its
    example's relief: empty above and below the world's heights, as its mesh is."""
    tiling = world.world_tiling(model)
    heights = world.tile_grid(model, tiling, 1.0, options).positions[tiling.up]

    def occupancy(points):
        out = world_points.tile_points(model, seed, tile, points, options)
        out[(points[:, tiling.up] < heights[0]) | (points[:, tiling.up] > heights[-1])] = 0
        return out

    def colour(points):
        return world_points.tile_colours(model, seed, tile, points, options)[:, :3]

    def relief(points):
        return world_points.tile_relief(model, seed, tile, points, options)

    return bake.Field(occupancy, colour if world.coloured(model, options) else None,
                      relief if world_points.relieved(model, options, colouring.RELIEF_SCALE) else None)


def dense_surface(model, request, threads: int | None = None, progress=None) -> Dense:
    """The full-resolution surface of a request (a sample, an edit or a
    world tile) in its frame, and the field behind it."""
    spacing = np.asarray(model.manifest.spacing, np.float64)
    if request.tile is not None:
        vertices, faces = world_tiles.tile_mesh(model, request.sample_seed, request.tile, request.scale, progress=progress,
                                          options=request.world_options())
        offset = world_tiles.placed(model, request.tile, np.zeros((1, 3)), request.frame)[0]
        scale = world_tiles.placed(model, request.tile, np.ones((1, 3)), request.frame)[0] - offset
        field, lock, up = tile_field(model, request.sample_seed, request.tile, request.world_options()), True, None
    else:
        triplane = make(model, request)
        options = request.mesh_options()
        # The matching needs only the tri-plane: begun first, it runs beside the meshing.
        matching = colouring.matching(model, triplane, request.detail) if surface_read(model, request.detail) else None
        surface = mesh.finish(mesh.band_mesh(model, triplane, request.scale, progress, threads=threads),
                              options["smooth"], options["smoother"], options["largest"])
        vertices, faces = np.asarray(surface.vertices), np.asarray(surface.faces)
        offset, scale = ((np.asarray(model.manifest.origin, np.float64), spacing) if request.frame == "input"
                         else (np.zeros(3), np.ones(3)))
        field, lock, up = sample_field(model, triplane, request.detail, matching), False, UP_AXIS[model.manifest.up]
    frame = bake.Frame(offset, scale)
    return Dense(offset + vertices * scale, np.asarray(faces, np.int64), field, frame, float(np.max(scale)), lock, up)


def simplify(vertices: np.ndarray, faces: np.ndarray, target: int, lock_border: bool) -> tuple:
    """meshoptimizer's simplification of a mesh to at most `target`
    triangles, keeping its topology (a closed surface stays closed) and, with
    lock_border, every vertex of its open border: (vertices, faces, error),
    error the largest deviation in the mesh's units. Refused if the
    simplifier cannot get down to the target."""
    import meshoptimizer  # the assets extra

    indices = np.ascontiguousarray(faces, np.uint32).ravel()
    positions = np.ascontiguousarray(vertices, np.float32)
    out = np.zeros(len(indices), np.uint32)
    error = np.zeros(1, np.float32)
    count = meshoptimizer.simplify(out, indices, positions, target_index_count=3 * target, target_error=1.0,
                                   options=meshoptimizer.SIMPLIFY_LOCK_BORDER if lock_border else 0,
                                   result_error=error)
    if count // 3 > target:
        why = " (a world tile keeps every vertex of its border)" if lock_border else ""
        raise InputError(f"`lods` asks for {target} triangles, but the surface simplifies to no fewer than "
                         f"{count // 3}{why}", "lods")
    kept = without_folds(out[:count].reshape(-1, 3).astype(np.int64))
    used = np.unique(kept)
    remap = np.zeros(len(vertices), np.int64)
    remap[used] = np.arange(len(used))
    extent = float(np.max(vertices.max(axis=0) - vertices.min(axis=0))) if len(vertices) else 0.0
    return vertices[used], remap[kept], float(error[0]) * extent


def without_folds(faces: np.ndarray) -> np.ndarray:
    """Faces (F, 3) less what the simplifier can leave that has no surface:
    a face that names a vertex twice, and faces on the same three vertices,
    of which those wound one way cancel those wound the other (a pair back
    to back, whose normals sum to zero: it drew as a black triangle) and
    copies wound alike are kept once. The faces kept stay in their order."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    corners = np.sort(faces, axis=1)
    _, group, count = np.unique(corners, axis=0, return_inverse=True, return_counts=True)
    group = group.ravel()
    shared = count[group] > 1
    if not shared.any():
        return faces
    # A face's winding against its sorted corners: turning one into the other is an even permutation or odd.
    winding = np.where(np.all(np.roll(corners, 1, axis=1) == faces, axis=1)
                       | np.all(np.roll(corners, -1, axis=1) == faces, axis=1)
                       | np.all(corners == faces, axis=1), 1, -1)
    net = np.bincount(group, winding, minlength=len(count))
    first = np.full(len(count), len(faces))
    np.minimum.at(first, group[winding == np.sign(net[group])], np.flatnonzero(winding == np.sign(net[group])))
    keep = ~shared | (np.arange(len(faces)) == first[group])
    return faces[keep]


def unwrap(vertices: np.ndarray, faces: np.ndarray, size: int, unseen: np.ndarray | None = None) -> tuple:
    """Charts by the axis each face faces, packed by xatlas: (the original
    vertex of each new vertex (V',), faces (F, 3) of new vertices, UVs (V', 2)
    in [0, 1] of a square texture of `size` texels a side, glTF's: u right, v
    down). Charts are padding(size) texels apart.

    A sample's surface is cut from a voxel grid, and most of it faces along
    an axis: each face is charted with its neighbours facing the same way
    (axis_charts) and projected along that axis, which xatlas then packs as
    given (its own charting grew charts at a cost more than linear in the
    faces: 0.63-0.72 s for the tower's 20,000, against 0.17-0.24 s with the
    check for folds; its atlases 53-60% covered against 53-64%). Where a
    chart's projection overlaps itself (the surface winding round over
    itself, or a fold the simplifier left), the faces of the overlap are
    charted one by one and the level packed again.
    unseen: a mask of faces nobody sees (a sample's base, on the ground):
    charted apart, UNSEEN_SCALE times smaller a side, their texels left to
    the rest, which the atlas's scale grows into."""
    import xatlas  # the assets extra

    unseen = np.zeros(len(faces), bool) if unseen is None else unseen
    pairs = mesh.edge_neighbours(faces)
    chart, facing = axis_charts(vertices, faces, unseen, pairs)
    # Packed at PACK_SIDE texels a side at most, then scaled to the map: padding grows with the side, so
    # the gutters come out as wide.
    pack, packed_side = xatlas.PackOptions(), min(size, PACK_SIDE)
    pack.padding, pack.bilinear = padding(packed_side), True
    area = bake.area(vertices[faces[~unseen]]).sum() + bake.area(vertices[faces[unseen]]).sum() * UNSEEN_SCALE ** 2
    pack.texels_per_unit = packed_side * math.sqrt(FILL / max(area, 1e-30))
    charts = xatlas.ChartOptions()
    charts.use_input_mesh_uvs = True
    alone, colour = np.zeros(len(faces), bool), np.zeros(len(faces), np.int64)
    for last in [False] * (FOLD_PASSES - 1) + [True]:  # again while a chart overlaps itself: each face of the fold
        # then a chart of its own (once more, as a fold finer than a texel may show at the new scale)
        source, split_faces, positions, projected = chart_vertices(vertices, faces, chart, facing, unseen, colour)
        atlas = xatlas.Atlas()
        atlas.add_mesh(np.ascontiguousarray(positions, np.float32), np.ascontiguousarray(split_faces, np.uint32),
                       None, np.ascontiguousarray(projected, np.float32))
        atlas.generate(charts, pack)
        mapping, packed_faces, uvs = atlas[0]  # the faces in their order, their vertices xatlas's
        side = np.array([atlas.width, atlas.height], np.float64)
        # xatlas gives UVs in [0, 1] of its own width and height: the atlas fills the texture's square
        # along its longer side (its padding grows or shrinks with it).
        uvs, packed_faces = uvs * side / side.max(), packed_faces.astype(np.int64)
        folded = () if last else overlapping(source[mapping], packed_faces, uvs, min(size, FOLD_SIDE))
        if not len(folded):
            return source[mapping].astype(np.int64), packed_faces, uvs
        chart[folded], alone[folded] = chart.max() + 1 + np.arange(len(folded)), True
        # Faces alone that share an edge, coloured apart: xatlas joins faces across an edge whose UVs agree.
        both = alone[pairs[0]] & alone[pairs[1]]
        colour[alone] = 1 + greedy_colours(np.flatnonzero(alone), pairs[0][both], pairs[1][both])


def chart_vertices(vertices: np.ndarray, faces: np.ndarray, chart: np.ndarray, facing: np.ndarray,
                   unseen: np.ndarray, colour: np.ndarray) -> tuple:
    """A vertex of its own in each chart, so that a chart's UVs are its own:
    (the original vertex of each (V',), faces (F, 3) of them, their
    positions (V', 3), the unseen charts' shrunk UNSEEN_SCALE times about
    their middle (xatlas scales a chart by its area), and their projections
    along the direction their chart faces (V', 2), in a band of that
    direction and the face's `colour` (F,) (0, or that of a face charted
    alone: greedy_colours), so that xatlas joins no face to a neighbour of
    another chart whose UVs agree with its own)."""
    count = int(chart.max()) + 1
    keys, split_faces = np.unique(faces * count + chart[:, None], return_inverse=True)
    source, vertex_chart = keys // count, keys % count
    positions = vertices[source]
    if unseen.any():
        low = np.isin(vertex_chart, chart[unseen])
        middle = positions[low].mean(axis=0)
        positions[low] = middle + (positions[low] - middle) * UNSEEN_SCALE
    chart_facing, chart_colour = np.zeros(count, np.int64), np.zeros(count, np.int64)
    chart_facing[chart], chart_colour[chart] = facing, colour
    band = chart_facing[vertex_chart] + len(FACINGS) * chart_colour[vertex_chart]
    return source, split_faces.reshape(-1, 3), positions, projections(positions, chart_facing[vertex_chart], band)


# Directions a chart faces (-x, +x, -y, +y, -z, +z), and the axes its u and v run along.
FACINGS = np.array([(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)], np.float64)
ACROSS_AXIS = np.array([(1, 2), (2, 0), (0, 1)])  # u x v is the axis: a positive direction keeps the winding
CHART_ROUNDS = 3  # rounds of each face taking the direction most of its neighbours face (axis_charts)
CHART_FACING = 0.5  # ... only where the face is within 60 degrees of it (a projection's stretch, 2 at most)
FOLD_PASSES = 3  # packings at most, each with the faces of the charts' folds left charted alone (unwrap)
# The side of the map folds are looked for in: at 2048 the two z-buffers took 0.7-2.2 s for a 20,000-face
# level, at 512 0.05 s; a fold smaller than its texel shares at most a few texels of a larger map.
FOLD_SIDE = 512
PACK_SIDE = 1024  # the side xatlas packs at, at most: at 2048 it took 0.4 s for a 20,000-face level, at 1024 0.1 s


def axis_charts(vertices: np.ndarray, faces: np.ndarray, unseen: np.ndarray, pairs: tuple) -> tuple:
    """Each face's chart (F,) and the direction it faces (F,) into FACINGS:
    the direction nearest its normal, then CHART_ROUNDS rounds of taking the
    one most of its edge neighbours have (its own counting half a vote
    more), so that a chart's border does not zigzag where a surface turns
    between two; charts are the parts joined by edges of faces facing alike,
    seen or unseen alike. pairs: mesh.edge_neighbours(faces)."""
    corners = vertices[faces]
    normals = bake.unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    nearness = normals @ FACINGS.T
    facing = np.argmax(nearness, axis=1)
    a, b = pairs
    rows, sides = np.arange(len(faces)), len(FACINGS)
    for _ in range(CHART_ROUNDS):  # each edge a vote for each of its faces: counted by one bincount
        votes = np.bincount(np.concatenate([a * sides + facing[b], b * sides + facing[a]]),
                            minlength=len(faces) * sides).reshape(len(faces), sides).astype(np.float64)
        votes[rows, facing] += 0.5
        votes[nearness < CHART_FACING] = -1
        facing = np.argmax(votes, axis=1)
    alike = (facing[a] == facing[b]) & (unseen[a] == unseen[b])
    chart = mesh.connected_parts(a[alike], b[alike], len(faces))
    return np.unique(chart, return_inverse=True)[1].ravel(), facing


def greedy_colours(nodes: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least colour (0, 1, ...) of each of `nodes` (n,) that none of its
    neighbours before it took, joined by the edges a[i]-b[i] (node ids):
    (n,). A face has three edge neighbours, so four colours at most."""
    row = {node: k for k, node in enumerate(nodes.tolist())}
    beside = [[] for _ in range(len(nodes))]
    for x, y in zip(a.tolist(), b.tolist()):
        beside[row[x]].append(row[y])
        beside[row[y]].append(row[x])
    colours = [-1] * len(nodes)
    for k, others in enumerate(beside):
        taken = {colours[other] for other in others}
        colours[k] = next(c for c in range(len(others) + 1) if c not in taken)
    return np.array(colours, np.int64)


def projections(points: np.ndarray, facing: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Points (n, 3) projected along the direction each faces (n,) into
    FACINGS: (n, 2), mirrored for the negative directions so that every
    chart keeps its faces' winding, and each band (n,) of them set apart
    from the others, so that no two charts of different bands meet in UV
    (xatlas joins faces across an edge whose UVs agree)."""
    uv = points[np.arange(len(points))[:, None], ACROSS_AXIS[facing // 2]]
    uv[facing % 2 == 0, 0] *= -1
    span = float(np.ptp(points)) + 1.0 if len(points) else 1.0
    return uv - uv.min(axis=0, initial=0) + (band * 1.5 * span)[:, None]


def overlapping(source: np.ndarray, faces: np.ndarray, uvs: np.ndarray, size: int) -> np.ndarray:
    """The faces (F, 3) whose texels in a size x size map another face
    covers that shares no vertex with them (source: each vertex's original):
    a chart folded over itself, as packed charts never overlap each other.
    Two z-buffers of the faces, filled from one rasterising, the lowest
    index on top and the highest, see both where two cover a texel's centre."""
    order = np.arange(len(faces), dtype=np.float64)[:, None].repeat(3, axis=1)
    low, high = np.full(size * size, -1, np.int64), np.full(size * size, -1, np.int64)
    low_depth, high_depth = np.full(size * size, -np.inf), np.full(size * size, -np.inf)
    for pixel, near, face, _, _ in fragments(uvs[faces] * size, order, (size, size)):
        keep_nearest(pixel, -near, face, low_depth, low)
        keep_nearest(pixel, near, face, high_depth, high)
    both = np.flatnonzero((low != high) & (low >= 0))
    a, b = source[faces[low[both]]], source[faces[high[both]]]
    apart = ~(a[:, :, None] == b[:, None, :]).any(axis=(1, 2))
    return np.unique(np.concatenate([low[both[apart]], high[both[apart]]]))


def on_the_ground(vertices: np.ndarray, faces: np.ndarray, up: int, reach: float) -> np.ndarray:
    """The faces of a sample's base: facing the ground (their normal within
    BASE_ANGLE of straight down) and within `reach` of its lowest point."""
    corners = vertices[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    down = -normals[:, up] > np.cos(np.radians(BASE_ANGLE)) * np.maximum(length, 1e-30)
    return down & (corners[:, :, up].max(axis=1) <= vertices[:, up].min() + reach)


def convex_hulls(vertices: np.ndarray, faces: np.ndarray, count: int) -> list:
    """At most `count` convex hulls covering a closed surface, [(vertices,
    faces), ...]: CoACD's decomposition (compared in docs/ASSETS.md) of the
    surface simplified to HULL_SOURCE triangles, fewer where the surface
    needs fewer. Its settings trade a little of its search for time (1-3 s
    a tower, against 12-70 at its defaults), and its own remeshing is off:
    a sample's surface is closed already, and remeshing a simplified one
    took a minute. Its merge can leave more hulls than asked (the temple's
    surface, 16 for 8): then it is redone at a coarser concavity threshold
    (HULL_THRESHOLDS; no shipped model needed more than the second).
    Seeded, so the same surface gives the same hulls."""
    import coacd  # the assets extra; imported after onnxruntime (the other order crashes in coacd 1.0.14)

    if len(faces) > HULL_SOURCE:
        vertices, faces, _ = simplify(vertices, faces, HULL_SOURCE, False)
    coacd.set_log_level("off")
    surface = coacd.Mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int32))
    for threshold in HULL_THRESHOLDS:
        hulls = coacd.run_coacd(surface, threshold=threshold, max_convex_hull=count, preprocess_mode="off",
                                resolution=1000, mcts_nodes=10, mcts_iterations=50, mcts_max_depth=2, seed=0)
        if len(hulls) <= count:
            break
    return [(np.asarray(v, np.float64), np.asarray(f, np.int64)) for v, f in hulls]


def staged(dense: Dense, finest: int) -> tuple:
    """What the levels are simplified from: the full mesh, or where it has
    more than STAGE_FROM times the finest level's triangles, one mesh of
    STAGE times them simplified from it: (vertices, faces, error). Each pass
    of the simplifier costs by the triangles it reads (about 0.5 s of the
    tower's 587k at scale 4), so three levels read it once, not three
    times; the stage's error adds to each level's (a hundredth of a voxel
    there). Nearer the finest level's count a stage saves little, and the
    coloured terrain's 20,000-triangle level, simplified through one from
    its 188k, took xatlas 1.5 s to chart instead of 1.0."""
    if len(dense.faces) <= STAGE_FROM * finest:
        return dense.vertices, dense.faces, 0.0
    return simplify(dense.vertices, dense.faces, STAGE * finest, dense.lock_border)


def level(dense: Dense, stage: tuple, target: int, size: int, options: AssetOptions, threads: int | None,
          timings: dict) -> tuple:
    """One level of detail of `target` triangles, simplified from `stage`
    (staged), and maps of `size`, baked: (gltf.Level, its figures)."""
    started = time.perf_counter()
    vertices, faces, error = simplify(stage[0], stage[1], target, dense.lock_border)
    error += stage[2]
    simplified = time.perf_counter()
    unseen = None if dense.up is None else on_the_ground(vertices, faces, dense.up, dense.voxel)
    source, split_faces, uvs = unwrap(vertices, faces, size, unseen)
    unwrapped = time.perf_counter()
    normals = bake.vertex_normals(vertices, faces)[source]  # smooth across UV seams
    positions = vertices[source]
    tangents = bake.vertex_tangents(positions, split_faces, uvs, normals)
    maps = bake.bake(dense.field, dense.frame, positions, split_faces, uvs, normals, tangents, size,
                     dense.voxel, reach=error + 2 * dense.voxel, padding=padding(size), ao=options.ao,
                     threads=threads)
    baked = time.perf_counter()
    for stage, seconds in (("simplify", simplified - started), ("unwrap", unwrapped - simplified),
                           ("bake", baked - unwrapped)):
        timings[stage] = timings.get(stage, 0) + seconds
    figures = {"triangles": len(split_faces), "vertices": len(positions), "texture": size, "error": round(error, 6),
               "surface_found": round(maps.found, 4), "base_faces": int(0 if unseen is None else unseen.sum())}
    return gltf.Level(positions, normals, tangents, uvs, split_faces, maps.normal, maps.colour, maps.occlusion), figures


def asset_bytes(model, request, options: AssetOptions, name: str = "sample", threads: int | None = None,
                progress=None, memory_limit: int | None = None) -> tuple:
    """The .glb of the asset of a request (a request.SampleRequest: a sample,
    an edit or a world tile) and what it holds: (bytes, info), info with the
    full mesh's and each level's counts, and the seconds of each stage.
    progress(done, total) is called as meshing goes."""
    import meshoptimizer  # noqa: F401  the assets extra, asked for before any work
    import xatlas  # noqa: F401

    check_asset_memory(options, memory_limit)
    if options.ktx2:
        ktx2.encoder()  # asked for before any work, as the extra's modules are
    if request.tile is not None and options.height is not None:
        raise InputError("`height` scales one asset; a world's tiles keep the world's frame, so that they meet",
                         "height")
    if request.tile is not None and options.hulls:
        raise InputError("`hulls` decomposes a closed surface, and a world tile is open at its sides: give "
                         "`collision` (a mesh of its triangles) instead", "hulls")
    if options.hulls:
        try:
            import coacd  # noqa: F401
        except ImportError:
            raise InputError("`hulls` needs CoACD: pip install 'sinshape[assets]'", "hulls") from None
    threads = threads or os.cpu_count() or 1
    # numpy's BLAS would start threads of its own in every product (the decoder's, the matching's), which
    # then spin beside the bake's and the matching's own (as in mesh.band_mesh): one each.
    with threadpool_limits(1, user_api="blas"):
        return made_asset(model, request, options, name, threads, progress)


def made_asset(model, request, options: AssetOptions, name: str, threads: int, progress) -> tuple:
    """asset_bytes's work, its options checked."""
    started = time.perf_counter()
    dense = dense_surface(model, request, threads, progress)
    if not len(dense.faces):
        raise InputError("the sample has no surface at this scale and size; nothing written")
    lods = capped_lods(options.lods, len(dense.faces))
    if options.texture is None:
        options = replace(options, texture=sized_texture(len(dense.vertices)))
    timings = {"sample": time.perf_counter() - started}
    stage = staged(dense, lods[0])
    timings["simplify"] = time.perf_counter() - started - timings["sample"]
    levels, figures = [], []
    for k, target in enumerate(lods):
        built, described = level(dense, stage, target, options.level_texture(k), options, threads, timings)
        levels.append(built)
        figures.append(described)
    collision = len(levels) - 1 if options.collision is None else None  # the coarsest level's own triangles
    if options.collision:  # at most the finest level's triangles, as the stage holds
        collision = simplify(stage[0], stage[1], options.collision, dense.lock_border)[:2]
    hulls = []
    if options.hulls:
        decomposed = time.perf_counter()
        hulls = convex_hulls(dense.vertices, dense.faces, options.hulls)
        timings["hulls"] = time.perf_counter() - decomposed
    written = time.perf_counter()
    extras = {"sinshape": {"seed": request.sample_seed, "tile": list(request.tile) if request.tile else None,
                           "lods": list(lods), "textures": [f["texture"] for f in figures]}}
    capped = lods != options.lods
    if capped:
        extras["sinshape"]["asked_lods"] = list(options.lods)
    place = None
    if request.tile is None:  # a tile keeps its frame, so that its neighbours meet it
        place = on_its_base(dense.vertices, UP_AXIS[model.manifest.up], options.height)
        extras["sinshape"].update(pivot="the centre of its base", height_m=round(place.height, 6))
    data = gltf.glb_bytes(levels, name, extras, model.manifest.up, place, collision, options.naming, hulls,
                          options.quantise, options.compress, options.ktx2)
    timings["write"] = time.perf_counter() - written
    info = {"dense_triangles": len(dense.faces), "dense_vertices": len(dense.vertices), "levels": figures,
            "seconds": {k: round(v, 3) for k, v in timings.items()}, "bytes": len(data)}
    if collision is not None:
        vertices, faces = (levels[collision].positions, levels[collision].faces) if isinstance(collision, int) \
            else collision
        info["collision"] = {"triangles": len(faces), "vertices": len(vertices),
                             "level": collision if isinstance(collision, int) else None}
    if hulls:
        info["hulls"] = [len(v) for v, _ in hulls]  # each hull's vertices
    if capped:
        info["capped"] = (f"`lods` {','.join(map(str, options.lods))} asked for more triangles than the "
                          f"{'tile' if request.tile is not None else 'sample'}'s full-resolution mesh has "
                          f"({len(dense.faces)}): made {','.join(map(str, lods))}")

    return data, info


def capped_lods(lods: tuple, available: int) -> tuple:
    """The levels a mesh of `available` triangles can fill: each capped to
    it, and those that then no longer fall below the one before left out
    (20000,5000,1200 of an 11,736-triangle mesh: 11736,5000,1200)."""
    out = []
    for n in lods:
        n = min(n, available)
        if not out or n < out[-1]:
            out.append(n)
    return tuple(out)


def on_its_base(vertices: np.ndarray, up: int, height: float | None) -> gltf.Placement:
    """Where an asset's nodes put it: the centre of its base (the middle of
    its bounds across, their lowest point along `up`) at the origin, scaled
    to `height` metres from base to top (None: as it is)."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    base = (low + high) / 2
    base[up] = low[up]
    tall = float(high[up] - low[up])
    scale = height / tall if height and tall > 0 else 1.0
    return gltf.Placement(base, scale, tall * scale)


def options_of(**values) -> AssetOptions | None:
    """The asset a front end's values ask for, by the names of
    options.ASSET_OPTIONS (None or False: not given, the table's default):
    None without lods (a plain sample), which the others need. lods:
    counts, or their text."""
    unknown = sorted(set(values) - set(ASSET_OPTION))
    if unknown:
        raise InputError(f"an asset has no option {unknown[0]!r}; its options are {', '.join(ASSET_OPTION)}",
                         unknown[0])
    given = {name: value for name, value in values.items() if value is not None and value is not False}
    lods = given.pop("lods", None)
    if lods is None:
        if given:
            raise ConflictError(f"{named(given, ' and ')} {'are' if len(given) > 1 else 'is'} for an asset: give `lods` "
                                "too (its levels' triangle counts, like 20000,5000,1200)", (*given, "lods"))
        return None
    return AssetOptions(parse_lods(lods) if isinstance(lods, str) else lods, **given)
