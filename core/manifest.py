"""The manifest: the JSON inside every sinshape .onnx file (docs/FORMAT.md).

It holds everything the runtime needs (level sizes, noise amplitudes, tensor
names of each stage, plane order, the input's frame) and how the model was
made. The trainer writes it with `stage_names` and checks it with `parse`;
the runtime reads it with `parse`. This module is the contract in code.
"""

import hashlib
import json
import math
import re
from dataclasses import dataclass

import numpy as np

from .errors import InputError

FORMAT_NAME = "sinshape"
# 3 seals the file's bytes with a SHA-256 at its end; 2 had a `checksum`
# field over the weights and manifest only; 1 had none. 4 is 3 with a colour
# head (`colour`); 5 carries the example's surface as tiles, read by
# correspondence: a coloured model's colour and relief (`colour.tiles`), or a
# geometry-only model's relief alone (`relief.tiles`). A geometry-only model
# without a mesh to take relief from (a voxel pyramid) is still written as 3.
# All five load.
FORMAT_VERSION = 3
COLOUR_VERSION = 4
TILES_VERSION = 5
READ_VERSION = TILES_VERSION  # the newest version this code reads
COLOUR_SPACE = {"space": "srgb"}  # manifest `colour`: values are sRGB-encoded in [0, 1]
# Initializers of a format-5 model's tiles (prep/appearance.py, docs/FORMAT.md):
# (N, 3) int32 voxels, (N,) uint8 directions, (N, T, T, 4) uint8 images (sRGB
# and depth; a relief-only model's (N, T, T, 1), depth alone), and the finest
# level's (X, Y, Z) int8 signed distance to the example's surface.
TILE_TENSORS = ("colour_tiles.voxels", "colour_tiles.directions", "colour_tiles.images", "colour_tiles.distance")
MAX_TILE_SIDE = 64
# How colour_tiles encode where the surface lies (docs/FORMAT.md): prep writes them, the runtime reads them.
DEPTH_RANGE = 0.5  # an image's fourth byte, 0..255, spans this many voxels either side of the voxel's centre
DISTANCE_STEP = 1 / 63.5  # voxels per unit of colour_tiles.distance: its int8 holds -2..2 voxels
METADATA_KEY = "sinshape.manifest"  # key of the manifest in the ONNX metadata_props
SEAL_KEY = "sinshape.sha256"  # key of the last metadata_props entry: the seal (format 3 on)
NOISE_SCHEME = "splitmix64-boxmuller-v1"  # core/noise.py
UP_AXES = ("y", "z")  # manifest `up`: which input-frame axis points up (absent: y)
UP_AXIS = {"y": 1, "z": 2}  # the index of each
ARRANGEMENTS = ("blend", "scatter")  # manifest `arrange`: how the model's world is made unless asked (absent: blend)
# Manifest `contrast`: a blended world's contrast exponent (absent: CONTRAST).
# 1 keeps the variance of independent Gaussian windows; the head's threshold
# is not linear, and each model wants its own: 1.3 leaves the terrain's
# relief at tile centres 5% below its corners', the coloured terrain needs
# 2.0 (28% below at 1.3). `sinrun orient --contrast` records it.
CONTRAST = 1.3
CONTRAST_RANGE = (0.5, 4.0)
# Manifest `object_scale`: in a scattered world of several models, how many
# of the world's voxels one of this model's spans, against the world's first
# model's (absent: 1, a voxel of each model alike). `sinrun orient
# --object-scale` records it.
OBJECT_SCALE_RANGE = (1 / 16, 16.0)
PLANES = ("xy", "xz", "yz")  # plane k drops grid axis 2 - k
PLANE_AXES = ((0, 1), (0, 2), (1, 2))  # the grid axes each plane keeps, in PLANES order
# Initializers of stage decoder_head, (D,), (D, 1), (1,): b1, w2, b2.
HEAD_WEIGHTS = ("decoder_head.bias1", "decoder_head.weight2", "decoder_head.bias2")
# Initializers of a coloured model's colour head, (D, 3), (3,): RGB = sigmoid(h @ w + b).
COLOUR_WEIGHTS = ("decoder_head.weight_colour", "decoder_head.bias_colour")
MAX_LEVELS = 64
MIN_LEVEL_SIDE = 8  # a level's side in voxels: trained levels have 15 or more
MAX_LEVEL_SIDE = 4096  # far above anything trainable
MAX_MANIFEST_CHARS = 1 << 20  # a real manifest is a few kB
MAX_DEPTH = 16  # JSON nesting; a real manifest nests 5 deep
MAX_NOISE_AMP = 100.0  # sigma_i; trained amplitudes are below 1
MAX_COORD = 1e12  # |origin| and spacing: any more and the mesh's coordinates overflow float32
# A voxel's size in the input's units, at least: below it (or below one float32
# step at the origin's magnitude) every vertex of a mesh lands on one point.
MIN_SPACING = 1e-9
CHECKSUM_RE = re.compile(r"sha256:[0-9a-f]{64}")


