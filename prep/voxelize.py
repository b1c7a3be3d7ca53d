"""Load a triangle mesh and turn it into a solid occupancy grid.

Numpy, scipy and trimesh only (no torch): the torch-free evaluation code
voxelizes meshes too. Loading a mesh needs trimesh alone (`sinrun render`
of a mesh works without the prep extra); voxelizing needs scipy.

Method
------
All work happens in voxel units (grid coordinates, voxel ``i`` spans
``[i, i + 1)``), on a triangle soup, so duplicated vertices along UV seams
do not matter.

1. Split: triangles are bisected along their longest edge until no edge is
   longer than one voxel. The pieces tile the original triangles exactly, and
   each piece touches at most 2 voxels (surface) or 2 ray positions (interior)
   per axis, which keeps every later step a fixed-width vectorised numpy
   operation. Longest-edge bisection (not 1-to-4 subdivision) keeps long
   slivers linear in their length rather than quadratic.
2. Surface: every voxel a triangle passes through, by an exact
   triangle/box separating-axis test (Akenine-Moeller) on the <= 8 candidate
   voxels of each piece. Exact rather than dense point sampling, because
   sampling misses voxels that a triangle only clips at a corner or an edge,
   and that is where a thin wall would break up.
3. Interior: voxel centres judged inside by voting axis-aligned rays. Rays run
   through the voxel centres along each axis, and along each ray the signed
   crossings (sign of the normal's component along the ray) give a winding
   number at every voxel centre, counted once from each end of the ray: 6
   directed counts per voxel. A count votes "inside" if it is non-zero (the
   non-zero rule keeps overlapping bodies and bodies whose normals are all
   flipped solid, where parity would cut them out); a voxel is interior when
   at least 4 of its 6 votes say so. On a closed surface the two ends of a
   ray agree; a hole makes the count from its side wrong only for the rays
   that pass through it, and the other directions outvote it, where a flood
   fill from outside would leak through the hole into the whole inside.
   Rays are offset from the centres by a tiny irrational fraction of a voxel
   so that they never pass exactly through a vertex or an edge, which would
   be counted once per face around it. Without the offset that happens all
   the time on meshes extracted from a grid (marching cubes puts every
   vertex on a line through voxel centres).

Before voting, each connected body (faces connected through shared vertex
positions) whose signed volume is negative is flipped, so that an inside-out
body overlapping another one adds to its winding number instead of cancelling
it to zero. The price: a closed inner shell facing inwards (a modelled
cavity) is filled, which is harmless for shapes judged from outside.

Speed, 2 cores, grid = the mesh's bounding box with res voxels along its
longest side, first call / repeated call (towerruins: 24k faces):

    res        64           128          256
    towerruins 0.18/0.16 s  0.51/0.40 s  1.8-2.3/1.6 s  (process peak 480 MB)
    bunny      0.26/0.25 s  0.58/0.46 s  1.6/1.2 s      (69k faces)

measured with::

    python -c "import sys, time, numpy as np; from sinshape.prep.voxelize \\
    import load_mesh, voxelize; m = load_mesh(sys.argv[1]); h = m.extents.max() \\
    / int(sys.argv[2]); t = time.perf_counter(); voxelize(m, m.bounds[0], [h] * 3, \\
    np.ceil(m.extents / h)); print(time.perf_counter() - t)" MESH.obj 128
"""

from __future__ import annotations

import io
import itertools
import warnings
from pathlib import Path

import numpy as np
import trimesh

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import read_regular

from . import meshfiles

# A mesh thinner than this fraction of its size across some direction is
# flat: it has no inside to fill.
_FLAT_RATIO = 1e-3

# Ray offset from the voxel centres, in voxels, per axis (irrational ratios).
_RAY_JITTER = 1e-5 * np.sqrt([2.0, 3.0, 5.0])

# Relative slack of the separating-axis test, so that a triangle that exactly
# touches a voxel (up to rounding) counts as passing through it.
_OVERLAP_SLACK = 1e-9

# Pieces processed at once: bounds the per-candidate temporaries.
_CHUNK = 1 << 15
# Peak bytes per piece a triangle is cut into (measured: about 190, with the
# temporaries of orienting and splitting), for the memory check.
PIECE_BYTES = 256
# Coordinates beyond this overflow the principal-axis check and float32 meshes.
MAX_COORDINATE = 1e12
# Memory a mesh file takes to load, per byte of the file: 10 (.obj text) to
# 22 (binary .ply) measured on a sphere of 655362 vertices; more is refused up front.
MESH_BYTES_PER_FILE_BYTE = 24


