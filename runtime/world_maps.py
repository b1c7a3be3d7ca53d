"""A world's maps, read and checked before anything else reads them: a
height map (the world's large shape, a designer's painting) and a model map
(which model goes where in a scattered world), each from an image or an
array, given as bytes (an upload) or as a file."""

import io
import math
import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import read_regular
from sinshape.core.manifest import UP_AXIS

MAX_MAP_SIDE = 1 << 12  # pixels of a height map along each axis
MAX_RELIEF = 1 << 14  # voxels: a height map's values in +-MAX_RELIEF


@dataclass(frozen=True)
class HeightMap:
    """A designer's map of the world's large shape: heights in voxels at the
    centres of tiles (r, c), r along the first horizontal axis, from tile
    (0, 0); between them its cubic B-spline (smooth, and within the map's
    lowest and highest values), beyond its edges its edge. Held as bytes,
    so that a request stays a hashable value."""

    shape: tuple
    data: bytes  # float32, little-endian, C order

    @classmethod
    def of(cls, heights) -> "HeightMap":
        try:
            heights = np.asarray(heights, np.float64)
        except (TypeError, ValueError):
            raise InputError("a height map is a 2-D array of heights in voxels", "heights") from None
        if heights.ndim != 2 or not 0 < min(heights.shape) <= max(heights.shape) <= MAX_MAP_SIDE:
            raise InputError(f"a height map is a 2-D array of 1 to {MAX_MAP_SIDE} pixels a side, got shape "
                             f"{heights.shape}", "heights")
        if not (np.isfinite(heights).all() and np.abs(heights).max() <= MAX_RELIEF):
            raise InputError(f"a height map holds values in voxels within +-{MAX_RELIEF}: no NaN or infinities",
                             "heights")
        return cls(tuple(int(n) for n in heights.shape), heights.astype("<f4").tobytes())

    def array(self) -> np.ndarray:
        """(R, C) float32."""
        return np.frombuffer(self.data, "<f4").reshape(self.shape)

    def bounds(self) -> tuple:
        """The lowest and highest heights, rounded out to whole voxels."""
        heights = self.array()
        return math.floor(heights.min()), math.ceil(heights.max())


MAX_MAP_BYTES = 64 << 20  # a map file: 4096 x 4096 16-bit pixels fit


def read_npy_map(data: bytes, name, field: str) -> np.ndarray:
    """A map's 2-D numeric array from .npy bytes, its header checked before its data is read."""
    try:
        stream = io.BytesIO(data)
        header = {(1, 0): np.lib.format.read_array_header_1_0,
                  (2, 0): np.lib.format.read_array_header_2_0}.get(np.lib.format.read_magic(stream))
        if header is None:
            raise ValueError("an unknown .npy version")
        shape, _, dtype = header(stream)
        if dtype.kind not in "fiu" or len(shape) != 2 or max(shape, default=0) > MAX_MAP_SIDE:
            raise ValueError(f"{dtype} of shape {shape}")
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as error:
        raise InputError(f"{name}: not a 2-D numeric .npy array of at most {MAX_MAP_SIDE} a side ({error})",
                         field) from None


def image_pixels(data: bytes, name, what: str, field: str, read):
    """What `read(image)` takes from an image map's bytes, its size checked before its pixels are read."""
    from PIL import Image, UnidentifiedImageError  # pillow: only an image map needs it (Blender's, bundled)

    try:
        with Image.open(io.BytesIO(data)) as image:
            if max(image.size) > MAX_MAP_SIDE:
                raise InputError(f"{name}: {image.size[0]}x{image.size[1]} pixels; {what} has at most "
                                 f"{MAX_MAP_SIDE} a side", field)
            return read(image)
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError) as error:
        raise InputError(f"{name}: not a readable image ({error})", field) from None


def parse_height_map(data: bytes, suffix: str, name, relief: float | None = None) -> HeightMap:
    """A height map from a file's bytes: a greyscale image (.png: black 0,
    white `relief` voxels; its columns run along the first horizontal axis,
    its rows from the bottom up along the second, as a map seen from above)
    or an array (.npy: heights in voxels, [i, j] tile (i, j)'s). `name`
    says what the bytes are in messages."""
    if len(data) > MAX_MAP_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a height map")
    suffix = suffix.lower()
    if suffix == ".npy":
        if relief is not None:
            raise InputError(f"{name}: an array holds heights in voxels; `relief` scales an image's", "relief")
        return HeightMap.of(read_npy_map(data, name, "heights"))
    if suffix != ".png":
        raise InputError(f"{name}: a height map is a .png image or a .npy array, got {suffix or 'no extension'!r}",
                         "heights")
    if relief is None or not (isinstance(relief, numbers.Real) and 0 < relief <= MAX_RELIEF):
        raise InputError(f"`relief` must be a number of voxels in (0, {MAX_RELIEF}] for an image, got {relief!r}",
                         "relief")
    wide, pixels = image_pixels(data, name, "a height map", "heights", lambda image: (
        image.mode.startswith("I"), np.asarray(image if image.mode.startswith("I") else image.convert("L"), np.float64)))
    full = 65535.0 if wide else 255.0
    return HeightMap.of(np.flipud(np.clip(pixels, 0, full) / full).T * relief)


