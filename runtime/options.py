"""A sample request's options, declared once: each option's name, type,
range, default, help and the kind of request or edit it goes with.

`request.SampleRequest` has one field per option and checks its values
against this table; every front end (the command line, the HTTP routes,
the page and its worker, Blender) offers the options from it or is held to
it by a test (docs/ARCHITECTURE.md, "A sample's options"). The module is
plain data, light to import: `sinrun --help` builds its options from it
without loading the runtime, and `options_json` gives the browser its copy
(serve/static/sinshape/options.js, written by `python -m sinshape.runtime.options`).
"""

import dataclasses
import json
import math
import sys
from dataclasses import dataclass

from sinshape.core.files import OUTPUT_FORMATS
from sinshape.core.manifest import ARRANGEMENTS

SMOOTHERS = ("laplacian", "taubin")  # mesh.smoothed's filters
# Smoothing spreads each vertex over about sqrt(iterations) grid steps, and
# costs one pass over the mesh per iteration: 100 iterations already blur
# over about 10 steps, the size of the patches the model learnt (the paper
# smooths 3 times), so more would only erase the shape, slowly.
MAX_SMOOTH = 100
MAX_TILE = 1 << 62  # |i|, |j| below this: a window index and its neighbour fit in 64 bits in every runtime

# A scattered world's defaults. The share of its cells that hold an object:
# 0.75 left the temple's height field 0.28 correlated at a cell's side (3
# tiles), 0.6 under 0.1. A cell's side in tiles: an object (2S + 1) and up to
# S of room.
DENSITY = 0.6
SPACING = 3.0
MAX_SPACING = 64.0  # tiles: an object in every 64 x 64 tiles at most

FRAMES = ("input", "model", "tile")
MAX_PARTS = 16  # boxes kept in one sample: each runs a whole chain of its own
EDITS = ("keep", "grow", "layout")
NAMINGS = ("gltf", "godot", "unreal")  # how an asset's levels and collision mesh are named (asset.AssetOptions.naming)
KINDS = ("sample", "tile")  # what a request makes: a sample (plain or edited), or a tile of a world
# What an option's value is: a seed; a flag; a whole number or any number in
# its range; factors, one for all three axes or three; one of its choices;
# kept parts; the values no text spells (a Layout, a tile, a HeightMap,
# other models' files, a ModelMap); and an asset's triangle counts
# ('20000,5000,1200').
TYPES = ("seed", "bool", "int", "number", "factors", "choice", "parts", "layout", "tile", "heights", "models",
         "models_map", "counts")


@dataclass(frozen=True)
class Option:
    """One option of a sample request, declared once: `SampleRequest` checks
    its value against it, and every front end (the command line, the HTTP
    routes, the page, its worker, Blender) offers it from this record or is
    held to it by a test (docs/ARCHITECTURE.md, "A sample's options").

    type: TYPES; default: SampleRequest's; low, high: its range (of each
    number, or, for parts, how many), either None for no bound, with
    `bounds` saying which ends are in it ('[]', '[)', '(]' or '()');
    choices: a choice's values; goes_with: the KINDS of request it is for,
    or the one edit (EDITS) it belongs to; help: what it does, in the words
    every front end shows."""

    name: str
    type: str
    default: object
    help: str
    goes_with: tuple = ("sample",)
    low: float | None = None
    high: float | None = None
    bounds: str = "[]"
    choices: tuple = ()

    def __post_init__(self):
        """A record the table could not hold is a programming error, found at import."""
        known = self.type in TYPES and set(self.goes_with) <= {*KINDS, *EDITS}
        if not known or self.bounds not in ("[]", "[)", "(]", "()"):
            raise ValueError(f"option {self.name}: type {self.type!r}, goes_with {self.goes_with!r}, "
                             f"bounds {self.bounds!r}")

    def admits(self, value) -> bool:
        """Whether a number lies in the option's range (and is finite)."""
        above = self.low is None or (value > self.low if self.bounds[0] == "(" else value >= self.low)
        below = self.high is None or (value < self.high if self.bounds[1] == ")" else value <= self.high)
        return above and below and math.isfinite(value)

    def as_json(self) -> dict:
        """The record as JSON values (the browser's copy, sinshape/options.js)."""
        fields = dataclasses.asdict(self)
        for name in ("default", "goes_with", "choices"):
            if isinstance(fields[name], tuple):
                fields[name] = list(fields[name])
        return fields


