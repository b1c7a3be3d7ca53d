"""Query occupancy from a tri-plane: at points, on a dense grid, or only in a
band around the surface.

The decoder's first layer is applied to each plane once (stage
decoder_planes), and bilinear interpolation commutes with it, so a point
costs the sum of three interpolated hidden vectors, a ReLU and a dot product
(docs/METHOD.md, "The decoder's first layer"). On a regular grid the
interpolation is separable: a fine plane row is a matrix product of the
coarse plane with resize weights.

A grid `scale` times finer has round(N * scale) points per axis spanning the
same extent as the N plane cells (align_corners=True), so scale 1 reads the
cells themselves. Grid positions outside the tri-plane count as empty: the
grid is padded with one empty point on every side, so surfaces close.
"""

import numbers
from dataclasses import dataclass

import numpy as np
from scipy.special import expit

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES

from .generate import MAX_GRID_SIDE, TriPlane, resize_matrix

BLOCK = 16  # cells per block side in the band search; see benchmarks/sample_speed.py
BOUND_MARGIN = 1e-4  # a block is uniform only if its bound clears 0.5 by this much


def head_occupancy(head, hidden: np.ndarray) -> np.ndarray:
    """sigmoid(w2 . relu(hidden + b1) + b2): (..., D) pre-activations -> (...) float32."""
    return biased_head_occupancy(head, hidden + head.bias1)


def biased_head_occupancy(head, biased: np.ndarray) -> np.ndarray:
    """head_occupancy of pre-activations that already hold b1, computed in
    their own buffer (overwritten): the band search's inner loop."""
    np.maximum(biased, 0, out=biased)
    logits = biased @ head.weight2
    logits += np.float32(head.bias2)
    return expit(logits)


def head_bounds(head, low: np.ndarray, high: np.ndarray) -> tuple:
    """Exact occupancy bounds over a box of pre-activations [low, high] (..., D).

    Each term w2_c relu(h_c + b1_c) is monotone in h_c, rising where w2_c > 0
    and falling where it is negative, so the head is largest at the corner
    taking `high` where w2 > 0 and `low` elsewhere, and smallest at the
    opposite corner. Returns (lowest, highest) occupancy, (...) each.
    """
    rising = head.weight2 > 0
    return head_occupancy(head, np.where(rising, low, high)), head_occupancy(head, np.where(rising, high, low))


@dataclass
class Projected:
    """The final tri-plane times the decoder's first layer: 3 x (H, W, D)."""

    planes: list
    size: tuple  # (X, Y, Z) of the tri-plane


def project(model, triplane: TriPlane) -> Projected:
    """Run stage decoder_planes on a tri-plane."""
    outputs = model.decoder_planes.run([p[None] for p in triplane.planes])
    return Projected([o[0] for o in outputs], triplane.size)


