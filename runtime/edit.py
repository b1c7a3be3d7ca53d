"""Compose a sample from boxes of other samples: keep a part, regenerate the rest.

A part is an axis-aligned box of another seed's sample. Composing runs the
level chain for the base seed, for each part's seed, and for the result; at
every level the result's planes are blended, plane by plane, from three
zones around each box's projection onto that plane (its rectangle):

    inside, deeper than MARGIN cells     the part's planes, exactly
    MARGIN cells either side of a face   the result's own, as its generator
                                         made it from what surrounds it: the join
    further out                          the base sample's planes, exactly

and the result's noise is the part's inside the rectangle, the base's
outside. A voxel reads one cell of each plane, so:
- inside a box less MARGIN voxels (and one more at scale > 1, where a point
  interpolates its neighbours' cells) the result equals the part's sample:
  exact;
- a voxel whose three cells all lie further than MARGIN outside the
  rectangles equals the base sample: exact;
- the rest is generated: the join around each box, and its "shadow": a
  plane cell covers a whole line through the volume, so a voxel outside a
  box that shares its range on two axes reads some of the part's cells.
A face on the sample's own edge needs no join; its margin is not taken off.
"""

import dataclasses
import numbers
from dataclasses import dataclass

import numpy as np

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import PLANE_AXES, plane_sizes

from .generate import Noise, Taps, TriPlane, chain, check_seed, draw_noise, scaled_sizes, triplane

# Cells of each level blended on either side of a box's face: the reach of a
# level's generator (four 3x3 convolutions).
MARGIN = 4


@dataclass(frozen=True)
class Part:
    """The box [low, high] (finest-voxel coordinates of the composed sample,
    per axis) taken from the sample of `seed` at size `factors` (None: the
    composed sample's), whose voxel p lands at p + offset."""

    seed: int
    low: tuple
    high: tuple
    offset: tuple = (0, 0, 0)
    factors: tuple | None = None


def parse_part(text: str, manifest, size: tuple) -> Part:
    """'SEED:X0,Y0,Z0:X1,Y1,Z1' -> a Part of a sample of finest size `size`.
    Corners are in the model's input frame (the units of its meshes and of
    `sinrun info`), or percentages of the sample's extent ('50%'); the text
    form shared by the command line and the web API."""
    pieces = text.split(":")
    if len(pieces) != 3:
        raise InputError(f"part {text!r}: give SEED:X0,Y0,Z0:X1,Y1,Z1, like 3:0%,0%,0%:50%,100%,100%", "keep")
    try:
        seed = int(pieces[0])
    except ValueError:
        raise InputError(f"part {text!r}: the seed {pieces[0]!r} is not an integer", "keep") from None
    corners, percent = [], [False] * 3
    for corner in pieces[1:]:
        values = corner.split(",")
        if len(values) != 3:
            raise InputError(f"part {text!r}: a corner needs 3 values, got {corner!r}", "keep")
        point = []
        for axis, value in enumerate(values):
            try:
                if value.strip().endswith("%"):
                    point.append(float(value.strip()[:-1]) / 100 * (size[axis] - 1))
                    percent[axis] = True
                else:
                    point.append((float(value) - manifest.origin[axis]) / manifest.spacing[axis])
            except ValueError:
                raise InputError(f"part {text!r}: {value!r} is not a number or a percentage", "keep") from None
        corners.append(tuple(point))

    def in_units(axis: int, voxels: float, length: bool = False) -> str:
        """Voxels in the units the box was given in along `axis`: percent, or the model's frame."""
        if percent[axis]:
            return f"{voxels / max(size[axis] - 1, 1) * 100:g}%"
        return f"{voxels * manifest.spacing[axis] + (0 if length else manifest.origin[axis]):g}"

    return check_part(Part(seed, *corners), size, in_units)


