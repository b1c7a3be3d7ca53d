"""Write an asset as one glTF 2.0 binary (.glb): its levels of detail, each a
mesh with normals, tangents and UVs and a PBR metallic-roughness material
of its own baked maps (PNG, or KTX2), in one buffer.

Levels of detail: with MSFT_lod (Babylon.js, UnityGLTF), the finest
level's node lists the coarser levels' nodes, which stand outside the
scene, with MSFT_screencoverage in its extras; a reader that knows no
MSFT_lod shows the finest level alone, as the extension asks. Each level's
mesh is NAME_LOD0, NAME_LOD1, ..., what a person sees in an outliner; the
nodes' names carry Godot's import hints too, and Unreal's where asked
(glb_bytes; docs/ASSETS.md says what each engine reads).

With a Grid, the vertices are quantised (KHR_mesh_quantization): positions
as 16-bit integers on a grid the nodes' transforms undo, normals and
tangents as 8-bit, UVs as 16-bit: 20 bytes a vertex instead of 48.
Compressed (EXT_meshopt_compression), each vertex attribute and index view
is stored as meshoptimizer's codec writes it (its vertices and triangles
first put in the order that codec compresses best), and the views describe
the bytes it decodes to, in a fallback buffer that holds no data.
"""

import io
import json
import math
import os
import struct
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from . import ktx2 as basis

ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
BYTE, SHORT, FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5120, 5122, 5126, 5123, 5125
COMPONENTS = {np.dtype("int8"): BYTE, np.dtype("int16"): SHORT, np.dtype("float32"): FLOAT,
              np.dtype("uint16"): UNSIGNED_SHORT, np.dtype("uint32"): UNSIGNED_INT}
NORMALISED = {BYTE: 127, SHORT: 32767, UNSIGNED_SHORT: 65535}  # what a normalised integer's 1.0 is stored as
LINEAR, LINEAR_MIPMAP_LINEAR, CLAMP_TO_EDGE = 9729, 9987, 33071
GLB_MAGIC, GLB_JSON, GLB_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
ROUGHNESS = 0.9  # stone, earth, plaster: what sinshape's shapes are; not metal
CLAY = (0.80, 0.76, 0.70)  # the base colour of a geometry-only model's asset (linear)
Z_UP_TO_Y_UP = [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]  # a quaternion (x, y, z, w): -90 degrees about x
PNG_LEVEL = 3  # zlib level of the maps: 6 made a 2048 normal map 15% smaller in 2.9x the time


@dataclass(frozen=True)
class Placement:
    """Where a file's nodes put its levels: `base` (a point of the levels'
    frame) at the origin, the levels scaled by `scale`; `height` is what
    the scaled levels measure from base to top (metres, glTF's unit)."""

    base: np.ndarray
    scale: float
    height: float


@dataclass(frozen=True)
class Grid:
    """The grid quantised positions are stored on: p = centre + half * q, q
    in [-1, 1] (16-bit normalised integers); every node's transform
    carries it, so a reader sees the positions in their frame."""

    centre: np.ndarray  # (3,)
    half: float  # one scale for all axes, so that normals and tangents need no correction

    @classmethod
    def around(cls, positions: list) -> "Grid":
        low = np.min([p.min(axis=0) for p in positions], axis=0)
        high = np.max([p.max(axis=0) for p in positions], axis=0)
        return cls((low + high) / 2, float(max(np.max(high - low) / 2, 1e-12)))


def normalised(values: np.ndarray, dtype, width: int | None = None) -> np.ndarray:
    """Values in [-1, 1] (or [0, 1] for an unsigned type) as normalised
    integers, padded with zeros to `width` components (a vertex attribute's
    4-byte stride)."""
    top = NORMALISED[COMPONENTS[np.dtype(dtype)]]
    out = np.round(np.clip(values, -1, 1) * top).astype(dtype)
    if width and width > out.shape[1]:
        out = np.concatenate([out, np.zeros((len(out), width - out.shape[1]), dtype)], axis=1)
    return np.ascontiguousarray(out)


