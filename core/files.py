"""Files that are never half-written and never written over an input.

Every file sinshape writes (samples, models, checkpoints, layouts, sites) goes
through `atomic_write`: a temporary of a unique name beside the target,
fsynced and renamed into place, so a crash or Ctrl-C leaves the old file or
the new one. The checks before long work say, in one line, why a path cannot
be read or written.

An output path that is a symbolic link is written through: the file it
points to is replaced (atomically, as any other) and the link stays, in
every command alike (`written_path`).
"""

import errno
import os
import stat
from pathlib import Path

from .budget import check_memory
from .errors import InputError

# The mesh formats sinshape writes, by extension: trimesh's names for them.
MESH_FORMATS = {".ply": "ply", ".obj": "obj", ".stl": "stl", ".off": "off", ".glb": "glb"}
# ... and the grid's: a sample's occupancy grid.
GRID_FORMATS = {".npz": "npz"}
# Every format a sample or a tile is written in, by name: the command line's
# --format, the web API's `format` and the page's download are these
# (runtime/options.py gives the page its copy).
OUTPUT_FORMATS = (*MESH_FORMATS.values(), *GRID_FORMATS.values())

# Bytes of the target's name kept in its temporary's name: with the bytes
# added, well under the 255 bytes most file systems allow.
TEMPORARY_PREFIX = 200


def check_writable(path, inputs=()) -> None:
    """Fail before long work, not after it, if `path` cannot be written: it
    is not a regular file (a folder, a pipe, a device), its folder is
    missing or read-only, or it is one of `inputs` (the same file, also
    through a symbolic or hard link), which writing would destroy."""
    check_not_input(path, inputs)  # named as given, a link too
    path = written_path(path)
    try:
        check_replaceable(path)
        folder_exists = path.parent.is_dir()
    except OSError as error:  # a name too long for the file system
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None
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
    """A regular file to read, or one line saying what it is instead (the
    words of read_regular's)."""
    path = Path(path)
    if path.is_symlink() and not path.exists():
        raise InputError(f"the {what} {path} is a symbolic link that leads nowhere (or round in a loop)")
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise InputError(f"the {what} {path} is missing") from None
    except OSError as error:
        raise InputError(f"the {what} {path} cannot be read ({error.strerror})") from None
    if not stat.S_ISREG(mode):
        raise InputError(f"the {what} {path} is {kind_of(mode)}, not a regular file")
    return path


def kind_of(mode: int) -> str:
    """What a file that is not a regular one is, from its st_mode."""
    return ("a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket")


def read_regular(path, label: str, limit: int | None, per_byte: int = 1, field: str | None = None) -> bytes:
    """The bytes of the regular file `path` leads to, for every file a user
    names (a model, a map, a layout, a mesh and the files it names). Opened
    without blocking and looked at before a byte is read: anything else (a
    FIFO would wait for a writer, a device never ends) is refused, so is a
    file above `limit` bytes or whose memory (`per_byte` times its size)
    is not free; then at most its size is read, so a file that grows as it
    is read stays bounded. `label` says what the file is in the messages
    (`the height map x.npy`); `field` is the InputError's parameter."""
    try:
        handle = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        lost = os.path.islink(path)
        raise InputError(f"{label} is {'a symbolic link that leads nowhere' if lost else 'missing'}", field) from None
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise InputError(f"{label} is a symbolic link that goes round in a loop", field) from None
        raise InputError(f"{label} cannot be read ({error.strerror})", field) from None
    try:
        mode = os.fstat(handle)
        if not stat.S_ISREG(mode.st_mode):
            raise InputError(f"{label} is {kind_of(mode.st_mode)}, not a regular file", field)
        if limit is not None and mode.st_size > limit:
            raise InputError(f"{label} is {mode.st_size / 2**20:.1f} MiB; at most {limit / 2**20:.0f} MiB is read "
                             "for it", field)
        check_memory(mode.st_size * per_byte, f"reading {label}")
        with os.fdopen(handle, "rb", closefd=False) as file:  # a regular file: reading it cannot block
            return file.read(mode.st_size)
    except OSError as error:
        raise InputError(f"{label} cannot be read ({error.strerror})", field) from None
    finally:
        os.close(handle)


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


def written_path(path) -> Path:
    """Where writing `path` lands: the path itself, or for a symbolic link
    the file it leads to (made if the link leads to a name not there yet),
    so that writing keeps the link. A name with a control character (a
    newline could print a line that looks like another message) is refused."""
    path = Path(path)
    if any(ord(c) < 32 or ord(c) == 127 for c in str(path)):
        raise InputError(f"{str(path)!r}: a file name with a control character (a newline, a tab); name another")
    try:
        if not path.is_symlink():
            return path
    except OSError:  # a name too long to look up: writing it says so
        return path
    try:
        return Path(os.path.realpath(path, strict=True))
    except FileNotFoundError:
        return Path(os.path.realpath(path))
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise InputError(f"{path}: a symbolic link that goes round in a loop") from None
        raise InputError(f"{path}: cannot write here ({error.strerror})") from None


def atomic_write(path, write) -> None:
    """Call write(file) on a new temporary file beside `path`, fsync it and
    rename it over `path`: readers see the old file or the new one, never
    half of one. The temporary's name is unique (O_EXCL), so two writers
    never share it (the last complete rename wins), and it is removed on
    every failure (a full disk, Ctrl-C).
    The one writer of every file sinshape makes: samples, models, checkpoints.
    """
    path = written_path(path)
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
    return path.with_name(f".{prefix}.{os.urandom(4).hex()}.{kind}")


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
        except BaseException:  # a signal handled as open returned: the file is made, and ours
            tmp.unlink(missing_ok=True)
            raise
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))