def linear_to_srgb(linear):
    """The sRGB transfer function (IEC 61966-2-1) of `colour`'s space, on
    numpy arrays of values in [0, 1] (glTF's colours are linear)."""
    linear = np.clip(linear, 0, 1)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def srgb_to_linear(srgb):
    """linear_to_srgb undone."""
    srgb = np.clip(srgb, 0, 1)
    return np.where(srgb <= 0.04045, srgb / 12.92, np.power((srgb + 0.055) / 1.055, 2.4))


def plane_sizes(size) -> list:
    """Plane sizes of a grid (X, Y, Z), in PLANES order: [(X, Y), (X, Z), (Y, Z)]."""
    return [(size[a], size[b]) for a, b in PLANE_AXES]


def stage_names(levels: int, colour: bool = False) -> dict:
    """Input and output tensor names of every stage, as the trainer writes
    them; a coloured model's head has a second output, its RGB."""

    def io(stage):
        return {"inputs": [f"{stage}.{p}" for p in PLANES], "outputs": [f"{stage}.{p}.out" for p in PLANES]}

    return {
        "projection": io("projection"),
        "levels": [io(f"level{i}") for i in range(levels)],
        "decoder_planes": io("decoder_planes"),
        "decoder_head": {"inputs": [f"decoder_head.{p}" for p in PLANES],
                         "outputs": ["decoder_head.occupancy"] + ["decoder_head.colour"] * colour},
    }


@dataclass(frozen=True)
class Manifest:
    """The parts of the manifest the runtime uses; `raw` keeps all of it."""

    sizes: list  # [(X, Y, Z)] per level, coarsest first
    noise_amps: list  # sigma_i per level; sigma_0 is the std of z0
    channels: int
    pool_bins: int
    hidden: int
    recon_seed: int
    origin: tuple  # input-frame position of the finest level's voxel (0, 0, 0)
    spacing: tuple  # input-frame size of one finest-level voxel, per axis
    stages: dict
    raw: dict
    up: str = "y"  # the input frame's axis that points up: "y" (most meshes) or "z" (voxel data)
    arrange: str = "blend"  # how its world is made unless asked: "blend" (a landscape) or "scatter" (an object)
    contrast: float = CONTRAST  # a blended world's contrast exponent
    object_scale: float = 1.0  # its objects' size in a world of several models, against the first model's
    colour: bool = False  # the decoder also gives sRGB colour (format 4)
    tiles: tuple | None = None  # format 5: (count, side) of the example's surface tiles

    @property
    def tile_channels(self) -> int:
        """Bytes per texel of its tiles: sRGB and depth, or a relief-only model's depth."""
        return 4 if self.colour else 1


def _require(ok: bool, message: str) -> None:
    if not ok:
        raise InputError(f"bad model manifest: {message}")


