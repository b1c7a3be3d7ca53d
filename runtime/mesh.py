"""Mesh a sample block by block, so memory stays bounded at any scale.

Marching cubes (Lewiner, scikit-image) at 0.5 runs on every active block of
the band search (query.Band); uniform blocks hold no surface. Blocks share
their boundary points and see the same values there (query.Band makes sure),
so seam vertices come out bit-identical and merge exactly, and the padding
of empty points closes the surface at the grid's border.
"""

import numbers
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np
import trimesh
from threadpoolctl import threadpool_limits
from skimage import measure

from sinshape.core.errors import InputError

from . import query
from .load import default_threads

SMOOTHERS = ("laplacian", "taubin")
# Smoothing spreads each vertex over about sqrt(iterations) grid steps, and
# costs one pass over the mesh per iteration: 100 iterations already blur
# over about 10 steps, the size of the patches the model learnt (the paper
# smooths 3 times), so more would only erase the shape, slowly.
MAX_SMOOTH = 100


def band_mesh(model, triplane, scale: float = 1.0, block: int = query.BLOCK, progress=None,
              memory_limit: int | None = None, threads: int | None = None) -> trimesh.Trimesh:
    """The 0.5 surface of a tri-plane on a grid `scale` times finer.

    Vertices are in model coordinates (finest training voxels; see
    query.points). progress(done, total) is called after each slab.
    memory_limit: as for query.Band; threads: see `pieces`.
    """
    vertices, faces = [], []
    for v, f in pieces(model, triplane, scale, block, progress, memory_limit, threads):
        vertices.append(v)
        faces.append(f)
    if not vertices:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int), process=False)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def pieces(model, triplane, scale: float = 1.0, block: int = query.BLOCK, progress=None,
           memory_limit: int | None = None, threads: int | None = None):
    """The surface slab by slab, welded as it comes: yields (vertices, faces)
    per slab with new vertices only (model coordinates, float64) and faces
    indexing all vertices so far. Concatenated, they are the whole mesh;
    written one after another, a file of any size (write.write_ply_pieces).

    threads (None: all cores) evaluate and mesh several slabs at once; the
    result is the same bytes for any number, since every slab is computed
    the same way and collected in order.
    """
    threads = default_threads() if threads is None else threads
    if threads < 1:
        raise InputError(f"threads must be at least 1, got {threads}", "threads")
    search = query.Band(model, triplane, scale, block, memory_limit=memory_limit, slabs_at_once=2 * threads)
    shape = search.grid.shape
    # Padded grid index -> grid index -> model coordinates.
    steps = np.array([(n - 1) / (m - 1) for n, m in zip(triplane.size, shape)])
    pool = ThreadPoolExecutor(threads) if threads > 1 else None
    # numpy's BLAS would start threads of its own in every product, which then
    # compete with (and spin beside) these: one each, measured faster on any
    # count here, and results that do not depend on the machine's core count.
    blas = threadpool_limits(1, user_api="blas")
    try:
        slabs = search.carry(ordered_map(pool, search.slab, range(len(search)), threads))
        welder = SeamWelder(block)
        for done, (v, f) in enumerate(ordered_map(pool, partial(slab_mesh, block=block), slabs, threads), 1):
            v, f = welder.weld(v, f)
            if progress:
                progress(done, len(search))
            if len(f):
                yield (v - 1) * steps, f
    finally:
        blas.restore_original_limits()
        if pool:
            pool.shutdown(cancel_futures=True)


def ordered_map(pool, function, items, ahead: int):
    """map(function, items) on a thread pool (None: here), at most `ahead`
    items ahead of the one being yielded; results in the items' order."""
    if pool is None:
        yield from map(function, items)
        return
    pending = deque()
    for item in items:
        pending.append(pool.submit(function, item))
        if len(pending) > ahead:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def slab_mesh(slab, block: int) -> tuple:
    """Marching cubes on a slab's active blocks, in block order: float32 (V, 3)
    vertices in padded grid units and int64 (F, 3) faces, duplicates on the
    blocks' shared faces welded (those on the slab's x faces included)."""
    vertices, faces, count = [], [], 0
    if slab.values is not None:
        for by, bz in np.argwhere(slab.state == 0):
            cube = slab.values[:, by * block:by * block + block + 1, bz * block:bz * block + block + 1]
            if cube.min() >= 0.5 or cube.max() <= 0.5:
                continue  # active by its bounds, but no crossing after all
            v, f, _, _ = measure.marching_cubes(cube, 0.5)  # float32 (V, 3), int32 (F, 3)
            # float32 keeps seam vertices exact: block-local values plus integer offsets.
            v += np.array([slab.index * block, by * block, bz * block], np.float32)
            # Lewiner's "descent" convention winds faces towards higher values,
            # i.e. inwards for occupancy: reverse them so normals point out.
            vertices.append(v)
            faces.append(f[:, ::-1].astype(np.int64) + count)
            count += len(v)
    if not vertices:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64)
    return merge_seams(np.concatenate(vertices), np.concatenate(faces), block)


