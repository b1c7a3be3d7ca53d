"""Write a trained generator as one .onnx file: every stage plus the manifest.

The graphs are built node by node from the weights rather than traced by
torch.onnx: the networks are four op types deep, a hand-built graph has
exactly the ops and tensor names that docs/FORMAT.md promises (torch's
exporters have turned InstanceNorm into a training-mode BatchNormalization
and change their defaults between releases), and export needs no onnxscript.
The parity test checks the file against the torch model.

The stages are disconnected parts of one graph, each with its own inputs and
outputs; the runtime cuts the graph into one session per stage.
"""

import importlib.metadata
import json
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper

from sinshape.core import manifest as fmt
from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write
from sinshape.prep.pyramid import LEVEL_FACTOR, MIN_SIZE, pyramid_from_mesh

# ONNX IR 8 / opset 17: read by every onnxruntime since 1.14; newer onnx
# releases write newer IR versions by default, which older runtimes reject.
IR_VERSION = 8
OPSET = 17


class GraphBuilder:
    """Collects nodes, initializers and graph inputs/outputs."""

    def __init__(self):
        self.nodes, self.initializers, self.inputs, self.outputs = [], [], [], []
        self.counter = 0

    def weight(self, name: str, value) -> str:
        array = value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)
        self.initializers.append(numpy_helper.from_array(array.astype(np.float32), name))
        return name

    def node(self, op: str, inputs: list, output: str | None = None, **attrs) -> str:
        self.counter += 1
        output = output or f"{inputs[0]}/{op}{self.counter}"
        self.nodes.append(helper.make_node(op, inputs, [output], name=f"{op}_{self.counter}", **attrs))
        return output

    def input(self, name: str, dims: list) -> str:
        self.inputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, dims))
        return name

    def output(self, name: str, dims: list) -> None:
        self.outputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, dims))


def symbolic(name: str, fixed: dict) -> list:
    """Dims of a rank-4 tensor: `fixed` maps axis -> size, others are named."""
    return [fixed.get(axis, f"{name}_d{axis}") for axis in range(4)]


def add_projection(g: GraphBuilder, projection, names: dict) -> None:
    """P's 1x1 convs (bins -> C, with bias), one per plane."""
    for conv, x, y in zip(projection.convs, names["inputs"], names["outputs"]):
        g.input(x, symbolic(x, {0: 1, 1: conv.in_channels}))
        w = g.weight(f"{x}.weight", conv.weight)
        b = g.weight(f"{x}.bias", conv.bias)
        g.node("Conv", [x, w, b], y, kernel_shape=[1, 1])
        g.output(y, symbolic(y, {0: 1, 1: conv.out_channels}))


def add_level(g: GraphBuilder, level, names: dict, norm_scale: str, norm_bias: str) -> None:
    """G_i: per plane, (Conv3x3 -> InstanceNorm -> LeakyReLU) x 3 -> Conv3x3 + bias."""
    for stack, x, y in zip(level.stacks, names["inputs"], names["outputs"]):
        channels = stack[0].in_channels
        g.input(x, symbolic(x, {0: 1, 1: channels}))
        h = x
        convs = [m for m in stack if isinstance(m, torch.nn.Conv2d)]
        for k, conv in enumerate(convs):
            args = [h, g.weight(f"{x}.conv{k}.weight", conv.weight)]
            if conv.bias is not None:
                args.append(g.weight(f"{x}.conv{k}.bias", conv.bias))
            last = k == len(convs) - 1
            h = g.node("Conv", args, y if last else None, kernel_shape=[3, 3], pads=[1, 1, 1, 1])
            if not last:
                h = g.node("InstanceNormalization", [h, norm_scale, norm_bias], epsilon=1e-5)
                h = g.node("LeakyRelu", [h], alpha=0.2)
        g.output(y, symbolic(y, {0: 1, 1: channels}))


