"""Query occupancy from a tri-plane: at points, on a dense grid, or only in a
band around the surface.

The decoder's first layer is applied to each plane once (stage
decoder_planes), and bilinear interpolation commutes with it, so a point
costs the sum of three interpolated hidden vectors, a ReLU and a dot product
(docs/METHOD.md, "The decoder's first layer"). On a regular grid the
interpolation is separable: a fine plane is the coarse plane interpolated
along one axis, then the other, each point from its two neighbours
(`generate.Taps`), in separately rounded float32 multiplications and additions. A
matrix product would do the same sums, but BLAS rounds them differently
with its thread count and CPU (fused multiply-adds in some kernels), and a
sample must be the same bytes everywhere.

A grid `scale` times finer has round(N * scale) points per axis spanning the
same extent as the N plane cells (align_corners=True), so scale 1 reads the
cells themselves. Grid positions outside the tri-plane count as empty: the
grid is padded with one empty point on every side, so surfaces close.
"""

import numbers
from dataclasses import dataclass

import numpy as np

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES, plane_sizes

from .generate import MAX_GRID_SIDE, Taps, TriPlane

# The band search bounds blocks of BLOCK cells (a slab is one block thick),
# then the leaves of LEAF cells inside those it could not decide; only
# undecided leaves are evaluated and meshed (see benchmarks/sample_speed.py).
SIDES = (16, 8)
BLOCK, LEAF = SIDES[0], SIDES[-1]
BOUND_MARGIN = 1e-4  # a block is uniform only if its logit bound clears 0 by this much of its terms' size
BOUND_CHUNK = 256  # blocks bounded at once
FINE_ROWS = 32  # plane rows interpolated at once (a slab's 17 at a time)
LEAVES_AT_ONCE = 16  # leaves evaluated at once: (LEAF + 1)^3 hidden vectors each, 1.5 MB at D = 32


def head_occupancy(head, hidden: np.ndarray) -> np.ndarray:
    """sigmoid(w2 . relu(hidden + b1) + b2): (..., D) pre-activations -> (...) float32."""
    return biased_head_occupancy(head, hidden + head.bias1)


def biased_head_occupancy(head, biased: np.ndarray) -> np.ndarray:
    """head_occupancy of pre-activations that already hold b1, computed in
    their own buffer (overwritten): the band search's inner loop."""
    np.maximum(biased, 0, out=biased)
    logits = biased @ head.weight2
    logits += np.float32(head.bias2)
    return sigmoid(logits)


def head_colour(head, hidden: np.ndarray) -> np.ndarray:
    """sigmoid(relu(hidden + b1) @ w_colour + b_colour): (..., D) pre-activations
    -> (..., 3) float32 sRGB, the colour head of a coloured model."""
    return sigmoid(np.maximum(hidden + head.bias1, 0) @ head.weight_colour + head.bias_colour)


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
    return occupying(model, triplane, chunk)(coords)


def occupying(model, triplane: TriPlane, chunk: int = 1 << 16):
    """`points` of one tri-plane as a function of the points, the planes
    projected once: for work that asks again and again (an asset's bake)."""
    planes, top = project(model, triplane).planes, np.array(triplane.size) - 1

    def occupancy(coords) -> np.ndarray:
        coords = point_array(coords)
        out = np.zeros(len(coords), np.float32)
        inside = np.nonzero(np.all((coords >= 0) & (coords <= top), axis=1))[0]
        for start in range(0, len(inside), chunk):
            index = inside[start:start + chunk]
            out[index] = head_occupancy(model.head, hidden_at(planes, coords[index]))
        return out
    return occupancy


def colouring(model, triplane: TriPlane, chunk: int = 1 << 16):
    """A format-4 model's colour head on one tri-plane as a function of the
    points (coords as in `points`), the planes projected once; a point
    outside the tri-plane takes the colour of the nearest point inside (a
    mesh's vertices reach half a voxel beyond it, where the surface closes).
    (n, 3) float32 sRGB in [0, 1]. runtime.colour picks it or the tiles."""
    planes, top = project(model, triplane).planes, np.array(triplane.size) - 1

    def colour(coords) -> np.ndarray:
        coords = np.clip(point_array(coords), 0, top)
        out = np.empty((len(coords), 3), np.float32)
        for start in range(0, len(coords), chunk):
            out[start:start + chunk] = head_colour(model.head, hidden_at(planes, coords[start:start + chunk]))
        return out
    return colour


