"""Write samples by file extension, never leaving a half-written file.

Meshes: .ply .obj .stl .off .glb (trimesh's exporters). Occupancy grids:
.npz. Every file is written to a temporary name beside the target and then
renamed (`atomic_write`, which the trainer uses for its models and
checkpoints too), so a crash or Ctrl-C leaves either the old file or the new one;
mesh_bytes and grid_bytes give the same bytes in memory, to send elsewhere.
"""

import errno
import io
import os
import secrets
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
    try:
        is_dir, folder_exists = path.is_dir(), path.parent.is_dir()
    except OSError as error:  # a name too long for the file system
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None
    if is_dir:
        raise InputError(f"{path}: is a directory, not a file name")
    if not folder_exists:
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    probe = path.with_name(f".{path.name}.probe")
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as error:
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None


def atomic_write(path, write) -> None:
    """Call write(file) on a new temporary file beside `path`, fsync it and
    rename it over `path`: readers see the old file or the new one, never
    half of one. The temporary's name is unique (O_EXCL), so two writers
    never share it, and it is removed on every failure (a full disk, Ctrl-C).
    The one writer of every file sinshape makes: samples, models, checkpoints.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: exists and is not a regular file (a directory, pipe or device); "
                         "give a file name")
    try:
        tmp, fd = _create_temporary(path)
    except OSError as error:
        raise InputError(f"{path}: cannot write ({error.strerror})") from None
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as error:
        raise InputError(f"{path}: cannot write ({error.strerror})") from None
    finally:
        tmp.unlink(missing_ok=True)


def _create_temporary(path: Path) -> tuple:
    """A new, empty file `.NAME.RANDOM.tmp` beside `path` and its descriptor.

    os.open rather than tempfile.mkstemp, whose 0600 mode would survive the
    rename: the written file gets the usual mode (0666 less the umask).
    """
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return tmp, os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))


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


def write_sample(model, triplane, path, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
                 largest: bool = False, frame: str = "input", mesh_progress=None) -> None:
    """One sample as the file its extension names: a mesh, or the .npz grid.
    mesh_progress(done, total) is called as meshing goes (mesh.extract)."""
    from . import mesh, query

    if output_kind(path) == "grid":
        write_grid(query.dense(model, triplane, scale), path, size=triplane.size, scale=scale)
        return
    result = mesh.extract(model, triplane, scale, smooth, smoother, largest, frame, progress=mesh_progress)
    if not len(result.faces):
        raise InputError(f"{Path(path).name}: the sample has no surface at this scale and size; nothing written")
    write_mesh(result, path)


def write_samples(model, outputs, progress=None, **options) -> None:
    """Write each (path, tri-plane) of `outputs` with `write_sample(**options)`,
    then call progress(). `outputs` is consumed lazily, so a generator that
    makes each tri-plane when asked keeps one sample in memory at a time:
    `sinrun sample --seeds` and `sinrun interpolate` are this loop."""
    for path, triplane in outputs:
        write_sample(model, triplane, path, **options)
        if progress:
            progress()


def write_grid(occupancy: np.ndarray, path, **fields) -> None:
    """Save an occupancy grid (and small metadata arrays) as compressed .npz."""
    data = grid_bytes(occupancy, **fields)
    atomic_write(path, lambda f: f.write(data))
