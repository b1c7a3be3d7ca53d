"""Meshing on several threads, and the streamed PLY writer (issue 11)."""

import numpy as np
import pytest
import trimesh

from sinshape import runtime
from sinshape.runtime import mesh, write


@pytest.fixture(scope="module")
def model(tiny_model):
    return runtime.load_model(tiny_model, threads=1)


@pytest.mark.parametrize("scale", [1, 2, 2.5])
def test_threads_give_the_same_bytes(model, tmp_path, scale):
    triplane = runtime.sample(model, 3)
    for suffix in (".ply", ".glb"):  # streamed, and the whole mesh in memory
        one, three = tmp_path / f"one{suffix}", tmp_path / f"three{suffix}"
        write.write_sample(model, triplane, one, scale, threads=1)
        write.write_sample(model, triplane, three, scale, threads=3)
        assert one.read_bytes() == three.read_bytes()


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
    """Welding slab by slab gives the mesh that one weld of all blocks gives:
    the same vertices (no seam duplicates) and the same triangles."""
    triplane = runtime.sample(model, 2)
    pieces = list(mesh.pieces(model, triplane, 3, threads=2))
    vertices = np.concatenate([v for v, _ in pieces])
    faces = np.concatenate([f for _, f in pieces])
    assert len(np.unique(vertices, axis=0)) == len(vertices)
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_an_interrupted_stream_leaves_nothing(model, tmp_path, monkeypatch):
    slab_mesh, calls = mesh.slab_mesh, []

    def interrupted(slab, block):
        calls.append(slab.index)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return slab_mesh(slab, block)

    monkeypatch.setattr(mesh, "slab_mesh", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write.write_sample(model, runtime.sample(model, 3), tmp_path / "s.ply", 2, threads=2)
    assert list(tmp_path.iterdir()) == []
