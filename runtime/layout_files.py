"""Layout files: a sample's coarse layout (layout) written for an artist
to edit, and read back, checked before anything else reads it: MagicaVoxel
.vox (what voxel artists edit), .npz, or a rough mesh voxelised on the
layout's grid."""

import io
import struct
import zipfile
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import MESH_FORMATS, atomic_write, read_regular
from sinshape.core.manifest import MAX_LEVEL_SIDE

from .layout import cells, grid_size, layout

LAYOUT_FORMATS = (".vox", ".npz")
MAX_LAYOUT_SIDE = 256  # MagicaVoxel's own limit per axis
MAX_LAYOUT_BYTES = 64 << 20
MAX_LAYOUT_CELLS = 512**3  # an .npz layout; a coarse level is far smaller
VOX_VERSION = 150
VOX_COLOUR = 1  # palette index the voxels are written with (any non-zero index reads as full)


def check_layout_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in LAYOUT_FORMATS:
        raise InputError(f"{path}: a layout is a {' or '.join(LAYOUT_FORMATS)} file, not {path.suffix or 'no extension'}")
    return path


def vox_bytes(grid: np.ndarray) -> bytes:
    """A MagicaVoxel .vox file of one model: MAIN holding SIZE and XYZI."""
    x, y, z = np.nonzero(grid)
    voxels = np.stack([x, y, z, np.full_like(x, VOX_COLOUR)], axis=1).astype(np.uint8).tobytes()
    size = struct.pack("<3i", *grid.shape)
    xyzi = struct.pack("<i", len(x)) + voxels
    children = (b"SIZE" + struct.pack("<2i", len(size), 0) + size
                + b"XYZI" + struct.pack("<2i", len(xyzi), 0) + xyzi)
    return b"VOX " + struct.pack("<i", VOX_VERSION) + b"MAIN" + struct.pack("<2i", 0, len(children)) + children


def read_vox(data: bytes, path) -> np.ndarray:
    """The one model of a .vox file as a bool grid; chunks other than SIZE
    and XYZI (palette, materials, scene graph) are skipped. Every size a
    chunk declares is checked (sign, and that it fits what is left of its
    parent) before it is used."""
    def corrupt(why):
        return InputError(f"{path}: not a readable MagicaVoxel file ({why})")

    if len(data) < 20 or data[:4] != b"VOX " or data[8:12] != b"MAIN":
        raise corrupt("no 'VOX ' header and MAIN chunk")
    content, children = struct.unpack_from("<2i", data, 12)
    if not (0 <= content and 0 <= children and 20 + content + children <= len(data)):
        raise corrupt(f"MAIN declares {content} and {children} bytes, and runs past the end of the "
                      f"{len(data) - 20} after it")
    end = 20 + content + children
    size, voxels, at = None, None, 20 + content
    models = 0
    while at < end:
        if at + 12 > end:
            raise corrupt("a chunk runs past the end")
        name = data[at:at + 4]
        content, children = struct.unpack_from("<2i", data, at + 4)
        if content < 0 or children < 0 or at + 12 + content + children > end:
            raise corrupt(f"chunk {name!r} declares {content} and {children} bytes, past the end")
        body = data[at + 12:at + 12 + content]
        if name == b"SIZE":
            models += 1
            if content < 12:
                raise corrupt("a SIZE chunk too short")
            size = struct.unpack_from("<3i", body)
            if not all(1 <= n <= MAX_LAYOUT_SIDE for n in size):
                raise InputError(f"{path}: a model of {'x'.join(map(str, size))} voxels; a layout has 1 to "
                                 f"{MAX_LAYOUT_SIDE} per axis")
        elif name == b"XYZI":
            count = struct.unpack_from("<i", body)[0] if content >= 4 else -1
            if not 0 <= count <= (content - 4) // 4:
                raise corrupt("an XYZI chunk whose count does not fit it")
            voxels = np.frombuffer(body, np.uint8, count * 4, 4).reshape(count, 4)
        at += 12 + content + children
    if models != 1 or voxels is None or size is None:
        raise InputError(f"{path}: holds {models} models; a layout is one")
    xyz = voxels[:, :3].astype(int)
    if (xyz >= np.array(size)).any():
        raise corrupt("a voxel outside its model's size")
    grid = np.zeros(size, bool)
    grid[tuple(xyz.T)] = voxels[:, 3] > 0
    return grid


def check_fits(shape: tuple, suffix: str, name) -> None:
    """A layout of `shape` fits a `suffix` file (.vox: MagicaVoxel's 256 a
    side): checked from the level's size, before the layout is made."""
    if suffix.lower().lstrip(".") == "vox" and max(shape) > MAX_LAYOUT_SIDE:
        raise InputError(f"{name}: a {'x'.join(map(str, shape))} layout; .vox holds at most "
                         f"{MAX_LAYOUT_SIDE} voxels per axis (write .npz)")


def write_layout(grid: np.ndarray, path) -> None:
    """A layout to .vox or .npz (array `layout`), atomically."""
    path = check_layout_path(path)
    check_fits(grid.shape, path.suffix, path)
    if path.suffix.lower() == ".vox":
        data = vox_bytes(grid)
    else:
        buffer = io.BytesIO()
        np.savez_compressed(buffer, layout=grid.astype(bool))
        data = buffer.getvalue()
    atomic_write(path, lambda f: f.write(data))


