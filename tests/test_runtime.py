"""The torch-free runtime: generation, band queries, meshes, and the Python API."""

import io
import os

import numpy as np
import pytest

from conftest import TINY_ONNX
from sinshape import runtime
from sinshape.core import budget
from sinshape.runtime import generate, query


@pytest.fixture(scope="module")
def model(tiny_model):
    return runtime.load_model(tiny_model, threads=2)


def band_labels(model, triplane, scale):
    """Inside/outside of every grid point as the band search reports it."""
    shape = query.grid_shape(triplane.size, scale)
    leaf = query.LEAF
    labels = np.zeros(shape, bool)
    for slab in query.band(model, triplane, scale):
        padded = np.zeros((query.BLOCK + 1, *(n * leaf + 1 for n in slab.state.shape[1:])), bool)
        if slab.values is not None:
            padded[:] = slab.values > 0.5
        for (lx, ly, lz), state in np.ndenumerate(slab.state):
            if state != 0:  # a uniform leaf: its label for every point
                padded[lx * leaf:lx * leaf + leaf + 1, ly * leaf:ly * leaf + leaf + 1,
                       lz * leaf:lz * leaf + leaf + 1] = state > 0
        for i in range(query.BLOCK + 1):
            x = slab.index * query.BLOCK + i - 1
            if 0 <= x < shape[0]:
                labels[x] = padded[i, 1:shape[1] + 1, 1:shape[2] + 1]
    return labels


@pytest.mark.parametrize("scale", [2, 4])
def test_band_equals_dense(model, scale):
    for seed in (3, 8):
        triplane = runtime.sample(model, seed)
        dense = runtime.dense(model, triplane, scale) > 0.5
        assert 0.01 < dense.mean() < 0.99
        assert np.array_equal(band_labels(model, triplane, scale), dense)


def test_band_skips_uniform_blocks(model, monkeypatch):
    """On a half-space the band must evaluate only blocks near the plane."""
    triplane = runtime.sample(model, 3)
    size = triplane.size
    # Occupancy as a function of x alone: sigmoid(32 relu(x) - 16), x in [-1, 1]
    # along the grid, so the surface is the plane x = 0.5 and x < 0.5 is outside.
    d = model.manifest.hidden
    flat = [np.zeros((n_a, n_b, d), np.float32) for n_a, n_b in generate.plane_sizes(size)]
    flat[0][:] = np.linspace(-1, 1, size[0])[:, None, None]
    monkeypatch.setattr(query, "project", lambda m, t: query.Projected(flat, t.size))
    monkeypatch.setattr(model, "head", runtime.load.HeadWeights(np.zeros(d, np.float32),
                                                               np.full(d, 1.0, np.float32), -16.0))
    slabs = list(query.band(model, triplane, 4))
    last = query.grid_shape(size, 4)[0] - 1
    far = [s for s in slabs if -1 + 2 * min(s.index * query.BLOCK + query.BLOCK - 1, last) / last < 0.45]
    assert len(far) >= 2 and all((s.state == -1).all() and s.values is None for s in far)
    active = sum(int((s.state == 0).sum()) for s in slabs)
    assert active < sum(s.state.size for s in slabs) / 2
    assert np.array_equal(band_labels(model, triplane, 4), runtime.dense(model, triplane, 4) > 0.5)


def test_the_linear_bound_decides_leaves_the_interval_bound_leaves_open(monkeypatch):
    """Fewer leaves evaluated with it than without, on a shipped model (the
    tiny one's few channels leave it nothing to add), and the band still
    equals the dense grid."""
    from sinshape import models

    model = runtime.load_model(models.find("towerruins"), threads=2)
    triplane = runtime.sample(model, 3)
    assert np.array_equal(band_labels(model, triplane, 2), runtime.dense(model, triplane, 2) > 0.5)

    def open_leaves():
        return sum(int((slab.state == 0).sum()) for slab in query.band(model, triplane, 2))

    with_it = open_leaves()
    monkeypatch.setattr(query, "linear_logits",
                        lambda head, low, high, samples: (np.full(len(low), -np.inf), np.full(len(low), np.inf)))
    assert open_leaves() > with_it > 0


