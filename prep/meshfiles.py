"""The files a mesh names, read from inside its own folder: an OBJ's
material library and its textures, a glTF's buffers and images.

A mesh file is untrusted input, and so is every name in it. A name is
looked up in one folder (the mesh's own, unless the caller widens it) and
must lead, after symbolic links, to a regular file inside that folder;
anything else (an absolute path elsewhere, `../x.png`, a link out of the
folder, a FIFO, a device, a folder) is refused with one line naming it,
before a byte is read. Files are opened without blocking, so a FIFO cannot
hang a reader, and never read past a bound: an image of at most
MAX_IMAGE_BYTES, other files within the memory they would take.

The structure that names the files is checked here too, before trimesh
reads the mesh: a glTF's JSON (every index in range, every URI readable, a
base colour factor of four numbers in [0, 1]), an MTL's texture statements
parsed as the format defines their options. An image's pixels are counted
against the memory budget from its header, before it is decoded.

trimesh reads these files through `FolderResolver`, which applies the same
rules, so nothing it reads escapes them either (it drops a file it cannot
read without a word: the checks here come first and say why).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import io
import json
import math
import os
import re
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import trimesh
from PIL import Image

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import read_regular

# An image file larger than this is refused unread: 2^27 pixels (the most a
# texture may have) of 16-bit RGBA, uncompressed, fit in 1 GiB.
MAX_IMAGE_BYTES = 1 << 30
MAX_MTL_BYTES = 16 << 20  # a material library is text: a few kB in practice
# A texture larger than this is refused before it is decoded: 16k a side is
# the largest in common use; 2^27 pixels (16k x 8k) keeps its float copy
# near 1.6 GB, and below Pillow's own decompression-bomb limit.
MAX_TEXTURE_SIDE = 16384
MAX_TEXTURE_PIXELS = 1 << 27
# Peak bytes per pixel of decoding a texture and holding it as float32 RGB
# (the decoded image, its RGB copy, the float array; a base colour factor
# converts it through linear light): measured 30 on a 4096 x 4096 RGBA PNG.
TEXTURE_BYTES_PER_PIXEL = 40
# Memory a glTF buffer takes as trimesh reads it, per byte (the bytes, the
# arrays cut from them, the mesh): as a mesh file's (voxelize.py).
BUFFER_BYTES_PER_BYTE = 24

# MTL texture options (the Wavefront MTL specification, "texture map
# options"): how many arguments each takes, (fewest, most). Numbers only,
# but for the on/off switches and -imfchan/-type's one word.
MTL_OPTIONS = {"-blendu": (1, 1), "-blendv": (1, 1), "-cc": (1, 1), "-clamp": (1, 1), "-mm": (2, 2),
               "-o": (1, 3), "-s": (1, 3), "-t": (1, 3), "-texres": (1, 1), "-bm": (1, 1), "-boost": (1, 1),
               "-imfchan": (1, 1), "-type": (1, 1)}
WORD_OPTIONS = ("-blendu", "-blendv", "-cc", "-clamp", "-imfchan", "-type")


class MeshFolder:
    """Where the files a mesh names may lie (`root`, by default the mesh's
    own folder), and how they are read."""

    def __init__(self, mesh: Path, root: Path | None = None):
        self.mesh = Path(mesh)
        self.folder = Path(os.path.realpath(self.mesh.parent))
        self.root = Path(os.path.realpath(root)) if root is not None else self.folder
        if root is not None and not self.root.is_dir():
            raise InputError(f"{root}: not a folder", "asset_folder")
        self.read_before = {}  # name -> bytes the checks read, handed to trimesh once
        self.digest = hashlib.sha256()  # of every file read: what a resumed run compares

    def where(self) -> str:
        return "its folder" if self.root == self.folder else f"the folder {self.root}"

    def label(self, name: str, what: str, named_in: str = "") -> str:
        return f"{self.mesh.name}: {what} {name.strip()}" + (f" (named in {named_in})" if named_in else "")

    def resolve(self, name: str, what: str, named_in: str = "") -> Path:
        """The file `name` leads to from the mesh's folder: inside the root
        (after links), or refused in one line naming `what` refers to it."""
        if not isinstance(name, str) or not name.strip() or "\0" in name:
            raise InputError(f"{self.mesh.name}: {what} has no usable file name ({str(name)[:100]!r})")
        path = Path(os.path.realpath(self.folder / name.strip()))
        if not path.is_relative_to(self.root):
            raise InputError(f"{self.label(name, what, named_in)} lies outside {self.where()}, and a mesh's files "
                             "are read from there only (`asset_folder` widens it)", "asset_folder")
        return path

    def read(self, name: str, what: str, limit: int | None = None, per_byte: int = 1, named_in: str = "") -> bytes:
        """The bytes of the regular file `name` leads to, opened without
        blocking; at most `limit` bytes, and their memory (`per_byte` times
        their size) checked before they are read."""
        data = read_regular(self.resolve(name, what, named_in), self.label(name, what, named_in), limit, per_byte)
        self.digest.update(hashlib.sha256(name.strip().encode("utf-8", "replace")).digest())
        self.digest.update(hashlib.sha256(data).digest())
        self.read_before[name.strip()] = data
        return data


class FolderResolver(trimesh.resolvers.FilePathResolver):
    """trimesh's way to the files a mesh names, held to MeshFolder's rules.
    An MTL's texture statement reaches it whole (trimesh passes everything
    after `map_Kd`): its options are parsed off as the format defines."""

    def __init__(self, folder: MeshFolder):
        super().__init__(str(folder.mesh))
        self.mesh_folder = folder

    def get(self, name):
        name = str(name)
        if name.lstrip().startswith("-"):
            name = mtl_map(name)[1]
        checked = self.mesh_folder.read_before.pop(name.strip(), None)
        if checked is not None:
            return checked
        return self.mesh_folder.read(name, "the file", MAX_IMAGE_BYTES, BUFFER_BYTES_PER_BYTE)


# -- OBJ and MTL ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MtlTexture:
    """A diffuse texture an MTL names (`map_Kd [options] file`)."""

    library: str  # the .mtl's name, as the OBJ gives it
    file: str
    options: dict  # option -> its arguments (strings)


def mtl_map(arguments: str) -> tuple:
    """An MTL texture statement's arguments -> ({option: [arguments]}, file
    name), options parsed as the format defines them: -o, -s and -t take one
    to three numbers, -mm two, the others one. The file is the rest (it may
    hold spaces)."""
    words = arguments.split()
    options, at = {}, 0
    while at < len(words) and words[at].startswith("-") and words[at].lower() in MTL_OPTIONS:
        option = words[at].lower()
        fewest, most = MTL_OPTIONS[option]
        taken = []
        while len(taken) < most and at + 1 + len(taken) < len(words) - 1 and (
                option in WORD_OPTIONS or is_number(words[at + 1 + len(taken)])):
            taken.append(words[at + 1 + len(taken)])
        if len(taken) < fewest:
            raise InputError(f"its texture option {option} takes {fewest} argument{'s' * (fewest > 1)}, "
                             f"in {arguments.strip()[:100]!r}")
        if option in ("-blendu", "-blendv", "-cc", "-clamp") and taken[0].lower() not in ("on", "off"):
            raise InputError(f"its texture option {option} is on or off, not {taken[0][:20]!r}")
        options[option] = taken
        at += 1 + len(taken)
    if at >= len(words):
        raise InputError(f"its texture statement names no file ({arguments.strip()[:100]!r})")
    if words[at].startswith("-"):
        raise InputError(f"its texture statement has an option the format does not define: {words[at][:20]!r}")
    # The file name is the rest of the statement as written (spaces kept).
    rest = arguments.strip()
    for word in words[:at]:
        rest = rest[rest.index(word) + len(word):].lstrip()
    return options, rest


def is_number(word: str) -> bool:
    try:
        return math.isfinite(float(word))
    except ValueError:
        return False


STATEMENT = re.compile(r"^[ \t]*(\S+)[ \t]+(.*?)[ \t]*$", re.MULTILINE)
MTLLIB = re.compile(r"^[ \t]*mtllib[ \t]+(.*?)[ \t]*$", re.MULTILINE)


def obj_textures(text: str, folder: MeshFolder) -> list:
    """Every material library an OBJ names (`mtllib`), read from its folder,
    and the diffuse textures (`map_Kd`) they name: a list of MtlTexture.
    Colours (`Kd`) must be three numbers in [0, 1]."""
    textures = []
    for library in MTLLIB.findall(text):  # only these lines: an OBJ may hold millions of others
        mtl = folder.read(library, "material library", MAX_MTL_BYTES).decode("utf-8", errors="replace")
        for key, value in STATEMENT.findall(mtl):
            key = key.lower()
            where = f"{folder.mesh.name}: {library}"
            if key == "map_kd":
                try:
                    options, file = mtl_map(value)
                except InputError as error:
                    raise InputError(f"{where}: {error}") from None
                textures.append(MtlTexture(library, file, options))
            elif key == "kd":
                numbers = value.split()
                if not (len(numbers) == 3 and all(is_number(n) and 0 <= float(n) <= 1 for n in numbers)):
                    raise InputError(f"{where}: a diffuse colour (Kd) must be three numbers in [0, 1], got "
                                     f"{value[:60]!r}")
    return textures


# -- glTF -------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GltfImage:
    """An image a glTF's material uses as its base colour: its name for
    messages and where its bytes are."""

    index: int
    name: str
    data: bytes


def gltf_json(data: bytes, name: str) -> tuple:
    """(the JSON object, the binary chunk or b"") of a .glb or .gltf's bytes,
    its chunks checked against the file's length."""
    binary = b""
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise InputError(f"{name}: a .glb cut short ({len(data)} bytes)")
        version, length, chunk, kind = struct.unpack_from("<IIII", data, 4)
        if version != 2:
            raise InputError(f"{name}: glTF version {version}; only 2 is read")
        if kind != 0x4E4F534A or 20 + chunk > len(data):
            raise InputError(f"{name}: its JSON chunk is {'not first' if kind != 0x4E4F534A else 'cut short'}")
        text = data[20:20 + chunk]
        rest = data[20 + chunk:]
        if len(rest) >= 8:
            size, kind = struct.unpack_from("<II", rest)
            if kind == 0x004E4942:  # BIN
                if 8 + size > len(rest):
                    raise InputError(f"{name}: its binary chunk declares {size} bytes and holds {len(rest) - 8}")
                binary = rest[8:8 + size]
    else:
        text = data
    try:
        meta = json.loads(text)
    except (ValueError, RecursionError):
        raise InputError(f"{name}: its glTF JSON does not parse") from None
    if not isinstance(meta, dict):
        raise InputError(f"{name}: its glTF JSON is not an object")
    return meta, binary


