"""Generate a tri-plane: chain the level stages with noise injection.

Level 0: T_0 = G_0(P(z0)). Level i > 0: U = bilinear resize of T_(i-1) to
level i's plane sizes (align_corners=True); T_i = U + G_i(U + sigma_i n_i).
P's pooling and the resizes are plain numpy; the convolutions run in the
model's onnxruntime sessions.

Planes are (C, H, W) float32 in the order xy (X, Y), xz (X, Z), yz (Y, Z).
"""

import math
import numbers
from dataclasses import dataclass

import numpy as np

from sinshape.core import noise
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.manifest import plane_sizes

# A sample's coarsest grid may not shrink below this many voxels per axis.
MIN_SIDE = 2
# Points per axis of anything a sample makes: no level longer than this is
# generated, and no grid with more points is queried; beyond it a size or
# scale is absurd (and the noise is defined up to 2**21 only).
MAX_GRID_SIDE = 1 << 16
# How far `interpolate` extrapolates: its noise is then this many times the
# std the levels were trained on (1e308 overflowed to NaN and failed).
MAX_ALPHA = 100


def parse_triple(text: str, valid, example: str, name: str = "size") -> tuple:
    """'a,b,c', or one value for all three axes -> three floats passing `valid`.
    The text form of per-axis values, shared by the command line and the web API."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) == 1:
        values *= 3
    if len(values) != 3 or not all(valid(v) for v in values):
        raise InputError(f"{name} {text!r}: give {example}")
    return values


def parse_size(text: str) -> tuple:
    """'2' or '2,1,0.5' -> three finite positive size factors, one per axis."""
    return parse_triple(text, lambda f: 0 < f < float("inf"), "one or three positive factors, like 2 or 2,1,0.5")


def scaled_sizes(sizes: list, factors=(1.0, 1.0, 1.0)) -> list:
    """Every level's grid for a sample `factors` times the training size per axis."""
    if not (isinstance(factors, (tuple, list, np.ndarray)) and len(factors) == 3
            and all(isinstance(f, numbers.Real) and 0 < f < float("inf") for f in factors)):
        raise InputError(f"`factors` must be 3 positive numbers, got {factors!r}", "factors")
    longest = max(n * f for size in sizes for n, f in zip(size, factors))
    out = [] if longest > MAX_GRID_SIDE else [tuple(max(MIN_SIDE, round(n * f)) for n, f in zip(size, factors))
                                              for size in sizes]  # round() overflows for 1e308
    if longest > MAX_GRID_SIDE or max(max(size) for size in out) > MAX_GRID_SIDE:
        raise InputError(f"`factors` {','.join(f'{f:g}' for f in factors)} make a level longer than {MAX_GRID_SIDE} "
                         f"voxels, the most a sample may have per axis", "factors")
    return out


def adaptive_pool(volume: np.ndarray, bins: int) -> list:
    """Average-pool a (X, Y, Z) volume into `bins` slabs along each plane's
    dropped axis: [(bins, X, Y), (bins, X, Z), (bins, Y, Z)].

    Bin k of n covers floor(k n / bins) .. ceil((k + 1) n / bins), as torch's
    adaptive average pooling does (bins may overlap when n is not a multiple).
    """

    def pool(axis):
        n = volume.shape[axis]
        k = np.arange(bins)
        start, end = (k * n) // bins, -((-(k + 1) * n) // bins)
        cumsum = np.concatenate([np.zeros_like(np.take(volume, [0], axis)),
                                 np.cumsum(volume, axis=axis, dtype=np.float64)], axis=axis)
        sums = np.take(cumsum, end, axis) - np.take(cumsum, start, axis)
        shape = [1, 1, 1]
        shape[axis] = bins
        return (sums / (end - start).reshape(shape)).astype(np.float32)

    return [np.moveaxis(pool(axis), axis, 0) for axis in (2, 1, 0)]


def resize_matrix(n_in: int, n_out: int, dtype=np.float32) -> np.ndarray:
    """(n_out, n_in) linear interpolation weights, align_corners=True."""
    weights = np.zeros((n_out, n_in), dtype)
    src = np.arange(n_out) * ((n_in - 1) / (n_out - 1)) if n_out > 1 else np.zeros(1)
    low = np.minimum(np.floor(src).astype(int), n_in - 1)
    high = np.minimum(low + 1, n_in - 1)
    frac = (src - low).astype(dtype)
    rows = np.arange(n_out)
    np.add.at(weights, (rows, low), 1 - frac)
    np.add.at(weights, (rows, high), frac)
    return weights


def resize_volume(volume: np.ndarray, shape) -> np.ndarray:
    """Trilinear resize (align_corners=True) of an (X, Y, Z) volume to `shape`, float32.

    Computed in float64, so that a value of exactly 0.5 stays 0.5:
    evaluation's upsampling baseline thresholds at 0.5 and decides such ties
    the same way on every machine.
    """
    out = np.asarray(volume, dtype=np.float64)
    for axis, n in enumerate(shape):
        out = np.moveaxis(np.tensordot(resize_matrix(out.shape[axis], n, np.float64), out, axes=(1, axis)), 0, axis)
    return out.astype(np.float32)


