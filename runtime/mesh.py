"""Mesh a sample slab by slab, so memory stays bounded at any scale.

Marching cubes (cubes.march) runs on the undecided leaves of the band search
(query.Band); uniform leaves hold no surface. Neighbouring slabs see the same
values on the plane they share (query.Band.carry), and a vertex is named by
its grid edge, so seams weld exactly by name, and the padding of empty
points closes the surface at the grid's border.
"""

import math
import numbers
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from threadpoolctl import threadpool_limits

from sinshape.core import budget
from sinshape.core.errors import InputError, MemoryLimitError

from . import colour, cubes, query
from .generate import sample
from .load import default_threads
from .options import MAX_SMOOTH, SMOOTHERS  # noqa: F401  a request's limits, declared with its options
# Below this many grid points (or with no more slabs than threads) one thread
# meshes faster than a pool starts and feeds several: measured on 2 cores,
# terrain at scale 1 (39k points) took 33 ms on one thread and 39 on two;
# at scale 2 (315k) 117 and 93.
POOL_POINTS = 200_000


# Bytes a face of a whole mesh costs at its peak, beside the tri-plane and
# the band search (terrain at 6x6x6, 2.6 million faces): a mesh and its
# binary file (.ply, .glb: 126 to 157 measured), the same as text (.obj:
# 236), and while it is smoothed (489). A front end that copies the mesh
# again (Blender) asks for more.
MESH_BYTES_PER_FACE = 160
TEXT_BYTES_PER_FACE = 256
SMOOTH_BYTES_PER_FACE = 512
# Samples have about their reconstruction's faces per voxel; those grown
# far from the training size, more: measured 0.55 to 1.32 times it
# (towerruins at 3x3x3 and 12x12x12), 0.67 (terrain), 0.97 (acropolis at 8).
FACE_MARGIN = 1.5
MAX_FACES_PER_CELL = 5  # what marching cubes can cut from one cell, at most


def faces_per_voxel(model) -> float:
    """Faces of the model's reconstruction at scale 1 per finest voxel:
    measured once per loaded model (a sample's meshing at the training
    size), and kept on it."""
    if model.faces_per_voxel is None:
        faces = sum(len(f) for _, f in pieces(model, sample(model, None), 1.0, threads=1))
        model.faces_per_voxel = faces / math.prod(model.manifest.sizes[-1])
    return model.faces_per_voxel


def estimate_faces(model, size, scale: float) -> int:
    """About how many faces (with FACE_MARGIN) the mesh of a sample of
    `size` finest voxels has at `scale`: the reconstruction's faces per
    voxel times its voxels (a larger sample holds more of the same; a
    smaller one, no less than its area's share), times scale^2, as a
    surface's faces grow with the square of the grid's resolution."""
    voxels = math.prod(model.manifest.sizes[-1])
    grown = math.prod(size) / voxels
    share = max(grown, grown ** (2 / 3))
    return int(faces_per_voxel(model) * voxels * share * scale**2 * FACE_MARGIN) + 1