@dataclass
class Level:
    """One level of detail, ready to write: float32 arrays in the asset's
    frame and uint8 maps (size, size, channels)."""

    positions: np.ndarray  # (V, 3)
    normals: np.ndarray  # (V, 3) unit
    tangents: np.ndarray  # (V, 4)
    uvs: np.ndarray  # (V, 2)
    faces: np.ndarray  # (F, 3)
    normal_map: np.ndarray
    colour_map: np.ndarray | None
    occlusion_map: np.ndarray | None


def in_codec_order(faces: np.ndarray, vertex_count: int) -> tuple:
    """(faces, order): the triangles reordered for the vertex cache and the
    vertices renumbered in the order the triangles first use them, what
    meshoptimizer's codecs compress best; order[new] is a vertex's old index."""
    import meshoptimizer  # the assets extra

    cached = np.empty(faces.size, np.uint32)
    meshoptimizer.optimize_vertex_cache(cached, np.ascontiguousarray(faces, np.uint32).ravel(), faces.size, vertex_count)
    used, first = np.unique(cached, return_index=True)
    order = np.concatenate([used[np.argsort(first)], np.setdiff1d(np.arange(vertex_count), used)])
    renumbered = np.empty(vertex_count, np.int64)
    renumbered[order] = np.arange(vertex_count)
    return renumbered[cached].reshape(-1, 3), order


def encoded(array: np.ndarray, target: int) -> bytes:
    """`array` as EXT_meshopt_compression stores it: triangles by the index
    codec, a vertex attribute by the vertex codec's version 0 (the one that
    extension reads)."""
    import meshoptimizer  # the assets extra

    if target == ELEMENT_ARRAY_BUFFER:
        return meshoptimizer.encode_index_buffer(array.astype(np.uint32), array.size, int(array.max()) + 1)
    meshoptimizer.encode_vertex_version(0)
    return meshoptimizer.encode_vertex_buffer(np.ascontiguousarray(array), len(array), array.strides[0])


