"""Blender <-> runtime conversions, as plain functions: the request an
object's settings stand for, the model's frame turned to Blender's and back,
arrays into a mesh and out again in bulk, a box object's corners as a kept
part, the coarse layout as cubes and cubes back as a layout. They hold no
state and touch no Blender data beyond the mesh they are given, so each is
tested on its own; the operators only gather values and call them.
"""

import base64
import re
from pathlib import Path

import numpy as np

from sinshape import models
from sinshape.core.errors import InputError
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


def sample_request(values: dict, up: str) -> SampleRequest:
    """The request an object's settings stand for. `values`: seed, size
    (along Blender's axes), scale, smooth, edit (one of EDITS) and that
    edit's own values: keep (a part's text, `kept_part`), grow and anchor
    (along Blender's axes), layout (a request.Layout)."""
    edit = values.get("edit", "NONE")
    fields = dict(seed=values["seed"], size=factors_to_model(values["size"], up), scale=values["scale"],
                  smooth=values["smooth"], frame="input")
    if edit == "KEEP":
        fields["keep"] = values["keep"]
    elif edit == "GROW":
        fields.update(grow=factors_to_model(values["grow"], up), anchor=fractions_to_model(values["anchor"], up))
    elif edit == "LAYOUT":
        if values.get("layout") is None:
            raise InputError("no layout applied yet: show the layout, edit it, then apply it", "layout")
        fields["layout"] = values["layout"]
    return SampleRequest(**fields)


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
    if not text:
        return None
    return Layout(tuple(int(n) for n in shape), base64.b64decode(text))


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


def cubes_layout(vertices, edges, manifest, factors) -> np.ndarray:
    """The layout grid that cubes (vertices in the model's frame, and the
    mesh's edges) stand for: every connected piece fills the cells whose
    centres lie within its bounds, so a moved cube fills the nearest cell
    and an extruded one the cells it reaches."""
    corner, spacing, shape = layout.cells(manifest, factors)
    grid = np.zeros(shape, bool)
    vertices, edges = np.asarray(vertices, float), np.asarray(edges, np.int64).reshape(-1, 2)
    if not len(vertices):
        return grid
    piece = connected_parts(edges[:, 0], edges[:, 1], len(vertices))
    names, piece = np.unique(piece, return_inverse=True)
    low = np.full((len(names), 3), np.inf)
    high = np.full((len(names), 3), -np.inf)
    np.minimum.at(low, piece, vertices)
    np.maximum.at(high, piece, vertices)
    first = np.clip(np.ceil((low - corner) / spacing - 0.5), 0, None).astype(int)
    last = np.minimum(np.floor((high - corner) / spacing - 0.5), np.array(shape) - 1).astype(int)
    for (x0, y0, z0), (x1, y1, z1) in zip(first, last):  # one slice per piece, not per vertex
        grid[x0:x1 + 1, y0:y1 + 1, z0:z1 + 1] = True
    return grid


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


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear (IEC 61966-2-1), float32."""
    values = np.asarray(values, np.float32)
    return np.where(values <= 0.04045, values / np.float32(12.92),
                    ((values + np.float32(0.055)) / np.float32(1.055)) ** np.float32(2.4)).astype(np.float32)


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, np.float32)
    return np.where(values <= 0.0031308, values * np.float32(12.92),
                    np.float32(1.055) * values ** np.float32(1 / 2.4) - np.float32(0.055)).astype(np.float32)


def mesh_colours(mesh) -> np.ndarray | None:
    """(n, 3) float32 sRGB of a mesh's COLOUR attribute, or None where it has none."""
    colour = mesh.color_attributes.get(COLOUR)
    if colour is None:
        return None
    rgba = np.empty(len(colour.data) * 4, np.float32)
    colour.data.foreach_get("color", rgba)
    return linear_to_srgb(rgba.reshape(-1, 4)[:, :3])


def mesh_edges(mesh) -> np.ndarray:
    edges = np.empty(len(mesh.edges) * 2, np.int32)
    mesh.edges.foreach_get("vertices", edges)
    return edges.reshape(-1, 2)


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
