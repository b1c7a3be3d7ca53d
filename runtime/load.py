"""Load a sinshape .onnx file once: check it, cut it into one session per stage.

A model file is untrusted input. It is refused, with one line saying why,
unless it is a plain ONNX file of bounded size, with no external-data
references (nothing that reads other files), only the few standard ops the
stages use, a seal over all its bytes that matches (format 3; format 2 had a
checksum over the weights and manifest), a manifest of a supported format
version whose every field has a sane type and range, and stages that run and
give finite values of the shapes the manifest implies.
"""

import json
import numbers
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# onnxruntime's POSIX builds (its Linux wheel, checked) write telemetry as
# soon as they are imported: a device id and a database of queued events (the
# OS, the CPU, the process's path) under ~/.cache/Microsoft/DeveloperTools/. Only
# ORT_DISABLE_TELEMETRY, set before the import, stops the files; its call,
# disable_telemetry_events, stops the events of a module someone else
# imported first. A user who set the variable keeps their choice.
os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
import onnxruntime as ort  # noqa: E402

from sinshape.core import manifest as fmt
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write, check_writable, read_regular

from . import onnxfile
from .colour import Tiles
from .generate import sample
from .query import head_colour, head_occupancy, project

ort.disable_telemetry_events()

MAX_MODEL_BYTES = 512 * 1024 * 1024
# onnxruntime starts every thread of every stage's pool up front (a million
# took minutes before failing); more threads than cores only slow it down.
MAX_THREADS = 256
# Every op a stage may contain (default ONNX domain only: no custom ops).
ALLOWED_OPS = {"Conv", "InstanceNormalization", "LeakyRelu", "Transpose", "MatMul", "Add", "Relu", "Sigmoid"}


@dataclass
class Stage:
    """One runnable stage: a session and its tensor names, in plane order."""

    session: ort.InferenceSession
    inputs: list
    outputs: list

    def run(self, arrays: list) -> list:
        feeds = {name: np.ascontiguousarray(a, dtype=np.float32) for name, a in zip(self.inputs, arrays)}
        return self.session.run(self.outputs, feeds)


@dataclass(frozen=True)
class HeadWeights:
    """The decoder head's parameters, read from the graph by their documented
    names: the runtime evaluates the head in numpy and bounds it over boxes
    (which needs the signs of w2)."""

    bias1: np.ndarray  # (D,)
    weight2: np.ndarray  # (D,)
    bias2: float
    weight_colour: np.ndarray | None = None  # (D, 3) in a coloured model (format 4), else None
    bias_colour: np.ndarray | None = None  # (3,)


@dataclass
class Model:
    """A loaded model: its manifest and its stages."""

    path: Path
    data: bytes  # the file as read and checked
    manifest: fmt.Manifest
    projection: Stage
    levels: list  # one Stage per level, coarsest first
    decoder_planes: Stage
    decoder_head: Stage
    head: HeadWeights
    example_tiles: object = None  # format 5: the example's surface (colour.Tiles), read by correspondence
    matcher: object = None  # its matcher, made on the first sample that reads the tiles (colour.matcher)
    faces_per_voxel: float | None = None  # its reconstruction's, at scale 1: measured when first needed (mesh.py)
    threads: int = 1  # threads per session, and the runtime's own numpy work's (colour.SampleSurface)

    @property
    def colour_tiles(self):
        """Its tiles where they hold colour (a coloured format-5 model), else None (relief alone, or none)."""
        return self.example_tiles if self.manifest.colour else None