def _is_int(value, low, high) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _is_number(value) -> bool:
    if isinstance(value, int) and not isinstance(value, bool):
        return abs(value) <= 2**63  # math.isfinite of a huge int overflows
    return isinstance(value, float) and math.isfinite(value)


def _depth(text: str) -> int:
    """The deepest nesting of brackets outside strings, found without parsing
    (json.loads of a deep nesting raises RecursionError)."""
    depth = deepest = 0
    for token in re.finditer(r'"(?:[^"\\]|\\.)*"|[\[{]|[\]}]', text):
        t = token.group()
        if t in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif t in "]}":
            depth -= 1
    return deepest


def _plain(value, types) -> bool:
    """`value` is a dict of str -> values of `types`, or lists of them."""
    def ok(v):
        if isinstance(v, list):
            return all(ok(x) for x in v)
        return v is None or (isinstance(v, types) and (not isinstance(v, float) or math.isfinite(v)))

    return isinstance(value, dict) and all(isinstance(k, str) and ok(v) for k, v in value.items())


def checksum_v2(raw: dict, weights) -> str:
    """Format 2's `checksum` field: `sha256:` + hex digest over the manifest
    without `checksum` (canonical JSON: sorted keys, no spaces, ASCII) and
    then, for every initializer in order of name, its name, a zero byte and
    its float32 little-endian values. `weights`: (name, float32 array) pairs."""
    digest = hashlib.sha256()
    body = {k: v for k, v in raw.items() if k != "checksum"}
    digest.update(json.dumps(body, sort_keys=True, separators=(",", ":")).encode())
    for name, array in sorted(weights, key=lambda pair: pair[0]):
        digest.update(name.encode() + b"\0")
        digest.update(array.astype("<f4").tobytes())
    return "sha256:" + digest.hexdigest()


def _seal_prefix() -> bytes:
    """The seal's bytes before its digest: an ONNX ModelProto field 14
    (metadata_props) entry {key: SEAL_KEY, value: 64 hex digits}, in protobuf's
    wire format, so that any ONNX reader reads the sealed file unchanged."""
    key = SEAL_KEY.encode()
    entry_length = 2 + len(key) + 2 + 64
    return bytes([14 << 3 | 2, entry_length, 1 << 3 | 2, len(key)]) + key + bytes([2 << 3 | 2, 64])


SEAL_PREFIX = _seal_prefix()
SEAL_BYTES = len(SEAL_PREFIX) + 64


def seal(body: bytes) -> bytes:
    """A serialized ONNX model (without a seal) followed by its seal: the
    SHA-256 of every byte before it, so a runtime checks the whole file,
    graph, attributes, weights and manifest, with nothing but SHA-256."""
    return body + SEAL_PREFIX + hashlib.sha256(body).hexdigest().encode()


def unseal(data: bytes) -> tuple:
    """(body, sealed, intact): `sealed` when `data` ends with a seal, `intact`
    when its digest is that of the body. An unsealed file is all body."""
    tail = data[-SEAL_BYTES:]
    if len(data) <= SEAL_BYTES or not tail.startswith(SEAL_PREFIX):
        return data, False, False
    body = data[:-SEAL_BYTES]
    return body, True, hashlib.sha256(body).hexdigest().encode() == tail[len(SEAL_PREFIX):]