def point_array(coords) -> np.ndarray:
    try:
        coords = np.asarray(coords, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("points must be an (n, 3) array of numbers", "coords") from None
    if coords.ndim != 2 or coords.shape[1] != 3:
        raise InputError(f"points must be an (n, 3) array, got shape {coords.shape}", "coords")
    return coords


def hidden_at(planes: list, coords: np.ndarray) -> np.ndarray:
    """The decoder's hidden pre-activations (b1 not added) at points inside
    a tri-plane: the sum of its three projected planes (`Projected.planes`),
    interpolated. (n, D)."""
    return sum(bilinear(plane, coords[:, a], coords[:, b]) for plane, (a, b) in zip(planes, PLANE_AXES))


def bilinear(plane: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample a (H, W, D) plane at real cell positions (n,) u, v: (n, D)."""
    h, w = plane.shape[:2]
    u0 = np.clip(np.floor(u).astype(int), 0, max(h - 2, 0))
    v0 = np.clip(np.floor(v).astype(int), 0, max(w - 2, 0))
    u1, v1 = np.minimum(u0 + 1, h - 1), np.minimum(v0 + 1, w - 1)
    fu, fv = (u - u0)[:, None].astype(np.float32), (v - v0)[:, None].astype(np.float32)
    rows = plane.reshape(h * w, -1)  # rows taken by flat index: faster than indexing two axes
    top = np.take(rows, u0 * w + v0, axis=0) * (1 - fv) + np.take(rows, u0 * w + v1, axis=0) * fv
    bottom = np.take(rows, u1 * w + v0, axis=0) * (1 - fv) + np.take(rows, u1 * w + v1, axis=0) * fv
    return top * (1 - fu) + bottom * fu


def check_scale(scale: float) -> None:
    if not isinstance(scale, numbers.Real) or not 0 < scale < float("inf"):
        raise InputError(f"`scale` must be a positive number, got {scale}", "scale")


def grid_shape(size, scale: float) -> tuple:
    """Points per axis of a grid `scale` times finer than `size`."""
    check_scale(scale)
    if max(size) * scale > MAX_GRID_SIDE:  # before round(), which overflows for 1e308
        points = "x".join(f"{n * scale:.0f}" for n in size)  # inf past a float's range
        raise InputError(f"`scale` {scale} asks for a {points} grid; at most {MAX_GRID_SIDE} points per axis are supported",
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
        # Linear interpolation from coarse cells to every padded point (clipped), per axis.
        self.taps = [Taps.of(n, m).take(self.real_index(axis)) for axis, (n, m) in
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
        plane, first, second = self.proj.planes[k], self.taps[a].take(rows), self.taps[b]
        out = np.empty((len(first.low), self.padded[b], plane.shape[-1]), np.float32)
        for start in range(0, len(first.low), FINE_ROWS):
            along = first.take(slice(start, start + FINE_ROWS)).apply(plane, 0)  # (r, Nb, D)
            out[start:start + len(along)] = second.apply(along, 1)
        return out

    @property
    def yz(self) -> np.ndarray:
        """Plane yz on all padded (y, z) points, made once: (Py, Pz, D)."""
        if self._yz is None:
            self._yz = self.fine_plane(2)
        return self._yz

    def candidates(self, axis: int, side: int) -> np.ndarray:
        """Per block of `side` cells along an axis, the padded points where a
        plane interpolated along it can take its extremes over the block's
        points: between two coarse samples the interpolation is linear, so
        those are the first and last point of each run of points between the
        same two samples. (blocks, m) indices, short rows repeating their last.
        """
        n, m = self.proj.size[axis], self.shape[axis]
        cell = np.floor(self.real_index(axis) * ((n - 1) / (m - 1)))
        rows = []
        for start in range(0, self.padded[axis] - 1, side):
            points = np.arange(start, start + side + 1)
            runs = cell[points]
            ends = np.ones(len(points), bool)
            ends[1:-1] = (runs[1:-1] != runs[:-2]) | (runs[1:-1] != runs[2:])
            rows.append(points[ends])
        width = max(len(row) for row in rows)
        return np.array([np.pad(row, (0, width - len(row)), mode="edge") for row in rows])

    def padding(self, axis: int, side: int) -> tuple:
        """Per block of `side` cells along an axis: (has a padding point, has
        only padding points), (blocks,) bool each."""
        real = self.is_real(axis, np.arange(self.padded[axis]))
        per_block = np.lib.stride_tricks.sliding_window_view(real, side + 1)[::side]
        return ~per_block.all(axis=1), ~per_block.any(axis=1)


@dataclass
class Slab:
    """One x-slab of the band search: BLOCK cells thick, cut into leaves.

    values : (BLOCK + 1, Py, Pz) occupancy at padded points, exact at every
    point of an undecided leaf (the first plane shared with the previous slab,
    see `Band.carry`); None when no leaf is undecided. state : (BLOCK // LEAF,
    Py // LEAF, Pz // LEAF) int8 per leaf, +1 all inside, -1 all outside, 0
    undecided: the only leaves the surface can cross.
    """

    index: int  # padded x of values[0] is index * BLOCK
    values: np.ndarray | None
    state: np.ndarray

    def leaves(self) -> np.ndarray:
        """(K, 3) lowest padded points of the undecided leaves, slab-local x."""
        return np.argwhere(self.state == 0) * LEAF


def sigmoid(logits: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):  # exp(88+) is inf, and 1 / inf the right 0
        return 1 / (1 + np.exp(-logits))


def relaxed_head(head, low: np.ndarray, high: np.ndarray) -> tuple:
    """Linear bounds of the logit w2 . relu(s) + b2 for s between low and high
    (..., D), per block: (upper slopes, upper constant, lower slopes, lower
    constant), so that lower . s + c_low <= logit <= upper . s + c_high.

    Per channel, relu is itself where s >= 0, zero where s <= 0, and in
    between lies under its chord and over s or 0 (whichever is closer).
    """
    on, off = low >= 0, high <= 0
    between = ~on & ~off
    chord = np.where(between, high / np.where(between, high - low, 1), on)  # slope; on: 1, off: 0
    chord_at_zero = np.where(between, -chord * low, 0)
    under = on | (between & (high > -low))  # slope of the lower line: 1 or 0
    rising = head.weight2 > 0
    w = head.weight2
    upper = np.where(rising, w * chord, w * under)
    lower = np.where(rising, w * under, w * chord)
    return (upper, (np.where(rising, w, 0) * chord_at_zero).sum(-1) + head.bias2,
            lower, (np.where(rising, 0, w) * chord_at_zero).sum(-1) + head.bias2)


def interval_logits(head, low: np.ndarray, high: np.ndarray) -> tuple:
    """Lowest and highest logit where each channel of the hidden input (b1
    included) ranges over [low, high] (K, D) on its own: (K,) each."""
    rising = head.weight2 > 0
    top = np.maximum(np.where(rising, high, low), 0) @ head.weight2 + head.bias2
    bottom = np.maximum(np.where(rising, low, high), 0) @ head.weight2 + head.bias2
    return bottom, top


def linear_logits(head, low: np.ndarray, high: np.ndarray, samples: list) -> tuple:
    """Lowest and highest logit over blocks from `relaxed_head`'s linear forms,
    at their extremes over each plane's candidate samples (K, n, D), whose
    sum over the planes is the hidden input: it keeps the channels' joint
    variation that `interval_logits` loses. (K,) each."""
    upper, c_high, lower, c_low = relaxed_head(head, low, high)
    top = sum((s @ upper[:, :, None]).max(axis=(1, 2)) for s in samples) + c_high
    bottom = sum((s @ lower[:, :, None]).min(axis=(1, 2)) for s in samples) + c_low
    return bottom, top


def band_memory(size, scale: float, hidden: int, slabs_at_once: int = 1) -> int:
    """Bytes a band search (`Band`) of a tri-plane of `size` needs beside
    the tri-plane and its projection: the yz plane of D = `hidden`
    pre-activations at every padded (y, z); per slab being worked on, its
    values and cell configurations (5 bytes a point), the x rows of two
    planes, and the buffers of LEAVES_AT_ONCE leaves' hidden vectors (four,
    counting the gathered plane rows)."""
    shape = grid_shape(size, scale)
    py, pz = (-(-(m + 1) // BLOCK) * BLOCK + 1 for m in shape[1:])
    per_slab = py * pz * 5 * (BLOCK + 1) + (BLOCK + 1) * (py + pz) * hidden * 4 \
        + 4 * LEAVES_AT_ONCE * (LEAF + 1) ** 3 * hidden * 4
    return py * pz * hidden * 4 + per_slab * slabs_at_once


def check_band_memory(size, scale: float, hidden: int, memory_limit: int | None = None,
                      slabs_at_once: int = 1) -> None:
    """Refuse up front a band search that needs more than memory_limit bytes (band_memory)."""
    check_memory(band_memory(size, scale, hidden, slabs_at_once),
                 f"meshing a {'x'.join(map(str, grid_shape(size, scale)))} grid", memory_limit)


def projected_memory(size, hidden: int) -> int:
    """Bytes of a tri-plane's projection (`project`): each plane's D = `hidden` values per cell, float32."""
    return sum(h * w for h, w in plane_sizes(size)) * hidden * 4


def dense_memory(size, scale: float, hidden: int, colour: bool = False) -> int:
    """Bytes `dense` needs: the grid (and its colours), and the yz plane at every (y, z)."""
    mx, my, mz = grid_shape(size, scale)
    return mx * my * mz * (4 + 3 * colour) + my * mz * hidden * 4


class Band:
    """The band search of one tri-plane on a grid `scale` times finer: the
    occupancy of each x slab, evaluated only in the leaves (blocks of LEAF
    cells) that the surface may cross. Work needing more than memory_limit
    bytes (None: the memory available) is refused up front.

    Between coarse samples each plane is bilinear, so over a block's points it
    takes its extremes at a few candidate points (`FineGrid.candidates`);
    `interval_logits` and `linear_logits` turn the three planes' candidates
    into exact bounds of the logit. Blocks of BLOCK cells are bounded first,
    then the leaves of those left undecided (SIDES); leaves whose bounds
    clear 0 are uniform and never evaluated, so the result is the dense
    result, at a cost that grows with the surface's area rather than the
    volume (docs/METHOD.md, "The band search").

    Slabs are independent (`slab` may run on several threads at once);
    `carry` then makes neighbours agree on the plane of points they share.
    """

    def __init__(self, model, triplane: TriPlane, scale: float, memory_limit: int | None = None,
                 slabs_at_once: int = 1):
        check_band_memory(triplane.size, scale, model.manifest.hidden, memory_limit, slabs_at_once)
        self.grid = grid = FineGrid(project(model, triplane), scale, BLOCK)
        self.head = model.head
        self.yz = grid.fine_plane(2)  # (Py, Pz, D) at every padded (y, z), with the
        self.yz += self.head.bias1  # head's first bias added once
        self.candidates = {side: [grid.candidates(axis, side) for axis in range(3)] for side in SIDES}
        self.padding = {side: tuple(zip(*(grid.padding(axis, side) for axis in range(3)))) for side in SIDES}
        self.yz_range = {side: self.yz_ranges(side) for side in SIDES}

    def __len__(self) -> int:
        return self.grid.blocks[0]

    def yz_ranges(self, side: int) -> tuple:
        """The yz plane's (low, high) over each (y, z) block's candidates:
        (nby, nbz, D) each, the same for every slab."""
        _, cy, cz = self.candidates[side]
        return tuple(reduce(reduce(self.yz[:, cz], axis=2)[cy], axis=1) for reduce in (np.min, np.max))

    def states(self, side: int, blocks: np.ndarray, xy: np.ndarray, xz: np.ndarray, x0: int) -> np.ndarray:
        """+1 (all inside), -1 (all outside) or 0 per block of `side` cells:
        blocks (K, 3) block indices along x, y, z; xy, xz the slab's plane rows
        from padded x = x0."""
        (cx, cy, cz), (any_pad, all_pad) = self.candidates[side], self.padding[side]
        yz_low, yz_high = self.yz_range[side]
        state = np.zeros(len(blocks), np.int8)
        for column in sorted(set(blocks[:, 0].tolist())):  # blocks at one x: the same x candidates
            x = cx[column] - x0
            # Each plane's range over the x candidates first, then over the blocks' own.
            xy_low, xy_high, xz_low, xz_high = (reduce(p[x], axis=0) for p in (xy, xz) for reduce in (np.min, np.max))
            here = np.nonzero(blocks[:, 0] == column)[0]
            for part in np.array_split(here, -(-len(here) // BOUND_CHUNK)):
                by, bz = blocks[part, 1], blocks[part, 2]
                y, z = cy[by], cz[bz]
                low = xy_low[y].min(axis=1) + xz_low[z].min(axis=1) + yz_low[by, bz]
                high = xy_high[y].max(axis=1) + xz_high[z].max(axis=1) + yz_high[by, bz]
                bottom, top = interval_logits(self.head, low, high)
                # float32 sums of D terms are off by far less than 1e-4 of their size.
                slack = BOUND_MARGIN * (1 + np.maximum(np.abs(low), np.abs(high)) @ np.abs(self.head.weight2))
                # The linear bound, dearer, only where the interval bound leaves the block open.
                open_ = np.nonzero((bottom <= slack) & (top >= -slack))[0]
                if len(open_):
                    y, z, d = y[open_], z[open_], xy.shape[-1]
                    samples = [xy[x[None, :, None], y[:, None]].reshape(len(open_), -1, d),
                               xz[x[None, :, None], z[:, None]].reshape(len(open_), -1, d),
                               self.yz[y[:, :, None], z[:, None]].reshape(len(open_), -1, d)]
                    linear = linear_logits(self.head, low[open_], high[open_], samples)
                    bottom[open_] = np.maximum(bottom[open_], linear[0])
                    top[open_] = np.minimum(top[open_], linear[1])
                state[part] = np.where(bottom > slack, 1, np.where(top < -slack, -1, 0))
        padded = any_pad[0][blocks[:, 0]] | any_pad[1][blocks[:, 1]] | any_pad[2][blocks[:, 2]]
        state[(state == 1) & padded] = 0  # padding points are empty
        state[all_pad[0][blocks[:, 0]] | all_pad[1][blocks[:, 1]] | all_pad[2][blocks[:, 2]]] = -1
        return state

    def slab(self, bx: int) -> Slab:
        """The occupancy of x slab bx, before `carry`."""
        grid = self.grid
        rows = slice(bx * BLOCK, bx * BLOCK + BLOCK + 1)
        xy, xz = grid.fine_plane(0, rows), grid.fine_plane(1, rows)  # (B+1, Py, D), (B+1, Pz, D)
        state = np.zeros((1,) + grid.blocks[1:], np.int8)
        undecided = np.argwhere(state == 0)
        for coarse, side in zip((None,) + SIDES, SIDES):
            if coarse:  # each block's children take its state; the undecided ones are bounded again
                per = coarse // side
                state = np.repeat(np.repeat(np.repeat(state, per, 0), per, 1), per, 2)
                undecided = np.argwhere(state == 0)
            if len(undecided) == 0:
                break
            state[tuple(undecided.T)] = self.states(side, undecided + [bx * (BLOCK // side), 0, 0], xy, xz, rows.start)
        leaves = np.argwhere(state == 0) * LEAF
        if len(leaves) == 0:
            return Slab(bx, None, state)
        values = np.zeros((BLOCK + 1, grid.padded[1], grid.padded[2]), np.float32)
        real = [grid.is_real(0, np.arange(rows.start, rows.stop))] + \
               [grid.is_real(axis, np.arange(grid.padded[axis])) for axis in (1, 2)]
        span = np.arange(LEAF + 1)
        buffer = np.empty((LEAVES_AT_ONCE,) + (LEAF + 1,) * 3 + (self.yz.shape[-1],), np.float32)
        xy_flat = xy.reshape(-1, xy.shape[-1])
        flat_values, nz = values.reshape(-1), values.shape[2]
        plane = values.shape[1] * nz
        for part in np.array_split(leaves, -(-len(leaves) // LEAVES_AT_ONCE)):
            x, y, z = (part[:, axis, None] + span for axis in range(3))  # (k, LEAF + 1) each
            # xy's rows gathered for every z, then the others added: each
            # operation then runs along whole rows, not D values at a time.
            rows_xy = np.broadcast_to((x * xy.shape[1])[:, :, None, None] + y[:, None, :, None], buffer[:len(part)].shape[:-1])
            hidden = np.take(xy_flat, rows_xy, axis=0, out=buffer[:len(part)])  # (k, L+1, L+1, L+1, D)
            hidden += xz[x[:, :, None], z[:, None]][:, :, None]
            hidden += self.yz[y[:, :, None], z[:, None]][:, None]
            occupancy = biased_head_occupancy(self.head, hidden)
            occupancy *= (real[0][x][:, :, None, None] & real[1][y][:, None, :, None] & real[2][z][:, None, None, :])
            flat_values[(x * plane)[:, :, None, None] + (y * nz)[:, None, :, None] + z[:, None, None, :]] = occupancy
        return Slab(bx, values, state)

    def carry(self, slabs):
        """Consecutive slabs share one plane of points: give the later one the
        earlier one's values there, so both sides of a seam see the same
        numbers. slabs: in order, as `slab` made them; yields them."""
        previous = None  # (values of the last plane, where they are valid)
        for slab in slabs:
            if slab.values is None:
                previous = None
                yield slab
                continue
            if previous is not None:
                plane, valid = previous
                slab.values[0][valid] = plane[valid]
            valid = np.zeros(slab.values.shape[1:], bool)
            leaves = slab.leaves()
            for _, y, z in leaves[leaves[:, 0] == BLOCK - LEAF]:
                valid[y:y + LEAF + 1, z:z + LEAF + 1] = True
            previous = (slab.values[-1].copy(), valid)
            yield slab


def band(model, triplane: TriPlane, scale: float, memory_limit: int | None = None):
    """Occupancy on a grid `scale` times finer, evaluated only in leaves that
    the surface may cross (see Band); yields one Slab per x slab."""
    search = Band(model, triplane, scale, memory_limit)
    return search.carry(search.slab(bx) for bx in range(len(search)))


def dense(model, triplane: TriPlane, scale: float = 1.0, memory_limit: int | None = None,
          colour: bool = False):
    """Occupancy on every point of a grid `scale` times finer: (Mx, My, Mz)
    float32. With `colour` (a coloured model), also its colour there:
    (occupancy, (Mx, My, Mz, 3) uint8 sRGB). Refused up front if it needs
    more than memory_limit bytes (None: the memory available)."""
    mx, my, mz = grid_shape(triplane.size, scale)
    check_memory(dense_memory(triplane.size, scale, model.manifest.hidden, colour),
                 f"a dense {mx}x{my}x{mz} occupancy grid (a mesh output streams instead)", memory_limit)
    proj = project(model, triplane)
    grid = FineGrid(proj, scale)
    out = np.empty(grid.shape, np.float32)
    colours = np.empty((*grid.shape, 3), np.uint8) if colour else None
    yz = grid.yz[1:my + 1, 1:mz + 1]
    rows_per_slab = max(1, (1 << 18) // (my * mz * yz.shape[-1]))  # ~1 MB of hidden sums: under numpy's huge pages (colour.DISTANCE_CHUNK's note)
    for x0 in range(0, mx, rows_per_slab):
        rows = slice(x0 + 1, min(x0 + rows_per_slab, mx) + 1)
        xy = grid.fine_plane(0, rows)[:, 1:my + 1]
        xz = grid.fine_plane(1, rows)[:, 1:mz + 1]
        sums = xy[:, :, None] + xz[:, None] + yz[None]
        out[rows.start - 1:rows.stop - 1] = head_occupancy(model.head, sums)
        if colour:
            colours[rows.start - 1:rows.stop - 1] = np.round(head_colour(model.head, sums) * 255)
    return (out, colours) if colour else out
