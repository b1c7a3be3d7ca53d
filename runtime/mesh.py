"""Mesh a sample block by block, so memory stays bounded at any scale.

Marching cubes (Lewiner, scikit-image) at 0.5 runs on every active block of
the band search (query.band); uniform blocks hold no surface. Blocks share
their boundary points and see the same values there (query.band makes sure),
so seam vertices come out bit-identical and merge exactly, and the padding
of empty points closes the surface at the grid's border.
"""

import numbers

import numpy as np
import trimesh
from skimage import measure

from . import query
from .errors import InputError

SMOOTHERS = ("laplacian", "taubin")
# Smoothing spreads each vertex over about sqrt(iterations) grid steps, and
# costs one pass over the mesh per iteration: 100 iterations already blur
# over about 10 steps, the size of the patches the model learnt (the paper
# smooths 3 times), so more would only erase the shape, slowly.
MAX_SMOOTH = 100


def band_mesh(model, triplane, scale: float = 1.0, block: int = query.BLOCK, progress=None,
              memory_limit: int | None = None) -> trimesh.Trimesh:
    """The 0.5 surface of a tri-plane on a grid `scale` times finer.

    Vertices are in model coordinates (finest training voxels; see
    query.points). progress(done, total) is called after each slab.
    memory_limit: as for query.band.
    """
    shape = query.grid_shape(triplane.size, scale)
    slabs = -(-(shape[0] + 1) // block)
    vertices, faces, count = [], [], 0
    for slab in query.band(model, triplane, scale, block, memory_limit=memory_limit):
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
                faces.append(f[:, ::-1] + np.int32(count))
                count += len(v)
        if progress:
            progress(slab.index + 1, slabs)
    if not vertices:
        return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int), process=False)
    vertices, faces = np.concatenate(vertices), np.concatenate(faces)
    vertices, faces = merge_seams(vertices, faces, block)
    # Padded grid index -> grid index -> model coordinates.
    steps = np.array([(n - 1) / (m - 1) for n, m in zip(triplane.size, shape)])
    return trimesh.Trimesh((vertices - 1) * steps, faces, process=False)


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
            memory_limit: int | None = None) -> trimesh.Trimesh:
    """A sample's mesh: band marching cubes, clean-up, then the chosen frame
    ('input': overlays the training mesh; 'model': finest-voxel units).
    Meshing that needs more than memory_limit bytes (None: the memory
    available) is refused up front."""
    if frame not in ("input", "model"):
        raise InputError(f"unknown frame {frame!r}; choose input or model", "frame")
    mesh = finish(band_mesh(model, triplane, scale, progress=progress, memory_limit=memory_limit),
                  smooth, smoother, largest)
    return to_frame(mesh, model.manifest) if frame == "input" else mesh


def to_frame(mesh: trimesh.Trimesh, manifest) -> trimesh.Trimesh:
    """Move a mesh from model coordinates into the training input's frame."""
    mesh.vertices = np.asarray(manifest.origin) + mesh.vertices * np.asarray(manifest.spacing)
    return mesh


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
