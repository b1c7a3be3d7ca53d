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

import base64
import io
import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.manifest import linear_to_srgb, srgb_to_linear

# A texture larger than this is refused before it is decoded: 16k a side is
# the largest in common use; 2^27 pixels (16k x 8k) keeps its float copy
# near 1.6 GB, and below Pillow's own decompression-bomb limit.
MAX_TEXTURE_SIDE = 16384
MAX_TEXTURE_PIXELS = 1 << 27
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


def texture_array(image, name: str) -> np.ndarray:
    """A PIL image as (H, W, 3) float32 sRGB in [0, 1], refused when absurdly large."""
    width, height = image.size
    if not (1 <= width <= MAX_TEXTURE_SIDE and 1 <= height <= MAX_TEXTURE_SIDE) or width * height > MAX_TEXTURE_PIXELS:
        raise InputError(f"{name}: a {width}x{height} texture is not a usable size (at most {MAX_TEXTURE_SIDE} "
                         f"pixels a side and {MAX_TEXTURE_PIXELS} in all)")
    try:
        return np.asarray(image.convert("RGB"), dtype=np.float32) / 255
    except (OSError, ValueError) as error:
        raise InputError(f"{name}: cannot decode its texture ({str(error).splitlines()[0][:200]})") from None


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
    if base is not None:  # glTF: base colour = factor x texture (the factor is linear)
        factor = np.asarray(base, dtype=np.float32)[:3]
        factor = factor / 255 if factor.max() > 1 else factor
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
    uv = np.asarray(visual.uv, dtype=np.float64)
    if uv.ndim != 2 or len(uv) != len(geometry.vertices):
        raise InputError(f"{name}: its UVs do not match its vertices ({len(uv)} for {len(geometry.vertices)})")
    if not np.isfinite(uv).all():
        raise InputError(f"{name}: NaN or infinite texture coordinates")
    texture = texture_array(image, name)
    faces = geometry.faces
    if base is not None and not np.allclose(factor, 1):
        texture = linear_to_srgb(srgb_to_linear(texture) * factor).astype(np.float32)
    return lambda face, weights: sample_texture(texture, np.einsum("nk,nkc->nc", weights, uv[faces[face]]))


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


def gltf_textures_readable(data: bytes, path: Path) -> None:
    """Every image a glTF material uses as its base colour decodes, and has a
    usable size: trimesh drops a texture it cannot read without a word."""
    if data[:4] == b"glTF":
        length = struct.unpack_from("<I", data, 12)[0]
        meta = json.loads(data[20:20 + length])
        binary = data[20 + length + 8:] if len(data) > 20 + length + 8 else b""
    else:
        meta, binary = json.loads(data), b""
    images, textures = meta.get("images", []), meta.get("textures", [])
    used = {textures[m["pbrMetallicRoughness"]["baseColorTexture"]["index"]].get("source")
            for m in meta.get("materials", []) if "baseColorTexture" in m.get("pbrMetallicRoughness", {})}
    for index in sorted(i for i in used if i is not None):
        image = images[index]
        uri = str(image.get("uri", ""))
        name = f"{path.name}: base colour image {index if not uri or uri.startswith('data:') else uri}"
        if "bufferView" in image:
            view = meta["bufferViews"][image["bufferView"]]
            raw = binary[view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]]
        elif uri.startswith("data:"):
            raw = base64.b64decode(uri.split(",", 1)[1])
        else:
            file = path.parent / uri
            if not file.is_file():
                raise InputError(f"{name} is missing")
            raw = file.read_bytes()
        check_image(raw, name)


def check_image(raw: bytes, name: str) -> None:
    """An image file's bytes decode, and its size is usable."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(raw)) as image:
            texture_array(image, name)  # the size first, then the pixels
    except Image.DecompressionBombError:
        raise InputError(f"{name}: an image of absurd size is not a usable size for a texture") from None
    except (OSError, ValueError) as error:
        raise InputError(f"{name}: cannot read it as an image ({str(error).splitlines()[0][:200]})") from None


def obj_textures_readable(text: str, path: Path) -> None:
    """Every material library an OBJ names exists, and every diffuse texture
    (`map_Kd`) it names reads as an image: trimesh skips missing ones silently."""
    for library in re.findall(r"^\s*mtllib\s+(.+?)\s*$", text, re.MULTILINE):
        mtl = path.parent / library
        if not mtl.is_file():
            raise InputError(f"{path.name}: its material library {library} is missing")
        for texture in re.findall(r"^\s*map_Kd\s+(?:-\S+\s+\S+\s+)*(.+?)\s*$", mtl.read_text(errors="replace"),
                                  re.MULTILINE):
            file = mtl.parent / texture
            if not file.is_file():
                raise InputError(f"{path.name}: its texture {texture} (named in {library}) is missing")
            check_image(file.read_bytes(), f"{path.name}: texture {texture}")


def surface_colour(scene, path: Path, data: bytes, voxel: float, seed: int = 0) -> SurfaceColour | None:
    """The colour of a loaded scene's surface, sampled at SAMPLES_PER_VOXEL_AREA
    points per voxel face of size `voxel` (input units); None when no part
    of it has colour. A part without colour beside coloured parts, or a
    texture that cannot be read, is an InputError: colour is never dropped
    silently (`colour=False`, `--no-colour`, trains geometry alone)."""
    suffix = path.suffix.lower()
    if suffix in GLTF_SUFFIXES:
        gltf_textures_readable(data, path)
    elif suffix == ".obj":
        obj_textures_readable(data.decode("latin-1"), path)
    rng = np.random.default_rng(seed)
    points, colours, uncoloured = [], [], []
    for node in scene.graph.nodes_geometry:
        transform, key = scene.graph[node]
        geometry = scene.geometry[key]
        if not hasattr(geometry, "faces") or len(geometry.faces) == 0:
            continue
        colour = corner_colours(geometry, f"{path.name}: {key}" if len(scene.geometry) > 1 else path.name,
                                suffix in GLTF_SUFFIXES)
        if colour is None:
            uncoloured.append(str(key))
            continue
        vertices = np.asarray(geometry.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
        triangles = vertices[geometry.faces]
        face, weights = sample_faces(triangles, SAMPLES_PER_VOXEL_AREA / voxel**2, rng)
        points.append(np.einsum("nk,nkc->nc", weights, triangles[face]))
        colours.append(np.asarray(colour(face, weights), np.float32))
    if not points:
        return None
    if uncoloured:
        raise InputError(f"{path.name}: part {uncoloured[0]} has no colour while others have")
    rgb = np.concatenate(colours)
    if not np.isfinite(rgb).all():
        raise InputError(f"{path.name}: NaN or infinite colours")
    return SurfaceColour(np.concatenate(points), np.clip(rgb, 0, 1))


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