def add_decoder(g: GraphBuilder, decoder, plane_names: dict, head_names: dict) -> None:
    """The MLP split at its first layer (docs/METHOD.md, "The decoder's first layer").

    decoder_planes: each plane (1, C, H, W) -> (1, H, W, hidden) = plane^T W_k^T.
    decoder_head: three broadcastable (..., hidden) -> sigmoid(w2 relu(sum + b1) + b2),
    and with colour a second output sigmoid(relu(sum + b1) w_colour + b_colour).
    """
    hidden = decoder.fc1.out_features
    blocks = decoder.fc1.weight.split(decoder.channels, dim=1)
    for block, x, y in zip(blocks, plane_names["inputs"], plane_names["outputs"]):
        g.input(x, symbolic(x, {0: 1, 1: decoder.channels}))
        h = g.node("Transpose", [x], perm=[0, 2, 3, 1])
        g.node("MatMul", [h, g.weight(f"{x}.weight", block.T)], y)
        g.output(y, symbolic(y, {0: 1, 3: hidden}))
    a, b, c = (g.input(x, symbolic(x, {3: hidden})) for x in head_names["inputs"])
    h = g.node("Add", [g.node("Add", [a, b]), c])
    bias1, weight2, bias2 = fmt.HEAD_WEIGHTS
    hidden = g.node("Relu", [g.node("Add", [h, g.weight(bias1, decoder.fc1.bias)])])
    h = g.node("MatMul", [hidden, g.weight(weight2, decoder.fc2.weight.T)])
    h = g.node("Add", [h, g.weight(bias2, decoder.fc2.bias)])
    y = head_names["outputs"][0]
    g.node("Sigmoid", [h], y)
    g.output(y, ["head_d0", "head_d1", "head_d2", 1])
    if decoder.fc_colour is not None:
        weight, bias = fmt.COLOUR_WEIGHTS
        h = g.node("MatMul", [hidden, g.weight(weight, decoder.fc_colour.weight.T)])
        h = g.node("Add", [h, g.weight(bias, decoder.fc_colour.bias)])
        y = head_names["outputs"][1]
        g.node("Sigmoid", [h], y)
        g.output(y, ["head_d0", "head_d1", "head_d2", 3])


def build_model(generator, manifest: dict, tiles=None) -> onnx.ModelProto:
    """The ONNX model of a generator with its manifest in the metadata, and
    its example's surface tiles (prep.appearance.Tiles) as data."""
    stages = manifest["stages"]
    g = GraphBuilder()
    add_projection(g, generator.projection, stages["projection"])
    scale = g.weight("instance_norm.scale", np.ones(generator.channels))
    bias = g.weight("instance_norm.bias", np.zeros(generator.channels))
    for level, names in zip(generator.levels, stages["levels"]):
        add_level(g, level, names, scale, bias)
    add_decoder(g, generator.decoder, stages["decoder_planes"], stages["decoder_head"])
    if tiles is not None:
        g.initializers += tile_initializers(tiles)
    graph = helper.make_graph(g.nodes, "sinshape", g.inputs, g.outputs, g.initializers)
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        ir_version=IR_VERSION,
        producer_name="sinshape",
        producer_version=importlib.metadata.version("sinshape"),
    )
    text = json.dumps(manifest, indent=1)
    fmt.parse(text)  # the trainer never writes what the runtime would refuse
    helper.set_model_props(model, {fmt.METADATA_KEY: text})
    onnx.checker.check_model(model, full_check=True)
    return model


def tile_initializers(tiles) -> list:
    """An example's tiles (prep.appearance.Tiles) as the initializers docs/FORMAT.md names, of their own types."""
    return [numpy_helper.from_array(np.ascontiguousarray(array.astype(dtype)), name) for name, array, dtype in
            zip(fmt.TILE_TENSORS, (tiles.voxels, tiles.directions, tiles.images, tiles.distance),
                (np.int32, np.uint8, np.uint8, np.int8))]


def make_manifest(generator, *, sizes, noise_amps, config, pyramid, seconds, ran_on: dict) -> dict:
    """The manifest dict (build_model checks it): format 5 with `colour` and
    its tiles for a coloured example, format 5 with `relief` and its depth
    tiles for a geometry-only example that had a mesh, format 4 for a
    coloured decoder without tiles, else format 3, as before colour."""
    colour = generator.decoder.fc_colour is not None
    tiles = getattr(pyramid, "tiles", None)
    if tiles is not None and (tiles.images.shape[-1] == 4) != colour:
        raise ValueError("a coloured model needs colour tiles, a geometry-only one depth tiles")
    version = fmt.TILES_VERSION if tiles is not None else fmt.COLOUR_VERSION if colour else fmt.FORMAT_VERSION
    manifest = {
        "format": fmt.FORMAT_NAME,
        "format_version": version,
        "created_by": f"sinshape {importlib.metadata.version('sinshape')}, torch {torch.__version__}",
        "planes": list(fmt.PLANES),
        "channels": generator.channels,
        "pool_bins": generator.projection.bins,
        "mlp_hidden": generator.decoder.fc1.out_features,
        "levels": [{"size": list(s), "noise_amp": float(a)} for s, a in zip(sizes, noise_amps)],
        "recon_seed": config.recon_seed,
        "noise": fmt.NOISE_SCHEME,
        "frame": {"origin": list(pyramid.origin), "spacing": list(pyramid.spacing)},
        "up": config.up or pyramid.up,
        "stages": fmt.stage_names(len(sizes), colour),
        "source": {"name": pyramid.source_name, "sha256": pyramid.source_sha256, "kind": pyramid.source_kind},
        "config": config.to_dict(),
        "training": {
            "seconds": round(sum(seconds), 1),
            "level_seconds": [round(s, 1) for s in seconds],
            "iterations_per_level": list(config.level_iters) if config.level_iters else config.iters,
            **ran_on,
        },
    }
    counts = {"count": len(tiles.voxels), "side": tiles.images.shape[1]} if tiles is not None else None
    if tiles is not None and colour:
        manifest["colour"] = {**fmt.COLOUR_SPACE, "tiles": counts}
    elif tiles is not None:
        manifest["relief"] = {"tiles": counts}
    elif colour:
        manifest["colour"] = fmt.COLOUR_SPACE
    return manifest


