"""Textured example shapes, made by this project: a ruined brick enclosure
(a tiling 1024x768 brick texture on box-projected UVs) and a lichen-covered
rock (a 512x512 atlas baked from a solid stone-and-lichen pattern).

Textured assets are what artists bring: a mesh with UVs and a base-colour
image whose detail (a mortar line two texels wide) is far finer than any
training grid. These two stand for them in the tests and benchmarks and are
free of any licence: every pixel and vertex comes from a seed.

numpy, Pillow and trimesh only (no torch, no scipy).
"""

import numpy as np
import trimesh
from PIL import Image

# The brick texture: BRICK_PX x COURSE_PX per brick (its mortar included),
# BRICKS x COURSES of them in one tile of the image, which repeats.
BRICK_PX, COURSE_PX, MORTAR_PX = 64, 24, 2
BRICKS, COURSES = 16, 32
BRICK_LENGTH = 0.4  # units; a course is BRICK_LENGTH * COURSE_PX / BRICK_PX high
TEXTURE_UNITS = (BRICKS * BRICK_LENGTH, COURSES * BRICK_LENGTH * COURSE_PX / BRICK_PX)  # what one image covers
MORTAR = (0.74, 0.71, 0.65)
BRICK_REDS = np.array([(0.56, 0.23, 0.17), (0.63, 0.29, 0.20), (0.50, 0.21, 0.16), (0.68, 0.36, 0.26),
                       (0.45, 0.19, 0.15), (0.60, 0.33, 0.24)])
BURNT = (0.33, 0.16, 0.13)
STONE, LICHEN, LICHEN_PALE = (0.47, 0.46, 0.44), (0.40, 0.50, 0.17), (0.60, 0.63, 0.27)


def value_noise(rng, points: np.ndarray, frequency: float, lattice: int = 32) -> np.ndarray:
    """Smooth value noise in [-1, 1] at (n, 3) points, from a random lattice
    that repeats every `lattice` cells (far beyond the shapes here)."""
    values = rng.uniform(-1, 1, (lattice,) * 3)
    p = points * frequency
    cell = np.floor(p).astype(np.int64)
    f = p - cell
    f = f * f * f * (f * (6 * f - 15) + 10)
    out = 0.0
    for corner in np.ndindex(2, 2, 2):
        index = (cell + corner) % lattice
        weight = np.prod(np.where(corner, f, 1 - f), axis=1)
        out = out + weight * values[index[:, 0], index[:, 1], index[:, 2]]
    return out


def fbm(rng, points: np.ndarray, frequency: float, octaves: int = 4) -> np.ndarray:
    """Fractal sum of `octaves` of value noise, about [-1, 1]."""
    return sum(0.5**o * value_noise(rng, points, frequency * 2**o) for o in range(octaves)) / (2 - 0.5 ** (octaves - 1))