# A mesh this many times wider than where 99% of its points lie has strays far away.
OUTLIER_RATIO = 1000


def load_mesh(path: str | Path, solid: bool = True, asset_folder: Path | None = None) -> trimesh.Trimesh:
    """Load any mesh file trimesh reads into one triangle mesh (its geometry:
    no material is read).

    A scene is concatenated with its transforms applied. Every way the file
    can be unusable raises `InputError` with a one-line message naming it:
    NaN or infinite coordinates (trimesh would drop their faces silently);
    `solid` also refuses a flat mesh, which has no inside to voxelize (a
    picture of one is fine).
    """
    path = Path(path)
    return scene_mesh(read_scene(path, materials=False, asset_folder=asset_folder)[0], path, solid)


def read_scene(path: Path, materials: bool = True, asset_folder: Path | None = None) -> tuple:
    """(scene, bytes) of a mesh file as trimesh reads it, unprocessed, its
    parts kept and, with `materials`, their materials (prep.colour reads
    them); a file it cannot read is an InputError. Every file it names is
    read from its folder (or `asset_folder`), checked first
    (prep.meshfiles): what was read is the scene's metadata[REFERENCES]."""
    formats = sorted(trimesh.exchange.load.mesh_formats())
    file_type = path.suffix.lower().lstrip(".")
    if file_type not in formats:
        works = ", ".join("." + f for f in formats)
        found = f"mesh format '{path.suffix}'" if path.suffix else "file name without extension"
        raise InputError(f"{path}: unsupported {found} (use one of {works})")
    data = read_regular(path, f"the mesh {path}", None, MESH_BYTES_PER_FILE_BYTE)
    if not data:
        raise InputError(f"{path}: empty file")
    data = _as_text(data, file_type, path)
    folder = meshfiles.MeshFolder(path, asset_folder)
    references = meshfiles.check_references(path, data, folder, materials)
    try:
        # Unprocessed, so that faces with NaN coordinates are seen, not dropped; garbage numbers
        # are refused below, without numpy's RuntimeWarning lines first.
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            scene = trimesh.load_scene(io.BytesIO(data), file_type=file_type, process=False,
                                       resolver=meshfiles.FolderResolver(folder), skip_materials=not materials)
    except InputError:  # from FolderResolver: it names the file
        raise
    except Exception as exc:  # trimesh's parsers raise anything on a bad file
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{path}: cannot read as .{file_type}: {reason}") from None
    scene.metadata[REFERENCES] = references
    return scene, data


REFERENCES = "sinshape.references"  # a read scene's metadata: the meshfiles.References of what it names


def scene_parts(scene) -> list:
    """The parts of a scene that have faces, in its graph's order, each as
    (name, vertices (V, 3) float64 with its transform applied, faces (F, 3),
    the geometry as read)."""
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, key = scene.graph[node]
        geometry = scene.geometry[key]
        if not hasattr(geometry, "faces") or len(geometry.faces) == 0:
            continue
        vertices = np.asarray(geometry.vertices, np.float64)
        transform = np.asarray(transform, np.float64)
        if vertices.ndim == 2 and vertices.shape[1] == 3 and not np.array_equal(transform, np.eye(4)):
            with np.errstate(all="ignore"):  # non-finite coordinates are refused by name later
                vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
        parts.append((str(key), vertices, np.asarray(geometry.faces), geometry))
    return parts