def read_layout(path) -> np.ndarray:
    """A layout file as a bool grid, checked: bounded size, one 3-D grid."""
    path = check_layout_path(path)
    data = read_regular(path, f"the layout {path}", MAX_LAYOUT_BYTES, field="layout")
    return parse_layout(data, path.suffix.lower(), path)


def parse_layout(data: bytes, suffix: str, name) -> np.ndarray:
    """The bytes of a .vox or .npz layout (`suffix`) as a bool grid; `name`
    says what they are in messages. Bounds come from what is read: an .npz
    must hold the one member `layout.npy` (np.load would read a member named
    plain `layout` first), whose header is checked before its data, and at
    most the bytes that header declares are decompressed."""
    if len(data) > MAX_LAYOUT_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a layout")
    if suffix == ".vox":
        return read_vox(data, name)
    return read_npz(data, name)


def read_npz(data: bytes, name) -> np.ndarray:
    """The array `layout` of an .npz archive, read member first, header
    second, data last, each bounded by what came before: deflate is read a
    bounded piece at a time, so at most the bytes the header declares (at
    most MAX_LAYOUT_BYTES) are ever decompressed."""
    def unreadable(why):
        return InputError(f"{name}: not a readable .npz layout ({why})")

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            members = archive.infolist()
            if [m.filename for m in members] != ["layout.npy"]:
                listed = ", ".join(repr(m.filename) for m in members[:4]) + (", ..." if len(members) > 4 else "")
                raise unreadable(f"it must hold one array, layout.npy, and holds {listed or 'nothing'}")
            if members[0].compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                # bzip2 and LZMA decompress a chunk whole: a few bytes could unpack into gigabytes at once
                raise unreadable("compressed other than as NumPy writes it, stored or deflated")
            with archive.open(members[0]) as member:
                major, _ = np.lib.format.read_magic(member)
                if major not in (1, 2):
                    raise unreadable(f"NPY format version {major}")
                read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
                shape, fortran, dtype = read_header(member, max_header_size=10000)
                check_npz_header(shape, dtype, name)
                needed = int(np.prod(shape)) * dtype.itemsize
                if needed > MAX_LAYOUT_BYTES:
                    raise InputError(f"{name}: its layout of shape {shape} holds {needed >> 20} MB; a layout "
                                     f"holds at most {MAX_LAYOUT_BYTES >> 20} MB")
                body = member.read(needed + 1)  # at most what the header declares, and one byte to see more
    except InputError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, NotImplementedError, SyntaxError, TypeError) as error:
        raise unreadable(type(error).__name__) from None
    if len(body) != needed:
        raise unreadable(f"its data is {len(body)} bytes and its header declares {needed}")
    grid = np.frombuffer(body, dtype).reshape(shape, order="F" if fortran else "C")
    if grid.dtype == bool:
        return grid.copy()
    if not np.isfinite(grid).all():
        raise InputError(f"{name}: 'layout' holds NaN or infinite values, not occupancy in [0, 1]")
    return grid > 0.5


def check_npz_header(shape: tuple, dtype, name) -> None:
    """An .npz layout's header, before a byte of its data is read: 3 bounded
    axes of booleans or real numbers."""
    if not (isinstance(shape, tuple) and len(shape) == 3 and all(isinstance(n, int) for n in shape)
            and all(1 <= n <= MAX_LEVEL_SIDE for n in shape) and np.prod(shape, dtype=object) <= MAX_LAYOUT_CELLS):
        raise InputError(f"{name}: needs an array 'layout' of 3 axes, 1 to {MAX_LEVEL_SIDE} each and at most "
                         f"{MAX_LAYOUT_CELLS} cells, got shape {shape}")
    if not (dtype.kind == "b" or np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)) \
            or dtype.hasobject or dtype.itemsize > 8:
        raise InputError(f"{name}: 'layout' holds {dtype}, not occupancy")


def mesh_layout(model, path, factors=(1.0, 1.0, 1.0)) -> np.ndarray:
    """A rough mesh (a few boxes, in the model's frame: the units of its
    samples' meshes) voxelised on level 0's grid of a sample of `factors`."""
    from sinshape.prep.voxelize import load_mesh, voxelize  # the prep extra: only a layout read from a mesh needs it

    corner, spacing, shape = cells(model.manifest, factors)
    grid = voxelize(load_mesh(path), corner, spacing, shape)
    if not grid.any():
        raise InputError(f"{path}: the mesh lies outside the sample's box (its frame is the model's: "
                         "the units of its samples' meshes)", "layout")
    return grid


def read_any(model, path, factors=(1.0, 1.0, 1.0)) -> np.ndarray:
    """A layout from a file: a .vox or .npz layout as it is, or a rough mesh
    in any format trimesh reads, voxelised on level 0's grid (`mesh_layout`)."""
    if Path(path).suffix.lower() in MESH_FORMATS:
        return mesh_layout(model, path, factors)
    return read_layout(path)


def export(model, seed: int, path, level: int = 0, factors=(1.0, 1.0, 1.0)) -> tuple:
    """Write the layout of the sample of `seed` at `level` to `path`; its grid size."""
    check_fits(grid_size(model, level, factors), check_layout_path(path).suffix, path)
    grid = layout(model, seed, level, factors)
    write_layout(grid, path)
    return grid.shape
