"""Blender <-> runtime conversions, as plain functions: the request an
object's settings stand for, the model's frame turned to Blender's and back,
arrays into a mesh and out again in bulk, a box object's corners as a kept
part, the coarse layout as cubes and cubes back as a layout. They hold no
state and touch no Blender data beyond the mesh they are given, so each is
tested on its own; the operators only gather values and call them.
"""

import base64
import binascii
import re
from pathlib import Path

import numpy as np

from sinshape import models
from sinshape.core.errors import InputError
from sinshape.core.manifest import linear_to_srgb, srgb_to_linear
from sinshape.runtime import layout, write
from sinshape.runtime.generate import scaled_sizes
from sinshape.runtime.mesh import connected_parts
from sinshape.runtime.request import Layout, SampleRequest

# Blender stands on z. A model whose training input stood on y (most mesh
# formats; the manifest's `up`) is turned as Blender's OBJ and glTF importers
# turn such files: the input's y becomes Blender's z, its z Blender's -y.
# A rotation (determinant 1), so outward faces stay outward.
TURNS = {"y": np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float), "z": np.eye(3)}
EDITS = ("NONE", "KEEP", "GROW", "LAYOUT")


def turned(points, turn: np.ndarray) -> np.ndarray:
    """(n, 3) points times a turn of TURNS (rows: each output axis, one
    input axis and its sign): a copy of the columns, exact and cheaper
    than a product."""
    points = np.asarray(points, float)
    axes = np.abs(turn).argmax(axis=1)
    return points[:, axes] * turn[np.arange(3), axes]


def to_blender(points, up: str) -> np.ndarray:
    """(n, 3) points in the model's frame -> Blender's axes."""
    return turned(points, TURNS[up])


def to_model(points, up: str) -> np.ndarray:
    """(n, 3) points along Blender's axes -> the model's frame."""
    return turned(points, TURNS[up].T)


def factors_to_model(values, up: str) -> tuple:
    """Per-axis factors (a size, a growth) given along Blender's axes -> along the model's."""
    return tuple(float(v) for v in np.abs(TURNS[up]).T @ np.asarray(values, float))


def fractions_to_model(values, up: str) -> tuple:
    """Per-axis fractions (an anchor, 0 the low side) along Blender's axes ->
    along the model's: an axis turned to its negative counts from the other side."""
    turn = TURNS[up]
    blender_axis = np.abs(turn).argmax(axis=0)  # model axis i lies along Blender axis blender_axis[i]
    return tuple(float(1 - values[j] if turn[j, i] < 0 else values[j]) for i, j in enumerate(blender_axis))


def model_path(reference: str) -> Path:
    """The file a model setting names: a shipped model's name, or a path (models.find)."""
    if not reference.strip():
        raise InputError(f"no model chosen: name a shipped model ({', '.join(sorted(models.available()))}) "
                         "or a .onnx file", "model")
    return models.find(reference)


def check_unchanged(reference: str, path: Path, digest: str, recorded: str) -> None:
    """A model must still be the one recorded when it was chosen (when one
    was): a changed file, or a shipped model that an update of the extension
    replaced, is refused, never used in its place."""
    if not recorded or digest == recorded:
        return
    what = (f"the shipped model {reference} has changed (an update of the extension)" if reference in models.available()
            else f"{path}: the model file has changed")
    raise InputError(f"{what} since this object was made from it (SHA-256 {recorded[:12]}..., now {digest[:12]}...); "
                     "its mesh is kept: choose the model again to use it as it is", "model")


# The options a sample object and a world object offer as the table's
# records make them (props.table_property), drawn in this order and read
# into the request by name: a plain option (a number, a flag, a choice) is
# offered in Blender by naming it here.
SAMPLE_TABLE_SETTINGS = ("seed", "scale", "smooth", "detail")
WORLD_TABLE_SETTINGS = ("seed", "scale", "arrange", "density", "spacing", "detail")
# The options of a sample request (runtime/options.py) the extension sets, and
# the setting that sets each: a sample object's (props.SinshapeSettings), or a
# world object's (props.SinshapeWorld: its tiles around the followed point,
# each tile's lod from the fine radius, its other models, model map and height map) ...
SETTINGS = {**{name: name for name in SAMPLE_TABLE_SETTINGS + WORLD_TABLE_SETTINGS}, "size": "size",
            "keep": "keep_box", "grow": "grow", "anchor": "anchor", "layout": "layout_bits", "tile": "radius",
            "lod": "fine", "models": "models", "models_map": "models_map", "heights": "heights"}
