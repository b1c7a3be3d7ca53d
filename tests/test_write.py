"""The one atomic writer: every file sinshape writes goes through it."""

import errno
import os
import stat

import pytest

from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write, check_writable


def temporaries(folder) -> list:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_two_writers_never_share_a_temporary(tmp_path):
    target = tmp_path / "m.ply"
    seen = []

    def outer(f):
        f.write(b"outer")
        seen.append(temporaries(tmp_path))
        atomic_write(target, inner)

    def inner(f):
        f.write(b"inner")
        seen.append(temporaries(tmp_path))

    atomic_write(target, outer)
    assert len(seen[0]) == 1 and len(seen[1]) == 2  # the inner writer got a name of its own
    assert target.read_bytes() == b"outer"  # the last rename wins
    assert temporaries(tmp_path) == []


@pytest.mark.parametrize("failure, caught", [
    (KeyboardInterrupt(), KeyboardInterrupt),
    (OSError(errno.ENOSPC, "No space left on device"), InputError),
])
def test_a_failing_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, failure, caught):
    target = tmp_path / "model.onnx"
    target.write_bytes(b"old")

    def half_then_fail(f):
        f.write(b"half a ne")
        raise failure

    with pytest.raises(caught):
        atomic_write(target, half_then_fail)
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["model.onnx"]


def test_a_signal_as_the_temporary_is_made_leaves_no_temporary(tmp_path, monkeypatch):
    """Python runs a signal's handler as soon as os.open returns: the file
    is made, its descriptor never handed back (a loaded machine, SIGTERM
    sent on seeing the file, hit it)."""
    opened = os.open

    def open_then_terminated(*args):
        opened(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "open", open_then_terminated)
    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "s.ply", lambda f: f.write(b"never"))
    assert os.listdir(tmp_path) == []


def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    def full(f):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(InputError, match=r"s\.npz: cannot write \(No space left on device\)"):
        atomic_write(tmp_path / "s.npz", full)


def test_a_directory_or_pipe_is_refused_not_replaced(tmp_path):
    folder = tmp_path / "out.ply"
    folder.mkdir()
    pipe = tmp_path / "pipe.ply"
    os.mkfifo(pipe)
    for target in (folder, pipe):
        with pytest.raises(InputError, match="not a regular file"):
            atomic_write(target, lambda f: f.write(b"x"))
    assert folder.is_dir() and stat.S_ISFIFO(pipe.stat().st_mode)
    assert temporaries(tmp_path) == []


def test_the_written_file_has_the_usual_mode(tmp_path):
    """Not the 0600 of a mkstemp file: a model is shared like any output."""
    umask = os.umask(0o022)
    try:
        atomic_write(tmp_path / "a.obj", lambda f: f.write(b"x"))
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "a.obj").stat().st_mode) == 0o644


def test_a_failed_checkpoint_save_leaves_no_temporary(tmp_path):
    pytest.importorskip("torch")
    from sinshape.trainer.checkpoint import atomic_save

    target = tmp_path / "m.ckpt.pt"
    target.write_bytes(b"old")
    with pytest.raises(Exception):
        atomic_save({"unpicklable": lambda: None}, target)
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["m.ckpt.pt"]


def test_a_name_of_254_characters_can_be_written(tmp_path):
    """The temporary beside it keeps only part of the name, so it stays
    within the file system's 255-byte limit."""
    target = tmp_path / ("m" * 250 + ".ply")
    check_writable(target)
    atomic_write(target, lambda f: f.write(b"x"))
    assert target.read_bytes() == b"x" and os.listdir(tmp_path) == [target.name]


def test_an_input_is_never_an_output(tmp_path):
    """The same file by its name, a symbolic link or a hard link is refused,
    and so is a pipe; the check writes nothing."""
    source = tmp_path / "shape.obj"
    source.write_bytes(b"v 0 0 0")
    (tmp_path / "soft.obj").symlink_to(source)
    os.link(source, tmp_path / "hard.obj")
    os.mkfifo(tmp_path / "pipe.obj")
    for name in ("shape.obj", "soft.obj", "hard.obj"):
        with pytest.raises(InputError, match="is the input"):
            check_writable(tmp_path / name, [source])
        with pytest.raises(InputError, match="is the input"):
            check_writable(tmp_path / ".." / tmp_path.name / name, [tmp_path / "hard.obj"])
    with pytest.raises(InputError, match="not a regular file"):
        check_writable(tmp_path / "pipe.obj")
    check_writable(tmp_path / "new.obj", [source, tmp_path / "missing.obj"])
    assert source.read_bytes() == b"v 0 0 0"
    assert sorted(os.listdir(tmp_path)) == ["hard.obj", "pipe.obj", "shape.obj", "soft.obj"]
