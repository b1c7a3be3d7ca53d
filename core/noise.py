"""Counter-based Gaussian noise, so that a seed means the same shape everywhere.

numpy's `Generator` promises its stream only on the same numpy build and
machine (NEP 19), and a sequential stream ties a value to the order it was
drawn in. Here every noise value is a pure function of

    (seed, stream, position)

where `stream` names the array (z0, or one channel of one plane at one level)
and `position` is the value's integer index in that array. That makes noise
reproducible on any machine, with any numpy, in any language, and lets any
tile of a large array be drawn on its own.

The recipe (docs/FORMAT.md repeats it for other implementations):

1. Key: start from k = 0 and absorb the seed, then each stream id in turn:
   k = mix64(k + GOLDEN * (id + 1)).
2. Counter: n = (p0 << 42) | (p1 << 21) | p2 for position (p0, p1, p2);
   a 2-D position (p1, p2) has p0 = 0. Each coordinate is below 2**21.
3. Bits: h = mix64(k + GOLDEN * (n + 1)), i.e. the (n+1)-th output of
   SplitMix64 started at state k.
4. Normal (Box-Muller, cosine branch), in float64, then rounded to float32:
   u1 = ((h >> 32) + 0.5) / 2**32,  u2 = (h & 0xFFFFFFFF) / 2**32,
   z = sqrt(-2 ln u1) * cos(2 pi u2).

All arithmetic is on unsigned 64-bit integers, wrapping. Steps 1-3 are exact
everywhere; step 4 can differ in the last float64 bit between libm builds,
which reaches the float32 result with a probability of about 1e-9 per value.
"""

import numpy as np

GOLDEN = 0x9E3779B97F4A7C15
_MASK64 = (1 << 64) - 1
_COORD_BITS = 21

# Stream ids: the first id names what the noise is for.
Z0_STREAM = 0  # (Z0_STREAM,): the 3-D input noise z0 of the coarsest level
PLANE_STREAM = 1  # (PLANE_STREAM, level, plane, channel): noise added at a level


def mix64(z):
    """SplitMix64's finaliser: a bijection on uint64 that scrambles every bit.

    z : python int or uint64 array; returns the same kind.
    """
    if isinstance(z, int):
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
        return z ^ (z >> 31)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def stream_key(seed: int, *ids: int) -> int:
    """The 64-bit key of one noise array: the seed and stream ids absorbed."""
    key = 0
    for value in (seed, *ids):
        if not 0 <= value <= _MASK64:
            raise ValueError(f"noise seed and stream ids must be in [0, 2**64), got {value}")
        key = mix64((key + GOLDEN * (value + 1)) & _MASK64)
    return key


def counters(shape, offset=None) -> np.ndarray:
    """Counter n of every position in a block of a 2-D or 3-D array.

    shape : (2,) or (3,) int, the block's size; offset : same length, where the
    block starts in the whole array. Returns `shape` uint64.
    """
    offset = (0,) * len(shape) if offset is None else tuple(offset)
    if len(shape) not in (2, 3) or len(offset) != len(shape):
        raise ValueError(f"noise blocks are 2-D or 3-D, got shape {shape}, offset {offset}")
    if any(o < 0 or o + s > 1 << _COORD_BITS for s, o in zip(shape, offset)):
        raise ValueError(f"noise positions must be in [0, 2**{_COORD_BITS}) per axis")
    n = np.zeros((), np.uint64)
    for axis, (size, start) in enumerate(zip(shape, offset)):
        shift = np.uint64(_COORD_BITS * (len(shape) - 1 - axis))
        coord = np.arange(start, start + size, dtype=np.uint64) << shift
        n = n[..., None] | coord  # broadcasting appends one axis per loop
    return n


def bits(key: int, n: np.ndarray) -> np.ndarray:
    """The (n+1)-th SplitMix64 output from state `key`: uint64, shape of n."""
    with np.errstate(over="ignore"):
        return mix64(np.uint64(key) + np.uint64(GOLDEN) * (n + np.uint64(1)))


def bits_to_normal(h: np.ndarray) -> np.ndarray:
    """Box-Muller on the two 32-bit halves of each uint64: float32 normals."""
    u1 = ((h >> np.uint64(32)).astype(np.float64) + 0.5) / 2.0**32
    u2 = (h & np.uint64(0xFFFFFFFF)).astype(np.float64) / 2.0**32
    return (np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)).astype(np.float32)


# Positions drawn at once: Box-Muller's float64 temporaries (about 50 bytes
# a value) stay a few MB, so a large array costs its own 4 bytes a value.
CHUNK = 1 << 18


def normal(seed: int, stream: tuple, shape, offset=None) -> np.ndarray:
    """Standard normal noise of one stream over a block of positions.

    Returns `shape` float32; `offset` (default zeros) is where the block
    starts, so a tile equals the same slice of the whole array. Drawn a
    slab of rows at a time (the values are the same however it is cut).
    """
    key = stream_key(seed, *stream)
    shape = tuple(shape)
    offset = (0,) * len(shape) if offset is None else tuple(offset)
    out = np.empty(shape, np.float32)
    rows = max(1, CHUNK // max(1, int(np.prod(shape[1:], dtype=np.int64))))
    for start in range(0, shape[0], rows):
        block = (min(rows, shape[0] - start), *shape[1:])
        out[start:start + block[0]] = bits_to_normal(bits(key, counters(block, (offset[0] + start, *offset[1:]))))
    return out


def z0_noise(seed: int, shape) -> np.ndarray:
    """The coarsest level's 3-D input noise z0: (X, Y, Z) float32."""
    return normal(seed, (Z0_STREAM,), shape)


def plane_noise(seed: int, level: int, plane: int, channels: int, shape) -> np.ndarray:
    """Noise added to one plane at one level: (channels, H, W) float32."""
    out = np.empty((channels, *shape), np.float32)
    for c in range(channels):  # one stream a channel, drawn as `normal` draws it
        out[c] = normal(seed, (PLANE_STREAM, level, plane, c), shape)
    return out