def brick_texture(seed: int = 0) -> np.ndarray:
    """The tiling brick image, (COURSES * COURSE_PX, BRICKS * BRICK_PX, 3) uint8:
    running bond, each brick its own red with grain and a darker rim, two-pixel
    pale mortar joints, and grime that is heavier low down."""
    rng = np.random.default_rng(seed)
    height, width = COURSES * COURSE_PX, BRICKS * BRICK_PX
    y, x = np.mgrid[0:height, 0:width]
    course = y // COURSE_PX
    shifted = (x + (course % 2) * (BRICK_PX // 2)) % width
    brick = course * BRICKS + shifted // BRICK_PX
    bx, by = shifted % BRICK_PX, y % COURSE_PX  # position inside the brick and its joint
    mortar = (bx < MORTAR_PX) | (by < MORTAR_PX)
    colours = BRICK_REDS[rng.integers(len(BRICK_REDS), size=COURSES * BRICKS)]
    burnt = rng.random(COURSES * BRICKS) < 0.06
    colours[burnt] = BURNT
    colours = colours * rng.uniform(0.9, 1.08, (COURSES * BRICKS, 1))
    image = colours[brick]
    rim = np.minimum(np.minimum(bx - MORTAR_PX, BRICK_PX - 1 - bx), np.minimum(by - MORTAR_PX, COURSE_PX - 1 - by))
    image = image * (1 - 0.12 * (rim < 2))[..., None]
    grain = rng.normal(0, 0.025, (height, width, 1)) + 0.03 * rng.normal(0, 1, (height // 4, width // 4, 1)).repeat(4, 0).repeat(4, 1)
    image = image + grain
    image[mortar] = np.asarray(MORTAR) + rng.normal(0, 0.02, (int(mortar.sum()), 1))
    texel = np.stack([x / width, y / height, np.zeros_like(x, dtype=float)], axis=-1).reshape(-1, 3)
    grime = 0.5 + 0.5 * fbm(rng, texel * np.array([1, 1, 0]), 6.0).reshape(height, width)
    image = image * (1 - 0.18 * grime * (y / height))[..., None]  # v grows upwards; the image's rows go down
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def cell_faces(filled: np.ndarray, origin, along: int, width: float, height: float, thickness: float):
    """Quads of an extruded 2-D grid of cells (columns along axis `along`,
    courses up z, `thickness` across): a front and back face per cell, and a
    side face wherever a neighbour cell is empty. Returns (corners (n, 4, 3),
    normals (n, 3)), corners counter-clockwise seen from outside."""
    across = 1 - along  # the other horizontal axis (x or y)
    quads, normals = [], []
    columns, courses = filled.shape
    padded = np.pad(filled, 1)
    for c, k in zip(*np.nonzero(filled)):
        a0, a1 = origin[along] + c * width, origin[along] + (c + 1) * width
        z0, z1 = k * height, (k + 1) * height
        t0, t1 = origin[across], origin[across] + thickness

        def point(a, t, z):
            p = [0.0, 0.0, z]
            p[along], p[across] = a, t
            return p

        def axis_normal(axis, sign):
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            return n

        faces = [  # (corners, normal, neighbour offset (dc, dk) or None for front and back)
            ([point(a0, t0, z0), point(a1, t0, z0), point(a1, t0, z1), point(a0, t0, z1)], axis_normal(across, -1), None),
            ([point(a1, t1, z0), point(a0, t1, z0), point(a0, t1, z1), point(a1, t1, z1)], axis_normal(across, 1), None),
            ([point(a0, t1, z0), point(a0, t0, z0), point(a0, t0, z1), point(a0, t1, z1)], axis_normal(along, -1), (-1, 0)),
            ([point(a1, t0, z0), point(a1, t1, z0), point(a1, t1, z1), point(a1, t0, z1)], axis_normal(along, 1), (1, 0)),
            ([point(a0, t0, z1), point(a1, t0, z1), point(a1, t1, z1), point(a0, t1, z1)], axis_normal(2, 1), (0, 1)),
            ([point(a0, t1, z0), point(a1, t1, z0), point(a1, t0, z0), point(a0, t0, z0)], axis_normal(2, -1), (0, -1)),
        ]
        for corners, normal, step in faces:
            if step is None or not padded[c + 1 + step[0], k + 1 + step[1]]:
                if np.dot(np.cross(np.subtract(corners[1], corners[0]), np.subtract(corners[2], corners[0])), normal) < 0:
                    corners = corners[::-1]
                quads.append(corners)
                normals.append(normal)
    return np.array(quads, float).reshape(-1, 4, 3), np.array(normals, float).reshape(-1, 3)


def box_uv(points: np.ndarray, normal: np.ndarray, units=TEXTURE_UNITS) -> np.ndarray:
    """Box-projected UVs: drop the axis the face looks along; the vertical
    axis (or y, for a face looking up or down) runs along v."""
    axis = int(np.argmax(np.abs(normal)))
    u_axis, v_axis = {0: (1, 2), 1: (0, 2), 2: (0, 1)}[axis]
    shift = 0.37 if normal[axis] > 0 else 0.0  # the two sides of a wall show different bricks
    return np.stack([points[:, u_axis] / units[0] + shift, points[:, v_axis] / units[1]], axis=1)


def brick_ruin(seed: int = 0, detail: int = 16) -> trimesh.Trimesh:
    """A roofless brick enclosure in ruins, `detail` bricks along its long
    walls: one brick thick, broken down to uneven heights in brick steps, a
    doorway and two windows, textured with the tiling brick image."""
    rng = np.random.default_rng(seed)
    long_cols, short_cols = 2 * detail, max(6, 2 * round(detail * 0.625))  # half-brick columns; short walls of 2 or more
    width, thickness = BRICK_LENGTH / 2, BRICK_LENGTH
    height = BRICK_LENGTH * COURSE_PX / BRICK_PX
    courses = max(4, round(detail * 1.25))
    quads, normals = [], []
    length_x, length_y = long_cols * width, short_cols * width
    walls = [  # (columns, origin, along): the long walls, then the short ones between them
        (long_cols, (0.0, 0.0, 0.0), 0), (long_cols, (0.0, length_y - thickness, 0.0), 0),
        (short_cols - 4, (0.0, thickness, 0.0), 1), (short_cols - 4, (length_x - thickness, thickness, 0.0), 1),
    ]
    for index, (columns, origin, along) in enumerate(walls):
        position = np.stack([np.arange(columns) / 8, np.full(columns, 3.0 * index), np.zeros(columns)], 1)
        profile = 0.62 + 0.38 * value_noise(rng, position, 1.0)
        drops = rng.integers(0, 3, columns) * (rng.random(columns) < 0.3)
        tops = np.clip(np.round(courses * profile) - drops, 2, courses).astype(int)
        filled = np.arange(courses)[None, :] < tops[:, None]
        if index == 0:  # a doorway
            door = columns // 3
            filled[door:door + max(2, columns // 8), :max(2, courses // 2)] = False
        if index in (1, 2):  # a window
            middle = columns // 2
            filled[middle - 1:middle + max(1, columns // 10), courses // 3:courses // 3 + max(2, courses // 5)] = False
        q, n = cell_faces(filled, origin, along, width, height, thickness)
        quads.append(q)
        normals.append(n)
    quads, normals = np.concatenate(quads), np.concatenate(normals)
    vertices = quads.reshape(-1, 3)
    uv = np.concatenate([box_uv(q, n) for q, n in zip(quads, normals)])
    faces = (np.arange(len(quads))[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    image = Image.fromarray(brick_texture(seed))
    visual = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.PBRMaterial(
        baseColorTexture=image, metallicFactor=0.0, roughnessFactor=0.9))
    return trimesh.Trimesh(vertices, faces, visual=visual, process=False)


def rock_colour(rng_seed: int, points: np.ndarray) -> np.ndarray:
    """The rock's solid pattern, (n, 3) sRGB: grey stone with grain and dark
    cracks, green lichen in patches with paler spots."""
    noise = lambda offset, frequency, octaves=4: fbm(np.random.default_rng(rng_seed + offset), points, frequency, octaves)  # noqa: E731
    stone = np.asarray(STONE) * (1 + 0.22 * noise(1, 2.5))[:, None] + 0.04 * noise(2, 24, 2)[:, None]
    crack = 1 - np.abs(noise(3, 3.0, 3))
    stone = stone * (1 - 0.45 * np.clip((crack - 0.9) / 0.06, 0, 1))[:, None]
    patches = np.clip((noise(4, 1.4) - 0.05) / 0.12, 0, 1)
    lichen = np.where((noise(5, 14, 2) > 0.25)[:, None], LICHEN_PALE, LICHEN) * (1 + 0.12 * noise(6, 30, 2))[:, None]
    return np.clip(stone * (1 - patches[:, None]) + lichen * patches[:, None], 0, 1)


def rasterise_uv(uv: np.ndarray, faces: np.ndarray, size: int) -> tuple:
    """Which face and barycentric weights cover each texel centre of a
    size x size atlas: (face (size, size) int64, -1 where none; weights (size, size, 3))."""
    face_of = np.full((size, size), -1, np.int64)
    weights = np.zeros((size, size, 3))
    pixels = uv * size - 0.5  # texel centres at integers
    for f, (a, b, c) in enumerate(pixels[faces]):
        low = np.maximum(np.floor(np.minimum(np.minimum(a, b), c)).astype(int), 0)
        high = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c)).astype(int), size - 1)
        if np.any(high < low):
            continue
        x, y = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1), indexing="ij")
        p = np.stack([x, y], -1).astype(float)
        d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(d) < 1e-12:
            continue
        w0 = ((b[1] - c[1]) * (p[..., 0] - c[0]) + (c[0] - b[0]) * (p[..., 1] - c[1])) / d
        w1 = ((c[1] - a[1]) * (p[..., 0] - c[0]) + (a[0] - c[0]) * (p[..., 1] - c[1])) / d
        w = np.stack([w0, w1, 1 - w0 - w1], -1)
        inside = np.all(w >= -1e-9, axis=-1)
        face_of[y[inside], x[inside]] = f
        weights[y[inside], x[inside]] = w[inside]
    return face_of, weights


def dilate(image: np.ndarray, covered: np.ndarray, steps: int) -> tuple:
    """Grow covered texels' colours into the uncovered ones around them,
    `steps` texels: the gutter that keeps filtering from reading the
    background. Returns the image and the texels it now covers."""
    image, covered = image.copy(), covered.copy()
    for _ in range(steps):
        total, count = np.zeros_like(image), np.zeros(covered.shape)
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            total += np.roll(image * covered[..., None], (dy, dx), (0, 1))
            count += np.roll(covered, (dy, dx), (0, 1))
        grow = ~covered & (count > 0)
        image[grow] = total[grow] / count[grow, None]
        covered = covered | grow
    return image, covered


def lichen_rock(seed: int = 0, detail: int = 5) -> trimesh.Trimesh:
    """A twisted, lichen-covered rock about 3.4 x 2 x 1.8 units; `detail` =
    the icosphere's subdivisions. UVs: the six faces of a cube around the
    undisplaced sphere, in a 512x512 atlas baked from `rock_colour`."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=detail)
    direction = np.asarray(sphere.vertices)
    bumps = 0.22 * fbm(rng, direction + 5, 1.2) + 0.06 * fbm(rng, direction + 9, 4.0)
    points = direction * (1 + bumps)[:, None] * np.array([1.7, 1.0, 0.9])
    twist = 0.45 * points[:, 0]
    c, s = np.cos(twist), np.sin(twist)
    points = np.stack([points[:, 0], c * points[:, 1] - s * points[:, 2], s * points[:, 1] + c * points[:, 2]], 1)
    # Each face to the cube face its centre's direction points at; corners split per chart.
    faces = np.asarray(sphere.faces)
    centre = direction[faces].mean(axis=1)
    axis = np.argmax(np.abs(centre), axis=1)
    side = np.sign(centre[np.arange(len(faces)), axis]) > 0
    chart = axis * 2 + side
    corners = direction[faces].reshape(-1, 3)
    chart_c = np.repeat(chart, 3)
    ax = chart_c // 2
    others = np.array([[1, 2], [0, 2], [0, 1]])[ax]
    projected = corners[np.arange(len(corners))[:, None], others] / np.abs(corners[np.arange(len(corners)), ax])[:, None]
    size, cell, gutter = 512, 160, 8
    column, row = chart_c % 3, chart_c // 3
    uv_pixels = (projected * 0.5 + 0.5) * cell + np.stack([gutter + column * (cell + gutter), gutter + row * (cell + gutter)], 1)
    uv = uv_pixels / size
    uv[:, 1] = 1 - uv[:, 1]  # v up, rows down
    vertices = points[faces].reshape(-1, 3)
    split_faces = np.arange(len(vertices)).reshape(-1, 3)
    face_of, weights = rasterise_uv(np.stack([uv[:, 0], 1 - uv[:, 1]], 1), split_faces, size)
    covered = face_of >= 0
    texel_points = np.einsum("nk,nkc->nc", weights[covered], vertices[split_faces[face_of[covered]]])
    image = np.zeros((size, size, 3))
    image[covered] = rock_colour(seed, texel_points)
    image, covered = dilate(image, covered, gutter)
    image[~covered] = STONE
    texture = Image.fromarray(np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    material = trimesh.visual.material.SimpleMaterial(image=texture, diffuse=(255, 255, 255, 255),
                                                      ambient=(255, 255, 255, 255), specular=(20, 20, 20, 255))
    visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return trimesh.Trimesh(vertices, split_faces, visual=visual, process=False)
