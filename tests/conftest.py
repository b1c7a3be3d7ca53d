"""Shared fixtures: tiny inputs and one tiny trained model per test session.

Tests need nothing outside the checkout: inputs are made here, by
prep/shapes.py, or read from tests/data (see its README for licences).
"""

import signal
import sys
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest

from browser import CHROMIUM


# How this process takes each signal when the session starts.
SESSION_HANDLERS = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)}


@pytest.fixture(autouse=True)
def no_signal_handler_left_behind(request):
    """A test (or a fixture of it) that changes how this process takes a
    signal puts it back: a handler left behind (Ray's SIGTERM exit, an
    ignored Ctrl-C) changes what every later test sees, and only in the
    full suite. The handler is restored and the test fails in its teardown."""
    yield
    left = {signum.name: signal.getsignal(signum) for signum, handler in SESSION_HANDLERS.items()
            if signal.getsignal(signum) != handler}
    for signum, handler in SESSION_HANDLERS.items():
        signal.signal(signum, handler)
    assert not left, f"{request.node.nodeid} left signal handlers behind: {left}"


# The test during which this process's peak resident memory first passes
# this fails, naming the figure: the whole suite peaks near 1.6 GB here
# (torch, onnxruntime and Blender loaded), and a test that kept or listed
# gigabytes (a refused render's 100 million seeds, once: 4.9 GB) shows at
# once rather than as a contributor's machine swapping. Chromium, servers and
# Ray workers are processes of their own, not counted. --max-rss-mb sets it
# (0: no check).
MAX_RSS_MB = 3072


def pytest_addoption(parser):
    parser.addoption("--max-rss-mb", type=int, default=MAX_RSS_MB,
                     help="fail the test during which the test process's peak resident memory first passes this "
                          f"many MB; 0: no check [default: {MAX_RSS_MB}]")


def peak_rss_mb():
    """This process's peak resident memory so far, in MB (None where the platform does not say)."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1 << 20 if sys.platform == "darwin" else 1 << 10)  # bytes on macOS, kB on Linux


# The marker a test gets for asking for a fixture: those that drive a real
# browser (tests/browser.py's chromium) and node (test_mirror.run_node).
MARKED_BY_FIXTURE = {"browser": "browser", "page": "browser", "run_node": "node"}


def pytest_collection_modifyitems(config, items):
    """Mark the tests that drive chromium `browser` and those that run node
    `node` (`pytest -m "not browser"` leaves them out), and skip the browser
    ones, saying why, where chromium is missing: the rest of their modules
    still run. (run_node skips its own where node is missing.)"""
    missing = None if Path(CHROMIUM).is_file() else "needs Debian's chromium (apt-get install chromium; .ci/run does)"
    for item in items:
        for name in {MARKED_BY_FIXTURE[f] for f in getattr(item, "fixturenames", ()) if f in MARKED_BY_FIXTURE}:
            item.add_marker(getattr(pytest.mark, name))
            if name == "browser" and missing:
                item.add_marker(pytest.mark.skip(reason=missing))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """The peak before the test's fixtures are made (what it crosses is its own)."""
    item.peak_before = peak_rss_mb()


@pytest.fixture(autouse=True)
def bounded_memory(request):
    """A test, its fixtures included, that takes this process's peak past
    --max-rss-mb (see MAX_RSS_MB) fails in its teardown. The peak only
    grows, so only the test that crossed the bound fails, not every later one."""
    yield
    limit, after = request.config.getoption("max_rss_mb"), peak_rss_mb()
    before = getattr(request.node, "peak_before", None)
    if limit and before is not None and after is not None:
        assert not before <= limit < after, (f"{request.node.nodeid}: this process's resident memory peaked at "
                                             f"{after:.0f} MB, past --max-rss-mb {limit}")


def finishes(call, seconds: float = 30.0):
    """call()'s result, or its exception raised here; fails if it does not
    return within `seconds` (a read that blocks: the thread is left behind)."""
    result = {}

    def target():
        try:
            result["value"] = call()
        except BaseException as error:  # noqa: BLE001 (handed back to the test)
            result["error"] = error

    worker = threading.Thread(target=target, daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), f"still running after {seconds} s: a read blocked"
    if "error" in result:
        raise result["error"]
    return result["value"]