# The options of a sample request, in SampleRequest's order: its fields are these.
OPTIONS = (
    Option("seed", "seed", None, "The seed of the sample (the same seed gives the same shape); default 0, unless "
           "recon.", ("sample", "tile"), 0, 2**63, "[)"),
    Option("recon", "bool", False, "The training shape itself (the fixed reconstruction noise), not a new sample."),
    Option("size", "factors", (1.0, 1.0, 1.0), "Sample size as factors of the training size: one factor, or "
           "three for another aspect ratio (2,1,1 is twice as long along x).", low=0, bounds="()"),
    Option("scale", "number", 1.0, "Query the shape on a grid this many times finer per axis (any positive "
           "number). Finer grids give smoother surfaces; from 2 on, a sample also takes its example's relief "
           "finer than a voxel (see detail).", ("sample", "tile"), 0, bounds="()"),
    Option("smooth", "int", 0, f"Smoothing iterations, 0 to {MAX_SMOOTH} (the paper uses 3 Laplacian iterations); "
           f"{MAX_SMOOTH} already blurs over about 10 grid steps, the size of the patches the model learnt.",
           low=0, high=MAX_SMOOTH),
    Option("smoother", "choice", SMOOTHERS[0], "Laplacian (as the paper) or Taubin (keeps volume).",
           choices=SMOOTHERS),
    Option("largest", "bool", False, "Keep only the largest connected piece."),
    Option("detail", "bool", True, "The example's own surface detail, read by correspondence: its relief finer "
           "than a voxel on a mesh at scale 2 or finer, and a coloured model's colour. Off: the voxels' surface "
           "and the decoder's colour, several times faster at scale 2 and above.", ("sample", "tile")),
    Option("frame", "choice", FRAMES[0], "Vertex coordinates: the training mesh's frame (samples overlay it), "
           "finest-voxel units, or, for a tile, the training mesh's units from the tile's own corner (any tile).",
           ("sample", "tile"), choices=FRAMES),
    Option("keep", "parts", (), "Take this box from the sample of SEED, the rest from the seed, joined without a "
           "seam: SEED:X0,Y0,Z0:X1,Y1,Z1, corners in the model's frame or as percentages "
           "(3:0%,0%,0%:50%,100%,100% is the lower half along x); several for more parts.", ("keep",),
           0, MAX_PARTS),
    Option("grow", "factors", None, "Grow the sample by these factors (one, or three, each at least 1), keeping "
           "what it had: new ground joining the old without a seam.", ("grow",), 1, bounds="[)"),
    Option("anchor", "factors", None, "With grow: where the old sample sits in the new, per axis from 0 (the low "
           "side, the default) to 1 (the high side); 0.5 centres it.", ("grow",), 0, 1),
    Option("layout", "layout", None, "Generate with the structure of this coarse layout (an occupancy grid of one "
           "of the model's levels); the seed still varies the detail.", ("layout",)),
    Option("tile", "tile", None, "A tile (i, j) of the endless world of the seed instead of a sample: it joins "
           "its neighbours without a seam.", ("tile",), -MAX_TILE, MAX_TILE, "()"),
    Option("arrange", "choice", ARRANGEMENTS[0], "blend: samples blended into one continuing surface (terrain, "
           "rock, walls); scatter: whole samples at drawn places on a ground (a temple, a tower).", ("tile",),
           choices=ARRANGEMENTS),
    Option("heights", "heights", None, "The world's large shape: a height in voxels per pixel, each a square "
           "of the tiles' longer side.", ("tile",)),
    Option("lod", "int", 0, "Levels of detail coarser than the finest: a distant tile, cheaper, with a skirt "
           "that hides the crack where it meets a finer one.", ("tile",), 0),
    Option("skirt", "bool", False, "A skirt at lod 0 too: a full tile beside a coarser one, so that the crack "
           "between them is hidden from the coarser side as well.", ("tile",)),
    Option("underside", "bool", True, "The tile closed underneath, as a solid piece of ground. Off: open below, "
           "for a view from above, which never sees it (a quarter fewer triangles on a terrain tile).", ("tile",)),
    Option("density", "number", DENSITY, "A scattered world's share of cells that hold an object, above 0 and "
           "at most 1.", ("tile",), 0.0, 1.0, "(]"),
    Option("spacing", "number", SPACING, "A scattered world's cell side in tiles (one object at most per cell, "
           "anywhere in it; at least its widest object and half a tile).", ("tile",), 1.0, MAX_SPACING),
    Option("models", "models", (), "A scattered world's other models (model files; a server's by name): model "
           "1, 2, ... of its model map, the first model being 0.", ("tile",)),
    Option("models_map", "models_map", None, "Which model goes where in a scattered world: a model's index per "
           "pixel, laid as the height map's (0 the first model); each object is drawn from the model its cell's centre's pixel names "
           "(a query's text: rows parted by ';', a row's pixels by ','; 0,1;1,0).", ("tile",)),
)
OPTION = {option.name: option for option in OPTIONS}