# ... those it leaves at their defaults (a mesh in the input's frame, turned to
# Blender's; a world's tiles closed underneath, as one may look from below in Blender) ...
LEFT = ("recon", "smoother", "largest", "frame", "underside")
# ... and those it sets to one value (worlds.world_options): every tile with a
# skirt, so that a border between levels is closed from both sides.
# tests/test_blender_options.py holds the three to the table.
FIXED = {"skirt": True}


def typed(value):
    """A setting's value as the user typed it: Blender keeps a float
    setting in 32 bits (1.1 is 1.100000023841858), and the request takes
    the shortest decimal that reads back to it (1.1, as the command line's)."""
    return float(str(np.float32(value))) if isinstance(value, float) else value


def table_values(settings, names) -> dict:
    """The values of the table settings `names` (SAMPLE_TABLE_SETTINGS,
    WORLD_TABLE_SETTINGS) of an object's settings or an operator, as typed."""
    return {name: typed(getattr(settings, name)) for name in names}


def sample_request(values: dict, up: str) -> SampleRequest:
    """The request an object's settings stand for. `values`: the
    SAMPLE_TABLE_SETTINGS, size (along Blender's axes), edit (one of EDITS)
    and that edit's own values: keep (a part's text, `kept_part`), grow and
    anchor (along Blender's axes), layout (a request.Layout)."""
    read = {"model", "size", "edit", "keep", "grow", "anchor", "layout", *SAMPLE_TABLE_SETTINGS}
    unknown = sorted(set(values) - read)
    if unknown:  # a setting added without its place in the request: refused, never dropped
        raise InputError(f"a sample's settings have no {unknown[0]!r} that its request takes", unknown[0])
    edit = values.get("edit", "NONE")
    fields = dict({name: values[name] for name in SAMPLE_TABLE_SETTINGS if name in values},
                  size=factors_to_model(values["size"], up), frame="input")
    if edit == "KEEP":
        fields["keep"] = values["keep"]
    elif edit == "GROW":
        fields.update(grow=factors_to_model(values["grow"], up), anchor=fractions_to_model(values["anchor"], up))
    elif edit == "LAYOUT":
        if values.get("layout") is None:
            raise InputError("no layout applied yet: show the layout, edit it, then apply it", "layout")
        fields["layout"] = values["layout"]
    return SampleRequest.of(fields)


# A model trained from an SSG .h5 pyramid has no units of its own: its
# frame is the finest level's voxels (docs/FORMAT.md), 100 or more Blender
# units wide. Its objects are scaled so that its training shape's longest
# side is this many units, about what the shipped models' meshes span.
VOXEL_MODEL_SIDE = 6.0


def object_scale(manifest) -> float:
    """The scale a new object of this model gets: 1, or for a model in voxel
    units (an .h5 pyramid's), one that makes it VOXEL_MODEL_SIDE units long.
    The object's scale, not its mesh: the mesh stays the command line's."""
    if manifest.raw.get("source", {}).get("kind") != "pyramid":
        return 1.0
    extent = (np.array(manifest.sizes[-1]) - 1) * np.asarray(manifest.spacing)
    return VOXEL_MODEL_SIDE / float(extent.max())


def sample_extent(manifest, factors) -> tuple:
    """(low, high) corners of a sample of `factors` (model axes) in the model's frame."""
    finest = np.array(scaled_sizes(manifest.sizes, factors)[-1])
    low = np.asarray(manifest.origin, float)
    return low, low + (finest - 1) * np.asarray(manifest.spacing, float)


def kept_part(seed: int, corners, up: str, manifest, factors) -> str:
    """The request's `keep` text for a box whose corners are given in the
    sample object's own space (Blender's axes): its bounds in the model's
    frame, cut to the sample's extent. Written with every digit, so that
    the command line given the same text keeps the same part."""
    points = to_model(corners, up)
    sample_low, sample_high = sample_extent(manifest, factors)
    low = np.maximum(points.min(axis=0), sample_low)
    high = np.minimum(points.max(axis=0), sample_high)
    if (low >= high).any():
        raise InputError("the keep box lies outside the sample: move it over the shape", "keep")
    return f"{int(seed)}:{','.join(map(repr, low.tolist()))}:{','.join(map(repr, high.tolist()))}"