def default_threads() -> int:
    """All cores this process may use (onnxruntime's own default counts
    physical cores only, which on small VMs can mean one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def read_model(path: Path) -> tuple:
    """(bytes, parsed ONNX, sealed): the file's seal checked first, so that a
    corrupt byte anywhere is named corrupt before anything reads it; then
    parsed as ONNX, refusing what could reach beyond the file."""
    data = read_regular(path, f"the model file {path}", MAX_MODEL_BYTES)
    _, sealed, intact = fmt.unseal(data)
    if sealed and not intact:
        raise InputError(f"{path}: corrupt model: its bytes do not match the SHA-256 sealed at its end")
    try:
        model = onnxfile.parse(data)
    except onnxfile.NotText:
        raise InputError(f"{path}: corrupt model: a name in it is not text (UTF-8)") from None
    except ValueError:
        raise InputError(f"{path}: not an ONNX file (truncated or corrupt)") from None
    if len(model.nodes) == 0:
        raise InputError(f"{path}: not a sinshape model (an empty or non-ONNX file)")
    if any(t.external for t in model.weights.values()):
        raise InputError(f"{path}: refers to external data files; sinshape models are self-contained")
    if model.has_sparse or model.has_functions:
        raise InputError(f"{path}: has sparse initializers or functions, which sinshape models never do")
    bad_ops = sorted({n.op_type for n in model.nodes if n.domain not in ("", "ai.onnx") or n.op_type not in ALLOWED_OPS})
    if bad_ops:
        raise InputError(f"{path}: uses ops a sinshape model never has ({', '.join(bad_ops[:5])})")
    if model.repeated_weights:  # ONNX names each initializer once: which copy is the weight? neither
        raise InputError(f"{path}: corrupt model: it holds the weight {min(model.repeated_weights)} twice")
    return data, model, sealed


def read_manifest(model: onnxfile.OnnxModel, sealed: bool, path: Path) -> fmt.Manifest:
    props = model.metadata
    if fmt.METADATA_KEY in model.repeated:  # which one is the manifest? neither
        raise InputError(f"{path}: corrupt model: it holds {fmt.METADATA_KEY} twice")
    if fmt.METADATA_KEY not in props:
        raise InputError(f"{path}: an ONNX model, but not a sinshape model (no {fmt.METADATA_KEY} metadata)")
    try:
        manifest = fmt.parse(props[fmt.METADATA_KEY])
    except InputError as error:
        if not sealed:  # what an unsealed file says of itself may be the corruption
            raise InputError(f"{path}: {error} (or a corrupt file: it has no seal)") from None
        raise InputError(f"{path}: {error}") from None
    version = manifest.raw["format_version"]
    if version >= 3 and not sealed:
        raise InputError(f"{path}: corrupt model: format {version} ends with a seal, and this file does not")
    if version < 3 and sealed:
        raise InputError(f"{path}: corrupt model: a seal on a format {version} file")
    if version == 2 and not checksum_v2_matches(model, manifest.raw):
        raise InputError(f"{path}: corrupt model: the checksum of its weights and manifest does not match")
    return manifest


def checksum_v2_matches(model: onnxfile.OnnxModel, raw: dict) -> bool:
    try:
        weights = [(name, onnxfile.tensor_array(tensor)) for name, tensor in model.weights.items()]
        return fmt.checksum_v2(raw, weights) == raw["checksum"]
    except ValueError:  # a weight whose type, shape or name is damaged cannot be read: corrupt
        return False


def format3_bytes(model: Model, **changes) -> bytes:
    """The model as a sealed format-3 file (its own bytes when it is one and
    nothing changes): what the browser reads, which checks seals only.
    `changes` replace manifest fields that do not change how the model is run (`up`, `arrange`, `contrast`,
    `object_scale`)."""
    if model.manifest.raw["format_version"] >= 3 and not changes:
        return model.data
    manifest = {k: v for k, v in model.manifest.raw.items() if k != "checksum"}
    manifest.update(changes, format_version=max(fmt.FORMAT_VERSION, manifest["format_version"]))
    fmt.parse(json.dumps(manifest))  # the changed manifest is checked as any other
    props = {**onnxfile.parse(model.data).metadata, fmt.METADATA_KEY: json.dumps(manifest, indent=1)}
    return fmt.seal(onnxfile.with_metadata(model.data, props))


def write_oriented(model: Model, up: str | None, path, arrange: str | None = None,
                   contrast: float | None = None, object_scale: float | None = None) -> None:
    """The model with `up` recorded as the input's up axis (y or z),
    `arrange` as its world's arrangement (blend or scatter), `contrast`
    as its blended world's contrast exponent and `object_scale` as its
    objects' size in a world of several models (None: each as it was),
    written to `path` (its own file too: atomically, so a crash leaves the
    old one). How the model runs does not change: only viewers, pictures
    and worlds read them."""
    if up is None and arrange is None and contrast is None and object_scale is None:
        raise InputError("give `up`, `arrange`, `contrast` or `object_scale`: nothing to change", "up")
    if up is not None and up not in fmt.UP_AXES:
        raise InputError(f"`up` must be one of {', '.join(fmt.UP_AXES)}, got {up!r}", "up")
    if arrange is not None and arrange not in fmt.ARRANGEMENTS:
        raise InputError(f"`arrange` must be one of {', '.join(fmt.ARRANGEMENTS)}, got {arrange!r}", "arrange")
    low, high = fmt.CONTRAST_RANGE
    if contrast is not None and not low <= contrast <= high:
        raise InputError(f"`contrast` must be in [{low:g}, {high:g}], got {contrast:g}", "contrast")
    low, high = fmt.OBJECT_SCALE_RANGE
    if object_scale is not None and not low <= object_scale <= high:
        raise InputError(f"`object_scale` must be in [{low:g}, {high:g}], got {object_scale:g}", "object_scale")
    path = Path(path)
    if path.suffix.lower() != ".onnx":
        raise InputError(f"{path}: a model is written as .onnx")
    check_writable(path)
    changes = {key: value for key, value in (("up", up), ("arrange", arrange), ("contrast", contrast),
                                             ("object_scale", object_scale)) if value is not None}
    data = format3_bytes(model, **changes)
    atomic_write(path, lambda f: f.write(data))


def stage_model(model: onnxfile.OnnxModel, inputs: list, outputs: list, path: Path) -> bytes:
    """The sub-graph computing `outputs` from `inputs`, as a serialized model."""
    producer = {out: node for node in model.nodes for out in node.outputs}
    missing = [n for n in inputs if n not in model.inputs] + [n for n in outputs if n not in model.outputs]
    if missing:
        raise InputError(f"{path}: the manifest names tensors the graph lacks ({', '.join(missing[:3])})")

    nodes, used, todo, seen = {}, set(), list(outputs), set()
    while todo:  # walk back from the outputs to the stage's inputs
        name = todo.pop()
        if name in seen or name in inputs:
            continue
        seen.add(name)
        if name in model.weights:
            used.add(name)
        elif name in producer:
            node = producer[name]
            nodes[id(node)] = node
            todo.extend(i for i in node.inputs if i)
        else:
            raise InputError(f"{path}: tensor {name!r} depends on something outside its stage")
    order = [node for node in model.nodes if id(node) in nodes]  # the file's topological order
    return onnxfile.stage_bytes(model, order, sorted(used), inputs, outputs)


def session(data: bytes, threads: int, path: Path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    # By default onnxruntime's idle threads spin, waiting for the next run; on
    # a 2-core machine they then starve the numpy work between stage runs
    # (a small matrix product took 50 ms instead of 0.3 ms right after a run).
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    # Fatal only: a stage that fails raises, and the exception is what we word;
    # at 3 (errors) onnxruntime also wrote its own line to stderr first.
    options.log_severity_level = 4
    try:
        # No fallback: it would print four "EP Error" lines to stdout and
        # retry on the same CPU provider (a model's damaged name did that).
        return ort.InferenceSession(data, options, providers=["CPUExecutionProvider"], enable_fallback=0)
    except Exception as error:  # onnxruntime raises its own exception types
        raise InputError(f"{path}: onnxruntime cannot load a stage ({str(error).splitlines()[0][:200]})") from None


def read_weights(model: onnxfile.OnnxModel, names: tuple, shapes: list, path: Path) -> list:
    """Initializers by name, each checked for its shape and finite values."""
    if any(name not in model.weights for name in names):
        raise InputError(f"{path}: the decoder head lacks its weights ({', '.join(names)})")
    try:
        arrays = [onnxfile.tensor_array(model.weights[name]) for name in names]
    except ValueError as error:
        raise InputError(f"{path}: corrupt model: {error}") from None
    if any(a.shape != shape for a, shape in zip(arrays, shapes)):
        raise InputError(f"{path}: decoder head weights have shapes {', '.join(str(a.shape) for a in arrays)}")
    if not all(np.isfinite(a).all() for a in arrays):
        raise InputError(f"{path}: decoder head weights are not finite")
    return arrays


def read_head(model: onnxfile.OnnxModel, manifest: fmt.Manifest, path: Path) -> HeadWeights:
    hidden = manifest.hidden
    b1, w2, b2 = read_weights(model, fmt.HEAD_WEIGHTS, [(hidden,), (hidden, 1), (1,)], path)
    colour = read_weights(model, fmt.COLOUR_WEIGHTS, [(hidden, 3), (3,)], path) if manifest.colour else (None, None)
    return HeadWeights(b1, w2[:, 0], float(b2[0]), *colour)


def read_tiles(model: onnxfile.OnnxModel, manifest: fmt.Manifest, path: Path):
    """A format-5 model's surface tiles, checked against its manifest and
    its finest level: (N, 3) voxels inside it, (N, ) directions below 6, each
    pair once and a voxel's tiles together, (N, T, T, 4) images (a
    relief-only model's (N, T, T, 1)), and the level's (X, Y, Z) signed
    distance grid."""
    count, side = manifest.tiles
    kind = "colour" if manifest.colour else "relief"
    names = fmt.TILE_TENSORS
    if any(name not in model.weights for name in names):
        raise InputError(f"{path}: its {kind} tiles are missing ({', '.join(names)})")
    try:
        voxels, directions, images, distance = (
            onnxfile.tensor_array(model.weights[name], dtype) for name, dtype in
            zip(names, (onnxfile.INT32, onnxfile.UINT8, onnxfile.UINT8, onnxfile.INT8)))
    except ValueError as error:
        raise InputError(f"{path}: corrupt model: {error}") from None
    size = np.array(manifest.sizes[-1])
    channels = manifest.tile_channels
    if voxels.shape != (count, 3) or directions.shape != (count,) or images.shape != (count, side, side, channels):
        raise InputError(f"{path}: {kind} tiles of shapes {voxels.shape}, {directions.shape}, {images.shape} "
                         f"do not match the manifest's {count} of side {side}")
    if distance.shape != tuple(size):
        raise InputError(f"{path}: a {kind} distance grid of shape {distance.shape}, not the finest level's "
                         f"{tuple(int(n) for n in size)}")
    if not (np.all((voxels >= 0) & (voxels < size)) and np.all(directions < 6)):
        raise InputError(f"{path}: {kind} tiles lie outside the model's finest level")
    key = ((voxels[:, 0].astype(np.int64) * size[1] + voxels[:, 1]) * size[2] + voxels[:, 2]) * 6 + directions
    if np.any(np.diff(key) <= 0):
        raise InputError(f"{path}: {kind} tiles are not each once, in order of their voxel")
    check_memory(Tiles.bytes(count, side, size), f"the {kind} tiles of {path.name}")
    return Tiles.of(voxels, directions, images, distance)


def check_stages(model: Model) -> None:
    """Run every stage once on a small input: the file is coherent, or refused."""
    m = model.manifest
    c, h = m.channels, m.hidden
    probes = [
        (model.projection, [np.zeros((1, m.pool_bins, 4, 5), np.float32)] * 3, (1, c, 4, 5)),
        *((level, [np.zeros((1, c, 4, 5), np.float32)] * 3, (1, c, 4, 5)) for level in model.levels),
        (model.decoder_planes, [np.zeros((1, c, 4, 5), np.float32)] * 3, (1, 4, 5, h)),
        (model.decoder_head, [np.zeros((2, 1, 1, h), np.float32)] * 3, (2, 1, 1, 1)),
    ]
    for stage, arrays, shape in probes:
        shapes = [shape] * len(stage.outputs) if stage is not model.decoder_head else [shape, (2, 1, 1, 3)]
        try:
            outputs = stage.run(arrays)
        except Exception as error:  # onnxruntime's own exception types
            raise InputError(f"{model.path}: stage {stage.inputs[0].split('.')[0]} does not run "
                             f"({str(error).splitlines()[0][:200]})") from None
        name = stage.inputs[0].split(".")[0]
        wrong = [(o.shape, want) for o, want in zip(outputs, shapes) if o.shape != want]
        if wrong:  # the first wrong one: another output's shape would read as a match
            raise InputError(f"{model.path}: stage {name} gives shape {wrong[0][0]}, expected {wrong[0][1]}")
        if not all(np.isfinite(o).all() for o in outputs):
            raise InputError(f"{model.path}: stage {name} gives NaN or infinite values (bad weights)")
    # The numpy head must be the graph's head.
    hidden = (2 * np.cos(np.arange(3 * 64 * h).reshape(3, 64, 1, 1, h) * 0.7)).astype(np.float32)  # varied values
    graph = model.decoder_head.run(list(hidden))
    if not all(np.isfinite(g).all() for g in graph):
        raise InputError(f"{model.path}: stage decoder_head gives NaN or infinite values (bad weights)")
    with np.errstate(all="ignore"):  # weights that overflow are refused below, in words
        numpy = [head_occupancy(model.head, hidden.sum(axis=0))[..., None]]
        if m.colour:
            numpy.append(head_colour(model.head, hidden.sum(axis=0)))
    if any(np.abs(g - n).max() > 1e-5 for g, n in zip(graph, numpy)):
        raise InputError(f"{model.path}: the decoder head graph does not match its weights")
    if m.colour:
        check_colour_head(model)


# The colour head's logits must stay below this: float32 overflows at 3.4e38.
MAX_COLOUR_LOGIT = 1e38


def check_colour_head(model: Model) -> None:
    """The colour head gives finite colours for the model's own
    reconstruction: its logits are bounded over every point of the
    reconstruction's planes (a point's hidden vector is a sum of the three
    planes' values there, each within its plane's range per channel), and
    the bound must stay far from float32's overflow, where inf - inf is NaN.
    Weights of 3e38, finite and sealed, sampled NaN colours written black."""
    planes = project(model, sample(model, None)).planes
    if not all(np.isfinite(p).all() for p in planes):
        raise InputError(f"{model.path}: its reconstruction's planes are not finite (bad weights)")
    most = sum(np.abs(p).reshape(-1, p.shape[-1]).max(axis=0).astype(np.float64) for p in planes)  # (D,)
    active = np.maximum(most + model.head.bias1.astype(np.float64), 0)  # relu(hidden + b1) lies in [0, active]
    bound = active @ np.abs(model.head.weight_colour.astype(np.float64)) + np.abs(model.head.bias_colour)
    if not bound.max() < MAX_COLOUR_LOGIT:
        raise InputError(f"{model.path}: its colour head gives no finite colour for its own reconstruction (its "
                         f"logits reach {bound.max():.3g}; bad weights)")


def load_model(path, threads: int | None = None) -> Model:
    """Read, check and prepare a model; `threads` per session (default: all cores)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"`path` must be a file name, got {path!r}", "path")
    path = Path(path)
    threads = default_threads() if threads is None else threads
    if not (isinstance(threads, numbers.Integral) and 1 <= threads <= MAX_THREADS):
        raise InputError(f"`threads` must be 1 to {MAX_THREADS}, got {threads}", "threads")
    data, proto, sealed = read_model(path)
    manifest = read_manifest(proto, sealed, path)

    def make(names: dict) -> Stage:
        data = stage_model(proto, names["inputs"], names["outputs"], path)
        return Stage(session(data, threads, path), names["inputs"], names["outputs"])

    stages = manifest.stages
    model = Model(
        path=path,
        data=data,
        manifest=manifest,
        projection=make(stages["projection"]),
        levels=[make(names) for names in stages["levels"]],
        decoder_planes=make(stages["decoder_planes"]),
        decoder_head=make(stages["decoder_head"]),
        head=read_head(proto, manifest, path),
        example_tiles=read_tiles(proto, manifest, path) if manifest.tiles else None,
        threads=threads,
    )
    check_stages(model)
    return model