@dataclass(frozen=True)
class Taps:
    """Linear interpolation (align_corners=True) along one axis: each output
    point's two coarse neighbours and their weights."""

    low: np.ndarray
    high: np.ndarray
    w_low: np.ndarray  # float32
    w_high: np.ndarray

    @classmethod
    def of(cls, n_in: int, n_out: int) -> "Taps":
        src = np.arange(n_out) * ((n_in - 1) / (n_out - 1)) if n_out > 1 else np.zeros(1)
        low = np.minimum(np.floor(src).astype(np.intp), n_in - 1)
        frac = (src - low).astype(np.float32)
        return cls(low, np.minimum(low + 1, n_in - 1), np.float32(1) - frac, frac)

    def take(self, index) -> "Taps":
        """The taps of the points `index` selects."""
        return Taps(self.low[index], self.high[index], self.w_low[index], self.w_high[index])

    def apply(self, values: np.ndarray, axis: int) -> np.ndarray:
        """`values` (float32) interpolated along `axis` to these points, in
        float32: each product and the sum rounded alone (the band search's)."""
        shape = [1] * values.ndim
        shape[axis] = -1
        low, high = np.take(values, self.low, axis), np.take(values, self.high, axis)
        low *= self.w_low.reshape(shape)
        high *= self.w_high.reshape(shape)
        low += high
        return low

    def sum64(self, values: np.ndarray, axis: int) -> np.ndarray:
        """`values` interpolated along `axis` to these points, each point's two
        products (exact in float64 for float32 values and weights) summed in
        float64: float64 (what the browser runtime computes)."""
        shape = [1] * values.ndim
        shape[axis] = -1
        low = np.take(values, self.low, axis).astype(np.float64)
        low *= self.w_low.reshape(shape)
        high = np.take(values, self.high, axis).astype(np.float64)
        high *= self.w_high.reshape(shape)
        low += high
        return low


RESIZE_CHUNK = 1 << 20  # plane values resized at once


