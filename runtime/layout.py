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

import io
import struct
import zipfile
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import MESH_FORMATS, atomic_write, read_regular
from sinshape.core.manifest import MAX_LEVEL_SIDE, PLANE_AXES

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


# -- layout files: MagicaVoxel .vox (what voxel artists edit) and .npz --------
LAYOUT_FORMATS = (".vox", ".npz")
MAX_LAYOUT_SIDE = 256  # MagicaVoxel's own limit per axis
MAX_LAYOUT_BYTES = 64 << 20
MAX_LAYOUT_CELLS = 512**3  # an .npz layout; a coarse level is far smaller
VOX_VERSION = 150
VOX_COLOUR = 1  # palette index the voxels are written with (any non-zero index reads as full)


def check_layout_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in LAYOUT_FORMATS:
        raise InputError(f"{path}: a layout is a {' or '.join(LAYOUT_FORMATS)} file, not {path.suffix or 'no extension'}")
    return path


def vox_bytes(grid: np.ndarray) -> bytes:
    """A MagicaVoxel .vox file of one model: MAIN holding SIZE and XYZI."""
    x, y, z = np.nonzero(grid)
    voxels = np.stack([x, y, z, np.full_like(x, VOX_COLOUR)], axis=1).astype(np.uint8).tobytes()
    size = struct.pack("<3i", *grid.shape)
    xyzi = struct.pack("<i", len(x)) + voxels
    children = (b"SIZE" + struct.pack("<2i", len(size), 0) + size
                + b"XYZI" + struct.pack("<2i", len(xyzi), 0) + xyzi)
    return b"VOX " + struct.pack("<i", VOX_VERSION) + b"MAIN" + struct.pack("<2i", 0, len(children)) + children


def read_vox(data: bytes, path) -> np.ndarray:
    """The one model of a .vox file as a bool grid; chunks other than SIZE
    and XYZI (palette, materials, scene graph) are skipped. Every size a
    chunk declares is checked (sign, and that it fits what is left of its
    parent) before it is used."""
    def corrupt(why):
        return InputError(f"{path}: not a readable MagicaVoxel file ({why})")

    if len(data) < 20 or data[:4] != b"VOX " or data[8:12] != b"MAIN":
        raise corrupt("no 'VOX ' header and MAIN chunk")
    content, children = struct.unpack_from("<2i", data, 12)
    if not (0 <= content and 0 <= children and 20 + content + children <= len(data)):
        raise corrupt(f"MAIN declares {content} and {children} bytes, and runs past the end of the "
                      f"{len(data) - 20} after it")
    end = 20 + content + children
    size, voxels, at = None, None, 20 + content
    models = 0
    while at < end:
        if at + 12 > end:
            raise corrupt("a chunk runs past the end")
        name = data[at:at + 4]
        content, children = struct.unpack_from("<2i", data, at + 4)
        if content < 0 or children < 0 or at + 12 + content + children > end:
            raise corrupt(f"chunk {name!r} declares {content} and {children} bytes, past the end")
        body = data[at + 12:at + 12 + content]
        if name == b"SIZE":
            models += 1
            if content < 12:
                raise corrupt("a SIZE chunk too short")
            size = struct.unpack_from("<3i", body)
            if not all(1 <= n <= MAX_LAYOUT_SIDE for n in size):
                raise InputError(f"{path}: a model of {'x'.join(map(str, size))} voxels; a layout has 1 to "
                                 f"{MAX_LAYOUT_SIDE} per axis")
        elif name == b"XYZI":
            count = struct.unpack_from("<i", body)[0] if content >= 4 else -1
            if not 0 <= count <= (content - 4) // 4:
                raise corrupt("an XYZI chunk whose count does not fit it")
            voxels = np.frombuffer(body, np.uint8, count * 4, 4).reshape(count, 4)
        at += 12 + content + children
    if models != 1 or voxels is None or size is None:
        raise InputError(f"{path}: holds {models} models; a layout is one")
    xyz = voxels[:, :3].astype(int)
    if (xyz >= np.array(size)).any():
        raise corrupt("a voxel outside its model's size")
    grid = np.zeros(size, bool)
    grid[tuple(xyz.T)] = voxels[:, 3] > 0
    return grid


def check_fits(shape: tuple, suffix: str, name) -> None:
    """A layout of `shape` fits a `suffix` file (.vox: MagicaVoxel's 256 a
    side): checked from the level's size, before the layout is made."""
    if suffix.lower().lstrip(".") == "vox" and max(shape) > MAX_LAYOUT_SIDE:
        raise InputError(f"{name}: a {'x'.join(map(str, shape))} layout; .vox holds at most "
                         f"{MAX_LAYOUT_SIDE} voxels per axis (write .npz)")


def grid_size(model, level: int = 0, factors=(1.0, 1.0, 1.0)) -> tuple:
    """The shape of the layout of `level` of a sample of `factors`, from the arguments alone."""
    return tuple(scaled_sizes(model.manifest.sizes, factors)[check_level(model, level)])


def write_layout(grid: np.ndarray, path) -> None:
    """A layout to .vox or .npz (array `layout`), atomically."""
    path = check_layout_path(path)
    check_fits(grid.shape, path.suffix, path)
    if path.suffix.lower() == ".vox":
        data = vox_bytes(grid)
    else:
        buffer = io.BytesIO()
        np.savez_compressed(buffer, layout=grid.astype(bool))
        data = buffer.getvalue()
    atomic_write(path, lambda f: f.write(data))