class Builder:
    """glTF's JSON and its one binary buffer, filled as parts are added."""

    def __init__(self, grid: Grid | None = None, compress: bool = False, ktx2: bool = False):
        self.grid = grid
        self.compress = compress
        self.ktx2 = ktx2  # the maps' files are KTX2 (KHR_texture_basisu), not PNG
        self.fallback = 0  # bytes the compressed views decode to: the fallback buffer's length
        self.json = {"asset": {"version": "2.0", "generator": "sinshape"}, "buffers": [], "bufferViews": [],
                     "accessors": [], "images": [], "textures": [], "samplers": [], "materials": [],
                     "meshes": [], "nodes": []}
        self.binary = io.BytesIO()

    def view(self, data: bytes, target: int | None = None, stride: int | None = None) -> int:
        """A buffer view of `data`, 4-byte aligned (what every accessor type needs)."""
        self.binary.write(b"\0" * (-self.binary.tell() % 4))
        view = {"buffer": 0, "byteOffset": self.binary.tell(), "byteLength": len(data)}
        if target:
            view["target"] = target
        if stride:
            view["byteStride"] = stride
        self.binary.write(data)
        self.json["bufferViews"].append(view)
        return len(self.json["bufferViews"]) - 1

    def compressed_view(self, array: np.ndarray, target: int, stride: int | None) -> int:
        """A view of `array` stored compressed (EXT_meshopt_compression): the
        codec's bytes in the binary, the view itself the decoded bytes' place
        in the fallback buffer."""
        data = encoded(array, target)
        self.binary.write(b"\0" * (-self.binary.tell() % 4))
        element = array.strides[0]
        codec = {"buffer": 0, "byteOffset": self.binary.tell(), "byteLength": len(data), "byteStride": element,
                 "count": len(array), "mode": "TRIANGLES" if target == ELEMENT_ARRAY_BUFFER else "ATTRIBUTES"}
        self.binary.write(data)
        self.fallback += -self.fallback % 4
        view = {"buffer": 1, "byteOffset": self.fallback, "byteLength": array.nbytes, "target": target,
                "extensions": {"EXT_meshopt_compression": codec}}
        if stride:
            view["byteStride"] = stride
        self.fallback += array.nbytes
        self.json["bufferViews"].append(view)
        return len(self.json["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False,
                 normalised: bool = False) -> int:
        """An accessor of `array`; an integer vertex attribute padded to a
        4-byte stride (normalised: read as [-1, 1] or [0, 1]) keeps its
        padding out of `kind`'s components."""
        component = COMPONENTS[array.dtype]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[kind]
        padded = array.ndim > 1 and array.shape[1] > width
        stride = array.strides[0] if padded else None
        view = self.compressed_view(array, target, stride) if self.compress else self.view(array.tobytes(), target, stride)
        entry = {"bufferView": view,
                 "componentType": component, "count": len(array) if array.ndim > 1 else array.size, "type": kind}
        if normalised:
            entry["normalized"] = True
        if bounds:  # POSITION needs its bounds, in the stored values
            values = array[:, :width]
            entry["min"], entry["max"] = values.min(axis=0).tolist(), values.max(axis=0).tolist()
        self.json["accessors"].append(entry)
        return len(self.json["accessors"]) - 1

    def positions(self, positions: np.ndarray) -> int:
        if self.grid is None:
            return self.accessor(np.asarray(positions, np.float32), "VEC3", ARRAY_BUFFER, True)
        stored = normalised((positions - self.grid.centre) / self.grid.half, np.int16, 4)
        return self.accessor(stored, "VEC3", ARRAY_BUFFER, True, True)

    def texture(self, data: bytes, name: str) -> int:
        """A texture of a map's file (PNG, or KTX2 named by KHR_texture_basisu, which has no PNG beside it)."""
        mime = "image/ktx2" if self.ktx2 else "image/png"
        self.json["images"].append({"name": name, "mimeType": mime, "bufferView": self.view(data)})
        if not self.json["samplers"]:
            self.json["samplers"].append({"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR,
                                          "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE})
        image = len(self.json["images"]) - 1
        self.json["textures"].append({"sampler": 0, "extensions": {"KHR_texture_basisu": {"source": image}}}
                                     if self.ktx2 else {"sampler": 0, "source": image})
        return len(self.json["textures"]) - 1

    def material(self, level: Level, maps: dict, name: str) -> int:
        pbr = {"metallicFactor": 0.0, "roughnessFactor": ROUGHNESS}
        if level.colour_map is not None:
            pbr["baseColorTexture"] = {"index": self.texture(maps["colour_map"], f"{name}_basecolor")}
        else:
            pbr["baseColorFactor"] = [*CLAY, 1.0]
        material = {"name": name, "pbrMetallicRoughness": pbr,
                    "normalTexture": {"index": self.texture(maps["normal_map"], f"{name}_normal")}}
        if level.occlusion_map is not None:
            material["occlusionTexture"] = {"index": self.texture(maps["occlusion_map"], f"{name}_occlusion")}
        self.json["materials"].append(material)
        return len(self.json["materials"]) - 1

    def mesh(self, level: Level, maps: dict, name: str) -> int:
        if self.grid is None:
            attributes = {"NORMAL": self.accessor(level.normals.astype(np.float32), "VEC3", ARRAY_BUFFER),
                          "TANGENT": self.accessor(level.tangents.astype(np.float32), "VEC4", ARRAY_BUFFER),
                          "TEXCOORD_0": self.accessor(level.uvs.astype(np.float32), "VEC2", ARRAY_BUFFER)}
        else:
            attributes = {
                "NORMAL": self.accessor(normalised(level.normals, np.int8, 4), "VEC3", ARRAY_BUFFER, normalised=True),
                "TANGENT": self.accessor(normalised(level.tangents, np.int8), "VEC4", ARRAY_BUFFER, normalised=True),
                "TEXCOORD_0": self.accessor(normalised(level.uvs, np.uint16), "VEC2", ARRAY_BUFFER, normalised=True)}
        attributes = {"POSITION": self.positions(level.positions), **attributes}
        index_type = np.uint16 if len(level.positions) < 65535 else np.uint32
        indices = self.accessor(level.faces.astype(index_type).ravel(), "SCALAR", ELEMENT_ARRAY_BUFFER)
        self.json["meshes"].append({"name": name, "primitives": [
            {"attributes": attributes, "indices": indices, "material": self.material(level, maps, name)}]})
        return len(self.json["meshes"]) - 1

    def bare_mesh(self, positions: np.ndarray, faces: np.ndarray, name: str) -> int:
        """A mesh of positions and triangles alone (a collision mesh: no normals, UVs or material)."""
        index_type = np.uint16 if len(positions) < 65535 else np.uint32
        self.json["meshes"].append({"name": name, "primitives": [{
            "attributes": {"POSITION": self.positions(positions)},
            "indices": self.accessor(np.asarray(faces).astype(index_type).ravel(), "SCALAR", ELEMENT_ARRAY_BUFFER)}]})
        return len(self.json["meshes"]) - 1

    def mesh_of(self, mesh: int, name: str) -> int:
        """A mesh of another's positions and triangles alone, its accessors shared (a level as the collision)."""
        primitive = self.json["meshes"][mesh]["primitives"][0]
        self.json["meshes"].append({"name": name, "primitives": [{
            "attributes": {"POSITION": primitive["attributes"]["POSITION"]}, "indices": primitive["indices"]}]})
        return len(self.json["meshes"]) - 1

    def glb(self) -> bytes:
        binary = self.binary.getvalue()
        binary += b"\0" * (-len(binary) % 4)
        self.json["buffers"].append({"byteLength": len(binary)})
        if self.fallback:  # no data: what a reader that lacks the extension would need, so it must refuse the file
            self.json["buffers"].append({"byteLength": self.fallback,
                                         "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
        text = json.dumps({k: v for k, v in self.json.items() if v != []}, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(binary)
        return (struct.pack("<III", GLB_MAGIC, 2, total) + struct.pack("<II", len(text), GLB_JSON) + text
                + struct.pack("<II", len(binary), GLB_BIN) + binary)


def in_codec_level(level: Level) -> Level:
    """The level with its triangles and vertices in codec order (in_codec_order)."""
    faces, order = in_codec_order(level.faces, len(level.positions))
    return replace(level, positions=level.positions[order], normals=level.normals[order],
                               tangents=level.tangents[order], uvs=level.uvs[order], faces=faces)


def in_codec_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple:
    """A bare mesh's (vertices, faces) in codec order (in_codec_order)."""
    faces, order = in_codec_order(np.asarray(faces), len(vertices))
    return np.asarray(vertices)[order], faces


def screen_coverage(count: int) -> list:
    """MSFT_screencoverage: the share of the screen's height above which each
    level shows, finest first, halving level by level; the last shows down to 0."""
    return [0.5 ** (k + 1) for k in range(count - 1)] + [0.0]


def png_bytes(image: np.ndarray) -> bytes:
    """A (size, size, 1 or 3) uint8 map as a PNG file."""
    from PIL import Image  # pillow: only a map's image needs it, and Blender imports this module (its own copy, bundled)

    png = io.BytesIO()
    Image.fromarray(image[..., 0] if image.shape[2] == 1 else image).save(png, "PNG", compress_level=PNG_LEVEL)
    return png.getvalue()


def encoded_maps(levels: list, ktx2: bool = False) -> list:
    """Each level's maps as PNG files, or KTX2 ({field: bytes}), encoded on
    all cores (zlib lets go of the interpreter; the KTX2 encoder is a process a map)."""
    names = ("normal_map", "colour_map", "occlusion_map")
    jobs = [(k, name) for k, level in enumerate(levels) for name in names if getattr(level, name) is not None]

    def encode(job):
        image = getattr(levels[job[0]], job[1])
        png = png_bytes(image)
        return basis.ktx2_bytes(png, len(image), job[1]) if ktx2 else png
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        files = list(pool.map(encode, jobs))
    maps = [{} for _ in levels]
    for (k, name), data in zip(jobs, files):
        maps[k][name] = data
    return maps


def glb_bytes(levels: list, name: str, extras: dict | None = None, up: str = "y",
              place: Placement | None = None, collision: tuple | int | None = None, naming: str = "gltf",
              hulls: list = (), quantise: bool = False, compress: bool = False, ktx2: bool = False) -> bytes:
    """The levels (finest first) as one .glb; `extras` (plain values) go into
    the finest node's extras, beside the screen coverages. up: the axis of
    the levels' frame that points up; glTF's up is +Y, so a z-up frame's
    nodes turn it there (a quarter turn about x), the vertices kept as they
    are. place: where the nodes put the levels (None: where they are).
    collision: (vertices, faces) of a collision mesh in the levels' frame,
    or the index of the level whose own triangles collide (the mesh then
    shares that level's vertices and triangles: no bytes added); hulls:
    [(vertices, faces), ...] of convex hulls, in the levels' frame.
    Names carry Godot's import hints, whatever the naming: the coarser
    levels `NAME_LODn-noimp` (Godot leaves them out, so one level shows),
    the collision mesh `NAME_collision-colonly` and each hull
    `NAME_hullNN-convcolonly` (a static body's concave and convex shapes,
    not drawn). Godot 3 imports every node without a parent, in the scene
    or not; other readers import the scene, which holds the finest level
    alone.
    naming (options.NAMINGS): "gltf" keeps the coarser levels and the
    collision outside the scene, the levels listed by the finest one's
    MSFT_lod; "godot" puts the collision and the hulls in the scene too,
    for Godot 4's importer, which (from its naming version 2) reads the
    scene's nodes alone; "unreal" puts the hulls in the scene as
    `UCX_<finest level>_NN`, Unreal's convex collision of the mesh of that
    name (its importer reads no concave collision from a file, so the
    collision mesh stays outside the scene, as under "gltf").
    quantise: store the vertices quantised (KHR_mesh_quantization, a
    required extension: Grid); compress: quantised, and every vertex and
    index view compressed (EXT_meshopt_compression, required too); ktx2:
    the maps as KTX2 files (KHR_texture_basisu, required: no PNG beside them)."""
    shared = isinstance(collision, int)  # the collision is that level's own triangles
    if compress:
        levels = [in_codec_level(level) for level in levels]
        collision = collision if shared or collision is None else in_codec_mesh(*collision)
        hulls = [in_codec_mesh(*hull) for hull in hulls]
    meshes = [level.positions for level in levels] + [shape[0] for shape in ([] if shared or collision is None
                                                                             else [collision]) + list(hulls)]
    grid = Grid.around(meshes) if quantise or compress else None
    builder = Builder(grid, compress, ktx2)
    nodes = builder.json["nodes"]
    in_scene = {"gltf": (), "godot": ("collision", "hull"), "unreal": ("hull",)}[naming]
    for k, (level, maps) in enumerate(zip(levels, encoded_maps(levels, ktx2))):
        label = f"{name}_LOD{k}"
        nodes.append({"name": label + ("-noimp" if k else ""), "mesh": builder.mesh(level, maps, label)})
    shown = [0]
    if collision is not None:
        label = f"{name}_collision"
        mesh = builder.mesh_of(nodes[collision]["mesh"], label) if shared else builder.bare_mesh(*collision, label)
        nodes.append({"name": label + "-colonly", "mesh": mesh})
        shown += [len(nodes) - 1] if "collision" in in_scene else []
    for k, hull in enumerate(hulls):
        label = f"UCX_{name}_LOD0_{k:02d}" if naming == "unreal" else f"{name}_hull{k:02d}"
        nodes.append({"name": label + ("" if naming == "unreal" else "-convcolonly"),
                      "mesh": builder.bare_mesh(*hull, label)})
        shown += [len(nodes) - 1] if "hull" in in_scene else []
    # A node is translation * rotation * scale: the base (less the grid's centre), scaled and turned, moved to 0.
    base = np.zeros(3) if place is None else np.asarray(place.base, np.float64)
    size = 1.0 if place is None else place.scale
    shift = (base - (0 if grid is None else grid.centre)) * size
    node_scale = size * (1 if grid is None else grid.half)
    turned = [shift[0], shift[2], -shift[1]] if up == "z" else list(shift)
    for node in nodes:
        if up == "z":
            node["rotation"] = Z_UP_TO_Y_UP
        if shift.any():
            node["translation"] = [float(-t) for t in turned]
        if node_scale != 1:
            node["scale"] = [float(node_scale)] * 3
    used = []
    if len(levels) > 1:
        nodes[0]["extensions"] = {"MSFT_lod": {"ids": list(range(1, len(levels)))}}
        used.append("MSFT_lod")
    # A reader that cannot dequantise or decompress would draw nothing right: it must refuse the file.
    required = ((["KHR_mesh_quantization"] if grid is not None else []) + (["EXT_meshopt_compression"] if compress else [])
                + (["KHR_texture_basisu"] if ktx2 else []))
    if required:
        used += required
        builder.json["extensionsRequired"] = required
    if used:
        builder.json["extensionsUsed"] = used
    nodes[0]["extras"] = {"MSFT_screencoverage": screen_coverage(len(levels)), **(extras or {})}
    if grid is not None:
        nodes[0]["extras"].setdefault("sinshape", {})["grid"] = {"centre": grid.centre.tolist(), "half": grid.half}
    builder.json["scenes"] = [{"name": name, "nodes": shown}]
    builder.json["scene"] = 0
    return builder.glb()


def read(data: bytes) -> tuple:
    """(glTF JSON, binary chunk) of a .glb this module wrote (for tests, the
    benchmarks and pictures; a general reader is trimesh's or a viewer's)."""
    magic, version, total = struct.unpack("<III", data[:12])
    if (magic, version, total) != (GLB_MAGIC, 2, len(data)):
        raise ValueError("not a glTF 2.0 binary of its stated length")
    size = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + size]), data[20 + size + 8:]


def decoded(codec: dict, binary: bytes) -> bytes:
    """The bytes a compressed view (its EXT_meshopt_compression object) decodes to."""
    import meshoptimizer  # the assets extra

    data = binary[codec["byteOffset"]:codec["byteOffset"] + codec["byteLength"]]
    if codec["mode"] == "TRIANGLES":
        indices = meshoptimizer.decode_index_buffer(codec["count"], 4, data)
        return np.asarray(indices, np.uint32).astype({2: np.uint16, 4: np.uint32}[codec["byteStride"]]).tobytes()
    # Its default output: the decoded bytes, viewed as float32 (with a dtype given, the bindings' buffer is too short)
    return meshoptimizer.decode_vertex_buffer(codec["count"], codec["byteStride"], data).tobytes()


def level_arrays(document: dict, binary: bytes, node: int) -> dict:
    """A level's arrays (position, normal, tangent, texcoord_0, faces; float
    where they were quantised, positions in the levels' frame) and maps
    (normal_map, colour_map, occlusion_map: None where the material has
    none), by its node."""
    from PIL import Image  # pillow, as png_bytes

    def accessor(index):
        a = document["accessors"][index]
        view = document["bufferViews"][a["bufferView"]]
        dtype = {v: k for k, v in COMPONENTS.items()}[a["componentType"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[a["type"]]
        stride = view.get("byteStride", width * dtype.itemsize) // dtype.itemsize
        data, offset = binary, view["byteOffset"]
        if "EXT_meshopt_compression" in view.get("extensions", {}):
            data, offset = decoded(view["extensions"]["EXT_meshopt_compression"], binary), 0
        values = np.frombuffer(data, dtype, a["count"] * stride, offset).reshape(a["count"], stride)
        values = values[:, :width]
        if a.get("normalized"):
            values = np.maximum(values / NORMALISED[a["componentType"]], -1.0).astype(np.float32)
        return values if width > 1 else values[:, 0]

    def image(texture):
        if texture is None:
            return None
        found = document["textures"][texture["index"]]
        source = found["extensions"]["KHR_texture_basisu"]["source"] if "source" not in found else found["source"]
        view = document["bufferViews"][document["images"][source]["bufferView"]]
        data = binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
        if document["images"][source]["mimeType"] == "image/ktx2":
            return basis.decoded(data)
        return np.asarray(Image.open(io.BytesIO(data)))

    primitive = document["meshes"][document["nodes"][node]["mesh"]]["primitives"][0]
    out = {name.lower(): accessor(index) for name, index in primitive["attributes"].items()}
    grid = document["nodes"][0]["extras"].get("sinshape", {}).get("grid")
    if grid:  # quantised: positions back in the levels' frame
        out["position"] = (np.asarray(grid["centre"]) + grid["half"] * out["position"]).astype(np.float32)
    out["faces"] = accessor(primitive["indices"]).reshape(-1, 3).astype(np.int64)
    material = document["materials"][primitive["material"]]
    out["normal_map"] = image(material["normalTexture"])
    out["colour_map"] = image(material["pbrMetallicRoughness"].get("baseColorTexture"))
    out["occlusion_map"] = image(material.get("occlusionTexture"))
    return out