def test_points_agree_with_the_grid(model):
    triplane = runtime.sample(model, 5)
    grid = runtime.dense(model, triplane, 1)
    rng = np.random.default_rng(0)
    index = rng.integers(0, grid.shape, size=(50, 3))
    np.testing.assert_allclose(runtime.points(model, triplane, index.astype(float)), grid[tuple(index.T)], atol=1e-5)
    # Outside the grid a point is empty.
    assert runtime.points(model, triplane, np.array([[-1.0, 0, 0], [0, 0, 1e6]])).tolist() == [0.0, 0.0]
    # Between grid points: a finer grid's points lie between the cells, and
    # points() at their coordinates gives the finer grid's values.
    fine = runtime.dense(model, triplane, 2)
    assert fine.shape == tuple(2 * n for n in grid.shape)
    fine_index = rng.integers(0, fine.shape, size=(50, 3))
    coords = fine_index * (np.array(grid.shape) - 1) / (np.array(fine.shape) - 1)
    assert (coords % 1 > 0.01).any(axis=1).mean() > 0.9  # most are off the training grid
    np.testing.assert_allclose(runtime.points(model, triplane, coords), fine[tuple(fine_index.T)], atol=1e-5)
    np.testing.assert_allclose(fine[0, 0, 0], grid[0, 0, 0], atol=1e-5)  # corners align


@pytest.mark.parametrize("scale, factors", [(1, (1, 1, 1)), (2, (1, 1, 1)), (2.5, (1, 1, 1)), (1, (1.5, 1, 0.8))])
def test_meshes_are_closed(model, scale, factors):
    mesh = runtime.extract(model, runtime.sample(model, 3, factors), scale, frame="model")
    assert len(mesh.faces) > 100
    assert mesh.is_watertight and mesh.is_volume and mesh.volume > 0
    size = np.array(generate.scaled_sizes(model.manifest.sizes, factors)[-1])
    assert (mesh.bounds[0] >= -1).all() and (mesh.bounds[1] <= size).all()


def test_input_frame_places_the_sample_on_its_example(model):
    triplane = runtime.sample(model, 3)
    in_model = runtime.extract(model, triplane, frame="model")
    in_input = runtime.extract(model, triplane, frame="input")
    m = model.manifest
    np.testing.assert_allclose(in_input.vertices, np.array(m.origin) + in_model.vertices * np.array(m.spacing))


def test_reconstruction_and_seeds(model):
    recon = runtime.sample(model, None)
    assert recon.size == tuple(model.manifest.sizes[-1])
    a, b = runtime.sample(model, 1), runtime.sample(model, 1)
    assert all(np.array_equal(p, q) for p, q in zip(a.planes, b.planes))
    c = runtime.sample(model, 2)
    assert not np.array_equal(a.planes[0], c.planes[0])
    with pytest.raises(runtime.InputError, match="training size"):
        runtime.sample(model, None, (2, 1, 1))
    with pytest.raises(runtime.InputError, match="seed"):
        runtime.sample(model, -4)


def test_interpolation_ends_are_the_seeds(model):
    start, end = runtime.interpolate(model, 3, 7, 0.0), runtime.interpolate(model, 3, 7, 1.0)
    np.testing.assert_allclose(start.planes[0], runtime.sample(model, 3).planes[0], atol=1e-6)
    z0_only = generate.Noise(generate.draw_noise(7, model.manifest.sizes, 32).z0,
                             generate.draw_noise(3, model.manifest.sizes, 32).planes)
    np.testing.assert_allclose(end.planes[0], generate.triplane(model, z0_only, model.manifest.sizes).planes[0],
                               atol=1e-5)


def test_absurd_sizes_are_refused_with_the_memory_they_need(model):
    # Petabytes: beyond the memory of any machine these tests run on.
    with pytest.raises(runtime.MemoryLimitError, match="GiB"):
        runtime.sample(model, 1, (1000, 1000, 1000))
    with pytest.raises(runtime.MemoryLimitError, match="GiB"):
        runtime.dense(model, runtime.sample(model, 1), 3000)
    with pytest.raises(runtime.InputError, match="positive") as refused:
        query.grid_shape((10, 10, 10), -1)
    assert refused.value.parameter == "scale" and str(refused.value).startswith("scale must")


def test_the_memory_limit_is_a_parameter_defaulting_to_the_available_memory(model, monkeypatch):
    triplane = runtime.sample(model, 1)
    with pytest.raises(runtime.MemoryLimitError, match=r"\(limit 0\.0 GiB\)"):
        runtime.sample(model, 1, memory_limit=1000)
    with pytest.raises(runtime.MemoryLimitError, match="meshing"):
        runtime.extract(model, triplane, memory_limit=1000)
    with pytest.raises(runtime.MemoryLimitError, match="dense"):
        runtime.dense(model, triplane, memory_limit=1000)
    monkeypatch.setattr(budget, "available_memory", lambda: 1000)
    with pytest.raises(runtime.MemoryLimitError):
        runtime.interpolate(model, 1, 2, 0.5)
    assert len(runtime.extract(model, triplane, memory_limit=1 << 30).faces) > 0


