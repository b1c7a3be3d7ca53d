"""Write samples by file extension, never leaving a half-written file.

Meshes: .ply (binary, written here, streamed slab by slab so that its size
is bounded by the disk, not the memory) and .obj .stl .off .glb (trimesh's
exporters, which need the whole mesh in memory). Occupancy grids: .npz. Every file is written to a temporary name beside the target and then
renamed (`atomic_write`, which the trainer uses for its models and
checkpoints too), so a crash or Ctrl-C leaves either the old file or the new one;
mesh_bytes and grid_bytes give the same bytes in memory, to send elsewhere.
"""

import errno
import io
import os
import secrets
import shutil
import tempfile
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
    try:
        check_replaceable(path)
        folder_exists = path.parent.is_dir()
    except OSError as error:  # a name too long for the file system
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None
    check_not_input(path, inputs)
    if not folder_exists:
        if path.parent.exists():
            raise InputError(f"{path}: {path.parent} is a file, not a folder")
        raise InputError(f"{path}: the folder {path.parent} does not exist")
    try:
        tmp, fd = _create_temporary(path)
        os.close(fd)
        tmp.unlink()
    except OSError as error:
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None


def check_readable(path, what: str = "file") -> Path:
    """A regular file to read, or one line saying what it is instead."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a directory, not a {what}")
    if path.is_symlink() and not path.exists():
        raise InputError(f"{path}: a symbolic link that leads nowhere (or round in a loop)")
    if path.exists() and not path.is_file():
        raise InputError(f"{path}: not a regular file (a pipe or a device); give a {what}")
    if not path.exists():
        raise InputError(f"{path}: no such {what}")
    return path


def check_not_input(path, inputs) -> None:
    """Refuse an output that is one of `inputs` (the same file, also through
    a symbolic or hard link): writing it would destroy it."""
    for source in inputs:
        if source is not None and is_same_file(path, source):
            raise InputError(f"{path}: is the input {source}; writing it would destroy it, so name another file")


def is_same_file(a, b) -> bool:
    """Whether two paths name one existing file (os.path.samefile: links too)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def check_replaceable(path: Path) -> None:
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
    check_replaceable(path)
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


# A binary PLY face: the vertex count (3) and three int32 indices.
PLY_FACE = np.dtype([("count", "u1"), ("indices", "<i4", (3,))])
PLY_COUNT_DIGITS = 10  # counts are zero-padded to a fixed width, so the header can be patched in place


def ply_header(vertices: int, faces: int) -> bytes:
    return (f"ply\nformat binary_little_endian 1.0\ncomment made by sinshape\n"
            f"element vertex {vertices:0{PLY_COUNT_DIGITS}d}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {faces:0{PLY_COUNT_DIGITS}d}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()


def ply_faces(faces: np.ndarray) -> bytes:
    if len(faces) and faces.max() >= 2**31:
        raise InputError("the mesh has more than 2**31 vertices, beyond what a PLY face index holds")
    records = np.empty(len(faces), PLY_FACE)
    records["count"] = 3
    records["indices"] = faces
    return records.tobytes()


def write_ply_pieces(file, pieces, folder) -> tuple:
    """Write (vertices, faces) pieces (mesh.pieces: new vertices, global face
    indices) to a binary file as one PLY, holding one piece at a time.
    folder: where the temporary faces go (None: the system's).

    PLY puts all vertices before all faces, so faces wait in an unnamed
    temporary file in `folder` (gone with the process, whatever happens),
    and are appended at the end; then the header's counts are patched.
    Returns (vertices, faces) counts.
    """
    counts = [0, 0]
    file.write(ply_header(0, 0))
    with tempfile.TemporaryFile(dir=folder) as faces_file:
        for vertices, faces in pieces:
            file.write(np.asarray(vertices, "<f4").tobytes())  # float32, as trimesh writes PLY
            faces_file.write(ply_faces(faces))
            counts[0] += len(vertices)
            counts[1] += len(faces)
        faces_file.seek(0)
        shutil.copyfileobj(faces_file, file, 1 << 22)
    file.seek(0)
    file.write(ply_header(*counts))
    file.seek(0, os.SEEK_END)
    return tuple(counts)


def mesh_bytes(mesh, suffix: str) -> bytes:
    """A trimesh mesh as the file bytes of a mesh format ('.ply', '.glb', ...)."""
    if suffix.lower() == ".ply":  # the bytes a streamed write (write_ply_pieces) makes of the same mesh
        return (ply_header(len(mesh.vertices), len(mesh.faces)) + np.asarray(mesh.vertices, "<f4").tobytes()
                + ply_faces(mesh.faces))
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
                 largest: bool = False, frame: str = "input", threads: int | None = None,
                 mesh_progress=None) -> None:
    """One sample as the file its extension names: a mesh, or the .npz grid.
    A .ply without smoothing or --largest (which need the whole mesh) is
    streamed slab by slab: any size fits in memory. mesh_progress(done,
    total) is called as meshing goes."""
    from . import mesh

    check_writable(path, [model.path])  # every name `interpolate` writes, not only the first
    path = Path(path)
    if output_kind(path) == "grid" or path.suffix.lower() != ".ply" or smooth or largest:
        data, _ = sample_bytes(model, triplane, path, scale, smooth, smoother, largest, frame, threads,
                               mesh_progress)
        atomic_write(path, lambda f: f.write(data))
        return
    mesh.check_frame(frame)
    pieces = mesh.pieces(model, triplane, scale, progress=mesh_progress, threads=threads)
    if frame == "input":
        pieces = ((mesh.in_frame(v, model.manifest), f) for v, f in pieces)

    def write(file):
        if not write_ply_pieces(file, pieces, path.parent)[1]:
            raise no_surface(path)

    atomic_write(path, write)


def sample_bytes(model, triplane, path, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
                 largest: bool = False, frame: str = "input", threads: int | None = None,
                 mesh_progress=None) -> tuple:
    """One sample as the bytes of the file `path` names, made in memory, and
    its mesh (None for a grid): what write_sample writes, for a caller that
    writes elsewhere or wants the mesh too."""
    from . import mesh, query

    path = Path(path)
    if output_kind(path) == "grid":
        return grid_bytes(query.dense(model, triplane, scale), size=triplane.size, scale=scale), None
    result = mesh.extract(model, triplane, scale, smooth, smoother, largest, frame, progress=mesh_progress,
                          threads=threads)
    if not len(result.faces):
        raise no_surface(path)
    return mesh_bytes(result, path.suffix), result


def no_surface(path: Path) -> InputError:
    return InputError(f"{path.name}: the sample has no surface at this scale and size; nothing written")


def write_samples(model, outputs, progress=None, **options) -> None:
    """Write each (path, tri-plane) of `outputs` with `write_sample(**options)`,
    then call progress(). `outputs` is consumed lazily, so a generator that
    makes each tri-plane when asked keeps one sample in memory at a time:
    `sinrun interpolate` is this loop (`sample --seeds` is runtime.many)."""
    for path, triplane in outputs:
        write_sample(model, triplane, path, **options)
        if progress:
            progress()
