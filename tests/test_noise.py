"""The counter-based noise: exact integer stream, fixed transform, tileable."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sinshape.core import noise

MASK = (1 << 64) - 1


def reference_normal(seed, stream, position):
    """docs/FORMAT.md's recipe, one value at a time in plain Python."""

    def mix(z):
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        return z ^ (z >> 31)

    key = 0
    for value in (seed, *stream):
        key = mix((key + 0x9E3779B97F4A7C15 * (value + 1)) & MASK)
    p = (0,) * (3 - len(position)) + tuple(position)
    n = (p[0] << 42) | (p[1] << 21) | p[2]
    h = mix((key + 0x9E3779B97F4A7C15 * (n + 1)) & MASK)
    u1 = ((h >> 32) + 0.5) / 2**32
    u2 = (h & 0xFFFFFFFF) / 2**32
    return math.sqrt(-2 * math.log(u1)) * math.cos(2 * math.pi * u2)


def test_bits_are_splitmix64():
    # Published SplitMix64 outputs for state 1234567 (Vigna's reference code).
    expected = [6457827717110365317, 3203168211198807973, 9817491932198370423,
                4593380528125082431, 16408922859458223821]
    assert noise.bits(1234567, np.arange(5, dtype=np.uint64)).tolist() == expected


def test_vectorised_noise_follows_the_written_recipe():
    z0 = noise.z0_noise(42, (5, 4, 3))
    for position in [(0, 0, 0), (4, 3, 2), (2, 1, 0), (1, 3, 2)]:
        assert z0[position] == pytest.approx(reference_normal(42, (0,), position), abs=1e-6)
    planes = noise.plane_noise(7, 3, 2, 4, (6, 5))
    for c, i, j in [(0, 0, 0), (3, 5, 4), (2, 1, 3)]:
        assert planes[c, i, j] == pytest.approx(reference_normal(7, (1, 3, 2, c), (i, j)), abs=1e-6)


def test_committed_vectors():
    """The values other implementations must reproduce (docs/FORMAT.md)."""
    vectors = json.loads((Path(__file__).parent / "data" / "noise_vectors.json").read_text())
    assert len(vectors) >= 5
    for v in vectors:
        block = noise.normal(v["seed"], tuple(v["stream"]), [1] * len(v["position"]), v["position"])
        assert block.item() == pytest.approx(v["normal"], abs=1e-6)
        assert f"{int(block.view(np.uint32).item()):08x}" == v["float32_bits"]  # bit for bit


def test_tiles_equal_slices_of_the_whole():
    whole = noise.normal(5, (1, 2, 0, 9), (40, 30))
    tile = noise.normal(5, (1, 2, 0, 9), (7, 11), offset=(20, 13))
    np.testing.assert_array_equal(tile, whole[20:27, 13:24])


def test_seeds_streams_and_statistics():
    a = noise.z0_noise(0, (32, 32, 32))
    assert not np.array_equal(a, noise.z0_noise(1, (32, 32, 32)))
    assert not np.array_equal(noise.plane_noise(0, 1, 0, 1, (8, 8)), noise.plane_noise(0, 1, 1, 1, (8, 8)))
    assert abs(a.mean()) < 0.02 and abs(a.std() - 1) < 0.02
    # Neighbouring values are independent: no correlation along any axis.
    for axis in range(3):
        lagged = np.corrcoef(np.take(a, range(31), axis).ravel(), np.take(a, range(1, 32), axis).ravel())[0, 1]
        assert abs(lagged) < 0.02


def test_bad_positions_and_seeds_are_refused():
    with pytest.raises(ValueError):
        noise.normal(-1, (0,), (2, 2))
    with pytest.raises(ValueError):
        noise.normal(0, (0,), (2, 2), offset=(2**21, 0))