def check_part(part: Part, size: tuple, in_units=None) -> Part:
    """A box inside the sample, with something left once its margins are
    taken off. in_units(axis, voxels, length) says a figure in the units the
    box was written in (percent or the model's frame), beside the voxels."""
    check_seed(part.seed)
    corners = (part.low, part.high)
    if not all(isinstance(c, (tuple, list)) and len(c) == 3 and all(isinstance(v, numbers.Real) and np.isfinite(v)
                                                                    for v in c) for c in corners):
        raise InputError(f"a box needs two corners of 3 finite numbers, got {part.low!r}, {part.high!r}", "keep")

    def also(axis, voxels, length=False):
        return f" ({in_units(axis, voxels, length)})" if in_units else ""

    for axis, (lo, hi, n) in enumerate(zip(part.low, part.high, size)):
        name = "xyz"[axis]
        if not lo < hi:
            raise InputError(f"the box is empty or inverted along {name} ({lo:g}{also(axis, lo)} to "
                             f"{hi:g}{also(axis, hi)} voxels)", "keep")
        if lo < 0 or hi > n - 1:
            raise InputError(f"the box ({lo:g}{also(axis, lo)} to {hi:g}{also(axis, hi)} voxels along {name}) "
                             f"leaves the sample, whose voxels run 0 to {n - 1}{also(axis, n - 1)} along {name}",
                             "keep")
        kept = (hi if hi < n - 1 else np.inf) - (lo if lo > 0 else -np.inf) - 2 * MARGIN
        if kept <= 0:
            raise InputError(f"the box is {hi - lo:g}{also(axis, hi - lo, True)} voxels along {name}: a kept box "
                             f"needs more than {2 * MARGIN}{also(axis, 2 * MARGIN, True)} (a {MARGIN}-voxel join "
                             "on each side inside the sample)", "keep")
    if not (len(part.offset) == 3 and all(isinstance(v, (int, np.integer)) for v in part.offset)):
        raise InputError(f"a part's `offset` must be 3 whole voxels, got {part.offset!r}", "offset")
    return Part(int(part.seed), tuple(float(v) for v in part.low), tuple(float(v) for v in part.high),
                tuple(int(v) for v in part.offset), part.factors)


def depth(part: Part, finest: tuple, level_size: tuple, plane: int) -> np.ndarray:
    """(H, W): how many level cells each cell of a plane lies inside the box's
    rectangle (negative outside), by the nearer of its two axes; a face on
    the sample's edge is infinitely far."""
    out = None
    for axis in PLANE_AXES[plane]:
        n, cells = finest[axis], level_size[axis]
        to_level = (cells - 1) / (n - 1) if n > 1 else 0.0
        lo = part.low[axis] * to_level if part.low[axis] > 0 else -np.inf
        hi = part.high[axis] * to_level if part.high[axis] < n - 1 else np.inf
        c = np.arange(cells, dtype=np.float64)
        d = np.minimum(c - lo, hi - c)
        d = d[:, None] if out is None else d[None, :]
        out = d if out is None else np.minimum(out, d)
    return out


def blend(base: list, made: list, parts: list, sources: list, finest: tuple, level_size: tuple) -> list:
    """One level's planes: the base far from every box, each part deep inside its own, the result between."""
    out = []
    for k, made_plane in enumerate(made):
        depths = [depth(part, finest, level_size, k) for part in parts]
        near = np.ones(made_plane.shape[1:])  # how much of the result (not the base) a cell takes
        for d in depths:
            near = near * (1 - np.clip((d + MARGIN) / MARGIN, 0, 1))
        plane = near[None] * base[k] + (1 - near[None]) * made_plane
        for d, source in zip(depths, sources):
            inside = np.clip(d / MARGIN, 0, 1)[None]
            plane = inside * source[k] + (1 - inside) * plane
        out.append(plane.astype(np.float32))
    return out