def items(meta: dict, key: str, name: str) -> list:
    """A top-level glTF array of objects (empty when absent)."""
    value = meta.get(key, [])
    if not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
        raise InputError(f"{name}: its glTF {key} must be a list of objects")
    return value


def index(value, count: int, what: str, name: str, kind: str) -> int:
    """A glTF index: an integer in [0, count)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
        raise InputError(f"{name}: {what} is {json.dumps(value)[:40]}, not one of its {count} {kind}")
    return value


def data_uri(uri: str, what: str, name: str) -> bytes:
    """The bytes of a base64 `data:` URI (trimesh reads no other kind)."""
    head, comma, payload = uri.partition(",")
    if not comma or not head.endswith(";base64"):
        raise InputError(f"{name}: {what} is a data: URI that is not base64 (data:[type];base64,...)")
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError):
        raise InputError(f"{name}: {what} is a data: URI whose base64 does not decode") from None


def gltf_images(data: bytes, folder: MeshFolder, materials: bool = True) -> list:
    """Check a glTF's structure before trimesh reads it: its buffers (each
    URI readable from the folder or a base64 data: URI, of the length it
    declares), buffer views inside them, its images' URIs and views, its
    textures' and materials' indices and base colour factors. Returns the
    GltfImage of every image a material uses as its base colour (with
    `materials`; without, only the buffers are checked, as trimesh then
    reads nothing else)."""
    name = folder.mesh.name
    meta, binary = gltf_json(data, name)
    buffers = []
    for number, buffer in enumerate(items(meta, "buffers", name)):
        length = buffer.get("byteLength")
        if isinstance(length, bool) or not isinstance(length, int) or length < 0:
            raise InputError(f"{name}: buffer {number}'s byteLength must be a whole number")
        uri = buffer.get("uri")
        what = f"buffer {number}'s file"
        if uri is None:
            raw = binary if number == 0 else b""
        elif not isinstance(uri, str):
            raise InputError(f"{name}: buffer {number}'s uri must be a string")
        elif uri.startswith("data:"):
            raw = data_uri(uri, f"buffer {number}'s uri", name)
        else:
            raw = folder.read(uri, what, None, BUFFER_BYTES_PER_BYTE)
        if len(raw) < length:
            raise InputError(f"{name}: buffer {number} holds {len(raw)} bytes and declares {length}")
        buffers.append(raw)
    views = items(meta, "bufferViews", name)
    for number, view in enumerate(views):
        buffer = index(view.get("buffer"), len(buffers), f"buffer view {number}'s buffer", name, "buffers")
        offset, length = view.get("byteOffset", 0), view.get("byteLength")
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (offset, length)) \
                or offset + length > len(buffers[buffer]):
            raise InputError(f"{name}: buffer view {number} does not lie inside buffer {buffer}")
    if not materials:
        return []
    try:
        return base_colour_images(meta, buffers, views, folder)
    except InputError as error:
        raise colour_input(error) from None


def colour_input(error: InputError) -> InputError:
    """A refusal of what a mesh's colour is read from, marked so (its
    parameters include no_colour): reading without colour gets past it."""
    return type(error)(error.template, parameters(error) + ("no_colour",))


def parameters(error: InputError) -> tuple:
    """The parameters an InputError names, as a tuple."""
    names = error.parameter if isinstance(error.parameter, tuple) else (error.parameter,)
    return tuple(name for name in names if name)


def base_colour_images(meta: dict, buffers: list, views: list, folder: MeshFolder) -> list:
    """The GltfImage of every image a glTF's materials use as their base
    colour, after checking its images' URIs and views, its textures' and
    materials' indices and its base colour factors."""
    name = folder.mesh.name
    images = items(meta, "images", name)
    for number, image in enumerate(images):
        uri = image.get("uri")
        if "bufferView" in image:
            index(image["bufferView"], len(views), f"image {number}'s bufferView", name, "buffer views")
        elif not isinstance(uri, str):
            raise InputError(f"{name}: image {number} has neither a uri nor a bufferView")
        elif not uri.startswith("data:"):
            folder.resolve(uri, f"image {number}'s file")  # trimesh reads every image: none from outside
    textures = items(meta, "textures", name)
    for number, texture in enumerate(textures):
        if "source" in texture:
            index(texture["source"], len(images), f"texture {number}'s source", name, "images")
    used = set()
    for number, material in enumerate(items(meta, "materials", name)):
        pbr = material.get("pbrMetallicRoughness", {})
        if not isinstance(pbr, dict):
            raise InputError(f"{name}: material {number}'s pbrMetallicRoughness must be an object")
        factor = pbr.get("baseColorFactor", [1, 1, 1, 1])
        if not (isinstance(factor, list) and len(factor) == 4 and all(
                isinstance(f, (int, float)) and not isinstance(f, bool) and 0 <= f <= 1 for f in factor)):
            raise InputError(f"{name}: material {number}'s baseColorFactor must be four numbers in [0, 1], got "
                             f"{json.dumps(factor)[:80]}")
        if "baseColorTexture" in pbr:
            reference = pbr["baseColorTexture"]
            if not isinstance(reference, dict):
                raise InputError(f"{name}: material {number}'s baseColorTexture must be an object")
            texture = textures[index(reference.get("index"), len(textures), f"material {number}'s base colour "
                                     "texture", name, "textures")]
            if "source" in texture:
                used.add(texture["source"])
    for mesh in items(meta, "meshes", name):
        for primitive in mesh.get("primitives", []) if isinstance(mesh.get("primitives"), list) else []:
            if isinstance(primitive, dict) and "material" in primitive:
                index(primitive["material"], len(meta.get("materials", [])), "a primitive's material", name,
                      "materials")
    found = []
    for number in sorted(used):
        image = images[number]
        uri = image.get("uri")
        label = uri if uri and not uri.startswith("data:") else f"embedded image {number}"
        if "bufferView" in image:
            view = views[image["bufferView"]]
            start = view.get("byteOffset", 0)
            raw = buffers[view["buffer"]][start:start + view["byteLength"]]
        elif uri.startswith("data:"):
            raw = data_uri(uri, f"image {number}'s uri", name)
        else:
            raw = folder.read(uri, f"image {number}'s file", MAX_IMAGE_BYTES)
        found.append(GltfImage(number, label, raw))
    return found