def test_a_sample_whose_mesh_would_not_fit_is_refused_before_any_work(model, monkeypatch):
    """The check counts the mesh (its faces estimated from the model's
    reconstruction) besides the tri-plane, before anything is generated; a
    mesh streamed to a .ply holds no mesh, so the same request fits that way."""
    from sinshape.runtime import edit, layout, request as requests  # noqa: F401 (bound before the patch below)

    monkeypatch.setattr(generate, "draw_noise", lambda *a, **k: pytest.fail("sampled before the check"))
    asked = runtime.SampleRequest(seed=1, scale=40)
    with pytest.raises(runtime.MemoryLimitError, match=r"with a mesh of about [\d,]+ faces needs about"):
        requests.make(model, asked, memory_limit=1 << 30)
    requests.check_memory(model, asked, "stream", memory_limit=1 << 30)
    with pytest.raises(runtime.MemoryLimitError, match="dense grid"):
        requests.check_memory(model, asked, "grid", memory_limit=1 << 30)
    grid = np.ones(generate.scaled_sizes(model.manifest.sizes, (30, 30, 30))[0], bool)
    with pytest.raises(runtime.MemoryLimitError, match="needs about"):  # a layout's fit is counted too
        requests.check_memory(model, runtime.SampleRequest(seed=1, size=30, layout=runtime.Layout.of(grid)), "planes",
                              memory_limit=1 << 30)


@pytest.mark.parametrize("factors, scale", [((1, 1, 1), 1), ((2, 2, 1), 2), ((0.5, 1, 1), 3), ((1, 1, 1), 6)])
def test_the_face_estimate_covers_the_faces_a_sample_has(model, factors, scale):
    from sinshape.runtime import mesh

    triplane = runtime.sample(model, 3, factors)
    faces = sum(len(f) for _, f in mesh.pieces(model, triplane, scale))
    assert faces <= mesh.estimate_faces(model, triplane.size, scale) <= 3 * faces


def test_meshing_stops_when_its_faces_pass_the_limit(model):
    """The estimate is an estimate: a whole mesh's faces are counted as
    they come, and meshing stops before they fill the memory."""
    from sinshape.runtime import mesh

    triplane = runtime.sample(model, 3)
    with pytest.raises(runtime.MemoryLimitError, match=r"passed [\d,]+ faces"):
        mesh.extract(model, triplane, 4, memory_limit=64 << 20, per_face=1 << 20)


def test_the_command_line_refuses_what_would_not_fit_under_an_address_space_limit(tmp_path):
    """`ulimit -v`: the limit counts, and a size whose sample and mesh
    would not fit is refused in one line before any work (it died with a
    numpy MemoryError traceback after 30 s)."""
    import resource
    import subprocess
    import sys

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, resource.getrlimit(resource.RLIMIT_AS)[1]))

    out = tmp_path / "big.ply"
    done = subprocess.run([sys.executable, "-c", "from sinshape.cli.main import main; main()", "sample",
                           "towerruins", "--size", "40,40,40", "-o", str(out)],
                          capture_output=True, text=True, timeout=120, preexec_fn=limited)
    assert done.returncode == 1 and not out.exists()
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    limit = float(done.stderr.split("(limit ")[1].split()[0])
    assert "a sample of size 40x40x40" in done.stderr and "needs about" in done.stderr and limit < 3


def test_available_memory_reads_the_machine_or_falls_back(monkeypatch):
    """MemAvailable, read from a /proc/meminfo given here (the machine's own
    moves with other processes' work); the machine's lies within its total."""
    if os.path.exists("/proc/meminfo"):
        with open("/proc/meminfo") as f:
            total = next(int(line.split()[1]) for line in f if line.startswith("MemTotal:")) * 1024
        assert 0 < budget.machine_memory() <= total
    meminfo = "MemTotal:       24000000 kB\nMemFree:          500000 kB\nMemAvailable:   12345678 kB\n"
    with monkeypatch.context() as patched:
        patched.setattr(budget, "open", lambda path, *args: io.StringIO(meminfo) if path == "/proc/meminfo"
                        else open(path, *args), raising=False)  # shadows the builtin there
        assert budget.machine_memory() == 12345678 * 1024

    def unreadable(*args):
        raise OSError("no /proc/meminfo here")

    def unknown(name):
        raise ValueError(f"unrecognized configuration name {name}")

    monkeypatch.setattr(budget, "open", unreadable, raising=False)  # shadows the builtin there
    assert budget.available_memory() > 0  # sysconf's free pages
    monkeypatch.setattr(budget.os, "sysconf", unknown)
    assert budget.available_memory() == budget.FALLBACK_MEMORY_LIMIT