class SeamWelder:
    """Welds each slab's vertices on its first x plane to the previous
    slab's on the same plane, and numbers the rest after all vertices so
    far. The plane's vertices are bit-identical on both sides (query.Band.carry),
    so they are matched by value."""

    def __init__(self, block: int):
        self.block, self.count = block, 0
        self.last = (np.zeros((0, 3), np.float32), np.zeros(0, np.int64))  # previous slab's last plane: values, indices

    def weld(self, vertices: np.ndarray, faces: np.ndarray) -> tuple:
        """One slab's (vertices, faces) -> (its new vertices, faces in global indices)."""
        index = np.full(len(vertices), -1, np.int64)
        if len(vertices):
            x0 = vertices[:, 0].min()
            first = np.nonzero(vertices[:, 0] == x0)[0] if x0 % self.block == 0 else np.zeros(0, int)
            known, known_index = self.last
            if len(first) and len(known):
                both, inverse = np.unique(np.concatenate([known, vertices[first]]), axis=0, return_inverse=True)
                table = np.full(len(both), -1, np.int64)
                table[inverse.reshape(-1)[:len(known)]] = known_index
                index[first] = table[inverse.reshape(-1)[len(known):]]
        new = index < 0
        index[new] = self.count + np.arange(new.sum())
        self.count += int(new.sum())
        last = np.nonzero(vertices[:, 0] == vertices[:, 0].max())[0] if len(vertices) else np.zeros(0, int)
        self.last = (vertices[last], index[last])
        return vertices[new], index[faces]


def estimate_seconds(model, triplane, scale: float) -> float:
    """About how long band_mesh takes at `scale`: measured at a scale of at
    most 2 and extrapolated as scale^2.2. The surface, and so the blocks
    evaluated, grows as scale^2, and the shipped models measure scale^1.8
    to scale^2.4 between scales 2 and 16 (docs/RELIABILITY.md)."""
    import time

    query.check_band_memory(triplane.size, scale, model.manifest.hidden)  # refused work takes no time
    measured = min(scale, 2.0)
    started = time.perf_counter()
    band_mesh(model, triplane, measured)
    return (time.perf_counter() - started) * (scale / measured) ** 2.2


def merge_seams(vertices: np.ndarray, faces: np.ndarray, block: int) -> tuple:
    """Weld the duplicate vertices that neighbouring blocks make on their
    shared faces. Only vertices on a block face (a coordinate that is a
    multiple of the block size, exactly, since it lies on a grid edge) can be
    duplicates, so only those are compared, by value.

    vertices : (n, 3) float, faces : (m, 3) int -> the welded pair.
    """
    seam = (vertices % block == 0).any(axis=1)
    inner = np.nonzero(~seam)[0]
    welded, inverse = np.unique(vertices[seam], axis=0, return_inverse=True)
    index = np.empty(len(vertices), faces.dtype)
    index[inner] = np.arange(len(inner))
    index[seam] = len(inner) + inverse.reshape(-1)
    return np.concatenate([vertices[inner], welded]), index[faces]


def extract(model, triplane, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
            largest: bool = False, frame: str = "input", progress=None,
            memory_limit: int | None = None, threads: int | None = None) -> trimesh.Trimesh:
    """A sample's mesh: band marching cubes, clean-up, then the chosen frame
    ('input': overlays the training mesh; 'model': finest-voxel units).
    Meshing that needs more than memory_limit bytes (None: the memory
    available) is refused up front; threads: see `pieces`."""
    check_frame(frame)
    mesh = finish(band_mesh(model, triplane, scale, progress=progress, memory_limit=memory_limit, threads=threads),
                  smooth, smoother, largest)
    return to_frame(mesh, model.manifest) if frame == "input" else mesh


def check_frame(frame: str) -> None:
    if frame not in ("input", "model"):
        raise InputError(f"unknown frame {frame!r}; choose input or model", "frame")


def to_frame(mesh: trimesh.Trimesh, manifest) -> trimesh.Trimesh:
    """Move a mesh from model coordinates into the training input's frame."""
    mesh.vertices = in_frame(mesh.vertices, manifest)
    return mesh


def in_frame(vertices: np.ndarray, manifest) -> np.ndarray:
    """(n, 3) model coordinates -> the training input's frame."""
    return np.asarray(manifest.origin) + vertices * np.asarray(manifest.spacing)


def finish(mesh: trimesh.Trimesh, smooth: int = 0, smoother: str = "laplacian", largest: bool = False) -> trimesh.Trimesh:
    """Optional clean-up: keep the largest component, then smooth."""
    if not (isinstance(smooth, numbers.Integral) and 0 <= smooth <= MAX_SMOOTH):
        raise InputError(f"smooth must be 0 to {MAX_SMOOTH} iterations, got {smooth}", "smooth")
    if smoother not in SMOOTHERS:
        raise InputError(f"unknown smoother {smoother!r}; choose {' or '.join(SMOOTHERS)}", "smoother")
    if largest and len(mesh.faces):
        parts = mesh.split(only_watertight=False)
        mesh = max(parts, key=lambda part: len(part.faces))
    if smooth and len(mesh.faces):
        # The paper smooths with 3 Laplacian iterations; Taubin keeps the volume.
        if smoother == "laplacian":
            trimesh.smoothing.filter_laplacian(mesh, iterations=smooth)
        else:
            trimesh.smoothing.filter_taubin(mesh, iterations=smooth)
    return mesh
