"""Deterministic procedural example shapes: terrain, acropolis, stairs, wall,
cheese, and painted_terrain, the terrain with vertex colours.

The shipped demo models and the tests need example shapes that anyone can
regenerate bit for bit, without downloading meshes. Each shape is a function
of a `seed` and a `detail` knob (its size or resolution; small values make
small, fast versions for tests) and returns a closed, consistently oriented
trimesh.

Every shape is built the same way: a signed distance field (negative inside)
is sampled on a regular grid by combining primitives (union = min, cut =
max with the negated primitive), and marching cubes extracts its zero level.
The grid is padded with outside values, so the surface is closed by
construction, and unions and holes need no mesh booleans (trimesh's need an
external engine). Units are arbitrary; each shape's longest side is a few
units.

numpy, scikit-image and trimesh only: no torch.
"""

from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from skimage import measure

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import MESH_FORMATS, atomic_write

from . import textured

# Grid points farther than MARGIN voxels outside a primitive's bounding box
# are left alone: its distance there exceeds MARGIN voxels, so it cannot
# change the sign of the field or the values next to the surface, which are
# all that marching cubes reads. FAR is the field before anything is added.
MARGIN = 2
FAR = 1e3
# Peak bytes per grid point of making a shape (the float64 field, its padded
# copy, marching cubes' work and its mesh): 26 to 56 measured over the five
# shapes, terrain at detail 1000 (150M points) included (docs/RELIABILITY.md).
BYTES_PER_POINT = 64
# Every shape's grid grows as detail^2 or detail^3, so far below this any
# detail is refused by the memory check; the cap only keeps the per-element
# lists that some shapes draw before their grid from growing unchecked.
MAX_DETAIL = 100_000


def _box_distance(*q):
    """Signed distance to a box (or rectangle) from per-axis offsets q = |p - centre| - half size."""
    outside = np.sqrt(sum(np.maximum(a, 0.0) ** 2 for a in q))
    inside = np.minimum(np.maximum.reduce(np.broadcast_arrays(*q)), 0.0)
    return outside + inside


def _box_sdf(p, lo, hi):
    """Signed distance from points p = (x, y, z) to the box from corner `lo` to corner `hi`."""
    return _box_distance(*(np.abs(c - (a + b) / 2) - (b - a) / 2 for c, a, b in zip(p, lo, hi)))