def band_mesh(model, triplane, scale: float = 1.0, progress=None, memory_limit: int | None = None,
              threads: int | None = None, per_face: int = MESH_BYTES_PER_FACE):
    """The 0.5 surface of a tri-plane on a grid `scale` times finer, as a
    trimesh.Trimesh.

    Vertices are in model coordinates (finest training voxels; see
    query.points). progress(done, total) is called after each slab.
    memory_limit: as for query.Band, and the mesh itself: its faces at
    `per_face` bytes each (what the caller will hold at its peak) are
    counted as they come, and meshing stops with MemoryLimitError as soon
    as they pass the limit, before they fill the memory (the estimate
    made up front, request.check_memory, is an estimate). threads: see
    `pieces`.
    """
    limit = budget.available_memory() if memory_limit is None else memory_limit
    vertices, faces = [], []
    count = 0
    for done, (v, f) in enumerate(pieces(model, triplane, scale, progress, memory_limit, threads), 1):
        vertices.append(v)
        faces.append(f)
        count += len(f)
        if count * per_face > limit:
            shape = "x".join(map(str, query.grid_shape(triplane.size, scale)))
            raise MemoryLimitError(f"meshing a {shape} grid passed {count:,} faces ({count * per_face / 2**30:.1f} "
                                   f"GiB of mesh) before it was done; the memory limit is {budget.gib(limit)} GiB: "
                                   "choose a smaller size or scale")
    import trimesh  # only a whole mesh needs it (a .ply streams without); after the work, which can be cancelled

    if not vertices:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int), process=False)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def pieces(model, triplane, scale: float = 1.0, progress=None, memory_limit: int | None = None,
           threads: int | None = None):
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
        raise InputError(f"`threads` must be at least 1, got {threads}", "threads")
    search = query.Band(model, triplane, scale, memory_limit=memory_limit, slabs_at_once=2 * threads)
    shape = search.grid.shape
    # Padded grid index -> grid index -> model coordinates.
    steps = np.array([(n - 1) / (m - 1) for n, m in zip(triplane.size, shape)])
    pool = None
    if threads > 1 and len(search) > threads and np.prod(shape) >= POOL_POINTS:
        pool = ThreadPoolExecutor(threads)
    # numpy's BLAS would start threads of its own in every product, which then
    # compete with (and spin beside) these: one each, measured faster on any
    # count here, and results that do not depend on the machine's core count.
    blas = threadpool_limits(1, user_api="blas")
    try:
        slabs = search.carry(ordered_map(pool, search.slab, range(len(search)), threads))
        welder = SeamWelder()
        for done, surface in enumerate(ordered_map(pool, slab_mesh, slabs, threads), 1):
            v, f = welder.weld(*surface)
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


def slab_mesh(slab) -> tuple:
    """Marching cubes on a slab's undecided leaves: (edge keys, vertices in
    padded grid units, faces, keys per x plane) as cubes.march gives them,
    vertices' x moved from the slab's to the grid's."""
    if slab.values is None:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.int64), 1
    keys, vertices, faces = cubes.march(slab.values, slab.leaves(), query.LEAF)
    vertices[:, 0] += slab.index * query.BLOCK
    return keys, vertices, faces, 3 * slab.values.shape[1] * slab.values.shape[2]


class SeamWelder:
    """Numbers each slab's vertices after all vertices so far, except those
    on its first x plane that the previous slab made on its last: the same
    grid edge, so the same vertex."""

    def __init__(self):
        self.count = 0
        self.last = (np.zeros(0, np.int64), np.zeros(0, np.int64))  # previous slab's last plane: keys, indices

    def weld(self, keys: np.ndarray, vertices: np.ndarray, faces: np.ndarray, plane: int) -> tuple:
        """One slab's edge keys, vertices, faces and keys per x plane ->
        (its new vertices, faces in global indices)."""
        index = np.full(len(keys), -1, np.int64)
        known, known_index = self.last
        first = np.nonzero((keys < plane) & (keys % 3 != 0))[0]  # y and z edges on plane x = 0
        if len(first) and len(known):
            at = np.minimum(np.searchsorted(known, keys[first]), len(known) - 1)
            found = known[at] == keys[first]
            index[first[found]] = known_index[at[found]]
        new = index < 0
        index[new] = self.count + np.arange(new.sum())
        self.count += int(new.sum())
        last = keys >= query.BLOCK * plane
        self.last = (keys[last] - query.BLOCK * plane, index[last])
        return vertices[new], index[faces]


def estimate_seconds(model, triplane, scale: float) -> float:
    """About how long meshing takes at `scale`: measured at a scale of at
    most 2 and extrapolated as scale^2.2. The surface, and so the leaves
    evaluated, grows as scale^2, and the shipped models measure scale^1.8
    to scale^2.4 between scales 2 and 16 (docs/RELIABILITY.md)."""
    query.check_band_memory(triplane.size, scale, model.manifest.hidden)  # refused work takes no time
    measured = min(scale, 2.0)
    started = time.perf_counter()
    for _ in pieces(model, triplane, measured):
        pass
    return (time.perf_counter() - started) * (scale / measured) ** 2.2