def scene_mesh(scene, path: Path, solid: bool = True) -> trimesh.Trimesh:
    """A scene's parts as one checked triangle mesh (see `load_mesh`), their
    faces in `scene_parts`' order: geometry only (trimesh's own
    concatenation would pack their textures into one, decoding them all)."""
    parts = scene_parts(scene)
    if any(vertices.ndim != 2 or vertices.shape[1] != 3 for _, vertices, _, _ in parts):
        shape = next(vertices.shape for _, vertices, _, _ in parts if vertices.ndim != 2 or vertices.shape[1] != 3)
        raise InputError(f"{path}: not a 3-D mesh (its vertices have {shape[-1]} coordinates)")
    if not parts:
        raise InputError(f"{path}: no triangles (an empty mesh, a point cloud or lines)")
    offsets = np.cumsum([0] + [len(vertices) for _, vertices, _, _ in parts])
    for (_, vertices, faces, _), offset in zip(parts, offsets):
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
            raise InputError(f"{path}: corrupt mesh: faces refer to vertices it does not have")
    mesh = trimesh.Trimesh(np.concatenate([vertices for _, vertices, _, _ in parts]),
                           np.concatenate([faces + offset for (_, _, faces, _), offset in zip(parts, offsets)]),
                           process=False)
    if not np.isfinite(mesh.vertices[mesh.faces]).all():
        raise InputError(f"{path}: NaN or infinite vertex coordinates")
    if np.abs(mesh.vertices[mesh.faces]).max() > MAX_COORDINATE:
        raise InputError(f"{path}: coordinates beyond +-{MAX_COORDINATE:g}; scale the mesh down")
    with np.errstate(all="ignore"):  # no RuntimeWarning lines: what matters is checked below
        mesh.process()  # merges duplicate vertices, as trimesh's default loading does
        mesh.remove_unreferenced_vertices()
        if solid:
            _check_solid(mesh, path)
    return mesh


def _bulk_extent(mesh: trimesh.Trimesh) -> float:
    """The widest extent, over the axes, of the middle 99% of the surface
    (face centres weighted by area): a tiny part far away does not count."""
    centres, areas = mesh.triangles_center, mesh.area_faces
    widths = []
    for axis in range(3):
        order = np.argsort(centres[:, axis])
        share = np.cumsum(areas[order]) / areas.sum()
        low, high = np.searchsorted(share, [0.005, 0.995])
        widths.append(centres[order[min(high, len(order) - 1)], axis] - centres[order[low], axis])
    return max(widths)


def _check_solid(mesh: trimesh.Trimesh, path: Path) -> None:
    """A mesh with an inside: no far outliers, not flat, faces with area."""
    if mesh.area > 0:
        bulk, whole = _bulk_extent(mesh), np.ptp(mesh.vertices, axis=0).max()
        if bulk > 0 and whole > OUTLIER_RATIO * bulk:
            raise InputError(f"{path}: parts of it lie far from the rest ({whole:.3g} across, while 99% of its "
                             f"surface lies within {bulk:.3g}); remove the stray parts")
    _check_not_flat(mesh.vertices, path)
    if not mesh.area > 0:
        raise InputError(f"{path}: all its faces have zero area, so it has no surface to voxelize")


# Formats that are always text, and STL, which is text unless its size fits
# the binary layout (an 84-byte header and count, 50 bytes a triangle).
_TEXT_FORMATS = ("obj", "off")


def _as_text(data: bytes, file_type: str, path: Path) -> bytes:
    """The bytes of a text format as UTF-8 that trimesh reads without its
    optional encoding guesser: a non-UTF-8 byte (a Latin-1 comment) is read
    as Latin-1, which decodes every byte; numbers and keywords are ASCII in
    both. A file with NUL bytes is binary data, not this format's text."""
    binary_stl = file_type == "stl" and len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little")
    if file_type not in _TEXT_FORMATS and (file_type != "stl" or binary_stl):
        return data
    if b"\0" in data:
        if file_type == "stl":
            raise InputError(f"{path}: neither binary STL (its size does not fit its triangle count) nor STL text")
        raise InputError(f"{path}: binary data, not .{file_type} text")
    try:
        return data.decode("utf-8").encode()
    except UnicodeDecodeError:
        return data.decode("latin-1").encode()


def _check_not_flat(vertices: np.ndarray, path: Path) -> None:
    """Refuse points that lie in a plane or on a line, in any orientation:
    thinner than _FLAT_RATIO of the mesh's size across its thinnest
    principal direction (the axis-aligned box would miss a tilted plane)."""
    centred = vertices - vertices.mean(axis=0)
    directions = np.linalg.eigh(centred.T @ centred)[1]  # principal directions, columns
    widths = np.sort(np.ptp(centred @ directions, axis=0))[::-1]  # largest first
    if widths[0] == 0:
        raise InputError(f"{path}: all its points coincide, so it has no inside to voxelize")
    thin = int(np.count_nonzero(widths < _FLAT_RATIO * widths[0]))
    if thin:
        lie = "on a line" if thin == 2 else "in a plane"
        raise InputError(f"{path}: flat mesh (its points lie {lie}), so it has no inside to voxelize")