# A game asset's options (asset.AssetOptions, what makes a request's mesh a
# .glb): the command line, the HTTP routes and Blender's Export Asset offer
# them from these records, and AssetOptions checks their ranges here; each
# but `lods` needs `lods`. goes_with: the KINDS it is for (a tile keeps its
# world's frame and is open at its sides: no height, no hulls).
ASSET_OPTIONS = (
    Option("lods", "counts", None, "Write a game asset (.glb): levels of detail of these triangle counts, finest "
           "first, e.g. 20000,5000,1200, simplified from the full-resolution surface, each with its own UVs and "
           "maps baked from the model (normal, and colour for a coloured model).", KINDS, 4),
    Option("texture", "int", None, "Texels per side of the finest level's maps, a power of two from 16 to 8192, "
           "halved level by level. Default: sized to the sample, the least power of two whose square holds the full "
           "mesh's vertices (at most 2048), so that the maps show what the full mesh shows and weigh less.", KINDS,
           16, 8192),
    Option("ao", "bool", False, "Bake ambient occlusion too.", KINDS),
    Option("height", "number", None, "The asset's height in metres, base to top (glTF's unit); without it, one "
           "unit of the training mesh is a metre. A sample's asset stands with the centre of its base at the "
           "origin.", ("sample",), 0.001, 10000.0),
    Option("collision", "int", None, "A collision mesh (positions and triangles, no maps) of this many triangles, "
           "simplified from the full-resolution surface; 0: none. Default: the coarsest level's own triangles, its "
           "vertices shared (no bytes added).", KINDS, 0),
    Option("hulls", "int", 0, "A collision of at most this many convex hulls (CoACD's decomposition; a second or "
           "two), what engines simulate fastest and Unreal's only collision; 0: none.", ("sample",), 0, 64),
    Option("naming", "choice", NAMINGS[0], "Where the collision goes and how it is named. Every naming shows the "
           "finest level alone in the scene, lists the coarser ones by MSFT_lod (Babylon.js, UnityGLTF) and names "
           "them with Godot's import hints, which Godot 3 reads: one level shown, the collision made a static "
           "body's shapes. gltf: the collision outside the scene, not drawn; godot: the collision in the scene "
           "too, for Godot 4, whose importer reads the scene alone (other importers then draw it); unreal: the "
           "hulls in the scene, named UCX_, Unreal's convex collision of the finest level.", KINDS, choices=NAMINGS),
    Option("quantise", "bool", False, "Store the vertices as 8- and 16-bit integers (KHR_mesh_quantization, a "
           "required extension: Blender, three.js, Babylon.js and glTFast read it; Godot 3 does not, so not with "
           "naming godot).", KINDS),
    Option("compress", "bool", False, "Compress the geometry with meshoptimizer's codecs (EXT_meshopt_compression, "
           "a required extension, on quantised vertices: three.js with its meshopt decoder, Babylon.js, glTFast and "
           "gltf-transform read it; Godot 3 does not, so not with naming godot).", KINDS),
    Option("ktx2", "bool", False, "Store the maps as KTX2 files of Basis Universal with their mip-maps "
           "(KHR_texture_basisu, a required extension), which a GPU keeps compressed: needs Basis Universal's "
           "`basisu` encoder on PATH; three.js (KTX2Loader), Babylon.js and glTFast read it, Godot 3 does not, so "
           "not with naming godot.", KINDS),
)
ASSET_OPTION = {option.name: option for option in ASSET_OPTIONS}


def options_json() -> list:
    """The table as JSON values, for front ends outside Python."""
    return [option.as_json() for option in OPTIONS]


def module_js() -> str:
    """The browser's copy of the table: serve/static/sinshape/options.js."""
    rows = ",\n".join(f"  {json.dumps(row)}" for row in options_json())
    return ("// A sample request's options, as runtime/options.py declares them: written by\n"
            "// `python -m sinshape.runtime.options > serve/static/sinshape/options.js`, never by hand\n"
            "// (tests/test_options.py compares).\n"
            f"export const OPTIONS = Object.freeze([\n{rows},\n]);\n"
            "export const OPTION = Object.freeze(Object.fromEntries(OPTIONS.map((option) => [option.name, option])));\n"
            "/** Whether a number lies in an option's range (and is finite), as Option.admits. */\n"
            "export function admits({ low, high, bounds }, value) {\n"
            "  const above = low === null || (bounds[0] === '(' ? value > low : value >= low);\n"
            "  const below = high === null || (bounds[1] === ')' ? value < high : value <= high);\n"
            "  return above && below && Number.isFinite(value);\n"
            "}\n"
            "// The formats a sample is written in (core.files.OUTPUT_FORMATS).\n"
            f"export const FORMATS = Object.freeze({json.dumps(OUTPUT_FORMATS)});\n")


if __name__ == "__main__":
    sys.stdout.write(module_js())
