"""A sample's coarse layout: read it out, edit it elsewhere, generate from it.

The layout is one level's tri-plane read on that level's own grid and
thresholded at 0.5 (level 0 by default: where the towers, columns, bays and
gaps are). Generating from an edited layout takes the seed's planes at that
level, fits them to the layout by gradient descent through the decoder (a
two-layer MLP whose gradient is written out below), staying close to where
they started so that the finer levels receive planes like the ones they
learnt from, then runs the finer levels with the seed's noise: the layout
sets the structure, the model and the seed the detail. Every step is fixed
(a set number of Adam steps from the seed's own planes), so the same
layout, seed and options give the same shape.
"""


import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES

from .generate import TriPlane, check_seed, draw_noise, resize_matrix, scaled_sizes, triplane
from .generate import sample as generate_sample
from .query import dense, sigmoid

# Adam steps per level, at most. 60, 30 and 30 (without SLOPE_FLOOR) followed
# the layout about as well (IoU with it within 0.015 on benchmarks/edit.py's
# edits) in 1.5 to 2.0 times the time.
FIT_STEPS = 30  # at the layout's level
FINER_STEPS = 10  # at each finer level, which would otherwise bring back what was removed
HOLD_STEPS = 20  # at the last level, whose occupancy is the result
FIT_RATE = 0.5  # Adam's step, in plane units (trained planes hold values of about +-2)
PULL = 0.001  # weight of the change's mean square
MARGIN = 0.1  # an edited cell is fitted until its occupancy is this far past 0.5, on the layout's side
KEEP_WEIGHT = 0.2  # an unedited cell's weight, against an edited cell's 1, once it has crossed 0.5
SLOPE_FLOOR = 0.1  # the sigmoid's slope in the fit's gradient, at least: see fit
SHARE = 0.4  # a plane cell may change where more than this share of the cells on its line were edited
# The decoder's hidden units a fit evaluates at once, over every voxel within
# reach: its logit sums them in this many lanes, as the browser's SIMD does
# (decode.wat), so that both runtimes add in one order.
LANES = 4
# Bytes per finest voxel and hidden unit a fit holds at its peak (the
# planes through the first layer within reach, the whole grid at worst, and
# LANES units' pre-activations and gradient): 4.2 and 5.2 measured
# for towerruins at sizes 1 and 2, 8.8 for terrain at 2.
FIT_BYTES = 12


def check_level(model, level: int) -> int:
    levels = len(model.manifest.sizes)
    if not (isinstance(level, (int, np.integer)) and 0 <= level < levels - 1):
        raise InputError(f"`level` must be 0 to {levels - 2} (a layout needs a finer level after it), got {level}",
                         "level")
    return int(level)