def layout_text(grid: np.ndarray) -> tuple:
    """A layout grid as (shape, text) that a string property keeps with the .blend."""
    value = Layout.of(grid)
    return value.shape, base64.b64encode(value.bits).decode()


def layout_from_text(shape, text: str) -> Layout | None:
    """The layout a .blend keeps (layout_text's), checked as the runtime
    checks a layout (request.Layout); None where there is none."""
    if not text:
        return None
    try:
        bits = base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise InputError("the applied layout is damaged (its cells are not base64): show the layout and apply "
                         "it again", "layout") from None
    return Layout(tuple(int(n) for n in shape), bits)


# A unit cube's corners (index 4x + 2y + z) and its six faces, each wound
# so that its normal points out.
CUBE_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
CUBE_FACES = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


def layout_cubes(grid: np.ndarray, manifest, factors) -> tuple:
    """(vertices in the model's frame, quads): one cube per full cell of a
    level-0 layout grid of a sample of `factors`, each on its own corners
    so that each can be moved, copied or deleted alone."""
    corner, spacing, _ = layout.cells(manifest, factors)
    full = np.argwhere(grid)
    vertices = corner + (full[:, None, :] + CUBE_CORNERS[None]) * spacing
    faces = CUBE_FACES[None] + 8 * np.arange(len(full))[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 4)


def cubes_layout(vertices, corners, starts, manifest, factors) -> np.ndarray:
    """The layout grid that cubes stand for, read from their faces whatever
    Blender's tools did to the mesh's topology (cubes welded by Merge by
    Distance, which also drops the doubled face between two of them; faces
    joined, split or deleted): a moved cube fills the nearest cell, an
    extruded one the cells it reaches. vertices: (n, 3) in the model's
    frame; the faces as Blender keeps them: corners (k,) each corner's
    vertex, starts (p,) each face's first corner.

    Faces are walls between cell centres (where a ray from one centre to
    the next crosses one). Cells the outside reaches without crossing a
    wall are empty; the rest fall into pieces that walls close off, and a
    piece is full unless every wall around it faces into it: an enclosed
    empty cell, seen from the cubes about it. Welding leaves one face of
    each doubled pair, but which one follows the cubes' order, so every
    cube keeps a face looking out of it."""
    corner, spacing, shape = layout.cells(manifest, factors)
    triangles = fan_triangles(vertices, corners, starts)
    cells = int(np.prod(shape))
    index = np.arange(cells).reshape(shape)
    outside = cells  # one more node: everything beyond the grid
    joined, walls = [], []  # (lower, upper) node pairs: neighbours with no wall between, and walls with their facing
    for axis in range(3):
        order = [(axis + 1) % 3, (axis + 2) % 3, axis]  # cyclic: handedness kept, the ray along the last axis
        up, down = segment_walls(triangles[:, :, order], corner[order], spacing[order],
                                        tuple(shape[a] for a in order))
        nodes = np.transpose(index, order)  # the cells along each ray last
        pad = np.full(nodes.shape[:2] + (1,), outside)
        ends = np.concatenate([pad, nodes, pad], axis=2)
        lower, upper = ends[..., :-1], ends[..., 1:]  # segment s joins node s - 1 and node s
        blocked = up | down
        joined.append(np.stack([lower[~blocked], upper[~blocked]], axis=1))
        walls.append(np.stack([lower[blocked], upper[blocked], up[blocked], down[blocked]], axis=1))
    joined, walls = np.concatenate(joined), np.concatenate(walls)
    piece = connected_parts(joined[:, 0], joined[:, 1], cells + 1)
    looks_out = np.zeros(cells + 1, bool)  # a wall of the piece faces out of it
    np.logical_or.at(looks_out, piece[walls[:, 0]], walls[:, 2] > 0)  # a face looking up: out of the lower node
    np.logical_or.at(looks_out, piece[walls[:, 1]], walls[:, 3] > 0)
    return ((piece != piece[outside]) & looks_out[piece])[:cells].reshape(shape)