class _Solid:
    """A signed distance field sampled on a grid, built from primitives.

    Each primitive is evaluated only on the grid points near its bounding
    box (see MARGIN), which keeps shapes made of hundreds of stones fast.

    Parts meant to fuse must overlap, not just touch: on a face two parts
    share, the min of their distances is ~0 even inside the union, and
    marching cubes notches the surface along the seam.
    """

    def __init__(self, lo, hi, step: float):
        self.step = step
        self.origin = np.asarray(lo, float) - MARGIN * step
        shape = np.ceil((np.asarray(hi, float) - lo) / step).astype(int) + 2 * MARGIN + 1
        check_memory(BYTES_PER_POINT * int(np.prod(shape)),
                     f"a shape on a {'x'.join(map(str, shape))} grid (its detail)")
        self.field = np.full(shape, FAR)

    def apply(self, lo, hi, sdf: Callable, cut: bool = False) -> None:
        """Union (or, if `cut`, subtract) the solid sdf(x, y, z) < 0 that lies within [lo, hi].

        sdf gets broadcastable coordinates x : (a, 1, 1), y : (1, b, 1),
        z : (1, 1, c) and returns (a, b, c) distances.
        """
        first = np.floor((np.asarray(lo) - self.origin) / self.step).astype(int) - MARGIN
        last = np.ceil((np.asarray(hi) - self.origin) / self.step).astype(int) + MARGIN + 1
        first, last = np.clip(first, 0, self.field.shape), np.clip(last, 0, self.field.shape)
        region = tuple(slice(a, b) for a, b in zip(first, last))
        coords = [
            (self.origin[i] + self.step * np.arange(first[i], last[i])).reshape([-1 if j == i else 1 for j in range(3)])
            for i in range(3)
        ]
        d = np.broadcast_to(sdf(*coords), self.field[region].shape)
        if cut:
            np.maximum(self.field[region], -d, out=self.field[region])
        else:
            np.minimum(self.field[region], d, out=self.field[region])

    def box(self, lo, hi, radius: float = 0.0) -> None:
        """An axis-aligned box from corner `lo` to corner `hi`, edges rounded by `radius`."""
        inner_lo, inner_hi = np.add(lo, radius), np.subtract(hi, radius)
        self.apply(lo, hi, lambda *p: _box_sdf(p, inner_lo, inner_hi) - radius)

    def cylinder(self, x: float, y: float, radius: float, z0: float, z1: float, slant=(0.0, 0.0)) -> None:
        """A vertical cylinder around (x, y) from height z0 up to a plane through (x, y, z1) of slope `slant`."""
        slant = np.asarray(slant, float)
        peak = z1 + radius * np.hypot(*slant)  # the plane's highest point over the disc
        self.apply(
            (x - radius, y - radius, z0),
            (x + radius, y + radius, peak),
            lambda px, py, pz: np.maximum(
                _box_distance(np.hypot(px - x, py - y) - radius, np.abs(pz - (z0 + peak) / 2) - (peak - z0) / 2),
                (pz - z1 - slant[0] * (px - x) - slant[1] * (py - y)) / np.sqrt(1 + slant @ slant),
            ),
        )

    def sphere(self, centre, radius: float, cut: bool = False) -> None:
        """A ball, or with `cut` a spherical hole."""
        c = np.asarray(centre, float)
        self.apply(c - radius, c + radius, lambda *p: np.sqrt(sum((p[i] - c[i]) ** 2 for i in range(3))) - radius, cut)

    def capsule(self, a, b, radius: float) -> None:
        """A rod of `radius` around the segment a-b, with round ends."""
        a, ab = np.asarray(a, float), np.subtract(b, a)

        def sdf(*p):
            ap = [p[i] - a[i] for i in range(3)]
            t = np.clip(sum(ap[i] * ab[i] for i in range(3)) / ab.dot(ab), 0.0, 1.0)
            return np.sqrt(sum((ap[i] - t * ab[i]) ** 2 for i in range(3))) - radius

        self.apply(np.minimum(a, b) - radius, np.maximum(a, b) + radius, sdf)

    def mesh(self) -> trimesh.Trimesh:
        """The zero level as a closed mesh, outward normals."""
        field = np.pad(self.field, 1, constant_values=FAR)
        # A sample exactly on the surface makes marching cubes emit several
        # vertices at one grid point, and merging them leaves degenerate
        # faces: move such samples a hair inside.
        eps = 1e-3 * self.step
        field[np.abs(field) < eps] = -eps
        verts, faces, _, _ = measure.marching_cubes(field, 0.0, spacing=(self.step,) * 3)
        # 'descent' (the default) orients faces towards decreasing values: outwards.
        return trimesh.Trimesh(verts + self.origin - self.step, faces)


def _gradient_noise(rng, x, y, frequency: float, extent) -> np.ndarray:
    """Perlin gradient noise, about [-1, 1], at points in [0, extent[0]] x [0, extent[1]].

    The lattice is drawn for the whole extent, independently of the points,
    so a seed gives the same landscape at every resolution.
    """
    lattice = rng.uniform(0, 2 * np.pi, (int(extent[0] * frequency) + 2, int(extent[1] * frequency) + 2))
    u, v = np.clip(x, 0, extent[0]) * frequency, np.clip(y, 0, extent[1]) * frequency
    i, j = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = u - i, v - j

    def corner(di, dj):
        angle = lattice[i + di, j + dj]
        return np.cos(angle) * (fu - di) + np.sin(angle) * (fv - dj)

    def fade(a):  # 6a^5 - 15a^4 + 10a^3: smooth blending, no creases at cell edges
        return a**3 * (a * (6 * a - 15) + 10)

    s, t = fade(fu), fade(fv)
    bottom = corner(0, 0) + s * (corner(1, 0) - corner(0, 0))
    top = corner(0, 1) + s * (corner(1, 1) - corner(0, 1))
    return np.sqrt(2) * (bottom + t * (top - bottom))  # unit gradients reach at most sqrt(1/2)


