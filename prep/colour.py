"""The colour of an example's surface, and the colour field its levels train on.

A mesh's colour comes from per-vertex (or per-face) colours, as PLY and
glTF's `COLOR_0` hold them, or from a base-colour texture read through the
mesh's UVs (glTF/GLB, and OBJ with its MTL and image). Colours are sRGB in
[0, 1]: PLY's 8-bit colours and texture images are sRGB already; glTF's
`COLOR_0` is linear and is converted.

The surface is sampled densely (several points per finest voxel face), and
every voxel of a level takes the colour of the sample nearest its centre:
the colour of the nearest surface point, up to a fraction of a voxel. Why
the nearest surface point: colour is defined on the surface only, and a
sample's colour is asked at its mesh's vertices, which lie between voxel
centres, on either side of the surface; the nearest surface point extends
the surface's colour across it smoothly, so the field is well defined
wherever a vertex may land, and inside a solid it is the colour of the skin
around it. Training weighs colour by `band`, the voxels within BAND voxels
of the surface, where vertices land.

numpy, scipy and Pillow only (no torch).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.manifest import linear_to_srgb, srgb_to_linear

from .meshfiles import check_texture_size, mtl_map
from .voxelize import REFERENCES, scene_parts

# Surface samples per finest voxel face of area, at least: the nearest sample
# is then within about a third of a voxel of the nearest surface point.
SAMPLES_PER_VOXEL_AREA = 8
MAX_SAMPLES = 1 << 24  # 16M samples: about 600 MB with their k-d tree
# Voxels nearer the surface than this many voxels (their centres) carry the
# colour loss: the mesh's vertices lie within one voxel of the surface.
BAND = 1.5
GLTF_SUFFIXES = (".glb", ".gltf")
# Peak bytes per voxel of all levels to colour them: the grid of centres
# (float32 x 3), the tree's answers (float64 + int64), the field (float32 x 4).
BYTES_PER_VOXEL = 48


@dataclass(frozen=True)
class SurfaceColour:
    """Points on the example's surface (input frame) and their sRGB colour."""

    points: np.ndarray  # (n, 3) float64
    rgb: np.ndarray  # (n, 3) float32 in [0, 1]
    read: str = ""  # what the colour was read from, in words
    warnings: tuple = ()  # what a user would not expect of it, in words


