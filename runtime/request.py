"""One sample request: what every front end asks the runtime to make.

A `SampleRequest` is a small frozen value: which sample (a seed, or the
training shape), its size, how its surface is made (scale, smoothing, frame)
and at most one edit (parts kept from other samples, a grown extent, or a
coarse layout). Making one checks it: a bad value raises InputError naming
its field, values that do not go together raise ConflictError naming them
all. These are the only rules of a sample request; the command line, the
HTTP routes, batch and Ray jobs and the Blender extension build this value
and hand it to `make` (or to the writers in `write`, which call it), and the
browser runtime's request.js mirrors it field for field.

What needs the model (a kept box inside the sample, a layout's grid size,
the memory a size needs) is checked by `resolved` and `make`, which take it.
"""

import dataclasses
import functools
import math
import numbers
import os
from dataclasses import dataclass

import numpy as np

from sinshape.core import budget
from sinshape.core.errors import ConflictError, InputError, MemoryLimitError, named
from sinshape.core.manifest import MAX_LEVEL_SIDE

from . import edit, generate, layout, mesh, query
from .edit import Part
from .load import default_threads, load_model
from .options import EDITS, FRAMES, MAX_PARTS, OPTION, OPTIONS  # noqa: F401  the request's table
from .world import ARRANGEMENTS, WorldOptions, check_tile
from .world_maps import HeightMap, ModelMap, read_height_map, read_model_map