def voxelize(mesh: trimesh.Trimesh, origin, spacing, shape) -> np.ndarray:
    """Solid occupancy of `mesh` on a regular grid.

    origin : (3,) float  lower corner of the grid box (not a voxel centre)
    spacing : (3,) float voxel edge length per axis
    shape : (3,) int     number of voxels per axis

    Voxel (i, j, k) covers ``origin + [i, i + 1) * spacing[0]`` etc.; its
    centre is ``origin + (idx + 0.5) * spacing``. Returns an (X, Y, Z) bool
    grid: surface voxels (every voxel a triangle passes through) united with
    interior voxels (voxel centres voted inside, see the module docstring).
    """
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    spacing = np.asarray(spacing, dtype=np.float64).reshape(3)
    shape = tuple(int(n) for n in np.asarray(shape).reshape(3))
    if not (np.isfinite(origin).all() and np.isfinite(spacing).all() and (spacing > 0).all()):
        raise ValueError(f"bad grid: origin {origin}, spacing {spacing}")
    if min(shape) < 1:
        raise ValueError(f"bad grid shape {shape}")

    triangles = (np.asarray(mesh.triangles, dtype=np.float64) - origin) / spacing
    if not np.isfinite(triangles).all():
        raise ValueError("mesh has non-finite vertex coordinates")
    check_memory(int(_piece_count(triangles) * PIECE_BYTES + 8 * np.prod(shape, dtype=np.float64)),
                 f"voxelising {len(triangles)} faces on a {'x'.join(map(str, shape))} grid")
    pieces = _split_to_size(_orient_bodies(triangles))

    surface = np.zeros(shape, dtype=bool)
    # Per ray axis: signed crossings by the voxel layer whose centre they
    # precede (cumulated below), and per ray the sum of all its crossings.
    starts = [np.zeros(shape, dtype=np.int16) for _ in range(3)]
    totals = [np.zeros(_flatten(shape, axis), dtype=np.int16) for axis in range(3)]
    for first in range(0, len(pieces), _CHUNK):
        chunk = np.ascontiguousarray(pieces[first:first + _CHUNK].transpose(1, 2, 0))
        _mark_surface(chunk, surface)
        for axis in range(3):
            _add_crossings(chunk, axis, starts[axis], totals[axis])

    votes = np.zeros(shape, dtype=np.uint8)
    for axis in range(3):
        # Signed crossings before each voxel centre. Winding number from the
        # low end = -before, from the high end = total - before.
        before = np.cumsum(starts[axis], axis=axis, dtype=np.int16)
        votes += before != 0
        votes += before != totals[axis]
    return surface | (votes >= 4)


def _piece_count(triangles: np.ndarray) -> float:
    """How many pieces `_split_to_size` cuts the triangles into, at most:
    halving the longest edge k times makes 2**k pieces, and it takes about
    two halvings to halve every edge. Memory follows this, not the face count."""
    if len(triangles) == 0:
        return 0.0
    edges = np.roll(triangles, -1, axis=1) - triangles
    longest = np.sqrt(np.einsum("ijk,ijk->ij", edges, edges).max(axis=1))
    return float((4.0 ** np.ceil(np.log2(np.maximum(longest, 1.0)))).sum())


def _orient_bodies(triangles: np.ndarray) -> np.ndarray:
    """Flip every connected body whose signed volume is negative.

    triangles : (n, 3, 3) float -> (n, 3, 3) float, some faces reversed
    Bodies are found through shared vertex positions, not indices: OBJ files
    duplicate vertices along UV seams, which would cut one body into patches.
    The signed volume is taken about the body's centroid, so that an open
    body (one with a hole) is judged by its shape, not by where it sits.
    """
    import scipy.sparse.csgraph  # the prep extra's; loading a mesh needs none of it

    if len(triangles) == 0:
        return triangles
    # Weld by exact position: seam duplicates are bit-identical copies.
    _, vertex = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)
    vertex = vertex.reshape(-1, 3)
    n_vertices = vertex.max() + 1
    links = scipy.sparse.coo_matrix(
        (np.ones(2 * len(vertex)), (vertex[:, :2].ravel(), vertex[:, 1:].ravel())),
        shape=(n_vertices, n_vertices),
    )
    _, labels = scipy.sparse.csgraph.connected_components(links, directed=False)
    body = labels[vertex[:, 0]]
    n_bodies = body.max() + 1

    counts = np.bincount(body, minlength=n_bodies)[:, None]
    centroid = np.stack(
        [np.bincount(body, triangles[:, :, i].mean(axis=1), n_bodies) for i in range(3)], axis=1
    ) / counts
    v = triangles - centroid[body][:, None, :]
    signed = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2]))
    inverted = np.bincount(body, signed, n_bodies) < 0
    flip = inverted[body]
    out = triangles.copy()
    out[flip] = triangles[flip][:, ::-1]
    return out