def texture_array(image, name: str) -> np.ndarray:
    """A PIL image as (H, W, 3) float32 sRGB in [0, 1], refused when absurdly large."""
    check_texture_size(*image.size, name)
    try:
        texture = np.asarray(image.convert("RGB"), dtype=np.float32)
    except (OSError, ValueError) as error:
        raise InputError(f"{name}: cannot decode its texture ({str(error).splitlines()[0][:200]})") from None
    texture /= 255  # in place: a second float copy would be the largest thing held
    return texture


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of (H, W, 3) at (n, 2) UVs, v = 0 at the image's bottom
    row (trimesh's convention for both OBJ and glTF), repeating outside
    [0, 1]: the default wrap of OBJ (`-clamp off`) and of glTF samplers."""
    height, width = texture.shape[:2]
    x = uv[:, 0] * width - 0.5  # pixel centres at (i + 0.5) / width
    y = (1 - uv[:, 1]) * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    x0, y0 = x0 % width, y0 % height
    top = texture[y0, x0] * (1 - fx) + texture[y0, x1] * fx
    bottom = texture[y1, x0] * (1 - fx) + texture[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def corner_colours(geometry, name: str, linear_vertex_colours: bool):
    """How to colour a point of one geometry: a function of (face index,
    barycentric weights) -> (n, 3) sRGB, or None when it has no colour."""
    visual = geometry.visual
    kind = getattr(visual, "kind", None)
    if kind in ("vertex", "face"):
        check_ply_colours(geometry, name)
    if kind == "vertex":
        colours = np.asarray(visual.vertex_colors, dtype=np.float32)[:, :3] / 255
        if linear_vertex_colours:
            colours = linear_to_srgb(colours)
        faces = geometry.faces
        return lambda face, weights: np.einsum("nk,nkc->nc", weights, colours[faces[face]])
    if kind == "face":
        colours = np.asarray(visual.face_colors, dtype=np.float32)[:, :3] / 255
        return lambda face, weights: colours[face]
    if kind != "texture":
        return None
    material = visual.material
    factor = np.ones(3, np.float32)
    base = getattr(material, "baseColorFactor", None)
    if base is not None:  # glTF: base colour = factor x texture x COLOR_0 (all linear)
        factor = np.asarray(base, dtype=np.float32)[:3]
        factor = factor / 255 if np.asarray(base).dtype.kind in "ui" else factor  # trimesh keeps bytes
    image = getattr(material, "baseColorTexture", None)  # glTF's (PBRMaterial)
    image = getattr(material, "image", None) if image is None else image  # OBJ's (SimpleMaterial)
    if image is None:  # a material of one colour
        if base is None:
            diffuse = getattr(material, "diffuse", None)
            if diffuse is None:
                return None
            colour = np.asarray(diffuse, dtype=np.float32)[:3] / 255
        else:
            colour = linear_to_srgb(factor)
        return lambda face, weights: np.broadcast_to(colour, (len(face), 3))
    uv = texture_coordinates(geometry, image, name)
    texture = texture_array(image, name)
    faces = geometry.faces
    if base is not None and not np.allclose(factor, 1):
        texture = linear_to_srgb(srgb_to_linear(texture) * factor).astype(np.float32)
    tint = gltf_vertex_colours(geometry, name) if linear_vertex_colours else None
    if tint is None:
        return lambda face, weights: sample_texture(texture, np.einsum("nk,nkc->nc", weights, uv[faces[face]]))
    return lambda face, weights: linear_to_srgb(
        srgb_to_linear(sample_texture(texture, np.einsum("nk,nkc->nc", weights, uv[faces[face]])))
        * np.einsum("nk,nkc->nc", weights, tint[faces[face]]))


# UVs beyond this are refused as coordinates beyond MAX_COORDINATE are: a
# million repeats of a 16k texture still address its pixels exactly.
MAX_UV = 1e6


def texture_coordinates(geometry, image, name: str) -> np.ndarray:
    """A textured geometry's UVs, (V, 2) float64, checked as vertex
    coordinates are (one per vertex, finite, not absurd), with an OBJ
    texture statement's options applied: -s scales them and -o offsets them
    (uv * s + o, as three.js's MTLLoader reads them), -clamp on clamps them
    to [0, 1] rather than repeating."""
    uv = np.asarray(geometry.visual.uv if geometry.visual.uv is not None else [], dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1:] != (2,) or len(uv) != len(geometry.vertices):
        raise InputError(f"{name}: its UVs do not match its vertices ({len(uv)} for {len(geometry.vertices)})")
    if not np.isfinite(uv).all():
        raise InputError(f"{name}: NaN or infinite texture coordinates")
    if len(uv) and np.abs(uv).max() > MAX_UV:
        raise InputError(f"{name}: texture coordinates beyond +-{MAX_UV:g}")
    statement = str(getattr(image, "info", {}).get("file_path", ""))  # an OBJ's map_Kd, as written
    if statement.lstrip().startswith("-"):
        options = mtl_map(statement)[0]
        scale = [float(v) for v in options.get("-s", [])] + [1.0, 1.0]  # u [v [w]]: v defaults to 1, w unused
        offset = [float(v) for v in options.get("-o", [])] + [0.0, 0.0]
        uv = uv * scale[:2] + offset[:2]
        if options.get("-clamp", ["off"])[0].lower() == "on":
            uv = np.clip(uv, 0, 1)
    return uv


def gltf_vertex_colours(geometry, name: str) -> np.ndarray | None:
    """A textured glTF primitive's COLOR_0, which glTF multiplies into its
    base colour: (V, 3) float32 linear in [0, 1], or None without one
    (trimesh keeps it beside the texture as the visual's `color`)."""
    colours = geometry.visual.vertex_attributes.get("color") if hasattr(geometry.visual, "vertex_attributes") \
        else None
    if colours is None:
        return None
    colours = np.asarray(colours)
    if colours.ndim != 2 or colours.shape[1] not in (3, 4) or len(colours) != len(geometry.vertices):
        raise InputError(f"{name}: its vertex colours (COLOR_0) do not match its vertices")
    if colours.dtype.kind in "ui":  # normalised integers
        colours = colours / float(np.iinfo(colours.dtype).max)
    colours = colours[:, :3].astype(np.float32)
    if not (np.isfinite(colours).all() and colours.min() >= 0 and colours.max() <= 1):
        raise InputError(f"{name}: its vertex colours (COLOR_0) must be numbers in [0, 1]")
    return colours


def colour_kind(geometry, gltf: bool) -> str | None:
    """What gives a geometry its colour, in words: for training to say what
    it read."""
    visual = geometry.visual
    kind = getattr(visual, "kind", None)
    if kind in ("vertex", "face"):
        return f"{kind} colours"
    if kind != "texture":
        return None
    material = visual.material
    if getattr(material, "baseColorTexture", None) is None and getattr(material, "image", None) is None:
        return "material colour"
    if gltf and getattr(visual, "vertex_attributes", {}).get("color") is not None:
        return "texture times vertex colours (COLOR_0, as glTF defines)"
    if not gltf and getattr(geometry, "vertex_attributes", {}).get("color") is not None:
        return "texture; its vertex colours are not used"
    return "texture"


def check_ply_colours(geometry, name: str) -> None:
    """A PLY's colours as stored are finite: trimesh turns a NaN colour into 0."""
    raw = geometry.metadata.get("_ply_raw", {})
    for element in ("vertex", "face"):
        data = raw.get(element, {}).get("data", {})
        for channel in ("red", "green", "blue", "alpha"):
            values = data.get(channel) if isinstance(data, dict) else None
            if values is not None and np.asarray(values).dtype.kind == "f" and not np.isfinite(values).all():
                raise InputError(f"{name}: NaN or infinite {element} colours")


def sample_faces(triangles: np.ndarray, per_area: float, rng) -> tuple:
    """Points spread over triangles, at least `per_area` per unit of area
    (one per face at least): (face index (n,), barycentric weights (n, 3))."""
    areas = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    counts = np.maximum(1, np.ceil(areas * per_area)).astype(np.int64)
    if counts.sum() > MAX_SAMPLES:
        counts = np.maximum(1, np.floor(counts * (MAX_SAMPLES / counts.sum()))).astype(np.int64)
    face = np.repeat(np.arange(len(triangles)), counts)
    a, b = rng.random((2, len(face)))
    flip = a + b > 1  # the square's far half folded onto the triangle
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    return face, np.stack([1 - a - b, a, b], axis=1)


def painted_parts(scene, path: Path) -> list | None:
    """How to colour each part of a read scene (voxelize.scene_parts, in its
    order): [(vertices (V, 3) float64, faces (F, 3), colour function of (face
    index, barycentric weights) -> (n, 3) sRGB, what gives it colour in
    words)], or None when no part has colour. A part without colour beside
    coloured parts is an InputError: colour is never dropped silently."""
    gltf = path.suffix.lower() in GLTF_SUFFIXES
    parts = scene_parts(scene)
    painted, uncoloured = [], []
    for key, vertices, faces, geometry in parts:
        colour = corner_colours(geometry, f"{path.name}: {key}" if len(parts) > 1 else path.name, gltf)
        if colour is None:
            uncoloured.append(key)
        painted.append((vertices, faces, colour, colour_kind(geometry, gltf)))
    if len(uncoloured) == len(painted):
        return None
    if uncoloured:
        raise InputError(f"{path.name}: part {uncoloured[0]} has no colour while others have")
    return painted


def colour_read(scene, kinds) -> tuple:
    """(what the colour was read from, in words; warnings about it) of a read
    scene whose parts are coloured by `kinds` (colour_kind's words)."""
    textures = scene.metadata[REFERENCES].textures if REFERENCES in scene.metadata else ()
    named = ", ".join(f"{t.name} ({t.width}x{t.height})" for t in textures)
    read = "; ".join(dict.fromkeys(kind.replace("texture", f"texture {named}", 1) if named else kind
                                   for kind in kinds))
    warnings = [f"texture {t.name} is one colour (#{''.join(f'{c:02x}' for c in t.one_colour)}): the model "
                "learns that colour alone" for t in textures if t.one_colour is not None]
    if any("not used" in kind for kind in kinds):
        warnings.append("its vertex colours are not used: an OBJ's texture gives its colour (the format does "
                        "not say how the two combine)")
    return read, tuple(warnings)


def surface_colour(scene, path: Path, data: bytes, voxel: float, seed: int = 0) -> SurfaceColour | None:
    """The colour of a read scene's surface, sampled at SAMPLES_PER_VOXEL_AREA
    points per voxel face of size `voxel` (input units); None when no part
    of it has colour. A part without colour beside coloured parts, or a
    texture that cannot be read, is an InputError: colour is never dropped
    silently (`colour=False`, `--no-colour`, trains geometry alone)."""
    parts = painted_parts(scene, path)
    if parts is None:
        return None
    rng = np.random.default_rng(seed)
    points, colours = [], []
    for vertices, faces, colour, _ in parts:
        triangles = vertices[faces]
        face, weights = sample_faces(triangles, SAMPLES_PER_VOXEL_AREA / voxel**2, rng)
        points.append(np.einsum("nk,nkc->nc", weights, triangles[face]))
        colours.append(np.asarray(colour(face, weights), np.float32))
    rgb = np.concatenate(colours)
    if not np.isfinite(rgb).all():
        raise InputError(f"{path.name}: NaN or infinite colours")
    read, warnings = colour_read(scene, [kind for *_, kind in parts])
    return SurfaceColour(np.concatenate(points), np.clip(rgb, 0, 1), read, warnings)


def surface_painter(scene, path: Path):
    """A read scene's colour as a function of (face index into its faces in
    voxelize.scene_mesh's order, barycentric weights (n, 3)) -> (n, 3)
    sRGB in [0, 1], for drawing it; None when it has no colour."""
    parts = painted_parts(scene, path)
    if parts is None:
        return None
    offsets = np.cumsum([0] + [len(faces) for _, faces, _, _ in parts])

    def paint(face: np.ndarray, weights: np.ndarray) -> np.ndarray:
        out = np.empty((len(face), 3), np.float32)
        part = np.searchsorted(offsets, face, side="right") - 1
        for index in np.unique(part):
            chosen = part == index
            out[chosen] = parts[index][2](face[chosen] - offsets[index], weights[chosen])
        return np.clip(np.nan_to_num(out), 0, 1)

    return paint


def colour_grid(surface: SurfaceColour, box_low, spacing, shape) -> tuple:
    """The colour of the nearest surface sample at every voxel centre of a
    grid (voxel (i, j, k) centred at box_low + (i + 0.5) * spacing), and how
    far that sample is, in voxels (each axis in its own voxel's size):
    ((3, X, Y, Z) float32, (X, Y, Z) float32)."""
    from scipy.spatial import cKDTree

    spacing = np.asarray(spacing, np.float64)
    tree = cKDTree((surface.points - np.asarray(box_low)) / spacing - 0.5)
    centres = np.stack(np.meshgrid(*(np.arange(n, dtype=np.float32) for n in shape), indexing="ij"), axis=-1)
    distance, nearest = tree.query(centres.reshape(-1, 3), workers=-1)
    rgb = surface.rgb[nearest].T.reshape(3, *shape)
    return np.ascontiguousarray(rgb, dtype=np.float32), distance.reshape(shape).astype(np.float32)


def band(distance: np.ndarray) -> np.ndarray:
    """The colour loss's weight per voxel: 1 within BAND voxels of the surface, else 0."""
    return (distance <= BAND).astype(np.float32)

