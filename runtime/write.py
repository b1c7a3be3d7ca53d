"""Write samples by file extension, never leaving a half-written file.

Meshes: .ply .obj .stl .off .glb (trimesh's exporters). Occupancy grids:
.npz. Every file is written to a temporary name beside the target and then
renamed, so a crash or Ctrl-C leaves either the old file or the new one;
mesh_bytes and grid_bytes give the same bytes in memory, to send elsewhere.
"""

import io
import os
from pathlib import Path

import numpy as np

from .errors import InputError

MESH_FORMATS = {".ply": "ply", ".obj": "obj", ".stl": "stl", ".off": "off", ".glb": "glb"}
GRID_FORMATS = {".npz"}


def output_kind(path) -> str:
    """'mesh' or 'grid', from the extension; InputError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix in MESH_FORMATS:
        return "mesh"
    if suffix in GRID_FORMATS:
        return "grid"
    known = ", ".join([*MESH_FORMATS, *GRID_FORMATS])
    raise InputError(f"{path}: unsupported output format {suffix or '(no extension)'!r}; use one of {known}")


def check_writable(path) -> None:
    """Fail before long work, not after it, if `path` cannot be written."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a file name")
    if not path.parent.is_dir():
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    probe = path.with_name(f".{path.name}.probe")
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as error:
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None


def atomic_write(path, write) -> None:
    """Call write(file) on a temporary file beside `path`, then rename it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except OSError as error:
        raise InputError(f"{path}: cannot write ({error.strerror})") from None
    finally:
        tmp.unlink(missing_ok=True)


def mesh_bytes(mesh, suffix: str) -> bytes:
    """A trimesh mesh as the file bytes of a mesh format ('.ply', '.glb', ...)."""
    data = mesh.export(file_type=MESH_FORMATS[suffix.lower()])
    return data.encode() if isinstance(data, str) else data


def grid_bytes(occupancy: np.ndarray, **fields) -> bytes:
    """An occupancy grid (and small metadata arrays) as compressed .npz bytes."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, occupancy=occupancy, **{k: np.asarray(v) for k, v in fields.items()})
    return buffer.getvalue()


def write_mesh(mesh, path) -> None:
    """Export a trimesh mesh in the format its extension names."""
    data = mesh_bytes(mesh, Path(path).suffix)
    atomic_write(path, lambda f: f.write(data))


def write_grid(occupancy: np.ndarray, path, **fields) -> None:
    """Save an occupancy grid (and small metadata arrays) as compressed .npz."""
    data = grid_bytes(occupancy, **fields)
    atomic_write(path, lambda f: f.write(data))