def extract(model, triplane, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
            largest: bool = False, frame: str = "input", progress=None,
            memory_limit: int | None = None, threads: int | None = None, per_face: int | None = None,
            detail: bool = True):
    """A sample's mesh: band marching cubes, clean-up, its relief and colour
    (`paint`), then the chosen frame ('input': overlays the training mesh;
    'model': finest-voxel units).
    Meshing that needs more than memory_limit bytes (None: the memory
    available) is refused up front, and stopped as soon as its faces, at
    `per_face` bytes each (None: held_per_face's), pass it; threads: see
    `pieces`."""
    check_frame(frame)
    per_face = held_per_face(smooth, largest=largest) if per_face is None else per_face
    surface = colour.matching(model, triplane, detail) if painted(model, scale, detail) else None
    mesh = finish(band_mesh(model, triplane, scale, progress=progress, memory_limit=memory_limit, threads=threads,
                            per_face=per_face), smooth, smoother, largest)
    paint(mesh, model, triplane, scale, detail, surface)
    return to_frame(mesh, model.manifest) if frame == "input" else mesh


def held_per_face(smooth: int = 0, suffix: str = ".ply", largest: bool = False) -> int:
    """Bytes a face of a whole mesh costs at its peak: smoothed or cut to its largest part, or written as `suffix`."""
    if smooth or largest:
        return SMOOTH_BYTES_PER_FACE
    return TEXT_BYTES_PER_FACE if suffix.lower() in (".obj", ".off") else MESH_BYTES_PER_FACE


def relieved(model, scale: float, detail: bool) -> bool:
    """Whether a sample's mesh at `scale` takes its example's relief: at full detail, fine enough to carry it."""
    return detail and model.example_tiles is not None and scale >= colour.RELIEF_SCALE


def painted(model, scale: float, detail: bool) -> bool:
    """Whether `paint` changes a sample's mesh: its relief or its colour."""
    return bool(model.manifest.colour or relieved(model, scale, detail))


def paint(mesh, model, triplane, scale: float = 1.0, detail: bool = True, surface=None) -> None:
    """Give a mesh in model coordinates its model's relief and colour at its
    vertices (their final places, after smoothing): on a grid at least
    colour.RELIEF_SCALE times finer than the voxels, a format-5 model's
    vertices move by its example's relief; then a coloured model's each take
    8-bit sRGB, the colour around it (a vertex of a grid `scale` times finer
    stands for 1 / scale voxels). A model with neither leaves the mesh as it
    is. Without `detail`, no relief, and colour from the decoder's head.
    `surface`: colour.matching's, begun before the mesh was made."""
    relief = relieved(model, scale, detail)
    if not len(mesh.vertices) or not painted(model, scale, detail):
        return
    surface = colour.colouring(model, triplane, detail=detail) if surface is None else surface.result()
    if relief:
        mesh.vertices = surface.relief(mesh.vertices)
    if model.manifest.colour:
        mesh.visual.vertex_colors = colour_bytes(surface(mesh.vertices, 1 / scale))


def colour_bytes(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) sRGB in [0, 1] -> (n, 4) uint8 RGBA, opaque."""
    out = np.full((len(rgb), 4), 255, np.uint8)
    out[:, :3] = np.round(np.clip(rgb, 0, 1) * 255)
    return out


def check_frame(frame: str) -> None:
    if frame not in ("input", "model"):
        raise InputError(f"unknown `frame` {frame!r}; choose input or model", "frame")


def to_frame(mesh, manifest):
    """Move a mesh from model coordinates into the training input's frame."""
    mesh.vertices = in_frame(mesh.vertices, manifest)
    return mesh


def in_frame(vertices: np.ndarray, manifest) -> np.ndarray:
    """(n, 3) model coordinates -> the training input's frame."""
    return np.asarray(manifest.origin) + vertices * np.asarray(manifest.spacing)


def finish(mesh, smooth: int = 0, smoother: str = "laplacian", largest: bool = False):
    """Optional clean-up: keep the largest component, then smooth."""
    if not (isinstance(smooth, numbers.Integral) and 0 <= smooth <= MAX_SMOOTH):
        raise InputError(f"`smooth` must be 0 to {MAX_SMOOTH} iterations, got {smooth}", "smooth")
    if smoother not in SMOOTHERS:
        raise InputError(f"unknown `smoother` {smoother!r}; choose {' or '.join(SMOOTHERS)}", "smoother")
    if largest and len(mesh.faces):
        mesh = largest_part(mesh)
    if smooth and len(mesh.faces):
        mesh.vertices = smoothed(mesh.vertices, mesh.faces, smooth, smoother)
    return mesh