def segment_walls(triangles: np.ndarray, corner, spacing, shape) -> tuple:
    """Along rays through the cell centres parallel to the last axis: which
    segments between neighbouring centres (and between the end centres and
    the outside) a face crosses, by how it looks: (up, down), (A, B, n + 1)
    bool each, a face there looking along the ray, or against it."""
    count = shape[2] + 1
    up = np.zeros(shape[:2] + (count,), bool)
    down = np.zeros_like(up)
    for i, j, height, sign in column_crossings(triangles, corner, spacing, shape):
        at = (height - corner[2]) / spacing[2] - 0.5  # in centres: cell k's at k
        segment = np.floor(at).astype(np.int64) + 1  # between centre segment - 1 and centre segment
        inside = (segment >= 0) & (segment < count)
        i, j, segment, sign = i[inside], j[inside], segment[inside], sign[inside]
        up[i[sign > 0], j[sign > 0], segment[sign > 0]] = True
        down[i[sign < 0], j[sign < 0], segment[sign < 0]] = True
    return up, down


def fan_triangles(vertices, corners, starts) -> np.ndarray:
    """(m, 3, 3) float64 triangles of faces given as Blender keeps them
    (each face fanned from its first corner: the fan's signed triangles
    cover what the face covers, convex or not), checked first: finite
    vertices, corners that name them, faces of at least 3 corners."""
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    corners, starts = np.asarray(corners).ravel(), np.asarray(starts).ravel()
    if not np.isfinite(vertices).all():
        raise InputError("the layout's cubes have vertices that are not finite numbers (NaN or infinite): "
                         "move them back or show the layout again", "layout")
    if not (np.issubdtype(corners.dtype, np.integer) or not corners.size) \
            or not (np.issubdtype(starts.dtype, np.integer) or not starts.size):
        raise InputError("the layout's cubes are not a mesh: corners and faces are not integers", "layout")
    counts = np.diff(np.append(starts, len(corners)))
    if len(corners) and ((corners < 0) | (corners >= len(vertices))).any():
        raise InputError(f"the layout's cubes are not a valid mesh: a face names a vertex outside its "
                         f"{len(vertices)}", "layout")
    if len(starts) and (starts[0] != 0 or (counts < 3).any()):
        raise InputError("the layout's cubes are not a valid mesh: a face has fewer than 3 corners", "layout")
    face = np.repeat(np.arange(len(starts)), counts - 2)  # face of each fan triangle
    step = np.arange(len(face)) - np.repeat(np.cumsum(counts - 2) - (counts - 2), counts - 2)
    first = starts[face]
    return vertices[corners[np.stack([first, first + step + 1, first + step + 2], axis=1)]]


COLUMN_BATCH = 1 << 20  # (triangle, column) candidates tested at once