def _split_to_size(triangles: np.ndarray, max_edge: float = 1.0) -> np.ndarray:
    """Bisect triangles along their longest edge until no edge exceeds `max_edge`.

    triangles : (n, 3, 3) float -> (m, 3, 3) float, same orientation, same union
    """
    done = []
    while len(triangles):
        edges = np.roll(triangles, -1, axis=1) - triangles  # edge k: vertex k to k + 1
        length2 = np.einsum("ijk,ijk->ij", edges, edges)
        longest = length2.argmax(axis=1)
        small = length2[np.arange(len(triangles)), longest] <= max_edge * max_edge
        done.append(triangles[small])
        triangles, longest = triangles[~small], longest[~small]
        # Rotate so the longest edge runs from vertex 0 to 1 (keeps orientation).
        order = (longest[:, None] + np.arange(3)) % 3
        a, b, c = np.moveaxis(np.take_along_axis(triangles, order[:, :, None], axis=1), 1, 0)
        mid = 0.5 * (a + b)
        triangles = np.concatenate([np.stack([a, mid, c], axis=1), np.stack([mid, b, c], axis=1)])
    return np.concatenate(done + [triangles])


def _mark_surface(vert: np.ndarray, surface: np.ndarray) -> None:
    """Set every voxel of `surface` that a piece passes through.

    vert : (3, 3, n) float  vert[j, c] = coordinate c of vertex j of each piece,
                            in voxel units, no edge longer than 1 voxel
    """
    shape = surface.shape
    coords = vert.transpose(1, 0, 2)  # (coordinate, vertex, piece)
    # Half-open voxels: a piece in the plane z = k belongs to voxel layer k.
    low = [np.floor(x.min(axis=0)).astype(np.int64) for x in coords]
    high = [np.floor(x.max(axis=0)).astype(np.int64) for x in coords]
    # Each piece spans 1 or 2 voxels per axis: try the 2x2x2 block at `low`.
    piece, voxel = [], []
    for offset in itertools.product((0, 1), repeat=3):
        index = [low[c] + offset[c] for c in range(3)]
        ok = np.ones(vert.shape[2], dtype=bool)
        for c in range(3):
            ok &= (index[c] <= high[c]) & (index[c] >= 0) & (index[c] < shape[c])
        piece.append(np.flatnonzero(ok))
        voxel.append(np.stack([i[ok] for i in index]))
    piece = np.concatenate(piece)
    voxel = np.concatenate(voxel, axis=1)
    rel = [[vert[j, c][piece] - (voxel[c] + 0.5) for c in range(3)] for j in range(3)]
    hit = _overlaps_voxel(rel)
    surface[tuple(voxel[:, hit])] = True


def _overlaps_voxel(v: list) -> np.ndarray:
    """Separating-axis test of triangles against the unit cube at the origin.

    v : v[j][c] (n,) float  coordinate c of vertex j, relative to the cube centre
    Returns (n,) bool. The 3 cube-face axes are left out: the caller only asks
    about voxels in each triangle's bounding box. Component arrays rather than
    an (n, 3, 3) array, because numpy reduces over a length-3 axis slowly.
    """
    slack = 1 + _OVERLAP_SLACK
    e = [[v[(k + 1) % 3][c] - v[k][c] for c in range(3)] for k in range(3)]
    # Triangle normal: the plane must pass within the cube's radius along it.
    normal = [e[0][(c + 1) % 3] * e[1][(c + 2) % 3] - e[0][(c + 2) % 3] * e[1][(c + 1) % 3]
              for c in range(3)]
    offset = sum(normal[c] * v[0][c] for c in range(3))
    radius = 0.5 * (np.abs(normal[0]) + np.abs(normal[1]) + np.abs(normal[2])) * slack
    overlap = np.abs(offset) <= radius
    # Axes (cube axis c) x (edge k). Both ends of edge k project to the same
    # value, so the edge's start and the opposite vertex give the extent.
    for k in range(3):
        for c in range(3):
            c1, c2 = (c + 1) % 3, (c + 2) % 3
            p = e[k][c1] * v[k][c2] - e[k][c2] * v[k][c1]
            q = e[k][c1] * v[(k + 2) % 3][c2] - e[k][c2] * v[(k + 2) % 3][c1]
            radius = 0.5 * (np.abs(e[k][c1]) + np.abs(e[k][c2])) * slack
            overlap &= (np.minimum(p, q) <= radius) & (np.maximum(p, q) >= -radius)
    return overlap