# -- what a mesh names, checked before trimesh reads it --------------------------------------------

@dataclass(frozen=True)
class Texture:
    """A base colour texture a mesh names, checked: its name for messages,
    its size and, if every pixel is one colour, that colour (8-bit sRGB)."""

    name: str
    width: int
    height: int
    one_colour: tuple | None


@dataclass(frozen=True)
class References:
    """What the files a mesh names hold, as checked: the textures, and the
    SHA-256 of every file read (names and bytes), which a resumed training
    run compares with its checkpoint's."""

    textures: tuple
    sha256: str


def check_references(path: Path, data: bytes, folder: MeshFolder, materials: bool = True) -> References:
    """Check every file a mesh names, and the structure that names them,
    before trimesh reads it: a glTF's buffers always (its geometry), and
    with `materials` an OBJ's material libraries and every base colour
    texture (decoded once, so a damaged one is named here)."""
    suffix = path.suffix.lower()
    textures = []
    if suffix in (".glb", ".gltf"):
        for image in gltf_images(data, folder, materials):
            try:
                textures.append(checked_texture(image.data, image.name,
                                                f"{path.name}: base colour texture {image.name}"))
            except InputError as error:
                raise colour_input(error) from None
    elif suffix == ".obj" and materials:
        try:
            for mtl in {mtl.file: mtl for mtl in obj_textures(data.decode("latin-1"), folder)}.values():
                raw = folder.read(mtl.file, "texture", MAX_IMAGE_BYTES, named_in=mtl.library)  # each file once
                textures.append(checked_texture(raw, mtl.file, f"{path.name}: texture {mtl.file}"))
        except InputError as error:
            raise colour_input(error) from None
    return References(tuple(textures), folder.digest.hexdigest())


