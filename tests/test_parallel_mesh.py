"""Meshing on several threads, and the streamed PLY writer."""

import threading

import numpy as np
import pytest
import trimesh

from sinshape import runtime
from sinshape.runtime import mesh, query, write


@pytest.fixture(scope="module")
def model(tiny_model):
    return runtime.load_model(tiny_model, threads=1)


@pytest.fixture(autouse=True)
def pool_at_any_size(monkeypatch):
    """The tiny model's grids are below the size where meshing starts a pool."""
    monkeypatch.setattr(mesh, "POOL_POINTS", 0)


@pytest.mark.parametrize("scale", [1, 2, 2.5])
def test_threads_give_the_same_bytes(model, tmp_path, scale, monkeypatch):
    slab_mesh, meshed_on = mesh.slab_mesh, set()
    monkeypatch.setattr(mesh, "slab_mesh", lambda slab: meshed_on.add(threading.get_ident()) or slab_mesh(slab))
    triplane = runtime.sample(model, 3)
    for suffix in (".ply", ".glb"):  # streamed, and the whole mesh in memory
        one, three = tmp_path / f"one{suffix}", tmp_path / f"three{suffix}"
        write.write_sample(model, triplane, one, scale, threads=1)
        meshed_on.clear()
        write.write_sample(model, triplane, three, scale, threads=3)
        assert len(meshed_on) > 1 or len(query.Band(model, triplane, scale)) <= 3  # a pool, where slabs allow
        assert one.read_bytes() == three.read_bytes()



def test_blas_threads_give_the_same_bytes(tiny_model, tmp_path):
    """numpy's BLAS reads its thread count when it loads (Ray's workers get
    OMP_NUM_THREADS=1): a sample's bytes must not depend on it, at a scale
    that interpolates the planes."""
    import os
    import subprocess
    import sys

    written = []
    for blas_threads in ("1", "2"):
        out = tmp_path / f"blas{blas_threads}.ply"
        env = {**os.environ, "OMP_NUM_THREADS": blas_threads, "OPENBLAS_NUM_THREADS": blas_threads}
        subprocess.run([sys.executable, "-c", "from sinshape.cli.main import main; main()", "sample",
                        str(tiny_model), "--seed", "3", "--scale", "2.5", "-o", str(out)], env=env, check=True,
                       capture_output=True)
        written.append(out.read_bytes())
    assert written[0] == written[1]

def test_small_grids_are_meshed_without_a_pool(model, monkeypatch):
    monkeypatch.setattr(mesh, "POOL_POINTS", 10**9)
    slab_mesh, meshed_on = mesh.slab_mesh, set()
    monkeypatch.setattr(mesh, "slab_mesh", lambda slab: meshed_on.add(threading.get_ident()) or slab_mesh(slab))
    list(mesh.pieces(model, runtime.sample(model, 3), 2.5, threads=3))
    assert meshed_on == {threading.get_ident()}


def test_streamed_ply_is_trimesh_export_of_the_same_mesh(model, tmp_path):
    triplane = runtime.sample(model, 5)
    assert len(list(mesh.pieces(model, triplane, 2.5, threads=1))) > 2  # written in several pieces
    write.write_sample(model, triplane, tmp_path / "streamed.ply", 2.5, threads=2)
    whole = mesh.extract(model, triplane, 2.5, threads=1)
    whole.export(tmp_path / "trimesh.ply")
    streamed, exported = (trimesh.load(tmp_path / name, process=False) for name in ("streamed.ply", "trimesh.ply"))
    assert np.array_equal(streamed.vertices, exported.vertices) and np.array_equal(streamed.faces, exported.faces)
    assert streamed.is_watertight
    # The served bytes of a whole mesh are the streamed file's.
    assert write.mesh_bytes(whole, ".ply") == (tmp_path / "streamed.ply").read_bytes()


def test_seams_weld_across_slabs_as_the_whole_mesh_does(model):
    """Welding slab by slab leaves no duplicate vertex on a seam between
    slabs, and the mesh closed. (Marching cubes itself may put two vertices
    on a grid point whose value is exactly 0.5, inside a block: this seed
    has one, as the global weld before it had.)"""
    triplane = runtime.sample(model, 2)
    scale = 3
    pieces = list(mesh.pieces(model, triplane, scale, threads=2))
    assert len(pieces) > 2
    vertices = np.concatenate([v for v, _ in pieces])
    faces = np.concatenate([f for _, f in pieces])
    _, inverse, counts = np.unique(vertices, axis=0, return_inverse=True, return_counts=True)
    doubled = vertices[counts[inverse.reshape(-1)] > 1]
    # model coordinates -> padded grid index along x, where slabs meet every BLOCK points
    size, points = triplane.size[0], query.grid_shape(triplane.size, scale)[0]
    grid_x = doubled[:, 0] * (points - 1) / (size - 1) + 1
    assert not np.isclose(grid_x % query.BLOCK, 0, atol=1e-4).any(), doubled
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_an_interrupted_stream_leaves_nothing(model, tmp_path, monkeypatch):
    slab_mesh, calls = mesh.slab_mesh, []

    def interrupted(slab):
        calls.append(slab.index)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return slab_mesh(slab)

    monkeypatch.setattr(mesh, "slab_mesh", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write.write_sample(model, runtime.sample(model, 3), tmp_path / "s.ply", 2, threads=2)
    assert list(tmp_path.iterdir()) == []