def write_pyramid(path, sizes):
    """An SSG-format .h5 pyramid of a wavy terrain, one grid per size (coarsest first)."""
    with h5py.File(path, "w") as f:
        f.attrs["n_scales"] = len(sizes)
        for i, size in enumerate(sizes):
            x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in size], indexing="ij")
            f.create_dataset(f"scale{i}", data=z < 0.4 * np.sin(3 * x) * np.cos(2 * y))
    return path


@pytest.fixture(scope="session")
def tiny_pyramid(tmp_path_factory):
    return write_pyramid(tmp_path_factory.mktemp("data") / "terrain.h5", [(15, 15, 15), (20, 18, 15)])


def sealed_bytes(proto) -> bytes:
    """An onnx.ModelProto's bytes sealed afresh (any old seal dropped), as if the
    trainer had written it: the checks after the seal's are what a test reaches."""
    from sinshape.core import manifest as fmt
    from sinshape.runtime import onnxfile

    data = proto.SerializeToString()
    props = {key: value for key, value in onnxfile.parse(data).metadata.items() if key != fmt.SEAL_KEY}
    return fmt.seal(onnxfile.with_metadata(data, props))


# The same model as tiny_model trains, made once with
#   sinrun train terrain.h5 -o tiny.onnx --preset tiny --iters 3
# on write_pyramid's terrain.h5 (sizes as in tiny_pyramid): where torch is not
# installed, the runtime's tests run on it instead of skipping.
TINY_ONNX = Path(__file__).parent / "data" / "tiny.onnx"


def trained_or_committed(tmp_path_factory, source, committed: Path) -> Path:
    """A two-level model trained for a few iterations on `source` where torch
    is installed (so the trainer's export is what the runtime reads), else
    the committed copy."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return committed
    from sinshape.trainer import train
    from sinshape.trainer.config import make_config

    out = tmp_path_factory.mktemp("model") / committed.name
    train.train(source, out, make_config("tiny", iters=3))
    return out


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory, tiny_pyramid):
    """A two-level model trained for a few iterations on tiny_pyramid (see trained_or_committed)."""
    return trained_or_committed(tmp_path_factory, tiny_pyramid, TINY_ONNX)


# A coloured model (format 4), made by the real trainer once with
#   sinrun train tests/data/colour/box_vertex.ply -o tiny_colour.onnx --preset tiny --iters 60 --lr 1e-3
# on the box painted red above and blue below (tests/data/colour): it has
# learnt the colours (tests/data/README.md).
TINY_COLOUR_ONNX = Path(__file__).parent / "data" / "tiny_colour.onnx"
PAINTED_BOX = Path(__file__).parent / "data" / "colour" / "box_vertex.ply"


@pytest.fixture(scope="session")
def tiny_colour_model(tmp_path_factory):
    """tiny_model's coloured counterpart, on the painted box (see trained_or_committed)."""
    return trained_or_committed(tmp_path_factory, PAINTED_BOX, TINY_COLOUR_ONNX)


# A geometry-only model with its example's relief (format 5, `relief`), made by the real trainer once with
#   sinrun train tests/data/relief/ridged_box.ply -o tiny_relief.onnx --preset tiny --iters 60 --lr 1e-3 --up z
# on the block whose top carries ridges finer than a voxel (tests/data/relief).
TINY_RELIEF_ONNX = Path(__file__).parent / "data" / "tiny_relief.onnx"
RIDGED_BOX = Path(__file__).parent / "data" / "relief" / "ridged_box.ply"


@pytest.fixture(scope="session")
def tiny_relief_model(tmp_path_factory):
    """tiny_model's counterpart with relief, on the ridged block (see trained_or_committed)."""
    return trained_or_committed(tmp_path_factory, RIDGED_BOX, TINY_RELIEF_ONNX)


@pytest.fixture(scope="session")
def addon():
    """The Blender extension (blender/), registered in this process's Blender
    (bpy, headless) on an empty scene; for tests marked `blender`."""
    import sys

    import bpy

    root = str(Path(__file__).resolve().parents[1])
    sys.path.insert(0, root)
    import blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender.register()
    yield blender
    blender.unregister()
    sys.path.remove(root)


@pytest.fixture
def scene(addon):
    """addon's scene, emptied for each test."""
    import bpy

    for data in (bpy.data.objects, bpy.data.meshes, bpy.data.collections):
        for item in list(data):
            data.remove(item)
    addon.live.MADE.clear()
    return bpy.context.scene