def _add_crossings(vert: np.ndarray, axis: int, starts: np.ndarray, totals: np.ndarray) -> None:
    """Add the signed crossings of the pieces by the rays along `axis`.

    vert : (3, 3, n) float  as for `_mark_surface`
    A crossing counts +1 where the piece's normal points along the ray, -1
    against it; it is added to `starts` at the first voxel layer whose centre
    lies beyond it (if any) and to the ray's entry in `totals`.
    """
    shape = starts.shape
    # (a, b, axis) is a cyclic permutation of (x, y, z), so the 2D cross
    # product in the (a, b) plane is the normal's component along the ray.
    a, b = (axis + 1) % 3, (axis + 2) % 3
    # Ray (i, j) runs along `axis` through (a, b) = (i, j) in these coordinates.
    pa = vert[:, a] - 0.5 - _RAY_JITTER[a]
    pb = vert[:, b] - 0.5 - _RAY_JITTER[b]
    low_a, low_b = (np.ceil(p.min(axis=0)).astype(np.int64) for p in (pa, pb))
    high_a, high_b = (np.floor(p.max(axis=0)).astype(np.int64) for p in (pa, pb))
    # Each piece covers 0, 1 or 2 rays per axis: try the 2x2 rays at `low`.
    piece, ray_a, ray_b = [], [], []
    for offset_a, offset_b in itertools.product((0, 1), repeat=2):
        i, j = low_a + offset_a, low_b + offset_b
        ok = (i <= high_a) & (j <= high_b) & (i >= 0) & (i < shape[a]) & (j >= 0) & (j < shape[b])
        piece.append(np.flatnonzero(ok))
        ray_a.append(i[ok])
        ray_b.append(j[ok])
    piece, ray_a, ray_b = np.concatenate(piece), np.concatenate(ray_a), np.concatenate(ray_b)

    # Edge functions: w[k] is twice the signed area of (v_k, v_k+1, ray); all
    # three share the sign of the piece's area when the ray is inside it.
    xa = [p[piece] for p in pa]
    xb = [p[piece] for p in pb]
    w = [(xa[(k + 1) % 3] - xa[k]) * (ray_b - xb[k]) - (xb[(k + 1) % 3] - xb[k]) * (ray_a - xa[k])
         for k in range(3)]
    area = w[0] + w[1] + w[2]
    hit = ((w[0] >= 0) & (w[1] >= 0) & (w[2] >= 0)) | ((w[0] <= 0) & (w[1] <= 0) & (w[2] <= 0))
    hit &= area != 0
    piece, ray_a, ray_b, area = piece[hit], ray_a[hit], ray_b[hit], area[hit]
    # Barycentric weight of vertex k is the edge function of the opposite edge.
    z = [vert[j, axis][piece] for j in range(3)]
    depth = (w[1][hit] * z[0] + w[2][hit] * z[1] + w[0][hit] * z[2]) / area
    sign = np.sign(area).astype(np.int16)

    # Voxel centres k + 0.5 beyond depth d are the layers k >= floor(d + 0.5).
    layer = np.clip(np.floor(depth + 0.5).astype(np.int64), 0, None)
    index = [ray_a, ray_b, np.zeros_like(ray_a)]
    np.add.at(totals, _unroll(index, axis), sign)
    in_grid = layer < shape[axis]
    index = [ray_a[in_grid], ray_b[in_grid], layer[in_grid]]
    np.add.at(starts, _unroll(index, axis), sign[in_grid])


def _unroll(index: list, axis: int) -> tuple:
    """(a, b, along-ray) index arrays -> (x, y, z) order, for rays along `axis`."""
    return tuple(index[(c - axis - 1) % 3] for c in range(3))


def _flatten(shape: tuple[int, int, int], axis: int) -> tuple[int, int, int]:
    """`shape` with a single layer along `axis`: one entry per ray."""
    return tuple(1 if c == axis else n for c, n in enumerate(shape))