def column_crossings(triangles: np.ndarray, corner, spacing, shape):
    """Where the vertical rays through the cell centres' columns cross the
    triangles: yields (i, j, z, sign) arrays, batch by batch, sign the
    triangle's facing (+1 up, -1 down); triangles seen edge-on cross none.
    A ray through an edge shared by two triangles counts once (the
    top-left rule of rasterisers), so welded and unwelded faces alike
    count each crossing once."""
    xy = (triangles[:, :, :2] - corner[:2]) / spacing[:2] - 0.5  # column units: column c at c
    area = ((xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1])
            - (xy[:, 2, 0] - xy[:, 0, 0]) * (xy[:, 1, 1] - xy[:, 0, 1]))
    keep = area != 0
    triangles, xy, area = triangles[keep], xy[keep], area[keep]
    sign = np.sign(area).astype(np.int64)
    xy = np.where(sign[:, None, None] < 0, xy[:, ::-1], xy)  # every triangle counter-clockwise
    z = np.where(sign[:, None] < 0, triangles[:, ::-1, 2], triangles[:, :, 2])
    low = np.clip(np.ceil(xy.min(axis=1)), 0, np.array(shape[:2])).astype(np.int64)
    high = np.clip(np.floor(xy.max(axis=1)) + 1, 0, np.array(shape[:2])).astype(np.int64)
    span = np.maximum(high - low, 0)
    count = span[:, 0] * span[:, 1]
    ends = np.cumsum(count)
    first = 0
    while first < len(count):
        last = max(first + 1, int(np.searchsorted(ends, (ends[first - 1] if first else 0) + COLUMN_BATCH)))
        which = np.repeat(np.arange(first, last), count[first:last])
        offset = np.arange(len(which)) - np.repeat(ends[first:last] - count[first:last], count[first:last])
        i = low[which, 0] + offset // np.maximum(span[which, 1], 1)
        j = low[which, 1] + offset % np.maximum(span[which, 1], 1)
        a, b, c = xy[which, 0], xy[which, 1], xy[which, 2]
        weights = []
        for start, end in ((b, c), (c, a), (a, b)):  # barycentric weight of the vertex opposite each edge
            edge = end - start
            # From the edge's lower end, so that two faces sharing it compute the same value, negated.
            flip = (start[:, 0] > end[:, 0]) | ((start[:, 0] == end[:, 0]) & (start[:, 1] > end[:, 1]))
            origin = np.where(flip[:, None], end, start)
            along = np.where(flip[:, None], -edge, edge)
            value = along[:, 0] * (j - origin[:, 1]) - along[:, 1] * (i - origin[:, 0])
            value = np.where(flip, -value, value)
            top_left = (edge[:, 1] < 0) | ((edge[:, 1] == 0) & (edge[:, 0] > 0))  # the ray nudged along +x, +y
            weights.append(np.where((value > 0) | ((value == 0) & top_left), value, np.nan))
        hit = ~np.isnan(weights[0] + weights[1] + weights[2])
        total = weights[0] + weights[1] + weights[2]
        height = (weights[0] * z[which, 0] + weights[1] * z[which, 1] + weights[2] * z[which, 2]) / total
        yield i[hit], j[hit], height[hit], sign[which][hit]
        first = last


def triangle_edges(faces) -> tuple:
    """(edges (e, 2), each corner's edge (3m,)) of (m, 3) triangles, corner
    k's edge joining it to corner k + 1, the edges numbered by their lower
    vertex then their higher: what Blender's calc_edges makes, computed in
    numpy where it may run off the main thread (and in less CPU time than
    calc_edges, docs/BLENDER.md)."""
    faces = np.asarray(faces, np.int32)  # fewer bytes to touch: fresh memory is much of the cost
    count = int(faces.max()) + 1 if faces.size else 0
    a, b = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    low, high = np.minimum(a, b), np.maximum(a, b)
    key = low.astype(np.int64)
    key *= count
    key += high
    order = np.argsort(key, kind="stable")  # the runtime's faces come slab by slab: long sorted runs
    ordered = key[order]
    first = np.ones(len(ordered), bool)
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    corner_edges = np.empty(len(key), np.int32)
    corner_edges[order] = np.cumsum(first, dtype=np.int32) - 1
    kept = order[first]
    return np.stack([low[kept], high[kept]], axis=1), corner_edges


COLOUR = "Col"  # a coloured model's colour attribute: float RGBA on the points


def fill_mesh(mesh, vertices, faces, smooth_shading: bool = False, edges: tuple | None = None,
              colours=None) -> None:
    """Replace a bpy Mesh's geometry with (n, 3) vertices and (m, k) faces
    of k corners each, in bulk; `edges` as `triangle_edges` gives them
    (None: Blender computes them); `colours`, (n, 3) sRGB in [0, 1] (a
    coloured model's), as the point colour attribute COLOUR. Everything
    goes through the mesh's attributes ('position', '.corner_vert', ...),
    which take a whole array at once; vertices.co and loops.vertex_index set
    one item at a time, about 40 times slower."""
    vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, np.int32)
    count, corners = faces.shape if faces.size else (0, 3)
    mesh.clear_geometry()
    mesh.vertices.add(len(vertices))
    mesh.loops.add(count * corners)
    mesh.polygons.add(count)
    attributes = mesh.attributes
    if len(vertices):
        attributes["position"].data.foreach_set("vector", vertices.ravel())
    if count:
        attributes[".corner_vert"].data.foreach_set("value", faces.ravel())
        mesh.polygons.foreach_set("loop_start", np.arange(0, count * corners, corners, dtype=np.int32))
    if edges is None or not count:
        mesh.update(calc_edges=True)
    else:
        mesh.edges.add(len(edges[0]))
        attributes[".edge_verts"].data.foreach_set("value", np.ascontiguousarray(edges[0], np.int32).ravel())
        attributes[".corner_edge"].data.foreach_set("value", np.ascontiguousarray(edges[1], np.int32))
        mesh.update()
    if count and not smooth_shading:  # faces are smooth unless marked sharp (Blender 4.1 on)
        attributes.new("sharp_face", "BOOLEAN", "FACE").data.foreach_set("value", np.ones(count, bool))
    old = mesh.color_attributes.get(COLOUR)  # clear_geometry keeps colour attributes
    if old is not None:
        mesh.color_attributes.remove(old)
    if colours is not None and len(vertices):
        # Blender keeps float colour linear; its own sRGB conversion (color_srgb) is good to 1e-4 only.
        rgba = np.ones((len(vertices), 4), np.float32)
        rgba[:, :3] = srgb_to_linear(np.asarray(colours, np.float32).reshape(-1, 3))
        colour = mesh.color_attributes.new(COLOUR, "FLOAT_COLOR", "POINT")
        colour.data.foreach_set("color", rgba.ravel())
        mesh.color_attributes.active_color = colour
        mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index