def layout(model, seed: int, level: int = 0, factors=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(X, Y, Z) bool at `level`'s grid: the sample of `seed`, area-averaged
    to that grid, where it is more than half full."""
    level = check_level(model, level)
    sizes = scaled_sizes(model.manifest.sizes, factors)
    return pool(dense(model, generate_sample(model, check_seed(seed), factors)), sizes[level]) > 0.5


def first_layer(model) -> list:
    """Each plane's block W_P of the decoder's first layer, (C, D), read by
    running stage decoder_planes (linear, no bias) on one-hot planes."""
    c = model.manifest.channels
    eye = np.eye(c, dtype=np.float32)[None, :, None, :]  # (1, C, 1, C): cell j holds channel j
    return [out[0, 0] for out in model.decoder_planes.run([eye] * 3)]  # (1, 1, C, D) -> (C, D)


def area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in): cell i of n_out averages the part of the n_in cells it covers."""
    edges = np.arange(n_out + 1) * (n_in / n_out)
    cells = np.arange(n_in)
    overlap = np.clip(np.minimum(edges[1:, None], cells + 1) - np.maximum(edges[:-1, None], cells), 0, None)
    return (overlap / overlap.sum(axis=1, keepdims=True)).astype(np.float32)


def along(matrix: np.ndarray, values: np.ndarray, axis: int) -> np.ndarray:
    """An (n_out, n_in) matrix applied along `axis` of `values` (n_in long
    there): out[o] = the sum over i, in order, of matrix[o, i] * values[i],
    each product and sum rounded alone (the values' and matrix's dtype).
    A matrix product does the same sums, but BLAS orders and fuses them by
    its version and the CPU it finds (and numpy's own reductions sum pairwise
    where the axis lies innermost in memory), and the same layout and seed
    must give the same shape with any numpy on any machine, and in the
    browser (layout.js's along). A sparse matrix (a resize, an area average:
    a few entries a row) gathers each row's entries in turn; a dense one (a
    layer's weights) adds a column at a time (its zeros add nothing)."""
    values = np.moveaxis(values, axis, 0)
    out = np.zeros((matrix.shape[0], *values.shape[1:]), np.result_type(matrix, values))
    shape = (-1,) + (1,) * (values.ndim - 1)
    nonzero = matrix != 0
    entries = nonzero.sum(axis=1)
    if 4 * entries.max(initial=0) <= matrix.shape[1]:
        columns = np.argsort(~nonzero, axis=1, kind="stable")  # each row's nonzero columns first, in order
        rows = np.arange(len(matrix))
        for k in range(entries.max(initial=0)):
            weight = np.where(k < entries, matrix[rows, columns[:, k]], 0)  # a row with fewer entries adds 0
            out += weight.reshape(shape) * values[columns[:, k]]
    else:
        for column in range(matrix.shape[1]):
            out += matrix[:, column].reshape(shape) * values[column]
    return np.ascontiguousarray(np.moveaxis(out, 0, axis))


def summed(values: np.ndarray, axis: int) -> np.ndarray:
    """The sum over `axis`, slab after slab in order (numpy's own reduction
    is several times slower along a short inner axis)."""
    slabs = np.moveaxis(values, axis, 0)
    out = slabs[0].copy()
    for slab in slabs[1:]:
        out += slab
    return out


def separable(weights: list, grid: np.ndarray) -> np.ndarray:
    """One (n_out, n_in) matrix applied along each axis of a 3-D grid."""
    out = grid.astype(np.float32)
    for axis, w in enumerate(weights):
        out = along(w, out, axis)
    return out


def pool(grid: np.ndarray, shape) -> np.ndarray:
    """Area-average a grid down (or up) to `shape`: what a layout cell holds of it."""
    return separable([area_weights(n, m) for n, m in zip(grid.shape, shape)], grid)


def plane_masks(edited: np.ndarray) -> list:
    """Per plane, where a fit may change it, at the layout's resolution.

    A plane cell is read by every voxel on a line through the volume, so
    changing it for an edit changes that whole line. A plane may change a
    cell where more than SHARE of its line was edited, and each edited cell
    may also use the plane where its line is most edited; then one cell
    more around. A slab removed along x thus changes the xy and xz planes
    there and leaves yz, which every x reads, alone."""
    shares = [edited.mean(axis=2 - k) for k in range(3)]  # plane k drops axis 2 - k
    on_grid = [shares[0][:, :, None], shares[1][:, None, :], shares[2][None]]
    best = np.argmax(np.stack([np.broadcast_to(a, edited.shape) for a in on_grid]), axis=0)
    masks = []
    for k in range(3):
        mask = (shares[k] > SHARE) | (edited & (best == k)).any(axis=2 - k)
        grown = mask.copy()
        grown[1:] |= mask[:-1]
        grown[:-1] |= mask[1:]
        grown[:, 1:] |= mask[:, :-1]
        grown[:, :-1] |= mask[:, 1:]
        masks.append(grown)
    return masks


def reach(masks: list, pools: list) -> tuple:
    """The layout cells and voxels a fit can change, per axis a slice each:
    every voxel reading a masked plane cell, grown to whole layout cells (so
    that each cell's average is over all it covers). The fit decodes only
    these; the rest cannot move."""
    xy, xz, yz = (m > 0 for m in masks)
    touched = [xy.any(axis=1) | xz.any(axis=1) | yz.any(),  # along x
               xy.any(axis=0) | yz.any(axis=1) | xz.any(),  # along y
               xz.any(axis=0) | yz.any(axis=0) | xy.any()]  # along z
    cells, voxels = [], []
    for weights, hit in zip(pools, touched):
        cell = np.flatnonzero(weights[:, hit].any(axis=1))
        voxel = np.flatnonzero(weights[cell[0]:cell[-1] + 1].any(axis=0))
        cells.append(slice(cell[0], cell[-1] + 1))
        voxels.append(slice(voxel[0], voxel[-1] + 1))
    return tuple(cells), tuple(voxels)


def resized(rows: np.ndarray, field: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """A (..., H, W) field resized by (rows, cols) matrices: rows @ field @ cols.T for each of its leading entries."""
    return along(cols, along(rows, field, -2), -1)


def through(weights: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(C, H, W) planes through a (C, D) block of the decoder's first layer: (D, H, W)."""
    return along(weights.T, planes, 0)


def fit(model, planes: list, target: np.ndarray, steps: int, edited: np.ndarray, hold: bool = False) -> list:
    """Planes (3 x (C, H, W)) changed so that their occupancy, area-averaged
    to the layout's grid, is on the layout `target`'s side of 0.5 (by MARGIN)
    in the `edited` cells, and stays on its own side in the others (with
    `hold`, on the layout's: at the last level, whose occupancy is the
    result, an unedited cell a finer level moved across is moved back), after
    at most `steps`. A hinge, not a cross-entropy: a cell already right adds
    nothing, so partly full cells keep their detail instead of being pushed
    to full or empty. The change is a field at the layout's own resolution,
    resized onto each plane (bilinear, align_corners), only where
    `plane_masks` allows it, and pulled toward zero: it moves where things
    are and leaves the detail to the generators. The sigmoid's slope in the
    gradient is floored at SLOPE_FLOOR: a voxel deep on the wrong side (a
    block added apart from the rest, which a finer level's generator
    emptied) has a slope near 0 and would not come back in the steps there
    are.

    Every sum runs in a fixed order (`along`, and the decoder's hidden
    units in LANES lanes), channels first in each array, and the sigmoid in
    float64, so that the fit is the same numbers with any numpy on any
    machine, and in the browser (layout.js, tests/test_mirror.py)."""
    if not edited.any():
        return planes
    weights = first_layer(model)
    head = model.head
    size = (planes[0].shape[1], planes[0].shape[2], planes[1].shape[2])
    pools = [area_weights(n, m) for n, m in zip(size, target.shape)]
    # Per plane, (rows, cols) resize matrices from the layout's cells to the plane's.
    grow = [(resize_matrix(target.shape[a], size[a]), resize_matrix(target.shape[b], size[b])) for a, b in PLANE_AXES]
    masks = [(resized(r, m.astype(np.float32), c) > 0).astype(np.float32) for m, (r, c) in zip(plane_masks(edited), grow)]
    cells, voxels = reach(masks, pools)
    pools = [w[c, v] for w, c, v in zip(pools, cells, voxels)]
    target, edited = target[cells], edited[cells]
    # Within reach only. The first layer is linear, so a plane's term is its
    # start's plus the mask times the change's term resized: the change is
    # multiplied through the layer at the layout's resolution, several times
    # fewer cells than the plane's, and so is its gradient.
    grow_in = [(r[voxels[a]], c[voxels[b]]) for (r, c), (a, b) in zip(grow, PLANE_AXES)]
    masks_in = [m[voxels[a], voxels[b]] for m, (a, b) in zip(masks, PLANE_AXES)]
    start = [through(w, p[:, voxels[a], voxels[b]].astype(np.float32))
             for p, w, (a, b) in zip(planes, weights, PLANE_AXES)]  # (D, h, w) each
    change = [np.zeros((p.shape[0], r.shape[1], c.shape[1]), np.float32) for p, (r, c) in zip(planes, grow)]
    moments = [(np.zeros_like(d), np.zeros_like(d)) for d in change]
    hidden = len(head.weight2)
    groups = [slice(u, min(u + LANES, hidden)) for u in range(0, hidden, LANES)]
    side = need = weight = None
    for step in range(1, steps + 1):
        a_xy, a_xz, a_yz = (s + mask * resized(r, through(w, d), c)
                            for s, mask, d, w, (r, c) in zip(start, masks_in, change, weights, grow_in))

        def pre(units):  # those hidden units' pre-activations at every voxel within reach: (u, X, Y, Z)
            return ((a_xy[units][:, :, :, None] + a_xz[units][:, :, None])
                    + (a_yz[units][:, None] + head.bias1[units, None, None, None]))

        lanes = np.zeros((LANES,) + a_xy.shape[1:] + a_xz.shape[2:], np.float32)  # lane l: units l, l + LANES, ...
        for units in groups:
            lanes[:units.stop - units.start] += np.maximum(pre(units), 0) * head.weight2[units, None, None, None]
        logits = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
        occupancy = sigmoid((logits + np.float32(head.bias2)).astype(np.float64)).astype(np.float32)
        pooled = separable(pools, occupancy)
        if side is None:  # the unedited cells keep the side these planes put them on (with hold, the layout's)
            side = np.where(edited | hold, target, pooled > 0.5).astype(np.float32) * 2 - 1
            need = np.where(edited, MARGIN, 0).astype(np.float32)
            weight = np.where(edited, 1.0, KEEP_WEIGHT).astype(np.float32) / edited.sum()
        short = need - side * (pooled - 0.5) > 0
        if not short.any() or step == steps:
            break
        # The hinge's gradient, back through the pooling, the sigmoid and the ReLU.
        d_occupancy = separable([w.T for w in pools], np.where(short, -side * weight, 0))
        d_logits = d_occupancy * np.maximum(occupancy * (1 - occupancy), SLOPE_FLOOR)
        d_a = [np.empty_like(a) for a in (a_xy, a_xz, a_yz)]
        for units in groups:
            d_pre = d_logits * (head.weight2[units, None, None, None] * (pre(units) > 0))
            d_a[0][units], d_a[1][units], d_a[2][units] = (summed(d_pre, axis) for axis in (3, 2, 1))
        for d, d_k, w, mask, (r, c), (m, v) in zip(change, d_a, weights, masks_in, grow_in, moments):
            grad = along(w, resized(r.T, mask * d_k, c.T), 0) + 2 * PULL / d.size * d
            m += 0.1 * (grad - m)  # Adam, beta1 0.9, beta2 0.999
            v += 0.001 * (grad * grad - v)
            d -= FIT_RATE * (m / (1 - 0.9**step)) / (np.sqrt(v / (1 - 0.999**step)) + 1e-8)
    return [p.astype(np.float32) + mask * resized(r, d, c) for p, mask, d, (r, c) in zip(planes, masks, change, grow)]


def fit_memory(sizes: list, hidden: int) -> int:
    """Bytes generating from a layout needs at its peak, at the finest level's fit."""
    return int(np.prod(sizes[-1], dtype=object)) * hidden * FIT_BYTES


def layout_level(model, shape: tuple, factors=(1.0, 1.0, 1.0), resample: bool = False) -> int:
    """The level whose grid a layout of `shape` is (level 0 with `resample`,
    which area-averages a layout of another size to it)."""
    sizes = scaled_sizes(model.manifest.sizes, factors)[:-1]
    if tuple(shape) in sizes:
        return sizes.index(tuple(shape))
    if resample:
        return 0
    grids = ", ".join("x".join(map(str, size)) for size in sizes)
    raise InputError(f"the layout is {'x'.join(map(str, shape))}, and this sample's levels are {grids}; "
                     "resample it to level 0's grid, or export one with `layout`", "layout")


def from_layout(model, seed: int, target: np.ndarray, factors=(1.0, 1.0, 1.0), resample: bool = False) -> TriPlane:
    """The sample of `seed` with the structure of the layout `target` (a bool
    grid of one level's size, found by its shape; any size with `resample`):
    structure from the layout, detail from the model and the seed."""
    sizes = scaled_sizes(model.manifest.sizes, factors)
    target = np.asarray(target) > 0.5
    level = layout_level(model, target.shape, factors, resample)
    if target.shape != tuple(sizes[level]):
        target = pool(target, sizes[level]) > 0.5
    noise = draw_noise(check_seed(seed), sizes, model.manifest.channels)
    # The cells the user edited: where the layout differs from the seed's own.
    own = pool(dense(model, triplane(model, noise, sizes)), target.shape) > 0.5
    edited = target != own

    def fitted(i, planes):
        if i < level:
            return planes
        last = i == len(sizes) - 1
        return fit(model, planes, target, FIT_STEPS if i == level else HOLD_STEPS if last else FINER_STEPS, edited, last)

    return triplane(model, noise, sizes, after_level=fitted)


def grid_size(model, level: int = 0, factors=(1.0, 1.0, 1.0)) -> tuple:
    """The shape of the layout of `level` of a sample of `factors`, from the arguments alone."""
    return tuple(scaled_sizes(model.manifest.sizes, factors)[check_level(model, level)])


def cells(manifest, factors=(1.0, 1.0, 1.0)) -> tuple:
    """Where level 0's cells of a sample of `factors` lie in the model's
    frame (the units of its meshes): (the low corner of cell (0, 0, 0), a
    cell's size, the grid's shape). Cell c spans corner + c * size to
    corner + (c + 1) * size, centred where finest voxel c (N - 1) / (n - 1)
    is (align_corners)."""
    sizes = scaled_sizes(manifest.sizes, factors)
    coarse, finest = np.array(sizes[0]), np.array(sizes[-1])
    spacing = np.asarray(manifest.spacing) * (finest - 1) / np.maximum(coarse - 1, 1)
    return np.asarray(manifest.origin) - spacing / 2, spacing, tuple(sizes[0])