@dataclass(frozen=True)
class Layout:
    """A coarse layout to generate from: an (X, Y, Z) occupancy grid of one
    of the sample's level sizes (any size with `resample`, fitted to level
    0's), held as packed bits so that a request stays a hashable value
    (equal layouts, equal requests)."""

    shape: tuple
    bits: bytes
    resample: bool = False

    def __post_init__(self):
        """A layout held elsewhere (a .blend, a request) is checked as one read from a file."""
        shape = self.shape
        if not (isinstance(shape, tuple) and len(shape) == 3
                and all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and 1 <= n <= MAX_LEVEL_SIDE
                        for n in shape)):
            raise InputError(f"a layout is a 3-D grid of 1 to {MAX_LEVEL_SIDE} cells per axis, got shape {shape!r}",
                             "layout")
        needed = -(-math.prod(shape) // 8)
        if not isinstance(self.bits, bytes) or len(self.bits) != needed:
            got = f"{len(self.bits)} bytes" if isinstance(self.bits, bytes) else type(self.bits).__name__
            raise InputError(f"a {'x'.join(map(str, shape))} layout is {needed} bytes of packed cells, got {got}",
                             "layout")

    @classmethod
    def of(cls, grid, resample: bool = False) -> "Layout":
        grid = np.asarray(grid)
        if grid.ndim != 3 or 0 in grid.shape:
            raise InputError(f"a layout is a 3-D grid, got shape {grid.shape}", "layout")
        if not (grid.dtype == bool or np.issubdtype(grid.dtype, np.number) and np.isfinite(grid).all()):
            raise InputError("a layout holds occupancy, numbers in [0, 1]: not NaN, infinities or other things",
                             "layout")
        return cls(tuple(int(n) for n in grid.shape), np.packbits(grid.ravel() > 0.5).tobytes(), bool(resample))

    def grid(self) -> np.ndarray:
        """(X, Y, Z) bool."""
        count = int(np.prod(self.shape))
        return np.unpackbits(np.frombuffer(self.bits, np.uint8), count=count).astype(bool).reshape(self.shape)


def per_axis(value, field: str, valid, wanted: str):
    """One number for all three axes, or three: a tuple of floats passing `valid`."""
    values = (value,) * 3 if isinstance(value, numbers.Real) else value
    try:
        values = tuple(values)
    except TypeError:
        values = ()
    if not (len(values) == 3 and all(isinstance(v, numbers.Real) and not isinstance(v, bool) and valid(v)
                                     for v in values)):
        raise InputError(f"`{field}` must be {wanted}, got {value!r}", field)
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class SampleRequest:
    """One sample and how to make it.

    seed: the sample's seed, an integer in [0, 2**63) (None: 0, unless
      `recon`); recon: the training shape itself (the reconstruction),
      which has no seed, no other size and no edits.
    size: factors of the training size, one or per axis (any size and aspect ratio).
    scale: the surface is queried on a grid this many times finer per axis.
    smooth, smoother: smoothing iterations (0 to MAX_SMOOTH) and which (SMOOTHERS);
    largest: keep only the largest connected piece; detail: the example's
      relief (on a mesh at scale 2 or finer) and colour, read by
      correspondence (off: the voxels' surface and the colour head); frame: the vertices'
      frame ('input': the training mesh's, 'model': finest voxels; for a
      tile, 'tile': the input's units from the tile's lowest corner, precise
      at any distance from the world's origin).
    tile: (i, j), a tile of the endless world of `seed` (world.py) instead
      of a sample: no size, edits or clean-up, which would break its seams.
    For a tile, how its world is made: arrange ('blend' or 'scatter',
      world.ARRANGEMENTS), heights (a world_maps.HeightMap: the world's large
      shape), lod (levels coarser than the finest: a distant tile), skirt
      (a skirt at lod 0 too, for a full tile beside a coarser one), underside
      (closed underneath; off: open below, for a view from above), density
      and spacing (a scattered world's share of cells holding an object and
      its cells' side in tiles), models
      (a scattered world's other models: their files' paths, as text) and
      models_map (a world_maps.ModelMap: which model each cell's object is of).
    At most one edit:
    keep: parts taken from other samples (edit.Part, or their text form
      'SEED:X0,Y0,Z0:X1,Y1,Z1', read against the model by `resolved`);
    grow: factors (each at least 1) the sample grows by, keeping what it
      had; anchor: where it sits in the grown one (per axis, 0 low to 1 high);
    layout: a Layout, the structure to generate with.
    """

    seed: int | None = None
    recon: bool = False
    size: tuple = (1.0, 1.0, 1.0)
    scale: float = 1.0
    smooth: int = 0
    smoother: str = "laplacian"
    largest: bool = False
    detail: bool = True
    frame: str = "input"
    keep: tuple = ()
    grow: tuple | None = None
    anchor: tuple | None = None
    layout: Layout | None = None
    tile: tuple | None = None
    arrange: str = "blend"
    heights: HeightMap | None = None
    lod: int = 0
    skirt: bool = False
    underside: bool = True
    density: float = OPTION["density"].default
    spacing: float = OPTION["spacing"].default
    models: tuple = ()
    models_map: ModelMap | None = None

    def __post_init__(self):
        def set_field(name, value):
            object.__setattr__(self, name, value)

        if self.seed is not None and not (isinstance(self.seed, (int, np.integer)) and not isinstance(self.seed, bool)
                                          and OPTION["seed"].admits(self.seed)):
            raise InputError(f"`seed` must be an integer in [0, 2**63), got {self.seed!r}", "seed")
        set_field("seed", None if self.seed is None else int(self.seed))
        set_field("size", per_axis(self.size, "size", OPTION["size"].admits, "one or three positive factors"))
        if not (isinstance(self.scale, numbers.Real) and OPTION["scale"].admits(self.scale)):
            raise InputError(f"`scale` must be a positive number, got {self.scale}", "scale")
        smooth = OPTION["smooth"]
        if not (isinstance(self.smooth, numbers.Integral) and smooth.admits(self.smooth)):
            raise InputError(f"`smooth` must be {smooth.low} to {smooth.high} iterations, got {self.smooth}", "smooth")
        for name in ("smoother", "frame"):
            if getattr(self, name) not in OPTION[name].choices:
                raise InputError(f"unknown `{name}` {getattr(self, name)!r}; choose {' or '.join(OPTION[name].choices)}",
                                 name)
        for name in (option.name for option in OPTIONS if option.type == "bool"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"`{name}` is true or false, got {getattr(self, name)!r}", name)
            set_field(name, bool(getattr(self, name)))
        keep = (self.keep,) if isinstance(self.keep, (str, Part)) else self.keep
        keep = tuple(keep) if isinstance(keep, (tuple, list)) else (None,)
        if not OPTION["keep"].admits(len(keep)) or not all(isinstance(part, (str, Part)) for part in keep):
            raise InputError(f"`keep` takes at most {OPTION['keep'].high} parts, each a Part or its text "
                             f"SEED:X0,Y0,Z0:X1,Y1,Z1", "keep")
        set_field("keep", keep)
        if self.grow is not None:
            set_field("grow", per_axis(self.grow, "grow", OPTION["grow"].admits, "one or three factors of at least 1"))
        if self.anchor is not None:
            set_field("anchor", per_axis(self.anchor, "anchor", OPTION["anchor"].admits, "three fractions in [0, 1]"))
        if self.layout is not None and not isinstance(self.layout, Layout):
            raise InputError("`layout` must be a request.Layout (Layout.of(grid))", "layout")
        if self.tile is not None:
            set_field("tile", check_tile(self.tile))
        models = (self.models,) if isinstance(self.models, str) else self.models
        if not (isinstance(models, (tuple, list)) and all(isinstance(path, str) for path in models)):
            raise InputError("`models` is the world's other models' files, as paths", "models")
        set_field("models", tuple(models))
        self.world_options()  # its fields' own checks
        self.check_together()

    @classmethod
    def of(cls, fields: dict) -> "SampleRequest":
        """The request of a front end's values by option name (OPTIONS); a
        name no option has is refused (InputError), never dropped."""
        unknown = [name for name in fields if name not in OPTION]
        if unknown:
            raise InputError(f"a sample request has no field {unknown[0]!r}; its fields are {', '.join(OPTION)}",
                             unknown[0])
        return cls(**fields)

    def check_together(self) -> None:
        """The rules of which fields go together."""
        given = self.edits()
        if len(given) > 1:
            raise ConflictError(f"give one of {named(given)}", tuple(given))
        if self.anchor is not None and self.grow is None:
            raise ConflictError("`anchor` is for `grow`", ("anchor", "grow"))
        if self.recon:
            if self.seed is not None:
                raise ConflictError("give `seed` or `recon`, not both", ("seed", "recon"))
            if given:
                raise ConflictError(f"`{given[0]}` edits a new sample, and `recon` is the training shape: "
                                    "give `seed`, not `recon`", (given[0], "recon", "seed"))
            if self.size != (1.0, 1.0, 1.0):
                raise InputError("the reconstruction exists only at the training size; drop `size`", "size")
        if self.tile is not None:
            kept = [name for name, value in (("recon", self.recon), *((edit, True) for edit in given),
                                             ("size", self.size != (1.0, 1.0, 1.0)), ("smooth", self.smooth),
                                             ("largest", self.largest)) if value]
            if kept:
                raise ConflictError(f"a tile shares its border with its neighbours, which `{kept[0]}` would break: "
                                    f"give `tile` or {named(kept)}", ("tile", *kept))


    def world_options(self) -> WorldOptions:
        """How a tile's world is made, and how finely the tile."""
        return WorldOptions(self.arrange, self.heights, self.lod, tuple(map(other_model, self.models)),
                            self.models_map, self.detail, self.skirt, self.underside, self.density, self.spacing)

    def world_fields(self) -> list:
        """The names of the world's fields given other than their defaults
        (a job of many tiles holds them in a request without a tile)."""
        return [name for name, value in (("arrange", self.arrange != ARRANGEMENTS[0]),
                                         ("heights", self.heights is not None), ("lod", self.lod),
                                         ("skirt", self.skirt), ("underside", not self.underside),
                                         ("density", self.density != OPTION["density"].default),
                                         ("spacing", self.spacing != OPTION["spacing"].default),
                                         ("models", self.models), ("models_map", self.models_map is not None))
                if value]

    def edits(self) -> list:
        """The names of the edits given."""
        return [name for name, value in (("keep", self.keep), ("grow", self.grow), ("layout", self.layout)) if value]

    @property
    def sample_seed(self) -> int | None:
        """The seed whose noise makes the sample (None: the training shape)."""
        return None if self.recon else self.seed or 0

    def mesh_options(self) -> dict:
        """How the surface is made: keyword arguments of mesh.extract and write.write_sample."""
        return dict(scale=self.scale, smooth=self.smooth, smoother=self.smoother, largest=self.largest,
                    frame=self.frame, detail=self.detail)

    def with_seed(self, seed: int) -> "SampleRequest":
        """The same request for another seed (a batch job's samples)."""
        return dataclasses.replace(self, seed=seed)


def other_model(path: str):
    """A world's other model, read from its file (checked as any model is)
    once per process while the file stays as it is (a worker's tiles all
    ask): a file written again since is read again."""
    try:
        found = os.stat(path)
    except OSError:
        return load_model(path)  # its own clear error
    return model_as_written(path, found.st_mtime_ns, found.st_size)


@functools.lru_cache(maxsize=16)
def model_as_written(path: str, modified: int, size: int):
    """The model in `path` as it was when last modified at `modified` (ns) with `size` bytes."""
    return load_model(path)


def resolved(model, request: SampleRequest) -> SampleRequest:
    """The request with its kept parts read against the model (text to
    edit.Part, in finest voxels, checked inside the sample): equal parts,
    however written, then make equal requests. A resolved request is
    returned as it is."""
    finest = generate.scaled_sizes(model.manifest.sizes, request.size)[-1]
    parts = tuple(edit.parse_part(part, model.manifest, finest) if isinstance(part, str) else edit.check_part(part, finest)
                  for part in request.keep)
    return request if parts == request.keep else dataclasses.replace(request, keep=parts)


# What a sample is made for, and so what its memory check counts besides the
# tri-plane: a whole mesh in memory, a mesh streamed to a file slab by
# slab, a dense occupancy grid, or nothing more.
OUTPUTS = ("mesh", "stream", "grid", "planes")


def check_memory(model, request: SampleRequest, output: str = "mesh", per_face: int | None = None,
                 memory_limit: int | None = None) -> None:
    """Refuse up front, with the figure (MemoryLimitError), a request whose
    work would need more than memory_limit bytes (None: the memory
    available now), before any of it is done: making its tri-plane (the
    chain, a composition of kept parts, a layout's fit), then, with the
    tri-plane held, what `output` (OUTPUTS) asks: 'mesh' the band search
    and the whole mesh, its faces (mesh.estimate_faces) at per_face bytes
    each (None: mesh.held_per_face's); 'stream' the band search; 'grid' the
    dense grid; 'planes' nothing more. The faces are estimated (a meshing
    of the model's reconstruction, once) only where their most possible
    would not fit."""
    if output not in OUTPUTS:
        raise InputError(f"unknown `output` {output!r}; choose {', '.join(OUTPUTS)}", "output")
    if request.tile is not None:  # a world's tile is bounded by world.check_world_scale
        return
    factors = request.size if request.grow is None else tuple(f * g for f, g in zip(request.size, request.grow))
    sizes = generate.scaled_sizes(model.manifest.sizes, factors)
    channels, hidden, finest = model.manifest.channels, model.manifest.hidden, sizes[-1]
    making = generate.generation_memory(sizes, channels)
    if request.keep or request.grow is not None:
        making = max(making, edit.compose_memory(sizes, channels, max(1, len(request.keep))))
    if request.layout is not None:
        making = max(making, layout.fit_memory(sizes, hidden))
    held = generate.triplane_values(finest, channels) * 4
    what = f"a sample of size {'x'.join(f'{f:g}' for f in factors)}"
    what += f" at scale {request.scale:g}" if output != "planes" else ""
    if output == "planes":
        return budget.check_memory(making, what, memory_limit)
    if output == "grid":
        dense = query.dense_memory(finest, request.scale, hidden, model.manifest.colour)
        return budget.check_memory(max(making, held + dense), f"{what} as a dense grid", memory_limit)
    held += query.projected_memory(finest, hidden) + query.band_memory(finest, request.scale, hidden,
                                                                       2 * default_threads())
    if output == "stream":
        return budget.check_memory(max(making, held), what, memory_limit)
    per_face = mesh.held_per_face(request.smooth, largest=request.largest) if per_face is None else per_face
    most = mesh.MAX_FACES_PER_CELL * math.prod(query.grid_shape(finest, request.scale))
    try:
        budget.check_memory(max(making, held + most * per_face), what, memory_limit)
    except MemoryLimitError:
        faces = mesh.estimate_faces(model, finest, request.scale)
        budget.check_memory(max(making, held + faces * per_face), f"{what} with a mesh of about {faces:,} faces",
                            memory_limit)


def make(model, request: SampleRequest, memory_limit: int | None = None, output: str = "mesh",
         per_face: int | None = None):
    """The tri-plane (generate.TriPlane) of the sample the request asks for,
    made for `output` (OUTPUTS; per_face: check_memory's). Work needing more
    than memory_limit bytes (None: the memory available now), the meshing
    it is made for included, is refused up front with MemoryLimitError
    (check_memory)."""
    if request.tile is not None:
        raise InputError("a tile of a world has no tri-plane of its own: make its mesh with world_tiles.tile_mesh, or "
                         "its file with write.request_bytes", "tile")
    if request.frame == "tile":
        raise InputError("`frame` tile (coordinates from a tile's corner) is for the tiles of a world; a sample "
                         "is placed in `frame` input or model", "frame")
    if request.world_fields():
        field = request.world_fields()[0]
        raise InputError(f"`{field}` is for the tiles of a world; a sample has none", field)
    request = resolved(model, request)
    check_memory(model, request, output, per_face, memory_limit)
    seed, size = request.sample_seed, request.size
    if request.layout is not None:
        return layout.from_layout(model, seed, request.layout.grid(), size, request.layout.resample)
    if request.grow is not None:
        return edit.grow(model, seed, request.grow, request.anchor or (0.0, 0.0, 0.0), size, memory_limit)
    if request.keep:
        return edit.compose(model, seed, list(request.keep), size, memory_limit)
    return generate.sample(model, seed, size, memory_limit)


def warnings(model, request: SampleRequest) -> list:
    """What is worth a warning before the work, as InputError values (not
    raised; each names its field): a size that shrinks some level, or a
    scale that shrinks the final grid, below the smallest grid it can have
    (clamped, so the shape is not to scale)."""
    sizes = generate.scaled_sizes(model.manifest.sizes, request.size)  # refuses what is too large to round
    said = []
    if any(round(n * f) < generate.MIN_SIDE for size in model.manifest.sizes for n, f in zip(size, request.size)):
        said.append(InputError(f"`size` {','.join(f'{f:g}' for f in request.size)} shrinks some levels below "
                               f"{generate.MIN_SIDE} voxels; they are clamped, so the shape is not to scale", "size"))
    if any(n * request.scale < 1.5 for n in sizes[-1]):  # a side that rounds below 2 points
        said.append(InputError(f"`scale` {request.scale:g} leaves under 2 grid points on an axis; the grid is "
                               "clamped to 2 and the shape barely resolved", "scale"))
    return said


def world_request(model, fields: dict, height_map=None, relief: float | None = None, models=(),
                  models_map=None) -> SampleRequest:
    """The request of a world's tiles (no tile yet) as a front end is asked
    for it: `fields` the tile's options by name (runtime.options: seed,
    scale, frame, lod, ...), the model's own arrangement unless one is given,
    the height map and model map read from their files
    (world_maps.read_height_map, read_model_map), `models` the other models' files."""
    heights = read_height_map(height_map, model, relief) if height_map else None
    placed = read_model_map(models_map) if models_map else None
    return SampleRequest.of({**fields, "arrange": fields.get("arrange") or model.manifest.arrange, "heights": heights,
                             "models": tuple(str(path) for path in models), "models_map": placed})