def parse(text: str) -> Manifest:
    """Check a manifest's JSON text, every field's type and range; raise
    InputError naming what is wrong."""
    _require(isinstance(text, str) and len(text) <= MAX_MANIFEST_CHARS, f"not JSON text of at most {MAX_MANIFEST_CHARS} characters")
    _require(_depth(text) <= MAX_DEPTH, f"JSON nested deeper than {MAX_DEPTH}")
    try:
        raw = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        raise InputError("bad model manifest: not valid JSON") from None
    except (ValueError, RecursionError):  # an integer of thousands of digits (Python 3.11+)
        raise InputError("bad model manifest: a number too large to read") from None
    _require(isinstance(raw, dict), "not a JSON object")
    _require(raw.get("format") == FORMAT_NAME, f"format is {raw.get('format')!r}, not {FORMAT_NAME!r}")
    version = raw.get("format_version")
    _require(_is_int(version, 1, 10**6), f"format_version {version!r} is not a positive integer")
    if version > READ_VERSION:
        raise InputError(
            f"model format version {version} is newer than this sinshape reads ({READ_VERSION}); upgrade sinshape"
        )
    colour = version >= COLOUR_VERSION
    tiles = None
    if version >= TILES_VERSION:
        # A coloured model's tiles are under `colour`, a relief-only model's under `relief`: one of the two.
        kind = "colour" if "colour" in raw else "relief"
        field = raw.get(kind)
        tiles = field.get("tiles") if isinstance(field, dict) else None
        _require(not ("colour" in raw and "relief" in raw), f"format {TILES_VERSION} has colour or relief, not both")
        _require(isinstance(field, dict) and set(field) == ({"space", "tiles"} if kind == "colour" else {"tiles"})
                 and field.get("space", "srgb") == "srgb"
                 and isinstance(tiles, dict) and set(tiles) == {"count", "side"}
                 and _is_int(tiles["count"], 1, 2**31 - 1) and _is_int(tiles["side"], 1, MAX_TILE_SIDE)
                 and tiles["side"] & (tiles["side"] - 1) == 0,
                 f'format {TILES_VERSION} needs colour {{"space": "srgb", "tiles": {{"count": N, "side": T}}}} or '
                 f'relief {{"tiles": {{"count": N, "side": T}}}}, T a power of two up to {MAX_TILE_SIDE}')
        colour = kind == "colour"
        tiles = (tiles["count"], tiles["side"])
    else:
        _require(raw.get("colour") == (COLOUR_SPACE if colour else None),
                 f"colour must be {json.dumps(COLOUR_SPACE)} in format {COLOUR_VERSION} and absent before it")
        _require("relief" not in raw, f"relief is read from format {TILES_VERSION} on, not {version}")
    if version == 2:
        _require(isinstance(raw.get("checksum"), str) and CHECKSUM_RE.fullmatch(raw["checksum"]) is not None,
                 "checksum must be 'sha256:' and 64 hex digits")
    _require(raw.get("planes") == list(PLANES), f"planes must be {list(PLANES)}")
    _require(raw.get("noise") == NOISE_SCHEME, f"noise scheme {raw.get('noise')!r} is not {NOISE_SCHEME!r}")
    for key in ("channels", "pool_bins", "mlp_hidden"):
        _require(_is_int(raw.get(key), 1, 1024), f"{key} must be an integer in [1, 1024]")
    _require(_is_int(raw.get("recon_seed"), 0, 2**64 - 1), "recon_seed must be an integer in [0, 2**64)")

    levels = raw.get("levels")
    _require(isinstance(levels, list) and 1 <= len(levels) <= MAX_LEVELS, f"levels must be a list of 1..{MAX_LEVELS}")
    sizes, amps = [], []
    for i, level in enumerate(levels):
        _require(isinstance(level, dict), f"level {i} is not an object")
        size = level.get("size")
        _require(isinstance(size, list) and len(size) == 3
                 and all(_is_int(n, MIN_LEVEL_SIDE, MAX_LEVEL_SIDE) for n in size),
                 f"level {i} size must be 3 integers in [{MIN_LEVEL_SIDE}, {MAX_LEVEL_SIDE}]")
        _require(i == 0 or all(a <= b for a, b in zip(sizes[-1], size)),
                 f"level {i} size {size} is smaller than level {i - 1}'s along an axis (levels grow)")
        amp = level.get("noise_amp")
        _require(_is_number(amp) and 0 <= amp <= MAX_NOISE_AMP, f"level {i} noise_amp must be a number in [0, {MAX_NOISE_AMP:g}]")
        sizes.append(tuple(size))
        amps.append(float(amp))

    _require(raw.get("up", "y") in UP_AXES, f"up must be one of {', '.join(UP_AXES)}")
    _require(raw.get("arrange", "blend") in ARRANGEMENTS, f"arrange must be one of {', '.join(ARRANGEMENTS)}")
    contrast = raw.get("contrast", CONTRAST)
    _require(_is_number(contrast) and CONTRAST_RANGE[0] <= contrast <= CONTRAST_RANGE[1],
             f"contrast must be a number in [{CONTRAST_RANGE[0]:g}, {CONTRAST_RANGE[1]:g}]")
    object_scale = raw.get("object_scale", 1.0)
    _require(_is_number(object_scale) and OBJECT_SCALE_RANGE[0] <= object_scale <= OBJECT_SCALE_RANGE[1],
             f"object_scale must be a number in [{OBJECT_SCALE_RANGE[0]:g}, {OBJECT_SCALE_RANGE[1]:g}]")
    frame = raw.get("frame")
    _require(isinstance(frame, dict), "frame is missing")
    origin, spacing = frame.get("origin"), frame.get("spacing")
    _require(isinstance(origin, list) and len(origin) == 3 and all(_is_number(v) and abs(v) <= MAX_COORD for v in origin),
             f"frame origin must be 3 numbers within +-{MAX_COORD:g}")
    _require(isinstance(spacing, list) and len(spacing) == 3
             and all(_is_number(s) and MIN_SPACING <= s and s * MAX_LEVEL_SIDE <= MAX_COORD for s in spacing),
             f"frame spacing must be 3 numbers in [{MIN_SPACING:g}, {MAX_COORD / MAX_LEVEL_SIDE:g}]")
    step = max(abs(v) for v in origin) * 2.0**-23  # float32's step at the origin
    _require(all(s > step for s in spacing),
             "frame spacing is below float32's step at the frame's origin: every vertex would land on the same points")
    _require(raw.get("created_by") is None or isinstance(raw["created_by"], str), "created_by must be a string")
    source = raw.get("source", {})
    _require(isinstance(source, dict) and all(isinstance(source.get(k, ""), str) for k in ("name", "sha256", "kind")),
             "source must be an object of strings name, sha256, kind")
    for key, types in (("config", (str, int, float, bool)), ("training", (str, int, float))):
        _require(_plain(raw.get(key, {}), types), f"{key} must be an object of plain values")
    res = raw.get("config", {}).get("res", 2)
    _require(_is_int(res, 1, MAX_LEVEL_SIDE), f"config res must be an integer in [1, {MAX_LEVEL_SIDE}]")
    training = raw.get("training", {})
    level_seconds = training.get("level_seconds") or []
    _require(_is_number(training.get("seconds", 0)) and isinstance(level_seconds, list)
             and all(_is_number(s) for s in level_seconds), "training seconds must be numbers")

    stages = raw.get("stages")
    _require(stages == stage_names(len(levels), colour), "stages do not name the standard tensors for this level count")
    return Manifest(
        sizes=sizes,
        noise_amps=amps,
        channels=raw["channels"],
        pool_bins=raw["pool_bins"],
        hidden=raw["mlp_hidden"],
        recon_seed=raw["recon_seed"],
        origin=tuple(float(v) for v in origin),
        spacing=tuple(float(v) for v in spacing),
        stages=stages,
        raw=raw,
        up=raw.get("up", "y"),
        arrange=raw.get("arrange", "blend"),
        contrast=float(contrast),
        object_scale=float(object_scale),
        colour=colour,
        tiles=tiles,
    )


