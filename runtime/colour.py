"""A sample's colour: read from the example by correspondence (format 5), or
from the decoder's colour head (format 4).

The generator makes a sample from the example's own features, so a voxel of
a sample whose features look like those of a voxel of the example's
reconstruction copies that part of the example. Its colour is read there,
from the example's colour tiles (prep/appearance.py, docs/FORMAT.md), at
the example's own detail: no colour is made up, so a sample has no hue its
example lacks, and a brick wall's mortar lines stay as sharp as its
texture's, whatever the voxel grid.

Matching runs coarse to fine, so that neighbouring voxels copy neighbouring
places of the example over regions many voxels wide (a brick course goes
on, a mortar line stays whole). The hidden sums are averaged over blocks of
2^LEVELS voxels a side (exactly: they are sums of three planes, so a block's
mean is the planes' means), and the sample's blocks are matched to the
example's by PatchMatch (Barnes et al. 2009): each block u gets the block
J(u) whose patch (its hidden sums and its six neighbours') is nearest.
Blocks picked by their content (about one in SEED_RATE) search the whole
example; the rest start at random and, in ITERATIONS rounds, take a
neighbour's match shifted by the step between them when it is nearer, or a
random block near their own match. Each finer level halves the blocks: a
child inherits its parent's match, twice as far, plus its place in the
parent (Lefebvre and Hoppe 2005), and in REFINE rounds takes a neighbour's
match continued, or its own moved by one, when that fits clearly better
(at the finest level, voxels compared alone in FINEST_REFINE rounds). A
match continued (inherited, or a neighbour's) is weighed at COHERENT of its
distance, so a piece stays whole unless another place fits better. A point
p then stands for q = J(u) + (p - u), u = round(p), and reads the tile of
q's voxel: within a voxel, the example's texture at full resolution.

The same sample matches the same way everywhere: hidden sums are compared
as integers (each plane in steps of 1/QUANTUM, blocks' means rounded down),
whose squared distances are exact in float64 in any order, and every random
choice is drawn from the specified noise (core/noise.py) keyed by the
block's own content, not its place, so a part of a sample that another
sample shares (a kept box) matches alike there, and so does the same
content moved by a whole number of the coarsest blocks. (The browser's
runtime leaves colour and relief to the server: docs/WEB.md, "One runtime".)
"""

import functools
import itertools
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from sinshape.core import noise
from sinshape.core.budget import check_memory
from sinshape.core.manifest import DEPTH_RANGE, DISTANCE_STEP

from . import generate, query

