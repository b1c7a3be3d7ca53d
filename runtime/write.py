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
# Bytes of the target's name kept in its temporary's name: with the bytes
# added, well under the 255 bytes most file systems allow.
TEMPORARY_PREFIX = 200


def output_kind(path) -> str:
    """'mesh' or 'grid', from the extension; InputError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix in MESH_FORMATS:
        return "mesh"
    if suffix in GRID_FORMATS:
        return "grid"
    known = ", ".join([*MESH_FORMATS, *GRID_FORMATS])
    raise InputError(f"{path}: unsupported output format {suffix or '(no extension)'!r}; use one of {known}")


def check_writable(path, inputs=()) -> None:
    """Fail before long work, not after it, if `path` cannot be written: it
    is not a regular file (a folder, a pipe, a device), its folder is
    missing or read-only, or it is one of `inputs` (the same file, also
    through a symbolic or hard link), which writing would destroy."""
    path = Path(path)
    _check_replaceable(path)
    for source in inputs:
        if source is not None and is_same_file(path, source):
            raise InputError(f"{path}: is the input {source}; writing it would destroy it, so name another file")
    if not path.parent.is_dir():
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    try:
        tmp, fd = _create_temporary(path)
        os.close(fd)
        tmp.unlink()
    except OSError as error:
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None


def is_same_file(a, b) -> bool:
    """Whether two paths name one existing file (os.path.samefile: links too)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def _check_replaceable(path: Path) -> None:
    """Only a regular file (or nothing) may be replaced by a rename: as root,
    renaming over /dev/full would replace the device."""
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a regular file; give a file name")
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: exists and is not a regular file (a pipe or device); give a file name")


def atomic_write(path, write) -> None:
    """Call write(file) on a new temporary file beside `path`, fsync it and
    rename it over `path`: readers see the old file or the new one, never
    half of one. The temporary's name is unique (O_EXCL), so two writers
    never share it (the last complete rename wins), and it is removed on
    every failure (a full disk, Ctrl-C).
    The one writer of every file sinshape makes: samples, models, checkpoints.
    """
    path = Path(path)
    _check_replaceable(path)
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


def temporary_path(path: Path, kind: str = "tmp") -> Path:
    """A random name `.NAME.RANDOM.KIND` beside `path`, for work renamed into
    place. NAME is cut to TEMPORARY_PREFIX bytes, so that a valid name of up
    to 255 bytes (the usual limit) still has a valid temporary."""
    prefix = os.fsdecode(os.fsencode(path.name)[:TEMPORARY_PREFIX])
    return path.with_name(f".{prefix}.{secrets.token_hex(4)}.{kind}")


def _create_temporary(path: Path) -> tuple:
    """A new, empty temporary file beside `path` and its descriptor.

    os.open rather than tempfile.mkstemp, whose 0600 mode would survive the
    rename: the written file gets the usual mode (0666 less the umask).
    """
    for _ in range(100):
        tmp = temporary_path(path)
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
                 largest: bool = False, frame: str = "input") -> None:
    """One sample as the file its extension names: a mesh, or the .npz grid."""
    from . import mesh, query

    check_writable(path, [model.path])  # each name of a --seeds list, not only the first
    if output_kind(path) == "grid":
        write_grid(query.dense(model, triplane, scale), path, size=triplane.size, scale=scale)
        return
    result = mesh.extract(model, triplane, scale, smooth, smoother, largest, frame)
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