def points(model, triplane: TriPlane, coords: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """Occupancy at arbitrary points.

    coords : (n, 3) in model coordinates, finest-voxel units: grid point
    (i, j, k) of the sample at scale 1 is at (i, j, k); the sample spans
    [0, N - 1] per axis. Points outside count as empty. Returns (n,) float32.
    """
    try:
        coords = np.asarray(coords, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("points must be an (n, 3) array of numbers", "coords") from None
    if coords.ndim != 2 or coords.shape[1] != 3:
        raise InputError(f"points must be an (n, 3) array, got shape {coords.shape}", "coords")
    proj = project(model, triplane)
    size = np.array(triplane.size)
    out = np.zeros(len(coords), np.float32)
    inside = np.all((coords >= 0) & (coords <= size - 1), axis=1)
    where = np.nonzero(inside)[0]
    for start in range(0, len(where), chunk):
        index = where[start:start + chunk]
        c = coords[index]
        hidden = sum(bilinear(plane, c[:, a], c[:, b]) for plane, (a, b) in zip(proj.planes, PLANE_AXES))
        out[index] = head_occupancy(model.head, hidden)
    return out


def bilinear(plane: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample a (H, W, D) plane at real cell positions (n,) u, v: (n, D)."""
    h, w = plane.shape[:2]
    u0 = np.clip(np.floor(u).astype(int), 0, max(h - 2, 0))
    v0 = np.clip(np.floor(v).astype(int), 0, max(w - 2, 0))
    u1, v1 = np.minimum(u0 + 1, h - 1), np.minimum(v0 + 1, w - 1)
    fu, fv = (u - u0)[:, None].astype(np.float32), (v - v0)[:, None].astype(np.float32)
    top = plane[u0, v0] * (1 - fv) + plane[u0, v1] * fv
    bottom = plane[u1, v0] * (1 - fv) + plane[u1, v1] * fv
    return top * (1 - fu) + bottom * fu


def grid_shape(size, scale: float) -> tuple:
    """Points per axis of a grid `scale` times finer than `size`."""
    if not isinstance(scale, numbers.Real) or not 0 < scale < float("inf"):
        raise InputError(f"scale must be a positive number, got {scale}", "scale")
    if max(size) * scale > MAX_GRID_SIDE:  # before round(), which overflows for 1e308
        points = "x".join(f"{n * scale:.0f}" for n in size)  # inf past a float's range
        raise InputError(f"scale {scale} asks for a {points} grid; at most {MAX_GRID_SIDE} points per axis are supported",
                         "scale")
    return tuple(max(2, round(n * scale)) for n in size)


class FineGrid:
    """A grid `scale` times finer than a projected tri-plane, padded by one
    empty point per side, with its interpolated planes made on demand.

    Padded index p is grid index p - 1; padded indices 0 and M + 1 (and any
    beyond, up to the block-rounded end) are empty.
    """

    def __init__(self, proj: Projected, scale: float, block: int = BLOCK):
        self.proj = proj
        self.shape = grid_shape(proj.size, scale)  # (Mx, My, Mz) real points
        self.block = block
        self.blocks = tuple(-(-(m + 1) // block) for m in self.shape)  # blocks cover 0 .. M + 1
        self.padded = tuple(n * block + 1 for n in self.blocks)
        # Resize weights from coarse cells to every padded point (clipped), per axis.
        self.weights = [resize_matrix(n, m)[self.real_index(axis)] for axis, (n, m) in
                        enumerate(zip(proj.size, self.shape))]
        self._yz = None

    def real_index(self, axis: int) -> np.ndarray:
        """Grid index of every padded point along an axis, clipped into range."""
        return np.clip(np.arange(self.padded[axis]) - 1, 0, self.shape[axis] - 1)

    def is_real(self, axis: int, padded: np.ndarray) -> np.ndarray:
        return (padded >= 1) & (padded <= self.shape[axis])

    def fine_plane(self, k: int, rows: slice = slice(None)) -> np.ndarray:
        """Plane k interpolated to padded points; `rows` selects points along
        the plane's first axis: (r, Pb, D)."""
        a, b = PLANE_AXES[k]
        partial = np.tensordot(self.weights[a][rows], self.proj.planes[k], axes=(1, 0))  # (r, Nb, D)
        return np.matmul(self.weights[b], partial)  # (Pb, Nb) @ (r, Nb, D)

    @property
    def yz(self) -> np.ndarray:
        """Plane yz on all padded (y, z) points, made once: (Py, Pz, D)."""
        if self._yz is None:
            self._yz = self.fine_plane(2)
        return self._yz

    def coarse_ranges(self, axis: int) -> list:
        """Per block along an axis: the coarse cell range [c0, c1] whose samples
        bound every real point of the block, or None if it has none."""
        n, m, step = self.proj.size[axis], self.shape[axis], self.block
        ratio = (n - 1) / (m - 1)
        ranges = []
        for b in range(self.blocks[axis]):
            first, last = max(b * step - 1, 0), min(b * step + step - 1, m - 1)
            if first > last:
                ranges.append(None)
            else:
                ranges.append((int(np.floor(first * ratio)), min(int(np.ceil(last * ratio)), n - 1)))
        return ranges


@dataclass
class Slab:
    """One x-slab of blocks from the band search.

    values : (B + 1, Py, Pz) occupancy at padded points, filled only inside
    active blocks (and the shared first plane, see `Band.carry`); state :
    (nby, nbz) int8 per block, +1 all inside, -1 all outside, 0 active.
    """

    index: int  # x block index; padded x of values[0] is index * B
    values: np.ndarray
    state: np.ndarray


def rectangle_bounds(plane: np.ndarray, ranges_a: list, ranges_b: list) -> tuple:
    """Min and max of a (Na, Nb, D) plane over every pair of index ranges:
    (len(ranges_a), len(ranges_b), D) each; empty ranges give +inf / -inf."""
    d = plane.shape[2]
    lo = np.full((len(ranges_a), len(ranges_b), d), np.inf, np.float32)
    hi = np.full_like(lo, -np.inf)
    for i, ra in enumerate(ranges_a):
        if ra is None:
            continue
        rows = plane[ra[0]:ra[1] + 1]
        row_lo, row_hi = rows.min(axis=0), rows.max(axis=0)  # (Nb, D)
        for j, rb in enumerate(ranges_b):
            if rb is not None:
                lo[i, j] = row_lo[rb[0]:rb[1] + 1].min(axis=0)
                hi[i, j] = row_hi[rb[0]:rb[1] + 1].max(axis=0)
    return lo, hi


def check_band_memory(size, scale: float, hidden: int, block: int = BLOCK, memory_limit: int | None = None,
                      slabs_at_once: int = 1) -> None:
    """Refuse up front a band search (`Band`) that needs more than
    memory_limit bytes: the yz plane of D = `hidden` pre-activations at every
    padded (y, z); per slab being worked on, three slab buffers and the x
    rows of two planes."""
    shape = grid_shape(size, scale)
    py, pz = (-(-(m + 1) // block) * block + 1 for m in shape[1:])
    per_slab = py * pz * 3 * (block + 1) * 4 + (block + 1) * (py + pz) * hidden * 4
    needed = py * pz * hidden * 4 + per_slab * slabs_at_once
    check_memory(needed, f"meshing a {'x'.join(map(str, shape))} grid", memory_limit)


class Band:
    """The band search of one tri-plane on a grid `scale` times finer: the
    occupancy of each x slab of blocks, evaluated only in blocks that the
    surface may cross. Work needing more than memory_limit bytes (None: the
    memory available) is refused up front.

    A block's hidden pre-activations are bounded, per channel, by the min and
    max of the coarse projected plane samples that its points interpolate
    between (interpolation weights are convex); head_bounds turns that into
    exact occupancy bounds. Blocks whose bounds clear 0.5 are uniform and
    never evaluated, so the result is the dense result, at a cost that grows
    with the surface's area rather than the volume.

    Slabs are independent (`slab` may run on several threads at once);
    `carry` then makes neighbours agree on the plane of points they share.
    """

    def __init__(self, model, triplane: TriPlane, scale: float, block: int = BLOCK,
                 memory_limit: int | None = None, slabs_at_once: int = 1):
        check_band_memory(triplane.size, scale, model.manifest.hidden, block, memory_limit, slabs_at_once)
        proj = project(model, triplane)
        self.grid = grid = FineGrid(proj, scale, block)
        self.head, self.block = model.head, block
        self.ranges = [grid.coarse_ranges(axis) for axis in range(3)]
        self.yz_bounds = rectangle_bounds(proj.planes[2], self.ranges[1], self.ranges[2])  # (nby, nbz, D) each
        self.real_y = grid.is_real(1, np.arange(grid.padded[1]))
        self.real_z = grid.is_real(2, np.arange(grid.padded[2]))
        # Blocks that hold padding points cannot be all inside.
        self.padded_yz = np.array([[not (self.real_y[b * block:b * block + block + 1].all() and
                                         self.real_z[c * block:c * block + block + 1].all())
                                    for c in range(grid.blocks[2])] for b in range(grid.blocks[1])])
        self.yz_biased = grid.fine_plane(2)  # the yz plane at every padded (y, z), with
        self.yz_biased += self.head.bias1  # the head's first bias added once

    def __len__(self) -> int:
        return self.grid.blocks[0]

    def slab(self, bx: int) -> "Slab":
        """The occupancy of x block row bx, before `carry`."""
        grid, block, head = self.grid, self.block, self.head
        if self.ranges[0][bx] is None:
            return Slab(bx, None, np.full(grid.blocks[1:], -1, np.int8))
        xy_lo, xy_hi = rectangle_bounds(grid.proj.planes[0], [self.ranges[0][bx]], self.ranges[1])
        xz_lo, xz_hi = rectangle_bounds(grid.proj.planes[1], [self.ranges[0][bx]], self.ranges[2])
        yz_lo, yz_hi = self.yz_bounds
        low = xy_lo[0][:, None] + xz_lo[0][None] + yz_lo
        high = xy_hi[0][:, None] + xz_hi[0][None] + yz_hi
        empty = np.isinf(low).any(axis=-1)  # blocks with no real points at all
        low[empty], high[empty] = 0, 0
        occ_low, occ_high = head_bounds(head, low, high)
        padded_x = not grid.is_real(0, np.arange(bx * block, bx * block + block + 1)).all()
        state = np.zeros(grid.blocks[1:], np.int8)
        state[(occ_low > 0.5 + BOUND_MARGIN) & ~self.padded_yz & (not padded_x)] = 1
        state[occ_high < 0.5 - BOUND_MARGIN] = -1
        state[empty] = -1
        active = np.argwhere(state == 0)
        if len(active) == 0:
            return Slab(bx, None, state)

        rows = slice(bx * block, bx * block + block + 1)
        xy = grid.fine_plane(0, rows)  # (B+1, Py, D)
        xz = grid.fine_plane(1, rows)  # (B+1, Pz, D)
        values = np.zeros((block + 1, grid.padded[1], grid.padded[2]), np.float32)
        real_x = grid.is_real(0, np.arange(rows.start, rows.stop))
        # One block at a time in one buffer of (B+1)^3 x D pre-activations
        # (0.6 MB at D = 32): it stays in cache through the sum, the ReLU and
        # the product, measured 1.2-1.5x faster than batches of blocks.
        hidden = np.empty((block + 1,) * 3 + (xy.shape[-1],), np.float32)
        for by, bz in active:
            ys, zs = slice(by * block, by * block + block + 1), slice(bz * block, bz * block + block + 1)
            np.add(xy[:, ys, None], xz[:, None, zs], out=hidden)  # (x, y, z, D)
            hidden += self.yz_biased[None, ys, zs]
            occupancy = biased_head_occupancy(head, hidden)
            occupancy *= real_x[:, None, None] & self.real_y[None, ys, None] & self.real_z[None, None, zs]
            values[:, ys, zs] = occupancy
        return Slab(bx, values, state)

    def carry(self, slabs):
        """Consecutive slabs share one plane of points: give the later one the
        earlier one's values there, so both sides of a seam see the same
        numbers. slabs: in order, as `slab` made them; yields them."""
        block, previous = self.block, None  # (values of the last plane, where they are valid)
        for slab in slabs:
            if slab.values is None:
                previous = None
                yield slab
                continue
            if previous is not None:
                plane, valid = previous
                slab.values[0][valid] = plane[valid]
            valid = np.zeros(slab.values.shape[1:], bool)
            for by, bz in np.argwhere(slab.state == 0):
                valid[by * block:by * block + block + 1, bz * block:bz * block + block + 1] = True
            previous = (slab.values[-1].copy(), valid)
            yield slab


def band(model, triplane: TriPlane, scale: float, block: int = BLOCK,
         memory_limit: int | None = None):
    """Occupancy on a grid `scale` times finer, evaluated only in blocks that
    the surface may cross (see Band); yields one Slab per x block row."""
    search = Band(model, triplane, scale, block, memory_limit)
    return search.carry(search.slab(bx) for bx in range(len(search)))


def dense(model, triplane: TriPlane, scale: float = 1.0, memory_limit: int | None = None) -> np.ndarray:
    """Occupancy on every point of a grid `scale` times finer: (Mx, My, Mz)
    float32. Refused up front if it needs more than memory_limit bytes (None:
    the memory available)."""
    mx, my, mz = grid_shape(triplane.size, scale)
    hidden = model.manifest.hidden  # the decoder's hidden width D
    # The grid, and the yz plane at every (y, z).
    check_memory(mx * my * mz * 4 + my * mz * hidden * 4,
                 f"a dense {mx}x{my}x{mz} occupancy grid (a mesh output streams instead)", memory_limit)
    proj = project(model, triplane)
    grid = FineGrid(proj, scale)
    out = np.empty(grid.shape, np.float32)
    yz = grid.yz[1:my + 1, 1:mz + 1]
    rows_per_slab = max(1, (1 << 22) // (my * mz * yz.shape[-1]))  # ~16 MB of hidden sums
    for x0 in range(0, mx, rows_per_slab):
        rows = slice(x0 + 1, min(x0 + rows_per_slab, mx) + 1)
        xy = grid.fine_plane(0, rows)[:, 1:my + 1]
        xz = grid.fine_plane(1, rows)[:, 1:mz + 1]
        out[rows.start - 1:rows.stop - 1] = head_occupancy(model.head, xy[:, :, None] + xz[:, None] + yz[None])
    return out