def terrain(seed: int = 0, detail: int = 128) -> trimesh.Trimesh:
    """A 8 x 5 terrain block with ridges and valleys; `detail` = grid samples along its length.

    Heights are ridged multi-octave gradient noise (1 - |noise| peaks in a
    sharp crest where the noise changes sign) scaled by a smooth noise, so
    that some regions are mountain ranges and others low valleys. The solid
    is everything below the height field within the block: vertical sides,
    flat bottom.
    """
    rng = np.random.default_rng(seed)
    extent, base, relief = (8.0, 5.0), 0.25, 1.6

    def heights(x, y):  # called once: each call draws new noise lattices
        # Ridged multifractal: each octave is weighted by the one below it,
        # so fine detail gathers on the crests and valleys stay smooth.
        ridges, weight = 0.0, 1.0
        for octave in range(5):
            signal = weight * (1 - np.abs(_gradient_noise(rng, x, y, 0.3 * 2**octave, extent))) ** 2
            ridges = ridges + 0.5**octave * signal
            weight = np.clip(2 * signal, 0, 1)
        uplift = 0.5 + 0.5 * _gradient_noise(rng, x, y, 0.15, extent)
        return base + relief * ridges / 1.6 * (0.25 + 0.75 * uplift)

    size = (*extent, base + relief)
    solid = _Solid((0, 0, 0), size, extent[0] / detail)
    # z - height is not a distance across steep slopes, but its zero level is
    # the surface, and this one primitive covers the whole grid (see MARGIN).
    solid.apply((0, 0, 0), size, lambda x, y, z: np.maximum(z - heights(x, y), _box_sdf((x, y, z), (0, 0, 0), size)))
    return solid.mesh()


# painted_terrain's colours, sRGB: grass on gentle low ground, rock on
# slopes (and the block's sides and bottom), snow on high gentle ground.
GRASS, ROCK, SNOW = (0.28, 0.46, 0.16), (0.45, 0.41, 0.37), (0.94, 0.95, 0.97)


def _smoothstep(low: float, high: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - low) / (high - low), 0, 1)
    return t * t * (3 - 2 * t)


def painted_terrain(seed: int = 0, detail: int = 128) -> trimesh.Trimesh:
    """`terrain` with per-vertex colours by height and slope: grass below,
    rock where the ground is steep, snow on the tops. An example with colour
    that anyone can make, free of any licence."""
    mesh = terrain(seed, detail)
    up = mesh.vertex_normals[:, 2]  # 1 on flat ground, 0 on a cliff, -1 underneath
    height = (mesh.vertices[:, 2] - mesh.vertices[:, 2].min()) / np.ptp(mesh.vertices[:, 2])
    rock = 1 - _smoothstep(0.5, 0.65, up)
    snow = _smoothstep(0.6, 0.7, height) * (1 - rock)
    rgb = (np.array(GRASS) * (1 - rock - snow)[:, None] + np.array(ROCK) * rock[:, None]
           + np.array(SNOW) * snow[:, None])
    colours = np.concatenate([np.round(rgb * 255), np.full((len(rgb), 1), 255)], axis=1).astype(np.uint8)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colours, process=False)