# The clean-up below is trimesh's split, filter_laplacian and filter_taubin
# (default arguments) in plain numpy: trimesh's need scipy or networkx, which
# the runtime does without. mesh.js's smooth is the same Laplacian.

def largest_part(mesh):
    """The connected part with the most faces (faces joined by a shared
    edge, as trimesh's split joins them; a tie goes to the part holding the
    lowest face index), with its vertices in their old order."""
    import trimesh  # half a second to import, and only a whole mesh in memory needs it

    faces = np.asarray(mesh.faces)
    part = connected_parts(*edge_neighbours(faces), len(faces))
    kept = faces[part == np.argmax(np.bincount(part))]
    used = np.bincount(kept.ravel(), minlength=len(mesh.vertices)) > 0
    return trimesh.Trimesh(np.asarray(mesh.vertices)[used], (np.cumsum(used) - 1)[kept], process=False)


def edge_neighbours(faces: np.ndarray) -> tuple:
    """The pairs of faces (F, 3) that share an edge: (a (E,), b (E,)), one
    pair for each two sides of an edge consecutive in a sort of its sides."""
    pairs = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    key = pairs[:, 0] * (int(faces.max(initial=0)) + 1) + pairs[:, 1]
    order = np.argsort(key, kind="stable")
    shared = key[order[1:]] == key[order[:-1]]  # consecutive sides of one edge
    return order[:-1][shared] // 3, order[1:][shared] // 3


def connected_parts(a: np.ndarray, b: np.ndarray, count: int) -> np.ndarray:
    """Each of `count` nodes labelled by the lowest node of its part, joined
    by the edges a[i]-b[i]: every round hooks each edge's higher root under
    the lower one, then jumps pointers until every node points at a root."""
    label = np.arange(count)
    while True:
        low = np.minimum(label[a], label[b])
        hooked = label.copy()
        np.minimum.at(hooked, label[a], low)
        np.minimum.at(hooked, label[b], low)
        while not np.array_equal(hooked, hooked[hooked]):
            hooked = hooked[hooked]
        if np.array_equal(hooked, label):
            return label
        label = hooked


def smoothed(vertices: np.ndarray, faces: np.ndarray, iterations: int, smoother: str = "laplacian",
             lamb: float = 0.5, nu: float = 0.5) -> np.ndarray:
    """The vertices after `iterations` steps that each move every vertex by
    lamb towards the mean of its neighbours. Laplacian then rescales about
    the centre of mass to the first volume; Taubin alternates the step with
    one back by nu instead, which keeps the volume without rescaling."""
    count = len(vertices)
    pairs = np.sort(np.asarray(faces)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    edge = np.sort(pairs[:, 0] * count + pairs[:, 1])
    edge = edge[np.append(True, edge[1:] != edge[:-1])]  # each edge once (np.unique is far slower)
    # Both directions of every edge, by their first vertex: a vertex's
    # neighbours are one run of `neighbour` (every vertex has some: it is on a face).
    first, neighbour = np.concatenate([edge // count, edge % count]), np.concatenate([edge % count, edge // count])
    order = np.argsort(first, kind="stable")
    neighbour, starts = neighbour[order], np.searchsorted(first[order], np.arange(count))
    degree = np.diff(np.append(starts, len(neighbour)))[:, None]
    current = np.array(vertices, dtype=np.float64)
    volume, center = mass_properties(current, faces) if smoother == "laplacian" else (None, None)
    for step in range(iterations):
        towards = np.add.reduceat(current[neighbour], starts) / degree - current
        if smoother == "taubin":
            current += lamb * towards if step % 2 == 0 else -nu * towards
            continue
        current += lamb * towards
        current = (current - center) * np.cbrt(volume / mass_properties(current, faces)[0]) + center
    return current


def mass_properties(vertices: np.ndarray, faces: np.ndarray) -> tuple:
    """(volume, centre of mass) of a closed mesh, by the divergence theorem."""
    x0, x1, x2 = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(x1 - x0, x2 - x0)
    f1 = x0 + x1 + x2
    volume = (cross[:, 0] * f1[:, 0]).sum() / 6
    return volume, (cross * (x0 * x0 + x1 * x1 + x0 * x1 + x2 * f1)).sum(axis=0) / 24 / volume