# The patch of a block: the block and its six neighbours. At the finest
# level (voxels), where a match comes from its parent block and its
# neighbours and only fine-tunes them, a voxel alone (FINEST_PATCH): 7 times
# less to compare, 2.6 to 2.9 times faster matching for 1-2% more distance
# (docs/BENCHMARKS.md, "Coherent pieces").
PATCH = np.array([(0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])
FINEST_PATCH = PATCH[:1]
QUANTUM = 256  # hidden sums are compared in steps of 1/QUANTUM
KEY_VALUES, KEY_QUANTUM = 8, 4  # a block's random choices are keyed by its first 8 hidden sums in steps of 1/4
LEVELS = 3  # matched first on blocks of 2^LEVELS voxels a side, then refined by halves down to voxels
ITERATIONS = 4  # PatchMatch's rounds on the coarsest blocks
REFINE = 2  # rounds at each finer level but the finest
FINEST_REFINE = 1  # rounds at the finest
PROPAGATION = (1,)  # neighbours this many voxels away along each axis offer their match
SEARCH = (8, 4, 2, 1)  # random candidates within this many voxels of the current match
SEED_RATE = 32  # about one block in this many searches the whole example
# A block whose match is still off the band after its level's rounds tries
# every block within this many of it along each axis, nearest first, before
# the whole example: a near piece continued, and at res 128 (229,000 band
# voxels) the whole example's search was a third of a sample's time.
LOST_REACH = 3
# A match continued (a parent's, or a neighbour's shifted by the step: the
# same piece of the example) is weighed at this share of its distance:
# pieces stay whole unless another place fits clearly better (Ashikhmin
# 2001's coherence).
COHERENT = 0.5
MATCH_STREAM = 2  # core/noise's stream id of the matching's random choices (0 and 1 are the generator's)
# A point reads the tiles of each direction of its own voxel and of those
# along the tile's axis, this many voxels away: the surface nearest it wins,
# a tile counted TURN voxels farther for each unit its axis turns from the
# example's normal there (1 - cosine): near the surface the nearest surface
# decides, farther off the normal does, so that the choice does not flicker.
REACH_ORDER = (0, -1, 1)
TURN = 0.25
# A sample's vertex moves by the example's relief at most this many voxels
# (a tile's depths span half a voxel either side of its centre, and the
# surface a model learns lies up to half a voxel out of the example's, the
# training grid holding every voxel the surface passes through), and only on
# a mesh at least RELIEF_SCALE times finer than the voxels: on a coarser one
# its vertices are too far apart to carry detail finer than a voxel.
RELIEF, RELIEF_SCALE = 1.0, 2
# Relief reads the tiles of q's voxel and of those along each tile's axis
# this far, ring by ring, a ring only where the nearer ones have none (the
# surface a model decodes lies up to a voxel and more from its example's:
# two voxels find a tile for 85% of the tower's vertices, one 78%).
RELIEF_REACH = ((0, -1, 1), (-2, 2))
# A direction's tiles give relief in full where they face the example's
# normal there with a cosine of FACING[1] or more, not at all below FACING[0].
FACING = (0.5, 0.7)
# A sample's points are read for relief and colour this many at a time: bounded
# temporaries, which stay in cache (16k points read 1.2 times faster than 64k).
READ_CHUNK = 1 << 14
# Patches are made and compared this many voxels at a time, and a sample's band
# decided in parts of 2^15 voxels: temporaries of a few MB at most. numpy asks
# the kernel for huge pages for every array of 4 MiB or more, and where
# transparent huge pages are given on request (`madvise`) a new one may
# wait while the kernel compacts memory: the tower's example side took 0.05 to
# 0.26 s from one run to the next, its band 0.03 to 0.16 s (docs/BENCHMARKS.md).
DISTANCE_CHUNK = 1 << 12
BAND_CHUNK = 1 << 15
# A voxel on a seam between two pieces weighs its own piece and its
# neighbours' (Level.settle): each face across which a piece, continued,
# would be read off the example's band costs SEAM_OFF times the worst fit
# of the seam's voxels (plus one), and each face between two pieces
# SEAM_CUT of that.
SEAM_OFF, SEAM_CUT = 4, 0.25
# A seam in colour between two pieces wanders up to SEAM_WANDER voxels
# either side of the voxels' face, by noise of a lattice WANDER_CELL voxels
# apart (seam_voxels).
SEAM_WANDER, WANDER_CELL = 0.4, 1.0
SEAM_STREAM = 3  # core/noise's stream id of the seams' wander
ACROSS = np.array([(1, 2), (0, 2), (0, 1)])  # a tile's rows and columns run along these axes, by its axis


@dataclass(frozen=True)
class Tiles:
    """The example's colour as the runtime reads it: directional tiles of its
    surface voxels (prep/appearance.py), and for every voxel near the surface
    the tile of each direction it reads."""

    voxels: np.ndarray  # (N, 3) int64: the voxel of each tile
    directions: np.ndarray  # (N,) int64: 2 * axis + (1 looking from +, else 0)
    mips: list  # RGB [(N, T, T, 3) uint8, (N, T/2, T/2, 3), ..., (N, 1, 1, 3)]; [] for relief alone
    depth: np.ndarray  # (N, T, T) uint8: where the surface is along the tile's axis, 0..255 for -0.5..0.5 voxel
    slopes: np.ndarray  # (N, 2) float64: the surface's mean slope across the tile (depth per voxel along its rows, columns)
    # Per voxel and direction, the tile it reads (`along`) and its own tile (`own`), -1 for none, with a
    # layer of -1 all round, (X + 2, Y + 2, Z + 2, 6) int32: a voxel is looked up by one gather, with no
    # test of whether it is inside (bordered_cells).
    along: np.ndarray
    own: np.ndarray
    distance: np.ndarray  # (X, Y, Z) float32: signed distance to the example's surface at voxel centres, voxels

    @classmethod
    def of(cls, voxels: np.ndarray, directions: np.ndarray, images: np.ndarray, distance: np.ndarray) -> "Tiles":
        """From a model's arrays: images (N, T, T, 4) sRGB and depth, or (N, T, T, 1) depth alone."""
        voxels, directions = voxels.astype(np.int64), directions.astype(np.int64)
        depth = np.ascontiguousarray(images[..., -1])
        size = distance.shape
        own = np.full((*size, 6), -1, np.int32)
        own[voxels[:, 0], voxels[:, 1], voxels[:, 2], directions] = np.arange(len(voxels), dtype=np.int32)
        mips = mip_levels(np.ascontiguousarray(images[..., :3])) if images.shape[-1] == 4 else []
        border = ((1, 1), (1, 1), (1, 1), (0, 0))
        return cls(voxels, directions, mips, depth, slopes(depth), np.pad(reads_along(own), border, constant_values=-1),
                   np.pad(own, border, constant_values=-1), distance.astype(np.float32) * np.float32(DISTANCE_STEP))

    @staticmethod
    def bytes(count: int, side: int, size) -> int:
        """Memory of `count` tiles of `side` read for a finest level of `size`."""
        return count * side * side * 5 + int(np.prod(np.asarray(size) + 2)) * 12 * 4 + int(np.prod(size)) * 4

    def band(self) -> np.ndarray:
        """The voxels (m, 3) where a match may land: every voxel with a tile to read."""
        return np.argwhere((self.along[1:-1, 1:-1, 1:-1] >= 0).any(axis=3))

    def own_along(self, voxels: np.ndarray, directions: np.ndarray, reaches) -> np.ndarray:
        """Each (n, 3) voxel's (inside the grid) own tile of its direction
        (n,), the voxel moved by each of `reaches` along the direction's
        axis: (r, n) int64, -1 for none (moved outside the grid: none). One
        gather a reach: the move is made on the voxel's flat cell, clamped
        to the border along its axis."""
        shape = np.array(self.own.shape[:3])
        cell = bordered_cells(self.own, voxels)
        axis = directions // 2
        at = voxels[np.arange(len(voxels)), axis] + 1
        stride, top = np.array([shape[1] * shape[2], shape[2], 1])[axis], shape[axis] - 1
        flat = self.own.ravel()
        return np.stack([flat[(cell + (np.minimum(np.maximum(at + reach, 0), top) - at) * stride) * 6 + directions]
                         for reach in reaches]).astype(np.int64)

    def read(self, voxels: np.ndarray) -> np.ndarray:
        """The tiles (n, 6) each (n, 3) voxel reads, -1 for none (outside the grid: none)."""
        return self.along.reshape(-1, 6)[bordered_cells(self.along, voxels)].astype(np.int64)


def bordered_cells(table: np.ndarray, voxels: np.ndarray) -> np.ndarray:
    """The flat cell (n,) of each (n, 3) voxel in a table bordered by one
    layer (Tiles.along, Tiles.own): a voxel beyond the border reads the
    border's nearest cell, which holds none."""
    at = np.clip(voxels + 1, 0, np.array(table.shape[:3]) - 1)
    return (at[:, 0] * table.shape[1] + at[:, 1]) * table.shape[2] + at[:, 2]


def reads_along(own: np.ndarray) -> np.ndarray:
    """Per voxel and direction (axis a, side s), the tile of that direction
    of the voxel itself, else of the nearest voxel along a that has one, up
    to two away, the side the tile looks from first (a point above a floor
    reads the floor below it): its in-plane position in that tile is its
    own. (X, Y, Z, 6) int32."""
    size = own.shape[:3]
    along = own.copy()
    for direction in range(6):
        axis, positive = divmod(direction, 2)
        for step in ((-1, 1, -2, 2) if positive else (1, -1, 2, -2)):  # the side it looks from first
            reach = abs(step)
            if reach >= size[axis]:
                continue
            src, dst = [slice(None)] * 3, [slice(None)] * 3
            if step < 0:  # the voxel `reach` below along the axis
                src[axis], dst[axis] = slice(0, -reach), slice(reach, None)
            else:
                src[axis], dst[axis] = slice(reach, None), slice(0, -reach)
            shifted = np.full(size, -1, np.int32)
            shifted[tuple(dst)] = own[(*src, direction)]
            take = (along[..., direction] < 0) & (shifted >= 0)
            along[..., direction][take] = shifted[take]
    return along


def slopes(depth: np.ndarray) -> np.ndarray:
    """The least-squares slope of each tile's depth across it, (N, T, T)
    uint8 -> (N, 2) float64 voxels of depth per voxel along rows and columns:
    sums of integers (exact in any order) over a fixed denominator."""
    side = depth.shape[1]
    centred = 2 * np.arange(side) - (side - 1)  # texel centres, in half texels from the tile's middle
    # slope = sum(x (h - mean)) / sum(x^2), x = centred / (2 side) voxels, h = value * DEPTH_RANGE / 127.5 - DEPTH_RANGE
    scale = 127.5 * float(np.sum(centred * centred)) / (2 * DEPTH_RANGE)
    values = depth.astype(np.int64)
    rows = np.einsum("ntc,t->n", values, centred)
    columns = np.einsum("ntc,c->n", values, centred)
    return np.stack([rows, columns], axis=1) / scale


def mip_levels(images: np.ndarray) -> list:
    """Box-filtered halvings of (N, T, T, 3) uint8 tiles down to 1 x 1, each
    texel the rounded mean of four (integers: the same in every runtime)."""
    levels = [images]
    while levels[-1].shape[1] > 1:
        t = levels[-1].astype(np.uint16)
        total = t[:, 0::2, 0::2] + t[:, 1::2, 0::2] + t[:, 0::2, 1::2] + t[:, 1::2, 1::2]
        levels.append(((total + 2) // 4).astype(np.uint8))
    return levels


def grid_hidden(model, planes: list, size):
    """Hidden pre-activations (b1 added) at the grid points of scale 1 of
    projected planes (query.project) spanning `size`, as a function of
    (n, 3) int voxels -> (n, D) float32, clamped to the grid: the three
    plane cells summed in float32, ((xy + xz) + yz) + b1."""
    xy, xz, yz = planes
    top = np.array(size) - 1
    bias = model.head.bias1

    def at(voxels: np.ndarray) -> np.ndarray:
        i, j, k = np.clip(voxels, 0, top).T
        return xy[i, j] + xz[i, k] + yz[j, k] + bias
    return at


def inside(model, hidden: np.ndarray) -> np.ndarray:
    """Where hidden sums (n, D) (b1 added) are inside the shape: the head's
    logit sum_c relu(h_c) w2_c + b2 > 0, summed in float32 in the order of
    c (no matrix product, whose rounding depends on the machine), so that
    every runtime draws the same band."""
    logit = np.full(len(hidden), np.float32(model.head.bias2), np.float32)
    active = np.maximum(hidden, 0)
    for c, weight in enumerate(model.head.weight2):
        logit += active[:, c] * weight
    return logit > 0


def surface_band(model, hidden_at, size) -> np.ndarray:
    """The voxels (n, 3) of a grid of scale 1 within one voxel of a change
    between inside and outside along an axis (beyond the grid is outside):
    where a mesh's vertices round to."""
    size = tuple(int(n) for n in size)
    solid = np.empty(size, bool)
    rows = max(1, BAND_CHUNK // (size[1] * size[2]))
    j, k = np.meshgrid(np.arange(size[1]), np.arange(size[2]), indexing="ij")
    for x0 in range(0, size[0], rows):
        x = np.arange(x0, min(x0 + rows, size[0]))
        voxels = np.stack(np.broadcast_arrays(x[:, None, None], j[None], k[None]), axis=-1).reshape(-1, 3)
        solid[x0:x0 + len(x)] = inside(model, hidden_at(voxels)).reshape(len(x), *size[1:])
    solid = np.pad(solid, 1)  # outside the grid is empty: a mesh closes there
    change = np.zeros(solid.shape, bool)
    for axis in range(3):
        a, b = [slice(None)] * 3, [slice(None)] * 3
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        differs = solid[tuple(a)] != solid[tuple(b)]
        change[tuple(a)] |= differs
        change[tuple(b)] |= differs
    change = change[1:-1, 1:-1, 1:-1]
    band = change.copy()
    for axis in range(3):  # grown by one voxel along each axis
        a, b = [slice(None)] * 3, [slice(None)] * 3
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        band[tuple(a)] |= change[tuple(b)]
        band[tuple(b)] |= change[tuple(a)]
    return np.argwhere(band)


class Pyramid:
    """Hidden sums (b1 added) of projected planes spanning `size` as
    integers, at voxels (level 0) and at blocks of 2^level voxels a side:
    each plane rounded to steps of 1/QUANTUM (halves to even), a block's
    value the floor of its mean. A block's mean of the sum of three planes
    is the sum of their means over its faces, so each plane is pooled alone;
    blocks past the grid's end repeat its last voxels. Values are integers
    below 2^24, held in float32."""

    def __init__(self, planes: list, bias: np.ndarray, size):
        self.size = np.array(size, np.int64)
        self.planes = [np.rint(plane * np.float32(QUANTUM)).astype(np.int64) for plane in planes]
        self.bias = np.rint(bias * np.float32(QUANTUM)).astype(np.int64)
        self.pooled = {}

    def at(self, level: int):
        """The hidden sums of level `level`'s blocks, (n, 3) int -> (n, D)
        float32, clamped to that level's grid."""
        if level not in self.pooled:
            side = 1 << level
            blocks = -(-self.size // side)
            pooled = []
            for plane, (a, b) in zip(self.planes, ((0, 1), (0, 2), (1, 2))):
                rows = np.minimum(np.arange(blocks[a] * side), self.size[a] - 1)
                columns = np.minimum(np.arange(blocks[b] * side), self.size[b] - 1)
                cells = plane[rows][:, columns]
                pooled.append(cells.reshape(blocks[a], side, blocks[b], side, -1).sum(axis=(1, 3)))
            self.pooled[level] = (pooled, blocks)
        (xy, xz, yz), blocks = self.pooled[level]
        area = 1 << (2 * level)
        bias = self.bias * area

        def hidden(voxels: np.ndarray) -> np.ndarray:
            i, j, k = np.clip(voxels, 0, blocks - 1).T
            return ((xy[i, j] + xz[i, k] + yz[j, k] + bias) // area).astype(np.float32)
        return hidden


def pyramid(model, planes: list, size) -> Pyramid:
    """A sample's (or the reconstruction's) Pyramid."""
    return Pyramid(planes, model.head.bias1, size)


def patches(hidden_at, voxels: np.ndarray, offsets: np.ndarray = PATCH) -> np.ndarray:
    """The patch of each voxel, (n, 3) -> (n, len(offsets) * D) float32: its
    integer hidden sums and those of the voxels `offsets` away (|values| <
    2^24), so squared distances are integers below 2^53, exact in float64
    in any order of summation (a matrix product included). DISTANCE_CHUNK
    voxels at a time: bounded temporaries."""
    parts = [voxels[start:start + DISTANCE_CHUNK] for start in range(0, max(len(voxels), 1), DISTANCE_CHUNK)]
    return np.concatenate([np.concatenate([hidden_at(part + offset) for offset in offsets], axis=1) for part in parts])


def content_keys(hidden: np.ndarray) -> np.ndarray:
    """A key per block from its own integer hidden sums (n, D): the random
    choices made for a block follow what is there, not where. Its first
    KEY_VALUES sums in steps of 1/KEY_QUANTUM (rounded down): two runtimes
    whose floats differ in the last bits give a block the same key but where
    a value lies within that difference of a step's edge. uint64."""
    key = np.full(len(hidden), noise.stream_key(0, MATCH_STREAM), np.uint64)
    values = np.floor_divide(hidden[:, :KEY_VALUES].astype(np.int64), QUANTUM // KEY_QUANTUM)
    with np.errstate(over="ignore"):
        for value in values.T:
            key = noise.mix64(key + np.uint64(noise.GOLDEN) * (value.astype(np.uint64) + np.uint64(1)))
    return key


def draw(keys: np.ndarray, slot: int) -> np.ndarray:
    """The random bits of draw `slot` for each block's key: SplitMix64's
    output number key + 1 from state `slot` (core/noise.bits). uint64."""
    return noise.bits(slot, keys)


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise squared distances of patches (n, K) of integers held in
    float32: the differences are exact in float32, their squares and sums
    exact in float64."""
    diff = a - b
    return np.einsum("nk,nk->n", diff, diff, dtype=np.float64)


def axis_steps(length: int) -> list:
    """The six steps of `length` along the axes, in the order +x, -x, +y, -y, +z, -z."""
    out = []
    for axis in range(3):
        for sign in (1, -1):
            step = np.zeros(3, np.int64)
            step[axis] = sign * length
            out.append(step)
    return out


# The steps to every block within LOST_REACH along each axis, nearest first (then in C order).
AROUND = sorted((np.array(step) for step in itertools.product(range(-LOST_REACH, LOST_REACH + 1), repeat=3) if any(step)),
                key=lambda step: int(step @ step))


def improve(level: "Level", sample: np.ndarray, current: np.ndarray, best: np.ndarray, candidates: list) -> None:
    """Each voxel's match replaced by the first candidate strictly nearer
    than its best, in the candidates' order: (voxels (n, 3), whether offered
    (n,) bool, coherent). A coherent candidate (a match continued) is
    weighed at COHERENT of its distance. `current`, `best` change in place."""
    for candidate, offered, coherent in candidates:
        new = np.flatnonzero(offered & np.any(candidate != current, axis=1))  # the current one is known
        d = level.distance(sample, candidate[new], new)
        if coherent:
            d = d * COHERENT
        won = d < best[new]
        current[new[won]], best[new[won]] = candidate[new[won]], d[won]


class Level:
    """One level of the example's side of matching: the blocks a match may
    land in (those holding a voxel with tiles to read), the reconstruction's
    patch at each (of `offsets`), and the refinement's rounds there."""

    def __init__(self, band: np.ndarray, reference_at, size, offsets: np.ndarray = PATCH, rounds: int = REFINE):
        self.band = band  # (B, 3), in C order
        self.offsets, self.rounds = offsets, rounds
        # Each block's band row, -1 off it, with a layer of -1 all round: one gather a lookup (bordered_cells).
        self.row = np.full(tuple(np.asarray(size) + 2), -1, np.int64)
        self.row[tuple(self.band.T + 1)] = np.arange(len(self.band))
        self.reference = patches(reference_at, self.band, offsets)  # (B, K)
        self.norms = np.einsum("mk,mk->m", self.reference, self.reference, dtype=np.float64)  # exact, as below

    def rows(self, voxels: np.ndarray) -> np.ndarray:
        """The band row of each (n, 3) example block, -1 outside the band."""
        return self.row.ravel()[bordered_cells(self.row, voxels)]

    def distance(self, sample: np.ndarray, candidates: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
        """Patch distances of sample patches (rows `which` of `sample`, all of
        them by default) to candidate example blocks (n, 3); infinite where a
        candidate is outside the band. DISTANCE_CHUNK rows at a time."""
        row = self.rows(candidates)
        d = np.empty(len(row))
        for start in range(0, len(row), DISTANCE_CHUNK):
            part = slice(start, start + DISTANCE_CHUNK)
            own = sample[part] if which is None else sample[which[part]]
            d[part] = squared_distances(own, self.reference[np.maximum(row[part], 0)])
        d[row < 0] = np.inf
        return d

    def nearest(self, sample: np.ndarray, chunk: int = 256) -> np.ndarray:
        """The nearest band block of each patch (n, K) of all: (n, 3), the
        first of equals. |s - r|^2 - |s|^2 = |r|^2 - 2 s.r, exact integers."""
        out = np.empty(len(sample), np.int64)
        reference = self.reference.astype(np.float64)
        for start in range(0, len(sample), chunk):
            block = sample[start:start + chunk].astype(np.float64)
            out[start:start + chunk] = np.argmin(self.norms[None, :] - 2 * (block @ reference.T), axis=1)
        return self.band[out]

    def search(self, sample_at, blocks: np.ndarray) -> np.ndarray:
        """PatchMatch: the example block J(u) of each block u (n, 3) of a
        sample, whose hidden sums `sample_at` gives: (n, 3) int64."""
        sample = patches(sample_at, blocks, self.offsets)
        keys = content_keys(sample_at(blocks))
        band, count = self.band, len(self.band)
        lookup = voxel_lookup(blocks)
        current = band[(draw(keys, 0) % np.uint64(count)).astype(np.int64)]
        seeds = np.flatnonzero(draw(keys, 1) % np.uint64(SEED_RATE) == 0)
        if len(seeds):
            current[seeds] = self.nearest(sample[seeds])
        best = self.distance(sample, current)
        changed = np.ones(len(blocks), bool)  # whose match changed last round: only their offers are new
        everyone = np.ones(len(blocks), bool)
        slot = 2
        for _ in range(ITERATIONS):
            previous = current.copy()
            candidates = []
            for length in PROPAGATION:
                for shift in axis_steps(length):
                    neighbour = lookup(blocks - shift)
                    candidates.append((previous[np.maximum(neighbour, 0)] + shift,
                                       (neighbour >= 0) & changed[np.maximum(neighbour, 0)], True))
            for radius in SEARCH:
                bits = draw(keys, slot)
                slot += 1
                offsets = np.stack([((bits >> np.uint64(16 * a)) & np.uint64(0xFFFF)).astype(np.int64)
                                    % (2 * radius + 1) for a in range(3)], axis=1) - radius
                candidates.append((previous + offsets, everyone, False))
            candidates.append((band[(draw(keys, slot) % np.uint64(count)).astype(np.int64)], everyone, False))
            slot += 1
            improve(self, sample, current, best, candidates)
            changed = np.any(current != previous, axis=1)
        return current

    def refine(self, sample_at, blocks: np.ndarray, inherited: np.ndarray) -> np.ndarray:
        """Each block u (n, 3) of a sample starting from its `inherited`
        match (a match continued), in the level's rounds offered each
        neighbour's match continued, then its own moved by one block along
        each axis. One whose match is off the band after them searches the
        whole example. (n, 3) int64."""
        sample = patches(sample_at, blocks, self.offsets)
        lookup = voxel_lookup(blocks)
        current = inherited.copy()
        best = self.distance(sample, current) * COHERENT
        everyone = np.ones(len(blocks), bool)
        for _ in range(self.rounds):
            previous = current.copy()
            candidates = []
            for shift in axis_steps(1):
                neighbour = lookup(blocks - shift)
                candidates.append((previous[np.maximum(neighbour, 0)] + shift, neighbour >= 0, True))
            candidates += [(previous + step, everyone, False) for step in axis_steps(1)]
            improve(self, sample, current, best, candidates)
        lost = np.flatnonzero(~np.isfinite(best))  # off the band still: the blocks around it searched
        if len(lost):
            near, near_best, start = current[lost], best[lost], current[lost].copy()
            offered = np.ones(len(lost), bool)
            improve(self, sample[lost], near, near_best, [(start + step, offered, False) for step in AROUND])
            current[lost] = near
            far = lost[~np.isfinite(near_best)]  # none of them on the band: the whole example
            if len(far):
                current[far] = self.nearest(sample[far])
        return current

    def settle(self, sample_at, voxels: np.ndarray, matched: np.ndarray) -> np.ndarray:
        """The sample's voxels u (n, 3) on seams between pieces settled where
        both pieces go on: a piece copied up to the edge of the example's
        band and continued across a seam is read beyond it, in tiles of
        other places (on a brick ruin, grey squares its example does not
        show). Each voxel on a seam takes, of its own piece and its
        neighbours' continued, the one of least fit plus the cost of its
        faces (SEAM_OFF, SEAM_CUT): off the band at the voxel (the
        neighbour's piece there) or at the neighbour (this one's there),
        and between two pieces at all, so that a seam moves as a whole and
        pieces stay whole. Of equals, its own first. A voxel of exact fit
        (as every one of the reconstruction's own is) keeps its match.
        Voxels of one parity at a time, so that no two neighbours move at
        once (one sweep of iterated conditional modes); exact integers, as
        the fit is. (n, 3) int64."""
        matched = matched.copy()
        lookup = voxel_lookup(voxels)
        steps = np.array(axis_steps(1))
        around = np.stack([lookup(voxels + step) for step in steps], axis=1)  # (n, 6)
        sample = patches(sample_at, voxels, self.offsets)
        parity = voxels.sum(axis=1) % 2
        for side in (0, 1):
            offset = matched - voxels
            rows = np.flatnonzero(parity == side)
            theirs = offset[np.maximum(around[rows], 0)]  # (m, 6, 3): each neighbour's piece
            exists = around[rows] >= 0
            differs = exists & np.any(theirs != offset[rows][:, None], axis=2)
            on_seam = np.flatnonzero(differs.any(axis=1))
            rows, theirs, exists, differs = rows[on_seam], theirs[on_seam], exists[on_seam], differs[on_seam]
            if not len(rows):
                continue
            here, own = voxels[rows], offset[rows]
            # Each neighbour's piece, continued into this voxel, and at the neighbour itself: off the band?
            theirs_here = (self.rows((here[:, None] + theirs).reshape(-1, 3)) < 0).reshape(-1, 6)
            theirs_there = (self.rows((here[:, None] + steps + theirs).reshape(-1, 3)) < 0).reshape(-1, 6)
            fit = self.distance(sample, here + own, rows)
            off = SEAM_OFF * fit[np.isfinite(fit)].max(initial=0) + 1
            cut_cost = SEAM_CUT * off

            def faces(at: np.ndarray, piece: np.ndarray) -> np.ndarray:
                """The cost of the faces of rows `at` (of rows) copying `piece` (k, 3)."""
                total = np.zeros(len(at))
                mine_here = self.rows(here[at] + piece) < 0
                for k in range(6):
                    cut = exists[at, k] & np.any(theirs[at, k] != piece, axis=1)
                    mine_there = self.rows(here[at] + steps[k] + piece) < 0
                    faces = cut * (cut_cost + off * ((mine_here | theirs_here[at, k]).astype(np.float64)
                                                     + (mine_there | theirs_there[at, k])))
                    total += faces
                return total

            # Multiples of a quarter below 2^53: sums exact in any order.
            best, choice = fit + faces(np.arange(len(rows)), own), own.copy()
            exact = fit == 0
            for k in range(6):
                # Each piece once: a neighbour's that differs from the voxel's own and from those before it.
                new = differs[:, k] & ~exact
                for j in range(k):
                    new &= ~(differs[:, j] & np.all(theirs[:, k] == theirs[:, j], axis=1))
                at = np.flatnonzero(new)
                e = self.distance(sample, here[at] + theirs[at, k], rows[at]) + faces(at, theirs[at, k])
                won = e < best[at]
                best[at[won]], choice[at[won]] = e[won], theirs[at[won], k]
            matched[rows] = here + choice
        return matched


class Matcher:
    """The example's side of matching, at every level: level l's blocks are
    2^l voxels a side, and its band the blocks that hold a voxel with tiles
    to read (a match lands where there is colour to read)."""

    learnt: np.ndarray | None = None  # learnt_distance's grid, set by `matcher`

    def __init__(self, tiles: Tiles, reference: Pyramid):
        # Seams are settled where colour is read: read off the band, a piece shows other places' colours
        # (a brick ruin's patch distance 1.45 -> 0.86); relief alone is blended across them, and the
        # tower's matching would take 0.1 s more.
        self.settles = bool(tiles.mips)
        band = tiles.band()
        self.levels = [Level(band, reference.at(0), reference.size, FINEST_PATCH, FINEST_REFINE)]
        for level in range(1, LEVELS + 1):
            blocks = unique_voxels(band >> level)
            self.levels.append(Level(blocks, reference.at(level), -(-reference.size // (1 << level))))

    def match(self, sample: Pyramid, voxels: np.ndarray) -> np.ndarray:
        """The example voxel J(u) of each voxel u (n, 3) of a sample's grid,
        coarse to fine, its seams then settled where the example is
        coloured (Level.settle): (n, 3) int64."""
        check_memory(len(voxels) * self.levels[0].reference.shape[1] * 16 + len(self.levels[0].band) * 8 * 64,
                     f"matching {len(voxels)} voxels to the example")
        if not len(voxels):
            return np.zeros((0, 3), np.int64)
        blocks = unique_voxels(voxels >> LEVELS)
        matched = self.levels[LEVELS].search(sample.at(LEVELS), blocks)
        for level in range(LEVELS - 1, -1, -1):
            finer = unique_voxels(voxels >> level) if level else voxels
            parents = finer >> 1
            inherited = 2 * matched[voxel_lookup(blocks)(parents)] + (finer - 2 * parents)
            matched = self.levels[level].refine(sample.at(level), finer, inherited)
            blocks = finer
        return self.levels[0].settle(sample.at(0), voxels, matched) if self.settles else matched


def unique_voxels(voxels: np.ndarray) -> np.ndarray:
    """np.unique(voxels, axis=0) of (n, 3) non-negative voxels, in the same
    (C) order, by one integer per voxel: several times faster than
    comparing rows."""
    if not len(voxels):
        return voxels.reshape(0, 3)
    size = voxels.max(axis=0) + 1
    return np.stack(np.unravel_index(np.unique(np.ravel_multi_index(voxels.T, size)), size), axis=1)


def voxel_lookup(voxels: np.ndarray):
    """A function from (n, 3) voxels to their row in `voxels`, -1 where absent:
    one gather from a table with a border of -1 all round (a voxel beyond
    it reads the border's nearest cell)."""
    low = (voxels.min(axis=0) if len(voxels) else np.zeros(3, np.int64)) - 1
    size = (voxels.max(axis=0) - low + 2) if len(voxels) else np.full(3, 3, np.int64)
    table = np.full(tuple(size), -1, np.int64)
    table[tuple((voxels - low).T)] = np.arange(len(voxels))
    flat, top = table.ravel(), size - 1

    def lookup(query_voxels: np.ndarray) -> np.ndarray:
        at = np.clip(query_voxels - low, 0, top)
        return flat[(at[:, 0] * size[1] + at[:, 1]) * size[2] + at[:, 2]]
    return lookup


def piece_sizes(voxels: np.ndarray, matched: np.ndarray) -> np.ndarray:
    """For each voxel (n, 3) of a sample, the size of its piece: the voxels
    joined to it through neighbours (along an axis) that copy neighbouring
    places of the example, J(u + e) = J(u) + e. A patchwork shows as small
    pieces, a coherent copy as large ones. (n,) int64."""
    lookup = voxel_lookup(voxels)
    pairs = []
    for step in axis_steps(1)[::2]:
        neighbour = lookup(voxels + step)
        has = np.flatnonzero(neighbour >= 0)
        same = np.all(matched[neighbour[has]] == matched[has] + step, axis=1)
        pairs.append(np.stack([has[same], neighbour[has[same]]], axis=1))
    a, b = np.concatenate(pairs).T if pairs else (np.zeros(0, np.int64),) * 2
    label = np.arange(len(voxels))
    while True:  # each piece labelled by its least voxel: spread the least label along pairs, then jump
        low = np.minimum(label[a], label[b])
        before = label.copy()
        np.minimum.at(label, a, low)
        np.minimum.at(label, b, low)
        label = label[label]
        if np.array_equal(label, before):
            return np.bincount(label, minlength=len(voxels))[label]


def matcher(model) -> Matcher:
    """The model's matcher, made once: the reconstruction's patches at every
    level of the example's band, and the surface it decodes (learnt_distance)."""
    if model.matcher is None:
        recon = generate.sample(model, None)
        model.matcher = Matcher(model.example_tiles, pyramid(model, query.project(model, recon).planes, recon.size))
        model.matcher.learnt = learnt_distance(model, recon)
    return model.matcher


LEARNT_REACH = 3.0  # voxels: learnt_distance's values are clamped to this either side


def learnt_distance(model, recon) -> np.ndarray:
    """The signed distance (voxels, positive outside) at each voxel to the
    surface the model decodes for its example (the reconstruction `recon`):
    its logit over the logit's gradient, to first order, clamped to
    LEARNT_REACH. Relief is the example's surface measured from this one:
    the training grid's surface (the tiles' distance grid) lies up to a
    voxel out of what the decoder learnt (its targets were blurred), and
    the decoder's own surface is what every sample's mesh is cut from, so
    the reconstruction moves onto its example's surface (measured: a median
    0.08 voxel off it on the tower, against 0.24 measured from the training grid's).
    (X, Y, Z) float32."""
    # Beyond the grid is empty, as a mesh closes there: padded, so that a
    # surface between the last voxels and the grid's end is found too.
    occupancy = np.clip(np.pad(query.dense(model, recon, 1.0).astype(np.float64), 1), 1e-6, 1 - 1e-6)
    logit = np.log(occupancy) - np.log1p(-occupancy)
    slope = np.linalg.norm(np.stack(np.gradient(logit), axis=-1), axis=-1)
    distance = np.clip(-logit / np.maximum(slope, 1e-3), -LEARNT_REACH, LEARNT_REACH)
    return distance[1:-1, 1:-1, 1:-1].astype(np.float32)


# A voxel outside the band takes the match of the first voxel beside it that
# has one, in this order, shifted by the step: the band's matches carried
# outwards (and inwards) one voxel a round.
STEPS = np.array([(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)])
# A kept box (edit.compose) is the part's own sample deeper than edit.MARGIN
# voxels inside it; its matches are the part's own deeper than this.
KEPT_MARGIN = 5


class Correspondence:
    """J of one sample: its surface band matched to the example as a whole,
    and the rest of its grid, when asked for, from the band outwards. A
    composed sample's `kept` parts ((low, high, their projected planes),
    TriPlane.kept) give its band deep in each box their own matches, so a
    kept box keeps its colour whatever the matches around it (a later part
    wins where boxes overlap)."""

    def __init__(self, model, planes: list, size, kept=()):
        self.size = np.array(size)
        example = matcher(model)
        self.band = surface_band(model, grid_hidden(model, planes, size), size)
        self.matched = example.match(pyramid(model, planes, size), self.band)
        self.lookup = voxel_lookup(self.band)
        self.field, self.spreading = None, threading.Lock()
        for low, high, part_planes in kept:
            low, high = np.asarray(low), np.asarray(high)
            # Deeper than the join inside the box (a box reaching the grid's edge has no join there).
            deep = np.all(((self.band >= low + KEPT_MARGIN) | (low <= 0))
                          & ((self.band <= high - KEPT_MARGIN) | (high >= self.size - 1)), axis=1)
            own = Correspondence(model, part_planes, size)
            row = own.lookup(self.band[deep])
            index = np.flatnonzero(deep)[row >= 0]
            self.matched[index] = own.matched[row[row >= 0]]

    def __call__(self, voxels: np.ndarray) -> np.ndarray:
        """The example voxel of each (n, 3) voxel of the sample's grid."""
        voxels = np.clip(voxels, 0, self.size - 1)
        row = self.lookup(voxels)
        if np.all(row >= 0):
            return self.matched[row]
        with self.spreading:  # SampleSurface reads on several threads: spread once
            if self.field is None:
                self.field = self.spread()
        return self.field[tuple(voxels.T)]

    def spread(self) -> np.ndarray:
        """J on every voxel of the grid: (X, Y, Z, 3) int64 (the band's own,
        or carried from it; all zeros if the sample has no surface)."""
        check_memory(int(np.prod(self.size)) * 8 * 8, f"matching a {'x'.join(map(str, self.size))} grid")
        field = np.zeros((*self.size, 3), np.int64)
        known = np.zeros(tuple(self.size), bool)
        field[tuple(self.band.T)] = self.matched
        known[tuple(self.band.T)] = True
        while len(self.band) and not known.all():
            before = known.copy()
            for step in STEPS:
                axis = int(np.flatnonzero(step)[0])
                src, dst = [slice(None)] * 3, [slice(None)] * 3
                if step[axis] < 0:  # take from the voxel before along the axis
                    src[axis], dst[axis] = slice(0, -1), slice(1, None)
                else:
                    src[axis], dst[axis] = slice(1, None), slice(0, -1)
                take = ~known[tuple(dst)] & before[tuple(src)]
                field[tuple(dst)][take] = field[tuple(src)][take] - step
                known[tuple(dst)] |= take
        return field


def example_palette(tiles: Tiles) -> np.ndarray:
    """The example's colours as a distant view shows them: each tile's mean
    (its 1x1 mip), once each, (P, 3) uint8 in increasing order of
    0xRRGGBB (so that the first of equally near ones is one colour everywhere)."""
    means = tiles.mips[-1].reshape(-1, 3).astype(np.int64)
    packed = np.unique(means[:, 0] << 16 | means[:, 1] << 8 | means[:, 2])
    return np.stack([packed >> 16, packed >> 8 & 255, packed & 255], axis=1).astype(np.uint8)


def nearest_in_palette(colours: np.ndarray, palette: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Each (n, 3) uint8 colour replaced by the palette's nearest (squared
    distance over the bytes, exact integers; the first of equals): a colour
    made by the colour head becomes one the example has."""
    wanted, inverse = np.unique(colours, axis=0, return_inverse=True)
    reference = palette.astype(np.float64)
    norms = (reference * reference).sum(axis=1)
    nearest = np.empty(len(wanted), np.int64)
    for start in range(0, len(wanted), chunk):  # |c - p|^2 - |c|^2 = |p|^2 - 2 c.p: integers, exact in float64
        block = wanted[start:start + chunk].astype(np.float64)
        nearest[start:start + chunk] = np.argmin(norms[None, :] - 2 * (block @ reference.T), axis=1)
    return palette[nearest[inverse.ravel()]]


def own_voxels(points: np.ndarray, grid) -> np.ndarray:
    """The voxel (n, 3) int64 each point (n, 3) lies in, round(p), halves up as
    in every runtime (numpy's rint rounds them to even); a point beyond the
    grid's last voxel (a mesh closes half a voxel outside) belongs to it."""
    return np.clip(np.floor(points + 0.5).astype(np.int64), 0, np.asarray(grid) - 1)


def example_points(tiles: Tiles, points: np.ndarray, voxels: np.ndarray, matches: np.ndarray) -> tuple:
    """Where points (n, 3) (sample model units) of a sample stand in the
    example, each read by a sample voxel (`voxels` (n, 3): its own, or a
    neighbour's across a seam, seam_voxels) whose match is `matches` (n, 3),
    and what its smooth surface is there. Point p read by voxel u stands for
    q = J(u) + (p - u), near the example's surface but rarely on it.
    Returns q (n, 3), the signed distance grid's value there (n,) (voxels,
    positive outside), the smooth surface's outward unit normal (n, 3) (the
    grid's gradient) and q's voxel (n, 3) int64."""
    q = matches + (points - voxels)
    smooth, normal = trilinear(tiles.distance, q)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    voxel = np.clip(np.floor(q + 0.5).astype(np.int64), 0, np.array(tiles.distance.shape) - 1)
    return q, smooth, normal, voxel


def tiles_found(tiles: Tiles, q: np.ndarray, voxel: np.ndarray, direction: np.ndarray, reaches, read=None) -> tuple:
    """For each of `reaches`, the tile of each point's (n,) direction at its
    voxel moved that far along the direction's axis (tile (r, n) int64, -1
    for none), and, for the tiles found alone (most voxels along a tile's
    axis have none; `found`, their flat indices into tile, in order), that
    tile's surface under q (n, 3) as a plane of its slope through its depth
    there (`read`'s, bilinear_depth unless given): q's distance outside it
    along its normal, scaled by 1 / lean (f,); where q lies on the tile's
    plane (f, 2); the slope (f, 2); lean = 1 + |slope|^2 (f,). (Along the
    plane's normal, so that tiles of two axes agree where they overlap.)"""
    candidate = tiles.own_along(voxel, direction, reaches)
    found = np.flatnonzero(candidate >= 0)
    point = found % len(q)
    tile, axis = candidate.ravel()[found], direction[point] // 2
    local = q[point] - tiles.voxels[tile]
    on_plane = np.take_along_axis(local, ACROSS[axis], axis=1)
    tilt = tiles.slopes[tile]
    tilted = 1 + np.einsum("nc,nc->n", tilt, tilt)
    above = (local[np.arange(len(found)), axis] - (read or bilinear_depth)(tiles.depth, tile, on_plane)) / tilted
    return candidate, found, above, on_plane, tilt, tilted


def surface_under(tiles: Tiles, matched, points: np.ndarray, grid) -> tuple:
    """The example's surface under points (n, 3) (sample model units) of a
    sample whose voxels `matched` maps to example voxels (example_points):
    of the tiles of q's voxel and of those beside it along each tile's axis,
    the one whose surface is nearest q (REACH_ORDER, TURN), and where on
    its plane that surface's point nearest q lies: ((n,) int64, (n, 2))."""
    q, _, normal, voxel = example_points(tiles, points, *seam_voxels(matched, points, grid))
    best = np.full(len(points), np.inf)
    tile = np.zeros(len(points), np.int64)
    across = np.zeros((len(points), 2))
    rows = np.arange(len(q))
    for direction in range(6):
        axis, positive = divmod(direction, 2)
        candidate, found, above, plane, slope, lean = tiles_found(tiles, q, voxel, np.full(len(q), direction),
                                                                  REACH_ORDER)
        facing = normal[:, axis] * (1 if positive else -1)
        score = np.full(candidate.shape, np.inf)
        score.ravel()[found] = np.abs(above) * np.sqrt(lean) + TURN * (1 - facing[found % len(q)])
        first = np.argmin(score, axis=0)  # the nearest of the direction's reaches; of equals, the first
        score, pick = score[first, rows], first * len(q) + rows
        better = np.flatnonzero(score < best)
        best[better], tile[better] = score[better], candidate.ravel()[pick[better]]
        at = np.searchsorted(found, pick[better])  # each better point's tile among those found (found is sorted)
        across[better] = plane[at] + above[at][:, None] * slope[at]
    return tile, across


def pieces_beside(matched, points: np.ndarray, grid) -> tuple:
    """Each point's (n, 3) own voxel (n, 3) and its match (n, 3), and per
    axis, of the points whose neighbour along it (the voxel across the face
    the point leans to) copies another piece, (rows (k,), that neighbour
    (k, 3), its match (k, 3)): the seams a point's colour and relief read
    across."""
    size = np.asarray(grid) - 1
    own = own_voxels(points, grid)
    match = matched(own)
    offset = match - own
    across = []
    for axis in range(3):
        beside = own.copy()
        beside[:, axis] += np.where(points[:, axis] >= own[:, axis], 1, -1)
        beside = np.clip(beside, 0, size)
        theirs = matched(beside)
        rows = np.flatnonzero((beside[:, axis] != own[:, axis]) & np.any(theirs - beside != offset, axis=1))
        across.append((rows, beside[rows], theirs[rows]))
    return own, match, across


def seam_voxels(matched, points: np.ndarray, grid) -> tuple:
    """The sample voxel whose match each point (n, 3) reads: its own, or,
    across a face between two pieces, the neighbour's where the seam
    between them, wandering up to SEAM_WANDER voxels either side of the
    face, lies on the point's side: a seam is a curve, not the voxels'
    straight edge. How far it wanders is smooth noise (wander) of the place
    in the example that the lower voxel's piece copies there, so both sides
    of a face find the same seam, and a kept box, or the same content
    moved, the same seams. A point past two faces' seams takes the one it
    lies farther past. The voxels (n, 3) and their matches (n, 3), int64."""
    own, match, across = pieces_beside(matched, points, grid)
    chosen, chosen_match, past = own.copy(), match.copy(), np.full(len(points), -1.0)
    for axis, (rows, beside, theirs) in enumerate(across):
        upper = beside[:, axis] > own[rows, axis]
        low = np.where(upper[:, None], own[rows], beside)
        face = points[rows].copy()
        face[:, axis] = low[:, axis] + 0.5
        seam = SEAM_WANDER * wander(np.where(upper[:, None], match[rows], theirs) + (face - low), axis)
        beyond = (points[rows, axis] - face[:, axis] - seam) * np.where(upper, 1, -1)  # past the seam, towards beside
        farther = (beyond >= 0) & (beyond > past[rows])
        take = rows[farther]
        chosen[take], chosen_match[take], past[take] = beside[farther], theirs[farther], beyond[farther]
    return chosen, chosen_match


def wander(places: np.ndarray, axis: int) -> np.ndarray:
    """Smooth noise in (-1, 1) over faces across `axis` of the example, at
    places (n, 3) (voxels) on them: values drawn at the corners of a
    lattice WANDER_CELL voxels apart across the face's plane (SplitMix64 of
    the corner and the plane, core/noise), blended by smoothstep. (n,)."""
    plane = np.floor(places[:, axis] + 2).astype(np.uint64) << np.uint64(42)  # places lie half a voxel out at most
    x = (places[:, ACROSS[axis]] + 2) / WANDER_CELL
    corner = np.floor(x).astype(np.int64)
    f = x - corner
    f = f * f * (3 - 2 * f)
    weights = (1 - f, f)
    key = noise.stream_key(0, SEAM_STREAM, axis)
    total = np.zeros(len(places))
    for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)):
        cell = plane | ((corner[:, 0] + i).astype(np.uint64) << np.uint64(21)) | (corner[:, 1] + j).astype(np.uint64)
        value = (noise.bits(key, cell) >> np.uint64(11)).astype(np.float64) * 2.0 ** -52 - 1
        total += value * weights[i][:, 0] * weights[j][:, 1]
    return total


def read_colours(tiles: Tiles, matched, points: np.ndarray, grid, footprint: float | None = None) -> np.ndarray:
    """The colour at points (n, 3) (sample model units) of a sample whose
    voxels `matched` maps to example voxels, read where `surface_under`
    says: (n, 3) float32 sRGB. `footprint`: the length a colour stands for
    (voxels), e.g. a vertex's spacing: its mip level averages the texture
    over it (None: full detail)."""
    tile, across = across_tiles(tiles, *surface_under(tiles, matched, points, grid))
    side = tiles.depth.shape[1]
    level = 0
    if footprint is not None and footprint > 0:
        level = int(np.clip(np.round(np.log2(footprint * side)), 0, len(tiles.mips) - 1))
    images = tiles.mips[level]
    n = images.shape[1]
    return bilinear_tiles(images, tile, (across[:, 0] + 0.5) * n - 0.5, (across[:, 1] + 0.5) * n - 0.5)


def relief(tiles: Tiles, matched, points: np.ndarray, grid, learnt: np.ndarray) -> np.ndarray:
    """Points (n, 3) of a sample's surface moved by the example's relief
    under them (relief_moves, at the place q of the example a point stands
    for). Where a neighbouring voxel copies another place of the example
    (a seam between two pieces), the point's move is blended with the move
    that voxel's match gives it, weighed by how near the point is to the
    face between them (0 at its voxel's centre, half at the face), so that
    the seam is a ramp a voxel wide, not a step. (n, 3) float64."""
    points = np.asarray(points, np.float64)
    u, match, across = pieces_beside(matched, points, grid)
    places, seams = [points + match - u], []  # every place read, the point's own first: one relief_moves call
    for axis, (rows, beside, theirs) in enumerate(across):
        places.append(points[rows] + theirs - beside)
        seams.append((rows, np.minimum(np.abs(points[rows, axis] - u[rows, axis]), 0.5)))
    read = relief_moves(tiles, np.concatenate(places), learnt)
    own, start = read[:len(points)], len(points)
    moves, weights = np.zeros_like(points), np.zeros(len(points))
    for rows, weight in seams:
        moves[rows] += weight[:, None] * read[start:start + len(rows)]
        weights[rows] += weight
        start += len(rows)
    keep = np.maximum(1 - weights, 0)
    moves += keep[:, None] * own
    return points + moves / (keep + weights)[:, None]


def relief_moves(tiles: Tiles, q: np.ndarray, learnt: np.ndarray) -> np.ndarray:
    """How points of a sample's surface standing for places q (n, 3) of the
    example move by the example's relief under them: along the example's normal, by how far its surface at full
    detail (the tiles' depths) stands out of the surface the model decodes
    for it (`learnt`: learnt_distance's grid, trilinear), at most RELIEF
    voxels. Where the sample's surface and the example's smooth one differ
    by d, both distances differ by d, so only the detail is carried: bricks
    stand out of their mortar, a course's groove sinks. The surface is read
    from the tiles of the directions that face the normal (the faces the
    point lies on, not a groove's side): each direction weighs by how near
    it is to the normal (FACING: nothing below a cosine of FACING[0], fully
    from FACING[1]), and the heights read are blended by those weights, so
    that a round wall, whose normal turns from one axis to the next, keeps
    its relief all round; it fades out only where no direction faces the
    normal enough. Of the texels read, those where the tile's surface left
    the voxel (a slope, a step) are left out (held_depth); a tile with none
    left is passed over for the voxel's neighbour's along the axis, or
    none. (n, 3) float64 moves."""
    smooth, normal = trilinear(learnt, q)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    voxel = np.clip(np.floor(q + 0.5).astype(np.int64), 0, np.array(learnt.shape) - 1)
    # Every (point, direction) read, direction by direction: sums over them run in that order.
    weights = np.clip((np.repeat(normal, 2, axis=1) * np.tile([-1.0, 1.0], 3) - FACING[0]) / (FACING[1] - FACING[0]), 0, 1)
    direction, row = np.nonzero(weights.T > 0)
    weight, sign = weights[row, direction], np.where(direction % 2, 1.0, -1.0)
    nearest = np.full(len(row), np.inf)
    height = np.zeros(len(row))  # how far q lies outside the nearest of the direction's tiles, along its normal
    for ring in RELIEF_REACH:
        at = np.flatnonzero(~np.isfinite(nearest))  # a ring is read only where the nearer ones found no tile
        _, found, above, _, _, lean = tiles_found(tiles, q[row[at]], voxel[row[at]], direction[at], ring, held_depth)
        signed = np.full((len(ring), len(at)), np.nan)  # q's distance outside the tile along its normal
        signed.ravel()[found] = above * np.sqrt(lean)
        distance = np.where(np.isfinite(signed), np.abs(signed), np.inf)  # NaN: no tile, or no texel held
        first = np.argmin(distance, axis=0)  # the nearest; of equals, the first reach
        pick = (first, np.arange(len(at)))
        nearest[at] = distance[pick]
        height[at] = signed[pick] * sign[at]
    found = np.isfinite(nearest)
    total = np.bincount(row[found], weight[found], minlength=len(q))  # the weights of the directions read
    blended = np.bincount(row[found], (weight * height)[found], minlength=len(q))  # their heights, weighed
    read = total > 0
    lift = np.zeros(len(q))
    lift[read] = np.clip(smooth[read] - blended[read] / total[read], -RELIEF, RELIEF) * np.minimum(total[read], 1)
    return lift[:, None] * normal


def trilinear(grid: np.ndarray, points: np.ndarray) -> tuple:
    """A grid (X, Y, Z) at points (n, 3), and its gradient: ((n,), (n, 3))
    float64. Past the outer voxel centres (a surface at the grid's edge lies
    up to half a voxel beyond them) the outer cells go on linearly, up to a
    voxel out; farther, clamped."""
    size = np.array(grid.shape)
    p = np.clip(points, -1, size)
    low = np.clip(np.floor(p).astype(np.int64), 0, np.maximum(size - 2, 0))
    f = p - low
    high = np.minimum(low + 1, size - 1)
    flat = grid.ravel()
    # Each axis's corner offsets into the flat grid and weights, for corner bit 0 (low) and 1 (high).
    strides = (size[1] * size[2], size[2], 1)
    offset = [(low[:, a] * strides[a], high[:, a] * strides[a]) for a in range(3)]
    weight = [(1 - f[:, a], f[:, a]) for a in range(3)]
    value = np.zeros(len(points))
    gradient = np.zeros((len(points), 3))
    for cx, cy, cz in itertools.product((0, 1), repeat=3):
        v = flat[offset[0][cx] + offset[1][cy] + offset[2][cz]].astype(np.float64)
        vx = v * weight[0][cx]
        vxy = vx * weight[1][cy]
        value += vxy * weight[2][cz]
        # The gradient's terms, each the value's with its own axis's weight
        # replaced by -1 or +1 (exact: a sign flips no rounding).
        gradient[:, 0] += (v * weight[1][cy] * weight[2][cz]) * (1.0 if cx else -1.0)
        gradient[:, 1] += (vx * weight[2][cz]) * (1.0 if cy else -1.0)
        gradient[:, 2] += vxy * (1.0 if cz else -1.0)
    return value, gradient


def across_tiles(tiles: Tiles, tile: np.ndarray, across: np.ndarray) -> tuple:
    """Where a place on a tile's plane (n, 2) lies beyond the tile's own
    voxel, the tile of the same direction of the voxel it lies in (its own
    voxel's, or one along the axis): a direction's tiles read as one
    surface, with no seam at voxels' edges. (tile (n,), across (n, 2))."""
    outside = np.flatnonzero(np.any(np.abs(across) > 0.5, axis=1))
    if not len(outside):
        return tile, across
    axis = tiles.directions[tile[outside]] // 2
    centre = tiles.voxels[tile[outside]]
    inplane = np.stack([centre[np.arange(len(outside)), ACROSS[axis, 0]],
                        centre[np.arange(len(outside)), ACROSS[axis, 1]]], axis=1)
    spot = inplane + across[outside]
    step = np.floor(spot + 0.5).astype(np.int64) - inplane
    neighbour = centre.copy()
    for k in range(2):
        neighbour[np.arange(len(outside)), ACROSS[axis, k]] += step[:, k]
    found = tiles.read(neighbour)[np.arange(len(outside)), tiles.directions[tile[outside]]]
    moved = found >= 0
    tile, across = tile.copy(), across.copy()
    tile[outside[moved]] = found[moved]
    across[outside[moved]] = (across[outside] - step)[moved]
    return tile, across


def bilinear_depth(depth: np.ndarray, tile: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Tiles' depth (N, T, T) uint8 at in-plane points (n, 2) of [-0.5, 0.5]^2, in voxels (float64)."""
    side = depth.shape[1]
    x, y = ((plane + 0.5) * side - 0.5).T
    return bilinear_tiles(depth[..., None], tile, x, y)[:, 0].astype(np.float64) * (2 * DEPTH_RANGE) - DEPTH_RANGE


def held_depth(depth: np.ndarray, tile: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """bilinear_depth of the texels whose depth is within its range (not 0
    or 255, where the tile's surface left the voxel), their weights made to
    sum to one: NaN where none of the four read holds the surface. A tile
    whose surface leaves the voxel over part of it (a slope, a step) still
    gives its depth where it holds it. (n,) float64 voxels."""
    side = depth.shape[1]
    x, y = ((plane + 0.5) * side - 0.5).T
    x0, y0, x1, y1 = texel_corners(x, y, side)
    fx = np.clip(x, 0, side - 1) - x0
    fy = np.clip(y, 0, side - 1) - y0
    total, weights = np.zeros(len(tile)), np.zeros(len(tile))
    flat, first = depth.ravel(), tile * (side * side)  # one flat gather a corner: faster than three indices
    for a, b, w in ((x0, y0, (1 - fx) * (1 - fy)), (x0, y1, (1 - fx) * fy), (x1, y0, fx * (1 - fy)), (x1, y1, fx * fy)):
        value = flat[first + a * side + b]
        w = np.where((value == 0) | (value == 255), 0.0, w)
        total += w * value
        weights += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weights > 0, total / weights, np.nan) / 255 * (2 * DEPTH_RANGE) - DEPTH_RANGE


def texel_corners(x: np.ndarray, y: np.ndarray, n: int) -> tuple:
    """The texels (x0, y0, x1, y1) a bilinear lookup at texel coordinates x, y of tiles of side n blends."""
    x = np.clip(x, 0, n - 1).astype(np.float32)
    y = np.clip(y, 0, n - 1).astype(np.float32)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(n - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(n - 2, 0))
    return x0, y0, np.minimum(x0 + 1, n - 1), np.minimum(y0 + 1, n - 1)


def bilinear_tiles(images: np.ndarray, tile: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup in tiles (N, T, T, 3) uint8 at texel coordinates x (rows), y (columns), clamped."""
    n = images.shape[1]
    x0, y0, x1, y1 = texel_corners(x, y, n)
    x = np.clip(x, 0, n - 1).astype(np.float32)
    y = np.clip(y, 0, n - 1).astype(np.float32)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = images[tile, x0, y0] * (1 - fy) + images[tile, x0, y1] * fy
    bottom = images[tile, x1, y0] * (1 - fy) + images[tile, x1, y1] * fy
    return ((top * (1 - fx) + bottom * fx) / np.float32(255)).astype(np.float32)


def colouring(model, triplane, detail: bool = True):
    """A coloured model's colour of one sample as a function of points:
    (n, 3) model coordinates -> (n, 3) float32 sRGB, with an optional
    footprint (the length in voxels a colour stands for), and its `relief`
    (points -> points moved by the example's relief). A format-5 model
    matches the sample once; a format-4 model reads its colour head, and
    has no relief, as does any without `detail`."""
    if model.example_tiles is None or not detail:
        return HeadColouring(query.colouring(model, triplane))
    kept = [(low, high, query.project(model, part).planes) for low, high, part in triplane.kept]
    return planes_colouring(model, query.project(model, triplane).planes, triplane.size, kept=kept)


class HeadColouring:
    """A format-4 sample's colour: its decoder's colour head, no relief."""

    def __init__(self, head):
        self.head = head

    def __call__(self, points, footprint=None) -> np.ndarray:
        return self.head(points)

    def relief(self, points) -> np.ndarray:
        return query.point_array(points)


class SampleSurface:
    """A format-5 sample's surface as its example's: matched once
    (Correspondence), then read at any points for colour and relief."""

    def __init__(self, model, planes: list, size, chunk: int = READ_CHUNK, kept=()):
        self.tiles, self.chunk, self.threads = model.example_tiles, chunk, model.threads
        self.matched = Correspondence(model, planes, size, kept)
        self.learnt = matcher(model).learnt
        self.grid = np.array(size)

    def __call__(self, points, footprint=None) -> np.ndarray:
        return self.chunked(points, np.float32, lambda part: read_colours(self.tiles, self.matched, part, self.grid,
                                                                          footprint))

    def relief(self, points) -> np.ndarray:
        return self.chunked(points, np.float64, lambda part: relief(self.tiles, self.matched, part, self.grid,
                                                                           self.learnt))

    def chunked(self, points, dtype, read) -> np.ndarray:
        """read(points) (n, 3) -> (n, 3), `chunk` points at a time (READ_CHUNK),
        on the model's threads (numpy lets go of the GIL in its
        loops: two threads read 1.8 times faster on two cores). Each point
        is read alone, so the result is the same whatever the threads."""
        points = query.point_array(points)
        out = np.empty((len(points), 3), dtype)
        starts = range(0, len(points), self.chunk)

        def one(start):
            out[start:start + self.chunk] = read(points[start:start + self.chunk])

        if self.threads > 1 and len(starts) > 1:
            list(readers(self.threads).map(one, starts))
        else:
            for start in starts:
                one(start)
        return out


def matching(model, triplane, detail: bool = True) -> Future:
    """`colouring` as a Future, begun on a thread of its own where the model
    has more than one: a sample's matching needs only its tri-plane, so it
    runs while the mesh is made (its numpy work lets go of the GIL, as the
    decoder's does): about 0.1 s less of a tower at scale 4."""
    if model.threads > 1:  # the reads' threads: a sample's reads begin only once its matching is done
        return readers(model.threads).submit(colouring, model, triplane, detail)
    done = Future()
    done.set_result(colouring(model, triplane, detail))
    return done


@functools.lru_cache(maxsize=None)
def readers(threads: int) -> ThreadPoolExecutor:
    """The `threads` threads every sample's reads share, made once per
    count: a pool per sample would start new threads, each growing its own
    allocator arena, and a server making samples at once would hold them all."""
    return ThreadPoolExecutor(threads, thread_name_prefix="sinshape-read")


def planes_colouring(model, planes: list, size, chunk: int = READ_CHUNK, kept=()) -> SampleSurface:
    """`colouring` of a format-5 sample given as its projected planes
    (query.project) and its size (a world's windows come so), and a composed
    sample's kept parts' (Correspondence)."""
    return SampleSurface(model, planes, size, chunk, kept)


def colours(model, triplane, coords, footprint: float | None = None) -> np.ndarray:
    """A coloured model's sRGB colour at arbitrary points of a sample (model
    coordinates, as `query.points`): (n, 3) float32 in [0, 1]."""
    return colouring(model, triplane)(coords, footprint)


def surface_painter(model, triplane, vertices: np.ndarray, faces: np.ndarray):
    """A format-5 sample's colour on its own mesh (vertices in model
    coordinates), as a function of (face (n,), barycentric weights (n, 3))
    -> (n, 3) sRGB at full detail: what a picture asks of each pixel
    (render.PAINT), so that it shows the texture, not the vertex colours."""
    read = colouring(model, triplane)
    corners = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return lambda face, weights: read(np.einsum("nk,nkc->nc", weights, corners[face]))


def dense_grids(model, triplane, scale: float = 1.0, detail: bool = True) -> dict:
    """What an .npz sample holds: {"occupancy"} on a grid `scale` times
    finer, and a coloured model's {"colour"} there, (X, Y, Z, 3) uint8 sRGB,
    each point's colour around it (1 / scale voxels); without `detail`, the
    colour head's."""
    occupancy = query.dense(model, triplane, scale)
    if not model.manifest.colour:
        return {"occupancy": occupancy}
    if model.example_tiles is None or not detail:
        return {"occupancy": occupancy, "colour": query.dense(model, triplane, scale, colour=True)[1]}
    check_memory(occupancy.size * 3 * 8, f"the colours of a {'x'.join(map(str, occupancy.shape))} grid")
    steps = [(np.array(triplane.size[a]) - 1) / max(occupancy.shape[a] - 1, 1) for a in range(3)]
    points = np.stack(np.meshgrid(*(np.arange(n) * step for n, step in zip(occupancy.shape, steps)), indexing="ij"),
                      axis=-1).reshape(-1, 3)
    rgb = colouring(model, triplane)(points, 1 / scale)
    return {"occupancy": occupancy, "colour": np.round(rgb * 255).astype(np.uint8).reshape(*occupancy.shape, 3)}
