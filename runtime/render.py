"""Draw shaded pictures of triangle meshes with numpy and pillow only.

For the README gallery and for previewing samples on machines with no
display and no OpenGL, without making the runtime heavier. A small software
rasteriser: the camera looks at the mesh's bounding-box centre from an
azimuth and elevation and frames the whole mesh; triangles go into a
z-buffer in vectorised batches; faces are lit flat (Lambert, two-sided, two
directional lights) and outlined where depth jumps.

Colours are RGB floats in [0, 1]; images are (H, W, 3) uint8; sizes are
(width, height), as in pillow.
"""

import math
import numbers
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw, ImageFont

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write

from . import mesh as meshing
from .colour import surface_painter
from .request import SampleRequest, make
from .raster import BATCH, cross, rasterise

CLAY = (0.86, 0.82, 0.76)
BACKGROUND = (0.97, 0.97, 0.96)
OUTLINE = (0.18, 0.18, 0.20)
LABEL = (0.15, 0.15, 0.15)

# Per "up" axis: that axis, the side the camera sees at azimuth 0 (the
# model's front by the usual convention) and the axis to the camera's right.
FRAMES = {
    "y": {"up": (0, 1, 0), "front": (0, 0, 1), "right": (1, 0, 0)},  # OBJ: front is +z
    "z": {"up": (0, 0, 1), "front": (0, -1, 0), "right": (1, 0, 0)},  # Blender: front is -y
}

# Lights are fixed to the camera (x right, y up, z towards the viewer), so
# every view is lit alike: a key light from the upper left, a weak fill from
# the right: (direction, strength).
LIGHTS = [((-0.4, 0.7, 0.6), 0.62), ((0.8, -0.1, 0.6), 0.12)]
AMBIENT = 0.30