def mesh_vertices(mesh) -> np.ndarray:
    """(n, 3) float32 vertex positions of a bpy Mesh."""
    vertices = np.empty(len(mesh.vertices) * 3, np.float32)
    if len(vertices):
        mesh.attributes["position"].data.foreach_get("vector", vertices)
    return vertices.reshape(-1, 3)


def mesh_arrays(mesh) -> tuple:
    """(vertices float32 (n, 3), triangles (m, 3)) of a triangle bpy Mesh."""
    corners = np.empty(len(mesh.loops), np.int32)
    if len(corners):
        mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    return mesh_vertices(mesh), corners.reshape(-1, 3)


def byte_colours(rgba) -> np.ndarray:
    """The runtime's 8-bit sRGB(A) vertex colours (what its files hold) -> (n, 3) float32 sRGB in [0, 1]."""
    return np.asarray(rgba)[:, :3] / np.float32(255)


def mesh_colours(mesh) -> np.ndarray | None:
    """(n, 3) float32 sRGB of a mesh's COLOUR attribute, or None where it has none."""
    colour = mesh.color_attributes.get(COLOUR)
    if colour is None:
        return None
    rgba = np.empty(len(colour.data) * 4, np.float32)
    colour.data.foreach_get("color", rgba)
    return linear_to_srgb(rgba.reshape(-1, 4)[:, :3]).astype(np.float32)


def mesh_faces(mesh) -> tuple:
    """(corners (k,), starts (p,)) of a bpy Mesh's faces: each corner's
    vertex, and each face's first corner (cubes_layout reads faces so)."""
    corners = np.empty(len(mesh.loops), np.int32)
    starts = np.empty(len(mesh.polygons), np.int32)
    if len(corners):
        mesh.attributes[".corner_vert"].data.foreach_get("value", corners)
    if len(starts):
        mesh.polygons.foreach_get("loop_start", starts)
    return corners, starts


PLY_TYPES = {b"float": "<f4", b"double": "<f8", b"uchar": "u1", b"int": "<i4", b"uint": "<u4"}


def ply_arrays(data: bytes) -> tuple:
    """(vertices, faces, sRGB colours or None) of a binary PLY as the
    runtime writes it (write.mesh_bytes): how a worker process's sample
    comes back; a coloured model's vertex colours are bytes (/ 255)."""
    header, _, body = data.partition(b"end_header\n")
    vertices, faces = (int(re.search(rb"element %s (\d+)" % name, header)[1]) for name in (b"vertex", b"face"))
    vertex_part = header.split(b"element vertex", 1)[1].split(b"element face", 1)[0]
    fields = np.dtype([(name.decode(), PLY_TYPES[kind]) for kind, name in
                       re.findall(rb"property (\w+) (\w+)", vertex_part)])
    table = np.frombuffer(body, fields, vertices)
    points = np.stack([table[axis] for axis in "xyz"], axis=1).astype(np.float32)
    colours = (byte_colours(np.stack([table[c] for c in ("red", "green", "blue")], axis=1))
               if "red" in fields.names else None)
    return points, np.frombuffer(body, write.PLY_FACE, faces, vertices * fields.itemsize)["indices"], colours