RELIEF = 4  # an image map's white, in the model's heights, unless a relief is given


def read_height_map(path, model, relief: float | None = None) -> HeightMap:
    """parse_height_map of a file; an image's white is `relief` voxels
    (default RELIEF times the model's height)."""
    path = Path(path)
    data = read_regular(path, f"the height map {path}", MAX_MAP_BYTES, field="heights")
    if relief is None and path.suffix.lower() == ".png":  # the model's height: world.world_tiling's stride along up
        relief = RELIEF * (model.manifest.sizes[-1][UP_AXIS[model.manifest.up]] - 1)
    return parse_height_map(data, path.suffix, path.name, relief)


MAX_MODELS = 256  # models in one world: a model map's pixel is a byte


@dataclass(frozen=True)
class ModelMap:
    """A designer's map of which model goes where in a scattered world: a
    model's index (0 the world's first model) per pixel (r, c), r along the
    first horizontal axis, as a height map's pixels lie (world.map_pixel);
    beyond its edges, its edge. A scatter cell's object comes from the model
    the pixel under the cell's centre names. Held as bytes, as HeightMap."""

    shape: tuple
    data: bytes  # uint8, C order

    @classmethod
    def of(cls, indices) -> "ModelMap":
        try:
            values = np.asarray(indices)
        except (TypeError, ValueError):
            values = np.empty(0)
        if values.ndim != 2 or not 0 < min(values.shape) <= max(values.shape) <= MAX_MAP_SIDE:
            raise InputError(f"a model map is a 2-D array of 1 to {MAX_MAP_SIDE} pixels a side, got shape "
                             f"{values.shape}", "models_map")
        numeric = values.dtype.kind in "iub" or values.dtype.kind == "f" and np.isfinite(values).all()
        if not (numeric and (values == np.round(values)).all() and 0 <= values.min() and values.max() < MAX_MODELS):
            raise InputError(f"a model map holds models' indices, whole numbers 0 to {MAX_MODELS - 1}", "models_map")
        return cls(tuple(int(n) for n in values.shape), values.astype(np.uint8).tobytes())

    @classmethod
    def of_text(cls, text: str) -> "ModelMap":
        """A map written as text, rows (along the first horizontal axis) parted
        by ';' and a row's pixels by ',': '0,1;1,0'."""
        try:
            rows = [[int(pixel) for pixel in row.split(",")] for row in text.split(";")]
        except ValueError:
            rows = None
        if not rows or len({len(row) for row in rows}) != 1:
            raise InputError(f"a model map's text is rows of whole numbers, ',' between pixels and ';' between "
                             f"rows, all rows as long (0,1;1,0), got {text[:40]!r}", "models_map")
        return cls.of(rows)

    def array(self) -> np.ndarray:
        """(R, C) uint8."""
        return np.frombuffer(self.data, np.uint8).reshape(self.shape)

    def at(self, r: int, c: int) -> int:
        """The index at pixel (r, c), the edge's beyond the map."""
        return int(self.array()[min(max(r, 0), self.shape[0] - 1), min(max(c, 0), self.shape[1] - 1)])


def parse_model_map(data: bytes, suffix: str, name) -> ModelMap:
    """A model map from a file's bytes: an image (.png: a palette image's
    indices, or a greyscale image's values, laid out as a height map's
    image) or an array (.npy: [i, j] tile (i, j)'s model index). `name` says
    what the bytes are in messages."""
    if len(data) > MAX_MAP_BYTES:
        raise InputError(f"{name}: {len(data) >> 20} MB is too large for a model map", "models_map")
    suffix = suffix.lower()
    if suffix == ".npy":
        return ModelMap.of(read_npy_map(data, name, "models_map"))
    if suffix != ".png":
        raise InputError(f"{name}: a model map is a .png image or a .npy array, got {suffix or 'no extension'!r}",
                         "models_map")

    def indices(image) -> np.ndarray:
        if image.mode not in ("P", "L", "I", "I;16", "1"):
            raise InputError(f"{name}: a model map is a palette or greyscale image (a model's index per pixel), "
                             f"got mode {image.mode}", "models_map")
        return np.asarray(image).astype(np.int64)

    return ModelMap.of(np.flipud(image_pixels(data, name, "a model map", "models_map", indices)).T)


def read_model_map(path) -> ModelMap:
    """parse_model_map of a file."""
    path = Path(path)
    data = read_regular(path, f"the model map {path}", MAX_MAP_BYTES, field="models_map")
    return parse_model_map(data, path.suffix, path.name)
