"""Marching cubes (runtime/cubes.py): closed, outward surfaces through the
0.5 crossings, welded by grid edge, the same cut block by block as whole."""

import numpy as np
import trimesh

from sinshape.runtime import cubes


def ball(n: int = 34, radius: float = 11.0) -> np.ndarray:
    """Occupancy of a ball in an (n, n, n) grid, empty at the border."""
    distance = np.linalg.norm(np.mgrid[:n, :n, :n] - (n - 1) / 2, axis=0)
    return (1 / (1 + np.exp(distance - radius))).astype(np.float32)


def blocks(n: int, side: int) -> np.ndarray:
    """Origins of the side-cell blocks that tile an (n+1)^3 grid of n cells a side."""
    return np.argwhere(np.ones((n // side,) * 3, bool)) * side


def test_a_ball_is_closed_outward_and_of_its_volume():
    keys, positions, faces = cubes.march(ball(33), blocks(32, 8), 8)
    surface = trimesh.Trimesh(positions, faces, process=False)
    assert surface.is_watertight and surface.is_winding_consistent
    assert abs(surface.volume / (4 / 3 * np.pi * 11 ** 3) - 1) < 0.01  # > 0: normals point out
    assert np.array_equal(keys, np.unique(keys))  # one vertex per edge


def test_vertices_lie_where_their_edge_crosses_the_level():
    values = np.pad(np.random.default_rng(0).random((15, 15, 15), np.float32), 1)  # empty border
    keys, positions, faces = cubes.march(values, blocks(16, 8), 8)
    axis, point = keys % 3, keys // 3
    start = np.stack(np.unravel_index(point, values.shape), axis=1)
    end = start + np.eye(3, dtype=int)[axis]
    low, high = values[tuple(start.T)], values[tuple(end.T)]
    assert ((low < 0.5) != (high < 0.5)).all()  # only crossed edges have vertices
    t = positions[np.arange(len(keys)), axis] - start[np.arange(len(keys)), axis]
    np.testing.assert_allclose(low + t * (high - low), 0.5, atol=1e-6)
    assert trimesh.Trimesh(positions, faces, process=False).is_watertight  # noise, with every ambiguous case


def test_blocks_share_edges_so_the_pieces_are_the_whole():
    values = ball(33)
    whole = cubes.march(values, np.zeros((1, 3), int), 32)
    pieces = cubes.march(values, blocks(32, 4), 4)
    assert np.array_equal(whole[0], pieces[0]) and np.array_equal(whole[1], pieces[1])
    assert {tuple(sorted(f)) for f in whole[2]} == {tuple(sorted(f)) for f in pieces[2]}


def test_no_crossing_no_surface():
    keys, positions, faces = cubes.march(np.ones((9, 9, 9), np.float32), blocks(8, 8), 8)
    assert len(keys) == len(positions) == len(faces) == 0