def checked_texture(raw: bytes, name: str, label: str) -> Texture:
    width, height, extrema = check_image(raw, label)
    one = tuple(low for low, high in extrema) if all(low == high for low, high in extrema) else None
    return Texture(name, width, height, one)


# -- images -----------------------------------------------------------------------------------------

def check_image(raw: bytes, name: str) -> tuple:
    """An image file's (width, height, (min, max) of each RGB channel), its
    pixels counted against the memory budget from its header before they are
    decoded, then decoded once to see that they can be. `name` says which
    image, for messages."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # our own bound applies
            image = Image.open(io.BytesIO(raw))
        with image:
            width, height = image.size
            check_texture_size(width, height, name)
            check_memory(width * height * TEXTURE_BYTES_PER_PIXEL, f"decoding {name} ({width}x{height})")
            image.load()
            extrema = image.convert("RGB").getextrema()
    except Image.DecompressionBombError:
        raise InputError(f"{name}: an image of absurd size is not a usable size for a texture") from None
    except (OSError, ValueError, SyntaxError, struct.error) as error:
        if isinstance(error, InputError):
            raise
        raise InputError(f"{name}: cannot read it as an image ({str(error).splitlines()[0][:200]})") from None
    return width, height, extrema


def check_texture_size(width: int, height: int, name: str) -> None:
    if not (1 <= width <= MAX_TEXTURE_SIDE and 1 <= height <= MAX_TEXTURE_SIDE) or width * height > MAX_TEXTURE_PIXELS:
        raise InputError(f"{name}: a {width}x{height} texture is not a usable size (at most {MAX_TEXTURE_SIDE} "
                         f"pixels a side and {MAX_TEXTURE_PIXELS} in all)")