def placement(cells: int, finest: int, source_cells: int, source_finest: int, offset: int) -> tuple:
    """Where each of `cells` cells of a composed level lies in its source's
    level: (index below, fraction to the next, nearest index), in exact
    integer arithmetic, so that a cell on a source cell takes it exactly."""
    c = np.arange(cells, dtype=np.int64)
    # source cell = (c (finest - 1) / (cells - 1) - offset) (source_cells - 1) / (source_finest - 1)
    numerator = (c * (finest - 1) - offset * (cells - 1)) * (source_cells - 1)
    denominator = max(1, (cells - 1) * (source_finest - 1))
    numerator = np.clip(numerator, 0, (source_cells - 1) * denominator)
    low = numerator // denominator
    nearest = (2 * numerator + denominator) // (2 * denominator)
    return low, (numerator - low * denominator) / denominator, nearest


def interpolation(where: tuple, source_cells: int) -> Taps:
    """Linear interpolation from `placement`: each cell's two source cells and their float64 weights."""
    low, frac, _ = where
    return Taps(low, np.minimum(low + 1, source_cells - 1), 1 - frac, frac)


def placed_plane(plane: np.ndarray, rows: Taps, cols: Taps) -> np.ndarray:
    """A (C, H, W) plane brought onto a composed level's cells: along H,
    then W, in float64, rounded to float32 once (as the browser runtime
    does; no matrix product, whose sums BLAS rounds by its version and CPU)."""
    return cols.sum64(rows.sum64(plane, 1), 2).astype(np.float32)


@dataclass
class Placed:
    """A part's source sample brought onto the composed sample's grids: each
    level's planes (interpolated) and noise (nearest cell), and z0."""

    planes: list
    noise: Noise


def place(model, part: Part, sizes: list, factors) -> Placed:
    """Run the part's sample at its own size and place it at its offset."""
    source_sizes = sizes if part.factors is None else scaled_sizes(model.manifest.sizes, part.factors)
    for axis in range(3):
        if part.low[axis] - part.offset[axis] < 0 or part.high[axis] - part.offset[axis] > source_sizes[-1][axis] - 1:
            raise InputError(f"the box reaches outside the sample of seed {part.seed} along {'xyz'[axis]}", "keep")
    source_noise = draw_noise(part.seed, source_sizes, model.manifest.channels)
    levels = chain(model, source_noise, source_sizes)
    finest, source_finest = sizes[-1], source_sizes[-1]
    planes, noise_planes = [], [None]
    for level, (size, source_size) in enumerate(zip(sizes, source_sizes)):
        where = [placement(size[a], finest[a], source_size[a], source_finest[a], part.offset[a]) for a in range(3)]
        level_planes, level_noise = [], []
        for k, (a, b) in enumerate(PLANE_AXES):
            rows, cols = interpolation(where[a], source_size[a]), interpolation(where[b], source_size[b])
            level_planes.append(placed_plane(levels[level][k], rows, cols))
            if level > 0:
                level_noise.append(source_noise.planes[level][k][:, where[a][2]][:, :, where[b][2]])
        planes.append(level_planes)
        if level > 0:
            noise_planes.append(level_noise)
    z0 = source_noise.z0[np.ix_(*(placement(sizes[0][a], finest[a], source_sizes[0][a], source_finest[a],
                                            part.offset[a])[2] for a in range(3)))]
    return Placed(planes, Noise(z0, noise_planes))


def compose_noise(base: Noise, parts: list, placed: list, sizes: list) -> Noise:
    """The base seed's noise, with each part's inside its box (z0 in 3-D, the rest per plane)."""
    finest = sizes[-1]
    z0 = base.z0.copy()
    box = [slice(None)] * 3
    for part, source in zip(parts, placed):
        for axis in range(3):
            to_level = (sizes[0][axis] - 1) / (finest[axis] - 1) if finest[axis] > 1 else 0.0
            box[axis] = slice(int(np.ceil(part.low[axis] * to_level)), int(np.floor(part.high[axis] * to_level)) + 1)
        z0[tuple(box)] = source.noise.z0[tuple(box)]
    planes = [None]
    for level in range(1, len(sizes)):
        merged = [p.copy() for p in base.planes[level]]
        for part, source in zip(parts, placed):
            for k in range(3):
                inside = depth(part, finest, sizes[level], k) >= 0
                merged[k][:, inside] = source.noise.planes[level][k][:, inside]
        planes.append(merged)
    return Noise(z0, planes)