def acropolis(seed: int = 0, detail: int = 8) -> trimesh.Trimesh:
    """A ruined colonnade: `detail` columns along the long side, about half as many across.

    A three-step platform carries a ring of columns (base disc, shaft,
    square capital) under an architrave slab and a gabled roof. A quarter of
    the non-corner columns (at least one) are missing or broken off at a
    slant; the corners stay, so the roof still reads as held up.
    """
    rng = np.random.default_rng(seed)
    spacing, radius, height, rise = 0.7, 0.14, 2.0, 0.15
    across = max(2, round(detail / 2))
    xs, ys = spacing * np.arange(detail), spacing * np.arange(across)
    lo, hi = np.array([xs[0], ys[0]]) - 0.4, np.array([xs[-1], ys[-1]]) + 0.4  # the top step
    floor, top = 3 * rise, 3 * rise + height
    solid = _Solid((*lo - 0.4, 0), (*hi + 0.4, top + 0.8), 0.045)
    for k in range(3):  # steps, widest at the bottom
        solid.box((*lo - 0.2 * (2 - k), 0), (*hi + 0.2 * (2 - k), rise * (k + 1)))

    ring = [(x, y) for x in xs for y in ys if x in (xs[0], xs[-1]) or y in (ys[0], ys[-1])]
    inner = [i for i, (x, y) in enumerate(ring) if x not in (xs[0], xs[-1]) or y not in (ys[0], ys[-1])]
    damaged = rng.choice(inner, (len(inner) + 3) // 4, replace=False)  # a quarter, at least one
    for i, (x, y) in enumerate(ring):
        if i not in damaged:
            _column(solid, x, y, radius, floor, top)
        elif rng.random() < 2 / 3:  # broken, else missing
            _column(solid, x, y, radius, floor, floor + rng.uniform(0.2, 0.6) * height, slant=rng.uniform(-0.6, 0.6, 2))

    # Architrave and gabled roof in one piece: a box whose top is cut by two
    # slopes meeting in a ridge along x. It reaches down into the capitals.
    roof_lo, roof_hi = (*lo + 0.1, top - 0.05), (*hi - 0.1, top + 0.8)
    eaves, middle, half = top + 0.3, (lo[1] + hi[1]) / 2, (hi[1] - lo[1]) / 2 - 0.1
    pitch = roof_hi[2] - eaves
    solid.apply(
        roof_lo,
        roof_hi,
        lambda x, y, z: np.maximum(
            _box_sdf((x, y, z), roof_lo, roof_hi),
            (pitch * (np.abs(y - middle) - half) + half * (z - eaves)) / np.hypot(pitch, half),  # the slopes
        ),
    )
    return solid.mesh()


def _column(solid: _Solid, x: float, y: float, radius: float, floor: float, top: float, slant=None) -> None:
    """A column from `floor` to `top`: base disc, shaft and square capital.

    With a `slant` (dz/dx, dz/dy) it is broken off: the shaft ends in a
    slanted plane through (x, y, top), without a capital. The parts overlap
    each other and reach 0.05 into the floor, so that they fuse.
    """
    solid.cylinder(x, y, 1.3 * radius, floor - 0.05, floor + 0.08)
    if slant is not None:
        solid.cylinder(x, y, radius, floor - 0.05, top, slant)
        return
    solid.cylinder(x, y, radius, floor - 0.05, top - 0.05)
    solid.cylinder(x, y, 1.25 * radius, top - 0.2, top - 0.05)
    solid.box((x - 1.5 * radius, y - 1.5 * radius, top - 0.1), (x + 1.5 * radius, y + 1.5 * radius, top))


def stairs(seed: int = 0, detail: int = 16) -> trimesh.Trimesh:
    """A straight flight of `detail` steps with a landing, a side wall and a railing.

    The steps are solid down to the ground. The wall on one side steps up
    with them; on the other side posts on every second step carry a
    handrail. Seeded: where the landing breaks the flight, and which posts
    (with the rail on either side of them) have fallen.
    """
    rng = np.random.default_rng(seed)
    run, rise, width, wall, landing = 0.28, 0.18, 1.35, 0.15, 1.0
    above = 0.9  # wall and rail height above the treads
    landing_step = rng.integers(max(1, detail // 3), max(2, detail - detail // 3))
    depths = np.where(np.arange(detail) == landing_step, landing, run)
    starts = np.concatenate([[0.0], np.cumsum(depths)[:-1]])
    tops = rise * np.arange(1, detail + 1)
    end = starts[-1] + depths[-1]
    solid = _Solid((0, 0, 0), (end, width, tops[-1] + above + 0.05), 0.03)
    # Each step and its piece of wall run to the end of the flight, so that
    # neighbours overlap (see _Solid); the wall stands on the steps' far edge.
    for x, top in zip(starts, tops):
        solid.box((x, 0, 0), (end, width, top))
        solid.box((x, width - wall, 0), (end, width, top + above))

    posts = [(x + depth / 2, 0.1, top + above) for x, depth, top in list(zip(starts, depths, tops))[::2]]
    standing = rng.random(len(posts)) > 0.2
    for (x, y, z), up in zip(posts, standing):
        if up:
            solid.cylinder(x, y, 0.05, z - above - 0.1, z)
    for a, b, up in zip(posts, posts[1:], standing[:-1] & standing[1:]):
        if up:
            solid.capsule(a, b, 0.04)
    return solid.mesh()


def wall(seed: int = 0, detail: int = 12) -> trimesh.Trimesh:
    """A ruined stone wall, `detail` stones long: rows of jittered stones, some top ones gone.

    Stones are rounded boxes that overlap their neighbours by a hair (see
    _Solid), so the wall is one solid and the rounded edges leave a groove
    at every joint. Each row has its own height and random stone widths, so
    joints do not line up, and each stone sticks out of the wall faces by
    its own amount. About a third of the top row is missing; the rest of it
    is weathered down a little.
    """
    rng = np.random.default_rng(seed)
    length, thickness, overlap = 0.5 * detail, 0.45, 0.01
    heights = rng.uniform(0.24, 0.34, max(3, round(0.4 * detail)))
    floors = np.concatenate([[0.0], np.cumsum(heights)])
    solid = _Solid((0, -0.03, 0), (length, thickness + 0.03, floors[-1]), 0.02)
    for row, (z0, z1) in enumerate(zip(floors, floors[1:])):
        widths = rng.uniform(0.3, 0.7, int(length / 0.3) + 1)  # enough to fill the row
        widths = widths[: np.searchsorted(np.cumsum(widths), length) + 1]
        ends = np.concatenate([[0.0], np.cumsum(widths) * length / widths.sum()])
        top_row = row == len(heights) - 1
        gone = rng.random(len(widths)) < (0.35 if top_row else 0.0)
        if top_row and not gone.any():
            gone[rng.integers(len(widths))] = True
        for x0, x1, missing in zip(ends, ends[1:], gone):
            front, back = rng.uniform(-0.03, 0.03, 2)
            top = z1 - rng.uniform(0, 0.1) if top_row else z1
            if not missing:
                lo, hi = (x0 - overlap, -front, z0 - overlap), (x1 + overlap, thickness + back, top + overlap)
                solid.box(lo, hi, radius=0.06)
    return solid.mesh()


def cheese(seed: int = 0, detail: int = 112) -> trimesh.Trimesh:
    """A 4 x 2.6 x 1.8 block of cheese with round holes; `detail` = grid samples along its length.

    Hole centres are uniform in the block, so holes near the faces open
    onto the surface. Radii are skewed towards small ones, as in real cheese.
    """
    rng = np.random.default_rng(seed)
    size = np.array([4.0, 2.6, 1.8])
    solid = _Solid((0, 0, 0), size, size[0] / detail)
    solid.box((0, 0, 0), size, radius=0.05)
    count = 70
    for centre, radius in zip(rng.uniform(0, size, (count, 3)), 0.08 + 0.32 * rng.random(count) ** 2):
        solid.sphere(centre, radius, cut=True)
    return solid.mesh()


def brick_ruin(seed: int = 0, detail: int = 16) -> trimesh.Trimesh:
    """A ruined brick enclosure with a 1024x768 brick texture (prep/textured.py)."""
    return textured.brick_ruin(seed, detail)


# relief_wall's joints between bricks and how far its bricks stand out of
# them (units): at res 48, about half a voxel along the wall, and (a thin
# wall's grid is finer across it) half a voxel across it.
MORTAR_GAP, RELIEF_DEPTH = 0.04, 0.012


def relief_wall(seed: int = 0, detail: int = 10) -> trimesh.Trimesh:
    """A straight ruined wall `detail` bricks long and one brick thick, whose
    bricks stand out RELIEF_DEPTH from recessed mortar on both faces, with
    MORTAR_GAP joints between them: running bond, broken down to uneven
    heights in half-brick steps, each brick its own red (vertex colours),
    the mortar pale. The detail an artist's brick wall has in its geometry,
    not only in its texture, and finer than a voxel at the usual training
    resolutions."""
    rng = np.random.default_rng(seed)
    length, thickness = detail * textured.BRICK_LENGTH, textured.BRICK_LENGTH
    course = textured.BRICK_LENGTH * textured.COURSE_PX / textured.BRICK_PX
    half = textured.BRICK_LENGTH / 2
    courses = max(4, round(detail * 1.2))
    columns = np.arange(2 * detail)  # half-brick columns: where the broken top steps
    profile = 0.65 + 0.35 * value_noise_1d(rng, columns / 6)
    tops = np.clip(np.round(courses * profile) - rng.integers(0, 3, len(columns)) * (rng.random(len(columns)) < 0.3),
                   2, courses).astype(int)
    solid = _Solid((0, 0, 0), (length, thickness, courses * course), step=MORTAR_GAP / 4)
    bricks = []  # (x0, x1, z0, z1) of each brick's face
    for k in range(courses):
        for x0 in np.arange(-(k % 2) * half, length, textured.BRICK_LENGTH):
            x0, x1 = max(x0, 0.0), min(x0 + textured.BRICK_LENGTH, length)
            cells = columns[(columns * half >= x0 - 1e-9) & (columns * half < x1 - 1e-9)]
            if not len(cells) or k >= tops[cells].min():
                continue
            z0, z1 = k * course, (k + 1) * course
            solid.box((x0, RELIEF_DEPTH, z0), (x1, thickness - RELIEF_DEPTH, z1 + (k + 1 < tops[cells].min()) * 1e-3))
            brick = (x0 + MORTAR_GAP / 2, x1 - MORTAR_GAP / 2, z0 + MORTAR_GAP / 2, z1 - MORTAR_GAP / 2)
            solid.box((brick[0], 0.0, brick[2]), (brick[1], thickness, brick[3]))
            bricks.append(brick)
    mesh = solid.mesh()
    bricks = np.array(bricks)
    reds = textured.BRICK_REDS[rng.integers(len(textured.BRICK_REDS), size=len(bricks))] * rng.uniform(0.9, 1.08, (len(bricks), 1))
    v = np.asarray(mesh.vertices)
    tolerance = solid.step
    on = ((v[:, None, 0] > bricks[None, :, 0] - tolerance) & (v[:, None, 0] < bricks[None, :, 1] + tolerance)
          & (v[:, None, 2] > bricks[None, :, 2] - tolerance) & (v[:, None, 2] < bricks[None, :, 3] + tolerance))
    brick_of = np.where(on.any(axis=1), on.argmax(axis=1), -1)
    # Out of the mortar's plane (or on a brick's own top or end): the brick's colour; in it, mortar.
    proud = (v[:, 1] < RELIEF_DEPTH - tolerance) | (v[:, 1] > thickness - RELIEF_DEPTH + tolerance)
    inside_face = (v[:, 1] > RELIEF_DEPTH + tolerance) & (v[:, 1] < thickness - RELIEF_DEPTH - tolerance)
    is_brick = (brick_of >= 0) & (proud | inside_face)
    rgb = np.where(is_brick[:, None], reds[np.maximum(brick_of, 0)], np.asarray(textured.MORTAR))
    rgb = np.clip(rgb + rng.normal(0, 0.02, rgb.shape), 0, 1)
    colours = np.concatenate([np.round(rgb * 255), np.full((len(rgb), 1), 255)], axis=1).astype(np.uint8)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colours, process=False)


def value_noise_1d(rng, t: np.ndarray) -> np.ndarray:
    """Smooth noise in [-1, 1] along a line (textured.value_noise on the x axis)."""
    return textured.value_noise(rng, np.stack([t, np.zeros_like(t), np.zeros_like(t)], 1).astype(float), 1.0)


def lichen_rock(seed: int = 0, detail: int = 5) -> trimesh.Trimesh:
    """A twisted rock with a 512x512 atlas of stone and lichen (prep/textured.py)."""
    return textured.lichen_rock(seed, detail)


SHAPES: dict[str, Callable[..., trimesh.Trimesh]] = {
    "terrain": terrain,
    "painted_terrain": painted_terrain,
    "acropolis": acropolis,
    "stairs": stairs,
    "wall": wall,
    "cheese": cheese,
    "brick_ruin": brick_ruin,
    "lichen_rock": lichen_rock,
    "relief_wall": relief_wall,
}
TEXTURED = ("brick_ruin", "lichen_rock")
TEXTURED_FORMATS = (".glb", ".obj")  # a textured shape keeps its texture in these (an .obj beside its .mtl and .png)


def make_shape(name: str, seed: int = 0, detail: int | None = None) -> trimesh.Trimesh:
    """The shape `name` for `seed`; `detail` None means the shape's demo default."""
    if name not in SHAPES:
        raise InputError(f"unknown shape {name!r}; known shapes: {', '.join(SHAPES)}")
    if seed < 0:
        raise InputError(f"shape seed must be non-negative, got {seed}")
    if detail is None:
        return SHAPES[name](seed)
    if not 2 <= detail <= MAX_DETAIL:
        raise InputError(f"shape `detail` must be in [2, {MAX_DETAIL}], got {detail}", "detail")
    return SHAPES[name](seed, detail)


def write_shape(name: str, path, seed: int = 0, detail: int | None = None) -> trimesh.Trimesh:
    """Make a shape and write it to `path`, in the format its suffix names
    (atomically, as every sample is written); returns the mesh. A textured
    shape is written as .glb (its texture inside) or .obj (beside it, a .mtl
    and a .png of the same stem)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise InputError(f"cannot write a mesh as {path.name!r}; use one of {', '.join(MESH_FORMATS)}")
    if name in SHAPES and name in TEXTURED and suffix not in TEXTURED_FORMATS:
        raise InputError(f"{name} is textured: write it as {' or '.join(TEXTURED_FORMATS)}, which keep its texture")
    mesh = make_shape(name, seed, detail)
    if name in TEXTURED and suffix == ".obj":
        mesh.visual.material.name = path.stem  # the .png is named for it
        text, files = trimesh.exchange.obj.export_obj(mesh, return_texture=True, mtl_name=f"{path.stem}.mtl")
        for file, data in files.items():  # the .mtl and the image it names
            atomic_write(path.parent / file, lambda f, data=data: f.write(data))
        atomic_write(path, lambda f: f.write(text.encode()))
        return mesh
    data = mesh.export(file_type=MESH_FORMATS[suffix])
    atomic_write(path, lambda f: f.write(data.encode() if isinstance(data, str) else data))
    return mesh