def printable(value) -> str:
    """A file's text for a terminal: control characters escaped, so a string
    in a model cannot print a fake line or move the cursor."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(value))


def describe(raw: dict) -> list:
    """How a model was made, line by line, from a manifest that `parse` accepted."""
    def clock(seconds) -> str:
        seconds = int(seconds)
        return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"

    version = raw["format_version"]
    seal = {1: "no checksum", 2: "checksum over weights and manifest"}.get(version, "sealed")
    source, training, config = raw.get("source", {}), raw.get("training", {}), raw.get("config", {})
    lines = [
        f"format      {raw['format']} {version}, {seal}  ({printable(raw.get('created_by', '?'))})",
        f"trained on  {printable(source.get('name', '?'))} ({printable(source.get('kind', '?'))}, "
        f"sha256 {printable(source.get('sha256', '?'))[:12]}...)",
        f"training    {clock(training.get('seconds', 0))} wall time, "
        f"{printable(training.get('iterations_per_level', '?'))} iterations per level",
    ]
    if config.get("minutes") is not None:
        guessed, costs = (training.get(key) for key in ("estimated_levels", "measured_seconds_per_iteration"))
        guessed = guessed if isinstance(guessed, list) else []
        costs = costs if isinstance(costs, list) else []
        measured = ", ".join(("~" if i in guessed else "") + (f"{c:.2f}" if _is_number(c) else "?")
                             for i, c in enumerate(costs))
        lines.append(f"budget      {config['minutes']:g} min; planned {printable(training.get('planned_iterations', '?'))}"
                     f" iterations per level from s/iteration {measured or '?'}"
                     + (" (~ estimated)" if guessed else ""))
    rewinds = training.get("rewinds")
    for rewind in rewinds if isinstance(rewinds, list) else []:
        if isinstance(rewind, list) and len(rewind) == 4 and all(_is_number(v) for v in rewind):
            level, at, to, lr = rewind
            lines.append(f"diverged    level {level:g} at iteration {at:g}; went back to iteration {to:g} "
                         f"and on at rate {lr:.3g}")
    origin, spacing = (", ".join(f"{v:.4g}" for v in raw["frame"][k]) for k in ("origin", "spacing"))
    if raw.get("colour"):
        tiles = raw["colour"].get("tiles")
        lines.append(f"colour      {printable(raw['colour'].get('space'))} RGB, " + (
            f"read from the example by correspondence: {tiles['count']} tiles of {tiles['side']}x{tiles['side']}"
            if tiles else "from the decoder's colour head"))
    if raw.get("relief"):
        tiles = raw["relief"]["tiles"]
        lines.append(f"relief      read from the example by correspondence: {tiles['count']} depth tiles of "
                     f"{tiles['side']}x{tiles['side']}")
    lines += [
        f"networks    {raw['channels']} channels, {raw['pool_bins']} pooling bins, MLP hidden {raw['mlp_hidden']}",
        f"frame       voxel (0, 0, 0) at ({origin}), voxel size ({spacing}); {raw.get('up', 'y')} points up",
        f"world       {raw.get('arrange', 'blend')}ed (sinrun world's arrangement unless asked), "
        f"blend contrast {raw.get('contrast', CONTRAST):g}, object scale {raw.get('object_scale', 1.0):g}",
        "levels      size          noise amplitude   learning rate   iterations   seconds",
    ]
    seconds = training.get("level_seconds", [])
    done = training.get("iterations_per_level")
    done = done if isinstance(done, list) else [done] * len(raw["levels"])
    # models from before per-level rates trained every level at config lr
    rates = training.get("learning_rates") or [config.get("lr")] * len(raw["levels"])
    rates = rates if isinstance(rates, list) else []
    for i, level in enumerate(raw["levels"]):
        took = f"{seconds[i]:.0f}" if i < len(seconds) else ""
        rate = f"{rates[i]:.3g}" if i < len(rates) and _is_number(rates[i]) else "?"
        count = f"{done[i]:g}" if i < len(done) and _is_number(done[i]) else "?"
        lines.append(f"  {i:<8}  {'x'.join(map(str, level['size'])):<12}  {level['noise_amp']:<16.4g}  {rate:<14}  "
                     f"{count:<11}  {took}")
    lines.append("config      " + printable(json.dumps(config, sort_keys=True)))
    return lines