def resize_plane(plane: np.ndarray, size) -> np.ndarray:
    """Bilinear resize (align_corners=True) of a (C, H, W) plane to `size`:
    along H, then W, each point from its two neighbours (`Taps`), summed in
    float64 and rounded to float32, as the browser runtime does. Not a
    matrix product: BLAS orders and fuses its sums by its version and the
    CPU it finds, and a seed must give the same planes with any numpy on
    any machine."""
    h, w = size
    if plane.shape[1:] == (h, w):
        return plane
    rows, cols = Taps.of(plane.shape[1], h), Taps.of(plane.shape[2], w)
    out = np.empty((plane.shape[0], h, w), np.float32)
    step = max(1, RESIZE_CHUNK // (max(plane.shape[1], h) * max(plane.shape[2], w)))
    for c in range(0, plane.shape[0], step):  # channels a few at a time: the float64 sums stay small
        out[c:c + step] = cols.sum64(rows.sum64(plane[c:c + step], 1).astype(np.float32), 2)
    return out


@dataclass
class TriPlane:
    """A generated tri-plane: 3 x (C, H, W) float32 planes (xy, xz, yz)
    spanning a grid of `size` (X, Y, Z) finest-level voxels. A composed one
    (edit.compose) holds its parts as `kept`: (low, high, the part's own
    TriPlane placed on this grid), so that deep in a kept box the colour is
    the part's own."""

    planes: list
    size: tuple
    kept: tuple = ()


@dataclass
class Noise:
    """The noise of one sample, unscaled (std 1).

    z0 : (X, Y, Z) at the coarsest level; planes[i] : 3 x (C, H, W) for
    level i > 0, or None for no noise (planes[0] is always None).
    """

    z0: np.ndarray
    planes: list


def draw_noise(seed: int, sizes: list, channels: int, first: int = 0) -> Noise:
    """The noise a seed stands for, at the given level sizes, from level
    `first` on (a chain resumed past level 0 needs none before it: None)."""
    planes = [None] + [
        [noise.plane_noise(seed, level, k, channels, shape) for k, shape in enumerate(plane_sizes(size))]
        if level >= first else None
        for level, size in enumerate(sizes) if level > 0
    ]
    return Noise(noise.z0_noise(seed, sizes[0]) if first == 0 else None, planes)


def triplane(model, sample: Noise, sizes: list, after_level=None, start: tuple | None = None) -> TriPlane:
    """Chain the levels with the given noise: the final tri-plane.
    `after_level(level, planes)`, if given, sees each level's planes and
    returns the planes the chain goes on from (editing blends parts in).
    `start` (level, planes): that level's planes, made before, to go on
    from (a world's window made finer): the same planes as from level 0."""
    m = model.manifest
    amps = m.noise_amps
    after_level = after_level or (lambda level, planes: planes)
    if start is None:
        pooled = adaptive_pool(amps[0] * sample.z0, m.pool_bins)
        projected = model.projection.run([p[None] for p in pooled])  # 3 x (1, C, H, W)
        first, planes = 1, after_level(0, [p[0] for p in model.levels[0].run(projected)])
    else:
        first, planes = start[0] + 1, start[1]
    for level in range(first, len(sizes)):
        upsampled = [resize_plane(p, s) for p, s in zip(planes, plane_sizes(sizes[level]))]
        inputs = upsampled
        if sample.planes[level] is not None:
            inputs = [u + amps[level] * n for u, n in zip(upsampled, sample.planes[level])]
        residuals = model.levels[level].run([x[None] for x in inputs])
        planes = after_level(level, [u + r[0] for u, r in zip(upsampled, residuals)])
    if not all(np.isfinite(p).all() for p in planes):  # weights that pass the load checks and still overflow
        raise InputError(f"{model.path}: the model gives NaN or infinite values for this sample (unusable weights)")
    return TriPlane(planes, tuple(sizes[-1]))


def chain(model, sample: Noise, sizes: list) -> list:
    """Every level's planes of one sample, coarsest first."""
    levels = []

    def keep(level, planes):
        levels.append(planes)
        return planes

    triplane(model, sample, sizes, after_level=keep)
    return levels


def reconstruction_noise(model, sizes: list) -> Noise:
    """z0* from the manifest's seed and no later noise: the training shape."""
    m = model.manifest
    return Noise(noise.z0_noise(m.recon_seed, sizes[0]), [None] * len(sizes))


# Bytes per value of the largest level's tri-plane while the chain runs
# there: the noise of every level, the upsampled planes, the noisy input,
# onnxruntime's activations and the residuals. Measured at its peak: 40 to
# 46 (towerruins at 4x4x4 to 16x16x16, terrain at 8x8x8).
CHAIN_BYTES_PER_VALUE = 52


def generation_memory(sizes: list, channels: int) -> int:
    """Bytes a sample's chain needs at its peak: z0 and its float64
    pooling sums, and the largest level's work (CHAIN_BYTES_PER_VALUE)."""
    z0 = math.prod(sizes[0]) * 16  # exact: numpy's int64 product wrapped round for huge sizes
    return z0 + max(triplane_values(size, channels) for size in sizes) * CHAIN_BYTES_PER_VALUE


def triplane_values(size, channels: int) -> int:
    """Values in the tri-plane of a grid of `size`: 3 planes of `channels`."""
    return sum(h * w for h, w in plane_sizes(size)) * channels


def check_generation_memory(sizes: list, channels: int, factors, limit: int | None = None) -> None:
    check_memory(generation_memory(sizes, channels), f"a sample of size {'x'.join(f'{f:g}' for f in factors)}",
                 limit)


def check_seed(seed: int) -> int:
    if not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise InputError(f"`seed` must be an integer in [0, 2**63), got {seed}", "seed")
    return int(seed)


def sample(model, seed: int | None = None, factors=(1.0, 1.0, 1.0), memory_limit: int | None = None) -> TriPlane:
    """The tri-plane of one sample: a seed, or None for the training shape.

    factors scale the training size per axis (any size and aspect ratio).
    Work needing more than memory_limit bytes (None: the memory available
    now) is refused up front with MemoryLimitError.
    """
    sizes = scaled_sizes(model.manifest.sizes, factors)
    check_generation_memory(sizes, model.manifest.channels, factors, memory_limit)
    if seed is None:
        if sizes != [tuple(s) for s in model.manifest.sizes]:
            raise InputError("the reconstruction exists only at the training size; drop `factors`", "factors")
        return triplane(model, reconstruction_noise(model, sizes), sizes)
    return triplane(model, draw_noise(check_seed(seed), sizes, model.manifest.channels), sizes)


def check_alpha(alpha: float) -> None:
    if not (isinstance(alpha, numbers.Real) and -MAX_ALPHA <= alpha <= MAX_ALPHA):
        raise InputError(f"`alpha` must be a number in [-{MAX_ALPHA}, {MAX_ALPHA}], got {alpha}", "alpha")


def blend_weights(low: float, high: float, steps: int):
    """alpha(k): the blend weight of shape k of `steps`, evenly spaced from
    low to high (the last exactly high), both checked first. A function, not
    a list, so that any number of steps costs nothing up front."""
    check_alpha(low)
    check_alpha(high)
    return lambda k: high if 0 < k == steps - 1 else low + k * (high - low) / max(steps - 1, 1)


def interpolate(model, seed_a: int, seed_b: int, alpha: float, factors=(1.0, 1.0, 1.0),
                memory_limit: int | None = None) -> TriPlane:
    """Blend two samples: z0 = (1 - alpha) z0_A + alpha z0_B, later noise of seed A held fixed.

    alpha outside [0, 1] extrapolates (the paper shows -0.5 .. 1.5) up to
    MAX_ALPHA; memory_limit as for `sample`.
    """
    check_alpha(alpha)
    sizes = scaled_sizes(model.manifest.sizes, factors)
    check_generation_memory(sizes, model.manifest.channels, factors, memory_limit)
    a = draw_noise(check_seed(seed_a), sizes, model.manifest.channels)
    z0_b = noise.z0_noise(check_seed(seed_b), sizes[0])
    return triplane(model, Noise((1 - alpha) * a.z0 + alpha * z0_b, a.planes), sizes)