def compose_memory(sizes: list, channels: int, parts: int) -> int:
    """Bytes `compose` holds at its peak: every level's planes and noise of
    the base, of each part and of the result (float32), and at the largest
    level the blend's float64 temporaries (six) beside the generator's
    working copies (six float32). Measured: 532 MB for a terrain grown
    8,8,1 (this says 696), 2.15 GB for 16,16,1 (2.66)."""
    every = sum(h * w for size in sizes for h, w in plane_sizes(size)) * channels * 4
    largest = max(sum(h * w for h, w in plane_sizes(size)) for size in sizes) * channels
    return int(every * 2 * (parts + 2) + largest * (8 * 6 + 4 * 6))


def compose(model, seed: int, parts, factors=(1.0, 1.0, 1.0), memory_limit: int | None = None) -> TriPlane:
    """The sample of `seed` at size `factors`, with each part's box taken
    from the part's own sample (a later part wins where boxes overlap).
    Exact inside each box less MARGIN voxels, and away from the boxes and
    their shadows; see the module's docstring. memory_limit as for
    `generate.sample`."""
    sizes = scaled_sizes(model.manifest.sizes, factors)
    channels = model.manifest.channels
    parts = [check_part(part, sizes[-1]) for part in parts]
    if not parts:
        raise InputError("give at least one part to keep", "parts")
    check_memory(compose_memory(sizes, channels, len(parts)),
                 f"composing {len(parts)} part{'s' if len(parts) > 1 else ''} into a sample of "
                 f"{'x'.join(map(str, sizes[-1]))} voxels", memory_limit)
    base_noise = draw_noise(check_seed(seed), sizes, channels)
    placed = [place(model, part, sizes, factors) for part in parts]
    base = chain(model, base_noise, sizes)
    made = triplane(model, compose_noise(base_noise, parts, placed, sizes), sizes, after_level=lambda level, planes: blend(
        base[level], planes, parts, [p.planes[level] for p in placed], sizes[-1], sizes[level]))
    return dataclasses.replace(made, kept=tuple((part.low, part.high, TriPlane(p.planes[-1], sizes[-1]))
                                                for part, p in zip(parts, placed)))


def grow(model, seed: int, by, anchor=(0.0, 0.0, 0.0), factors=(1.0, 1.0, 1.0),
         memory_limit: int | None = None) -> TriPlane:
    """The sample of `seed` (at size `factors`) grown `by` times per axis,
    keeping what it had: it sits at `anchor` of the larger sample (per axis,
    0 at the low side, 1 at the high side, 0.5 centred) and the new ground
    around it joins it as `compose` joins a part."""
    if not (len(by) == 3 and all(isinstance(f, numbers.Real) and 1 <= f < float("inf") for f in by)):
        raise InputError(f"`grow` factors must be 3 numbers of at least 1, got {by!r}", "grow")
    if not (len(anchor) == 3 and all(isinstance(a, numbers.Real) and 0 <= a <= 1 for a in anchor)):
        raise InputError(f"an anchor is 3 numbers in [0, 1], got {anchor!r}", "anchor")
    old = scaled_sizes(model.manifest.sizes, factors)[-1]
    grown = tuple(f * g for f, g in zip(factors, by))
    new = scaled_sizes(model.manifest.sizes, grown)[-1]
    offset = tuple(int(round(a * (n - o))) for a, n, o in zip(anchor, new, old))
    part = Part(seed, tuple(float(v) for v in offset), tuple(float(v + o - 1) for v, o in zip(offset, old)),
                offset, tuple(factors))
    return compose(model, seed, [part], grown, memory_limit)