def export_model(generator, *, sizes, noise_amps, config, pyramid, seconds, path, ran_on=None) -> dict:
    """Write the model to `path` atomically; returns its manifest. `ran_on`:
    where training ran ({"device", "precision"}) and, under a time budget,
    its plan, recorded with its times."""
    manifest = make_manifest(generator, sizes=sizes, noise_amps=noise_amps, config=config,
                             pyramid=pyramid, seconds=seconds, ran_on=ran_on or {})
    tiles = pyramid.tiles if manifest["format_version"] == fmt.TILES_VERSION else None
    model = build_model(generator, manifest, tiles)
    data = fmt.seal(model.SerializeToString())  # what onnx.save_model writes, then the seal
    atomic_write(path, lambda f: f.write(data))
    return manifest


def remake_tiles(model_path, source_path, out_path, asset_folder=None) -> dict:
    """A model trained on a mesh written again with the tiles this version
    of the trainer makes from that mesh, its weights as they are: a
    geometry-only model of format 3 (trained before relief) gets its
    example's relief (format 5, `relief`), a format-5 model fresh tiles of
    its kind (colour, or relief alone) in place of those an older version
    made. The mesh is voxelised with the model's own settings (and its
    colour read, for a coloured one, from its folder or `asset_folder`), and
    refused unless its file's SHA-256, its level sizes and its frame are the
    model's. Returns the new manifest."""
    model = onnx.load_model(str(model_path))
    props = {p.key: p.value for p in model.metadata_props}
    manifest = json.loads(props[fmt.METADATA_KEY])
    parsed = fmt.parse(props[fmt.METADATA_KEY])
    if parsed.colour and not parsed.tiles:
        raise InputError(f"{model_path}: a colour head without tiles (format {manifest['format_version']}): "
                         "train it again to read colour from its example")
    config = manifest.get("config", {})
    pyramid = pyramid_from_mesh(Path(source_path), config.get("res", max(parsed.sizes[-1])), len(parsed.sizes),
                                config.get("level_factor", LEVEL_FACTOR), config.get("min_size", MIN_SIZE),
                                colour=parsed.colour, asset_folder=asset_folder,
                                tile_bytes=int(config.get("colour_mb", 48.0) * 2**20))
    if pyramid.source_sha256 != manifest["source"]["sha256"]:
        raise InputError(f"{source_path}: not the file {model_path} was trained on (its SHA-256 differs)")
    if pyramid.sizes != parsed.sizes or not (np.allclose(pyramid.origin, parsed.origin, rtol=0, atol=1e-9)
                                             and np.allclose(pyramid.spacing, parsed.spacing, rtol=0, atol=1e-12)):
        raise InputError(f"{source_path}: voxelised as {pyramid.sizes}, not as {model_path} was ({parsed.sizes})")
    tiles = pyramid.tiles
    if tiles is None or (tiles.images.shape[-1] == 4) != parsed.colour:
        raise InputError(f"{source_path}: gives no {'colour' if parsed.colour else 'relief'} tiles")
    manifest["format_version"] = fmt.TILES_VERSION
    manifest.pop("checksum", None)
    counts = {"count": len(tiles.voxels), "side": tiles.images.shape[1]}
    if parsed.colour:
        manifest["colour"] = {**fmt.COLOUR_SPACE, "tiles": counts}
    else:
        manifest["relief"] = {"tiles": counts}
    text = json.dumps(manifest, indent=1)
    fmt.parse(text)
    for old in [t for t in model.graph.initializer if t.name in fmt.TILE_TENSORS]:
        model.graph.initializer.remove(old)
    model.graph.initializer.extend(tile_initializers(tiles))
    del model.metadata_props[:]  # the seal among them: it is made again below
    helper.set_model_props(model, {**{k: v for k, v in props.items() if k != fmt.SEAL_KEY}, fmt.METADATA_KEY: text})
    onnx.checker.check_model(model, full_check=True)
    data = fmt.seal(model.SerializeToString())
    atomic_write(out_path, lambda f: f.write(data))
    return manifest