@pytest.mark.parametrize("scale", [1, 2.5])
def test_memory_estimates_count_the_decoders_hidden_width(model, monkeypatch, scale):
    """dense: the grid and the yz plane of D-vectors; band: the yz plane, a
    slab's values and cell configurations, two planes' rows of D-vectors and
    the leaves' buffers (D = hidden width)."""
    needed = {}
    monkeypatch.setattr(query, "check_memory", lambda n, what, limit=None: needed.setdefault(what.split()[0], n))
    triplane = runtime.sample(model, 2)
    runtime.dense(model, triplane, scale)
    list(query.band(model, triplane, scale))
    d, block = model.manifest.hidden, query.BLOCK
    mx, my, mz = query.grid_shape(triplane.size, scale)
    assert needed["a"] == mx * my * mz * 4 + my * mz * d * 4
    py, pz = (-(-(m + 1) // block) * block + 1 for m in (my, mz))
    leaves = 4 * query.LEAVES_AT_ONCE * (query.LEAF + 1) ** 3 * d * 4  # hidden vectors, and the rows gathered for them
    assert needed["meshing"] == py * pz * (d * 4 + 5 * (block + 1)) + (block + 1) * (py + pz) * d * 4 + leaves


def test_the_committed_tiny_model_is_the_tiny_pyramids(tiny_pyramid):
    """tests/data/tiny.onnx stands in for tiny_model where torch is missing:
    it must still load and come from the pyramid the tests describe."""
    import hashlib

    model = runtime.load_model(TINY_ONNX, threads=1)
    source = model.manifest.raw["source"]
    assert source["name"] == tiny_pyramid.name
    assert source["sha256"] == hashlib.sha256(tiny_pyramid.read_bytes()).hexdigest()
    assert model.manifest.sizes == [(15, 15, 15), (20, 18, 15)]
    assert runtime.extract(model, runtime.sample(model, 3)).is_watertight


def test_the_runtime_writes_nothing_under_the_users_home(tmp_path):
    """onnxruntime writes a device id and queued telemetry events under
    ~/.cache/Microsoft/DeveloperTools/ when it is imported, unless told not
    to: a sample made in a fresh process leaves the home as it was."""
    import subprocess
    import sys

    home = tmp_path / "home"
    home.mkdir()
    env = {key: value for key, value in os.environ.items()
           if key not in ("ORT_DISABLE_TELEMETRY", "XDG_CACHE_HOME")}
    script = ("import sys\nfrom sinshape.runtime import load_model, sample, extract\n"
              "model = load_model(sys.argv[1], threads=1)\nassert len(extract(model, sample(model, 3)).faces)")
    done = subprocess.run([sys.executable, "-c", script, str(TINY_ONNX)], env={**env, "HOME": str(home)},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert [str(p.relative_to(home)) for p in home.rglob("*")] == []


SAME_EVERYWHERE = """
import hashlib, sys
import numpy as np
from sinshape.runtime import layout, load_model, request, extract
model = load_model(sys.argv[1], threads=1)
planes = {}
for name, asked in (("plain", request.SampleRequest(seed=3, size=(1.5, 1, 0.8))),
                    ("grow", request.SampleRequest(seed=3, grow=(1.5, 1, 1))),
                    ("keep", request.SampleRequest(seed=3, keep="5:0%,0%,0%:50%,100%,100%"))):
    planes[name] = request.make(model, asked).planes
own = layout.layout(model, 3)
own[: own.shape[0] // 2] = False
planes["layout"] = layout.from_layout(model, 3, own).planes
mesh = extract(model, request.make(model, request.SampleRequest(seed=3)), 2)
np.savez(sys.argv[2], vertices=mesh.vertices, faces=mesh.faces,
         **{name: hashlib.sha256(b"".join(p.tobytes() for p in made)).hexdigest() for name, made in planes.items()})
"""


def test_a_seed_gives_the_same_planes_whatever_blas_numpy_brings(tmp_path):
    """numpy's BLAS sums a matrix product in an order of its own, by its
    version and the CPU kernels it picks (OPENBLAS_CORETYPE picks two
    here): a sample's, a grown, a kept and a laid-out sample's tri-planes
    are the same bytes under both, and the mesh the same faces, its
    vertices within 1e-3 of a voxel (the decoder head's dot product is
    BLAS's; docs/BLENDER.md gives the figures)."""
    import subprocess
    import sys

    made = {}
    for kernels in ("Prescott", "Haswell"):
        out = tmp_path / f"{kernels}.npz"
        done = subprocess.run([sys.executable, "-c", SAME_EVERYWHERE, str(TINY_ONNX), str(out)], capture_output=True,
                              text=True, timeout=300, env={**os.environ, "OPENBLAS_CORETYPE": kernels})
        assert done.returncode == 0, done.stderr[-2000:]
        made[kernels] = dict(np.load(out))
    first, second = made.values()
    for name in ("plain", "grow", "keep", "layout"):
        assert first[name] == second[name], name
    assert np.array_equal(first["faces"], second["faces"])
    assert np.abs(first["vertices"] - second["vertices"]).max() < 1e-3  # the tiny model's frame: voxels