FIELD_OF_VIEW = 35.0  # degrees; only sets the strength of the perspective
MARGIN = 0.05  # blank border around the mesh, as a fraction of the image side
EDGE_JUMP = 0.04  # outline where depth jumps by this fraction of the mesh's depth range
# Peak bytes per drawn pixel (supersampled) of one render: z-buffer, face
# index, colours and the outline's depth arrays; 69 measured at 1000 to 3000
# pixels square (docs/RELIABILITY.md). And per pixel of the finished picture:
# its cells, the joined rows, the image pillow encodes.
RENDER_BYTES_PER_PIXEL = 72
PICTURE_BYTES_PER_PIXEL = 12
# Pillow refuses to open larger images (about 179M pixels: a decompression
# bomb to it), and other readers guard alike: a picture that could not be
# opened is not drawn.
MAX_PICTURE_PIXELS = 2 * (2**30 // 4 // 3)


def render(mesh: trimesh.Trimesh, size=(512, 512), azimuth=35.0, elevation=25.0, up="y",
           projection="perspective", color=CLAY, background=BACKGROUND, outline=True,
           supersample=2) -> np.ndarray:
    """A shaded picture of `mesh`, (height, width, 3) uint8.

    The camera circles the `up` axis ("y" or "z"): azimuth 0 looks at the
    front (+z if y is up, as in OBJ files; -y if z is up, as in Blender),
    positive azimuths turn it towards +x, positive elevations raise it.
    `projection` is "perspective" or "orthographic". Either way the mesh
    fills the picture less a small margin. Drawing `supersample` times larger
    and averaging smooths jagged edges; 1 is faster. A mesh whose metadata
    holds PAINT (a textured example: mesh_file) is drawn in it pixel by
    pixel; one with vertex colours (a coloured model's samples) in them, a
    colour per face; any other in `color`.
    """
    width, height = size
    s = supersample
    if min(width, height, s) < 1:
        raise InputError(f"size and supersample must be at least 1, got {tuple(size)} and {supersample}")
    camera = camera_triangles(mesh, azimuth, elevation, up)
    corners, nearness = project(camera, (width * s, height * s), projection)
    face, depth = rasterise(corners, nearness, (width * s, height * s))
    paint = mesh.metadata.get(PAINT)
    if paint is not None:
        image = painted_pixels(face, corners, nearness if projection == "perspective" else None,
                               lambert(camera, corners), paint, background)
    else:  # one colour per face, then the background last, where face -1 picks it
        palette = np.vstack([lambert(camera, corners)[:, None] * face_colours(mesh, color), background])
        image = palette.astype(np.float32)[face]
    if outline:
        image[depth_edges(depth, s)] = OUTLINE
    image = image.reshape(height, s, width, s, 3).mean(axis=(1, 3))
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def painted_pixels(face: np.ndarray, corners: np.ndarray, nearness: np.ndarray | None, light: np.ndarray,
                   paint, background) -> np.ndarray:
    """A picture's pixels in a painted mesh's colours: each covered pixel's
    point on its face (barycentric weights, made perspective-correct with
    the corners' `nearness`, None for orthographic) is asked its colour,
    times its face's light: (height, width, 3) float32."""
    height, width = face.shape
    image = np.empty((height * width, 3), np.float32)
    image[:] = background
    covered = np.flatnonzero(face.ravel() >= 0)
    for start in range(0, len(covered), BATCH):
        pixel = covered[start:start + BATCH]
        f = face.ravel()[pixel]
        row, col = np.divmod(pixel, width)
        a, b, c = corners[f, 0], corners[f, 1], corners[f, 2]
        p = np.stack([col + 0.5, row + 0.5], axis=1)
        area = cross(b - a, c - a)
        w1, w2 = cross(p - a, c - a) / area, cross(b - a, p - a) / area
        weights = np.clip(np.stack([1 - w1 - w2, w1, w2], axis=1), 0, 1)
        if nearness is not None:  # screen-space weights over depth: the point on the face itself
            weights = weights * nearness[f]
        weights /= np.maximum(weights.sum(axis=1, keepdims=True), 1e-30)
        image[pixel] = light[f, None] * paint(f, weights)
    return image.reshape(height, width, 3)


def mesh_file(path: Path, asset_folder: Path | None = None, warn=None) -> trimesh.Trimesh:
    """A mesh file to draw, as training reads it: its geometry and, where it
    has colour (vertex colours, a texture through its UVs), that colour as
    PAINT in its metadata. With `warn`, colour that cannot be read is told to
    warn(InputError) and the geometry drawn without it; else raised."""
    from sinshape.prep import colour, meshfiles, voxelize  # the prep extra: only a mesh file's picture needs it

    try:
        scene, _ = voxelize.read_scene(path, materials=True, asset_folder=asset_folder)
        paint = colour.surface_painter(scene, path)
    except InputError as error:
        if warn is None or "no_colour" not in meshfiles.parameters(error):
            raise
        warn(InputError(f"{error.template}; drawn without its colour", error.parameter))
        scene, paint = voxelize.read_scene(path, materials=False, asset_folder=asset_folder)[0], None
    mesh = voxelize.scene_mesh(scene, path, solid=False)
    if paint is not None:
        mesh.metadata[PAINT] = paint
    return mesh


def is_mesh_file(item) -> bool:
    """A file of a format trimesh reads as a mesh (not a model)."""
    path = Path(item)
    return path.is_file() and path.suffix.lower().lstrip(".") in trimesh.exchange.load.mesh_formats()


PAINT = "sinshape.paint"  # a mesh's metadata: its colour, f(faces (n,), barycentric weights (n, 3)) -> (n, 3) sRGB


def face_colours(mesh: trimesh.Trimesh, color) -> np.ndarray:
    """Each face's colour, the mean of its corners' vertex colours (sRGB in
    [0, 1]), or `color` for a mesh without vertex colours: (m, 3) or (3,)."""
    if mesh.visual.kind != "vertex":
        return np.asarray(color)
    return np.asarray(mesh.visual.vertex_colors, np.float32)[np.asarray(mesh.faces), :3].mean(axis=1) / 255


def picture_size(count: int, size, views: int = 1, columns: int = 4) -> tuple:
    """(width, height) of the picture of `count` shapes: one row of `views`
    per shape (render_views), or with one view a grid of `columns` labelled
    cells (render_grid)."""
    width, height = size
    if views > 1:
        return width * views, height * count
    columns = min(columns, count)
    return width * columns, -(-count // columns) * (height + label_height(size))


def check_picture(count: int, size, views: int = 1, columns: int = 4, supersample: int = 2,
                  memory_limit: int | None = None) -> None:
    """Refuse up front a picture that no image reader would open, or whose
    drawing needs more than memory_limit bytes (None: the memory available)."""
    if min(count, views, columns, *size) < 1:
        raise InputError(f"a picture needs at least one shape, view, column and pixel; got {count} shapes, "
                         f"{views} views, {columns} columns, size {tuple(size)}", "image_size")
    width, height = picture_size(count, size, views, columns)
    if width * height > MAX_PICTURE_PIXELS:
        raise InputError(f"a {width}x{height} picture has more than {MAX_PICTURE_PIXELS} pixels, which image "
                         "readers refuse to open; draw fewer shapes or views, or smaller ones", "image_size")
    drawn = size[0] * size[1] * supersample**2
    check_memory(RENDER_BYTES_PER_PIXEL * drawn + PICTURE_BYTES_PER_PIXEL * width * height,
                 f"a {width}x{height} picture", memory_limit)


def render_views(mesh: trimesh.Trimesh, size=(384, 384), views=((35, 25), (125, 25), (215, 25), (305, 25)),
                 progress=None, **options) -> np.ndarray:
    """One picture per (azimuth, elevation) in `views`, side by side:
    (height, width * len(views), 3) uint8. progress() is called after each
    view; `options` go to `render`."""
    pictures = []
    for azimuth, elevation in views:
        pictures.append(render(mesh, size, azimuth, elevation, **options))
        if progress:
            progress()
    return np.concatenate(pictures, axis=1)


def render_grid(meshes: list, labels: list, columns: int, size=(320, 320), progress=None, **options) -> np.ndarray:
    """The meshes in rows of `columns` cells, each a `size` picture with its
    label in a strip beneath: (rows * (height + strip), columns * width, 3)
    uint8, strip = `label_height(size)`. Cells past the last mesh stay blank.
    progress() is called after each cell; `options` go to `render`."""
    if len(meshes) != len(labels):
        raise InputError(f"render_grid got {len(meshes)} meshes but {len(labels)} labels")
    if not meshes or columns < 1:
        raise InputError("render_grid needs at least one mesh and one column")
    width, height = size
    strip = label_height(size)
    font = ImageFont.load_default(size=round(strip * 0.6))
    background = tuple(round(255 * c) for c in options.get("background", BACKGROUND))
    cells = []
    for mesh, label in zip(meshes, labels):
        cell = Image.new("RGB", (width, height + strip), background)
        cell.paste(Image.fromarray(render(mesh, size, **options)))
        # Drawn on its own cell, a long label is cut at the cell's edge rather
        # than running into the neighbour's.
        ImageDraw.Draw(cell).text((width / 2, height + strip / 2), str(label), anchor="mm", font=font,
                                  fill=tuple(round(255 * c) for c in LABEL))
        cells.append(np.asarray(cell))
        if progress:
            progress()
    rows = -(-len(cells) // columns)
    cells += [np.full_like(cells[0], background)] * (rows * columns - len(cells))
    return np.concatenate([np.concatenate(cells[r * columns:(r + 1) * columns], axis=1) for r in range(rows)])


def crop(mesh: trimesh.Trimesh, zoom: float, focus=(0.5, 0.5, 0.5)) -> trimesh.Trimesh:
    """A close-up: the part of the mesh in a box 1/zoom the size of its
    bounding box (zoom >= 1), centred at `focus` (fractions of the bounding
    box per axis), its faces cut at the box's sides (whole faces kept or
    dropped would leave a sawtooth edge a face deep, which reads as the
    shape's own). Vertex colours and PAINT follow the cut. InputError if the
    box holds none."""
    if zoom == 1:
        return mesh
    centre = mesh.bounds[0] + np.asarray(focus) * mesh.extents
    low, high = centre - mesh.extents / (2 * zoom), centre + mesh.extents / (2 * zoom)
    corners = mesh.triangles
    within = np.all((corners >= low) & (corners <= high), axis=2)  # (m, 3): each corner inside the box
    beyond = np.any(np.all(corners < low, axis=1) | np.all(corners > high, axis=1), axis=1)  # all past one side
    whole, cut = np.flatnonzero(within.all(axis=1)), np.flatnonzero(~within.all(axis=1) & ~beyond)
    pieces = [(f, weights) for f in cut for weights in clipped_triangles(corners[f], low, high)]
    if not len(whole) and not pieces:
        raise InputError(f"no part of the shape lies in the zoomed box at `focus` {','.join(map(str, focus))}", "focus")
    source = np.concatenate([whole, np.array([f for f, _ in pieces], np.int64)])
    weights = np.concatenate([np.broadcast_to(np.eye(3), (len(whole), 3, 3)),
                              np.array([w for _, w in pieces]).reshape(-1, 3, 3)])  # (k, corner, original corner)
    vertices = np.einsum("kcj,kjx->kcx", weights, corners[source]).reshape(-1, 3)
    part = trimesh.Trimesh(vertices, np.arange(len(vertices)).reshape(-1, 3), process=False)
    if mesh.visual.kind == "vertex":
        colours = np.asarray(mesh.visual.vertex_colors, np.float64)[mesh.faces[source]]
        part.visual.vertex_colors = np.round(np.einsum("kcj,kjx->kcx", weights, colours)).reshape(-1, 4).astype(np.uint8)
    paint = mesh.metadata.get(PAINT)
    if paint is not None:  # a point of a part's face, as the same point of the face it was cut from
        part.metadata[PAINT] = lambda face, w: paint(source[face], np.einsum("nc,ncj->nj", w, weights[face]))
    return part


def clipped_triangles(corners: np.ndarray, low: np.ndarray, high: np.ndarray) -> list:
    """The triangles of a triangle (corners (3, 3)) inside the box [low, high]
    (Sutherland and Hodgman's clipping, a side at a time, then a fan), each
    as its corners' barycentric weights in the triangle, (3, 3)."""
    polygon = list(np.eye(3))
    for axis in range(3):
        for bound, sign in ((low[axis], -1.0), (high[axis], 1.0)):
            outside = [sign * (w @ corners[:, axis] - bound) for w in polygon]
            kept = []
            for k, (w, d) in enumerate(zip(polygon, outside)):
                w_next, d_next = polygon[(k + 1) % len(polygon)], outside[(k + 1) % len(polygon)]
                if d <= 0:
                    kept.append(w)
                if (d <= 0) != (d_next <= 0):
                    kept.append(w + (w_next - w) * (d / (d - d_next)))
            polygon = kept
            if len(polygon) < 3:
                return []
    return [np.stack([polygon[0], polygon[k], polygon[k + 1]]) for k in range(1, len(polygon) - 1)]


def sample_label(seed, factors=(1, 1, 1), scale: float = 1.0) -> str:
    """The caption of a drawn sample: its seed (None: the reconstruction),
    and its size and scale where they are not the training ones."""
    label = "reconstruction" if seed is None else f"seed {seed}"
    if seed is not None and tuple(factors) != (1, 1, 1):
        label += ", size " + "x".join(f"{f:g}" for f in factors)
    return label if scale == 1 else f"{label}, scale {scale:g}"


def label_height(size) -> int:
    """Height in pixels of render_grid's label strip for cells of `size`."""
    return max(14, round(size[1] / 12))


def save_png(image: np.ndarray, path) -> None:
    """Write a (H, W, 3) uint8 image to `path` as PNG, through a temporary
    file and a rename, so that `path` never holds a half-written picture."""
    atomic_write(path, lambda f: Image.fromarray(image).save(f, format="PNG"))


def check_view(zoom: float = 1.0, azimuth: float = 0.0, elevation: float = 0.0) -> None:
    """A close-up factor of 1 or more and finite camera angles (inf and NaN drew blank pictures)."""
    if not (isinstance(zoom, numbers.Real) and 1 <= zoom < float("inf")):
        raise InputError(f"`zoom` must be 1 or more, got {zoom}", "zoom")
    for name, angle in (("azimuth", azimuth), ("elevation", elevation)):
        if not (isinstance(angle, numbers.Real) and math.isfinite(angle)):
            raise InputError(f"`{name}` must be a finite angle in degrees, got {angle}", name)


def camera_axes(azimuth: float, elevation: float, up: str) -> np.ndarray:
    """(3, 3): rows are the camera's right, up and backward (towards the eye)
    directions in world coordinates."""
    if up not in FRAMES:
        raise InputError(f"up must be one of {sorted(FRAMES)}, got {up!r}")
    world_up, front, right = (np.array(FRAMES[up][k], dtype=np.float64) for k in ("up", "front", "right"))
    azimuth, elevation = np.radians(azimuth), np.radians(elevation)
    horizontal = np.cos(azimuth) * front + np.sin(azimuth) * right
    backward = np.cos(elevation) * horizontal + np.sin(elevation) * world_up
    # Written out rather than cross(world_up, backward): stays defined looking straight down.
    camera_right = np.cos(azimuth) * right - np.sin(azimuth) * front
    return np.stack([camera_right, np.cross(backward, camera_right), backward])


def camera_triangles(mesh: trimesh.Trimesh, azimuth: float, elevation: float, up: str) -> np.ndarray:
    """The corners of every face, (m, 3, 3) float, in camera coordinates (x
    right, y up, z towards the eye) centred on the bounding box's centre."""
    if len(mesh.faces) == 0:
        raise InputError("cannot render an empty mesh (it has no faces)")
    faces = np.asarray(mesh.faces)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    used = vertices[np.bincount(faces.ravel(), minlength=len(vertices)) > 0]  # stray vertices don't count
    if not np.isfinite(used).all():
        raise InputError("cannot render a mesh with non-finite vertex coordinates")
    centre = (used.min(axis=0) + used.max(axis=0)) / 2
    # Vertices rather than corners: fewer, and numpy's product of a very
    # tall (k, 3) array with a (3, 3) one is oddly slow.
    return ((vertices - centre) @ camera_axes(azimuth, elevation, up).T)[faces]


def project(camera: np.ndarray, size, projection: str):
    """Camera-space corners (m, 3, 3) -> pixel positions (m, 3, 2) (x right,
    y down) and nearness (m, 3).

    Nearness grows towards the eye and, unlike depth under perspective, is
    affine in screen space: it interpolates linearly across a projected
    triangle and is what the z-buffer compares.
    """
    if projection == "perspective":
        radius = np.linalg.norm(camera, axis=-1).max()
        # The eye sits where the bounding sphere fills the field of view, so
        # every corner is in front of it (depth >= distance - radius > 0).
        distance = max(radius, 1e-12) / np.sin(np.radians(FIELD_OF_VIEW) / 2)
        depth = distance - camera[..., 2]
        flat, nearness = camera[..., :2] / depth[..., None], 1 / depth
    elif projection == "orthographic":
        flat, nearness = camera[..., :2], camera[..., 2]
    else:
        raise InputError(f"projection must be 'perspective' or 'orthographic', got {projection!r}")
    # Scale and shift the projected bounding box into the picture, less the margin.
    width, height = size
    low, high = flat.min(axis=(0, 1)), flat.max(axis=(0, 1))
    with np.errstate(divide="ignore"):  # a flat mesh seen edge-on has zero extent one way
        scale = (1 - 2 * MARGIN) * np.min(np.array([width, height]) / (high - low))
    if not np.isfinite(scale):  # every face projects to one point
        scale = 1.0
    pixels = (flat - (low + high) / 2) * scale * np.array([1, -1]) + np.array([width, height]) / 2
    return pixels, nearness


def lambert(camera: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Brightness of each face, (m,) float: ambient plus Lambert from LIGHTS,
    with each normal turned towards the eye, so that open meshes and flipped
    faces are lit like the rest."""
    normals = np.cross(camera[:, 1] - camera[:, 0], camera[:, 2] - camera[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    # A face whose normal points at the eye has its corners clockwise on
    # screen (y points down): negative signed area. That holds under
    # perspective too, where the sign of the normal's z does not tell.
    facing = cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) < 0
    normals[~facing] *= -1
    light = np.full(len(normals), AMBIENT)
    for direction, strength in LIGHTS:
        light += strength * np.maximum(normals @ (np.array(direction) / np.linalg.norm(direction)), 0)
    return light


def depth_edges(nearness: np.ndarray, width=1) -> np.ndarray:
    """Pixels to outline, (H, W) bool: the near side of every jump in depth,
    the mesh's silhouette included, in lines `width` pixels wide.

    A pixel is an edge when it is nearer than the mean of its two neighbours
    (along x or y) by more than EDGE_JUMP of the depth range. Nearness is
    affine across a flat face, so surfaces seen at a grazing angle are not
    outlined, and background pixels never are.
    """
    covered = np.isfinite(nearness)
    if not covered.any():
        return covered
    low, high = nearness[covered].min(), nearness[covered].max()
    # Depth range scaled to 0..1, the background at -2: far enough behind
    # that every silhouette pixel passes the test.
    level = np.where(covered, (nearness - low) / max(high - low, 1e-300), -2.0)
    padded = np.pad(level, 1, constant_values=-2.0)
    centre = padded[1:-1, 1:-1]
    across = centre - (padded[1:-1, :-2] + padded[1:-1, 2:]) / 2
    down = centre - (padded[:-2, 1:-1] + padded[2:, 1:-1]) / 2
    edges = covered & ((across > EDGE_JUMP) | (down > EDGE_JUMP))
    wide = edges.copy()
    for dy in range(width):
        for dx in range(width):
            wide[dy:, dx:] |= edges[:edges.shape[0] - dy, :edges.shape[1] - dx]
    return wide


def draw_shapes(items: list, seeds, recon: bool = False, request=None, views: int = 1, up: str | None = None,
                columns: int = 4, image_size: int = 320, zoom: float = 1.0, focus=(0.5, 0.5, 0.5),
                azimuth: float = 35.0, elevation: float = 25.0, progress=None, warn=None,
                asset_folder: Path | None = None) -> np.ndarray:
    """One picture of `items`: mesh files (Paths, drawn as they are, in
    their colours: `mesh_file`, the files they name read from their folder
    or `asset_folder`) and loaded models (their samples `seeds`, the
    reconstruction first with `recon`, each made as `request` (a
    request.SampleRequest, its seed replaced; None: the plain one) asks but
    the reconstruction at the training size), as a grid of labelled cells or, with
    views > 1, a turntable row per shape. `up` None: what the first model
    records, else y. progress(stage, done, total) follows the sampling, then
    the drawing; warn(InputError) hears of a mesh's colour that cannot be read."""
    check_view(zoom, azimuth, elevation)
    request = request or SampleRequest()
    models = [item for item in items if not isinstance(item, Path)]
    count = len(seeds) + bool(recon)  # counted, not listed: 0-100000000 would take gigabytes before the refusal
    check_picture(len(items) - len(models) + len(models) * count, (image_size, image_size), views, columns)
    chosen = [None, *seeds] if recon else list(seeds)
    up = up or (models[0].manifest.up if models else "y")
    shapes, labels, sampled = [], [], 0
    for item in items:
        if isinstance(item, Path):
            shapes.append(mesh_file(item, asset_folder, warn))
            labels.append(item.name)
            continue
        for seed in chosen:
            wanted = replace(request, seed=None, recon=True, size=1.0) if seed is None else request.with_seed(seed)
            triplane = make(item, wanted)
            shapes.append(meshing.extract(item, triplane, **{**wanted.mesh_options(), "frame": "model"}))
            if item.colour_tiles is not None and wanted.detail:  # its colour read at each pixel: the example's texture, not vertex colours
                shapes[-1].metadata[PAINT] = surface_painter(item, triplane, shapes[-1].vertices, shapes[-1].faces)
            meshing.to_frame(shapes[-1], item.manifest)
            if not len(shapes[-1].faces):
                raise InputError(f"{item.path.name}: seed {seed} has no surface at this scale and size; nothing drawn",
                                 "scale")
            labels.append(sample_label(seed, request.size, request.scale))
            sampled += 1
            if progress:
                progress("sampling", sampled, len(models) * len(chosen))
    shapes = [crop(shape, zoom, focus) for shape in shapes]
    drawn = [0]

    def step():
        drawn[0] += 1
        if progress:
            progress("drawing", drawn[0], len(shapes) * views)

    options = dict(up=up, size=(image_size, image_size), progress=step)
    if views > 1:
        turns = [((azimuth + 360 * k / views) % 360, elevation) for k in range(views)]
        return np.concatenate([render_views(shape, views=turns, **options) for shape in shapes])
    return render_grid(shapes, labels, min(columns, len(shapes)), azimuth=azimuth, elevation=elevation, **options)