def read_layout(path) -> np.ndarray:
    """A layout file as a bool grid, checked: bounded size, one 3-D grid."""
    path = check_layout_path(path)
    data = read_regular(path, f"the layout {path}", MAX_LAYOUT_BYTES, field="layout")
    return parse_layout(data, path.suffix.lower(), path)


def parse_layout(data: bytes, suffix: str, name) -> np.ndarray:
    """The bytes of a .vox or .npz layout (`suffix`) as a bool grid; `name`
    says what they are in messages. Bounds come from what is read: an .npz
    must hold the one member `layout.npy` (np.load would read a member named
    plain `layout` first), whose header is checked before its data, and at
    most the bytes that header declares are decompressed."""
    if len(data) > MAX_LAYOUT_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a layout")
    if suffix == ".vox":
        return read_vox(data, name)
    return read_npz(data, name)


def read_npz(data: bytes, name) -> np.ndarray:
    """The array `layout` of an .npz archive, read member first, header
    second, data last, each bounded by what came before: deflate is read a
    bounded piece at a time, so at most the bytes the header declares (at
    most MAX_LAYOUT_BYTES) are ever decompressed."""
    def unreadable(why):
        return InputError(f"{name}: not a readable .npz layout ({why})")

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            members = archive.infolist()
            if [m.filename for m in members] != ["layout.npy"]:
                listed = ", ".join(repr(m.filename) for m in members[:4]) + (", ..." if len(members) > 4 else "")
                raise unreadable(f"it must hold one array, layout.npy, and holds {listed or 'nothing'}")
            if members[0].compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                # bzip2 and LZMA decompress a chunk whole: a few bytes could unpack into gigabytes at once
                raise unreadable("compressed other than as NumPy writes it, stored or deflated")
            with archive.open(members[0]) as member:
                major, _ = np.lib.format.read_magic(member)
                if major not in (1, 2):
                    raise unreadable(f"NPY format version {major}")
                read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
                shape, fortran, dtype = read_header(member, max_header_size=10000)
                check_npz_header(shape, dtype, name)
                needed = int(np.prod(shape)) * dtype.itemsize
                if needed > MAX_LAYOUT_BYTES:
                    raise InputError(f"{name}: its layout of shape {shape} holds {needed >> 20} MB; a layout "
                                     f"holds at most {MAX_LAYOUT_BYTES >> 20} MB")
                body = member.read(needed + 1)  # at most what the header declares, and one byte to see more
    except InputError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, NotImplementedError, SyntaxError, TypeError) as error:
        raise unreadable(type(error).__name__) from None
    if len(body) != needed:
        raise unreadable(f"its data is {len(body)} bytes and its header declares {needed}")
    grid = np.frombuffer(body, dtype).reshape(shape, order="F" if fortran else "C")
    if grid.dtype == bool:
        return grid.copy()
    if not np.isfinite(grid).all():
        raise InputError(f"{name}: 'layout' holds NaN or infinite values, not occupancy in [0, 1]")
    return grid > 0.5


def check_npz_header(shape: tuple, dtype, name) -> None:
    """An .npz layout's header, before a byte of its data is read: 3 bounded
    axes of booleans or real numbers."""
    if not (isinstance(shape, tuple) and len(shape) == 3 and all(isinstance(n, int) for n in shape)
            and all(1 <= n <= MAX_LEVEL_SIDE for n in shape) and np.prod(shape, dtype=object) <= MAX_LAYOUT_CELLS):
        raise InputError(f"{name}: needs an array 'layout' of 3 axes, 1 to {MAX_LEVEL_SIDE} each and at most "
                         f"{MAX_LAYOUT_CELLS} cells, got shape {shape}")
    if not (dtype.kind == "b" or np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)) \
            or dtype.hasobject or dtype.itemsize > 8:
        raise InputError(f"{name}: 'layout' holds {dtype}, not occupancy")


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


def mesh_layout(model, path, factors=(1.0, 1.0, 1.0)) -> np.ndarray:
    """A rough mesh (a few boxes, in the model's frame: the units of its
    samples' meshes) voxelised on level 0's grid of a sample of `factors`."""
    from sinshape.prep.voxelize import load_mesh, voxelize  # the prep extra: only a layout read from a mesh needs it

    corner, spacing, shape = cells(model.manifest, factors)
    grid = voxelize(load_mesh(path), corner, spacing, shape)
    if not grid.any():
        raise InputError(f"{path}: the mesh lies outside the sample's box (its frame is the model's: "
                         "the units of its samples' meshes)", "layout")
    return grid


def read_any(model, path, factors=(1.0, 1.0, 1.0)) -> np.ndarray:
    """A layout from a file: a .vox or .npz layout as it is, or a rough mesh
    in any format trimesh reads, voxelised on level 0's grid (`mesh_layout`)."""
    if Path(path).suffix.lower() in MESH_FORMATS:
        return mesh_layout(model, path, factors)
    return read_layout(path)


def export(model, seed: int, path, level: int = 0, factors=(1.0, 1.0, 1.0)) -> tuple:
    """Write the layout of the sample of `seed` at `level` to `path`; its grid size."""
    check_fits(grid_size(model, level, factors), check_layout_path(path).suffix, path)
    grid = layout(model, seed, level, factors)
    write_layout(grid, path)
    return grid.shape
