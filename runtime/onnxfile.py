"""The parts of an ONNX file the runtime reads, straight from protobuf's wire
format, without the onnx package (which costs more to import than loading a
model does).

A model file is untrusted: every read is bounded by the message it is in,
and anything malformed raises ValueError. Only the fields named below are
decoded; the rest are kept as raw bytes, which is what cutting a stage out
of the model needs (`stage_bytes`): whole node, weight and input entries,
copied as they are.
"""

from dataclasses import dataclass, field

import numpy as np

# Field numbers (onnx.proto).
MODEL_IR_VERSION, MODEL_OPSET, MODEL_GRAPH, MODEL_METADATA, MODEL_FUNCTIONS = 1, 8, 7, 14, 25
GRAPH_NODE, GRAPH_INITIALIZER, GRAPH_SPARSE_INITIALIZER, GRAPH_INPUT, GRAPH_OUTPUT = 1, 5, 15, 11, 12
NODE_INPUT, NODE_OUTPUT, NODE_NAME, NODE_OP, NODE_DOMAIN = 1, 2, 3, 4, 7
TENSOR_DIMS, TENSOR_TYPE, TENSOR_FLOATS, TENSOR_NAME, TENSOR_RAW = 1, 2, 4, 8, 9
TENSOR_EXTERNAL, TENSOR_LOCATION = 13, 14
NAMED_NAME = 1  # ValueInfoProto.name; StringStringEntryProto.key (value is 2)
FLOAT, UINT8, INT8, INT32 = 1, 2, 3, 6  # TensorProto.DataType
DTYPES = {FLOAT: "<f4", UINT8: "u1", INT8: "i1", INT32: "<i4"}
MAX_DIM = 1 << 40  # a weight's side, below it: far past any model, and an exact float in every runtime


def fields(data: bytes, start: int = 0, end: int | None = None):
    """(field number, wire type, value, raw entry) per field of one message:
    value an int (varint and fixed) or a (start, end) span (length-delimited)."""
    end = len(data) if end is None else end
    at = start
    while at < end:
        first = at
        key, at = varint(data, at, end)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise ValueError("field number 0")
        if wire == 0:
            value, at = varint(data, at, end)
        elif wire == 2:
            length, at = varint(data, at, end)
            if length > end - at:
                raise ValueError("a field runs past its message")
            value, at = (at, at + length), at + length
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            if at + size > end:
                raise ValueError("a field runs past its message")
            value, at = int.from_bytes(data[at:at + size], "little"), at + size
        else:
            raise ValueError(f"wire type {wire}")
        yield number, wire, value, (first, at)


def varint(data: bytes, at: int, end: int) -> tuple:
    value = shift = 0
    while True:
        if at >= end or shift > 63:
            raise ValueError("a broken varint")
        byte = data[at]
        value |= (byte & 0x7F) << shift
        at, shift = at + 1, shift + 7
        if byte < 0x80:
            return value, at


class NotText(ValueError):
    """A string field that is not UTF-8: a corrupt name."""


def text(data: bytes, span: tuple) -> str:
    try:
        return data[span[0]:span[1]].decode("utf-8")
    except UnicodeDecodeError:
        raise NotText("a name is not text") from None


@dataclass
class Node:
    op_type: str
    domain: str
    name: str
    inputs: list
    outputs: list
    entry: bytes  # the whole field, as in the file


@dataclass
class Tensor:
    name: str
    entry: bytes
    data: bytes  # the message
    external: bool


@dataclass
class OnnxModel:
    """A parsed model: its graph's parts by name, as raw entries."""

    data: bytes
    ir_version: int = 0
    opsets: list = field(default_factory=list)  # raw opset_import entries
    metadata: dict = field(default_factory=dict)
    repeated: set = field(default_factory=set)  # metadata keys given more than once (the last one is kept)
    has_functions: bool = False
    nodes: list = field(default_factory=list)
    weights: dict = field(default_factory=dict)  # name -> Tensor
    repeated_weights: set = field(default_factory=set)  # initializer names given more than once
    has_sparse: bool = False
    inputs: dict = field(default_factory=dict)  # name -> raw entry
    outputs: dict = field(default_factory=dict)


def parse(data: bytes) -> OnnxModel:
    """Read a model file's bytes (ValueError if they are not a well-formed model)."""
    model = OnnxModel(data)
    graphs = []
    for number, wire, value, (first, last) in fields(data):
        if number == MODEL_IR_VERSION and wire == 0:
            model.ir_version = value
        elif number == MODEL_OPSET and wire == 2:
            model.opsets.append(data[first:last])
        elif number == MODEL_METADATA and wire == 2:
            entry = {n: text(data, v) for n, w, v, _ in fields(data, *value) if w == 2 and n in (1, 2)}
            key = entry.get(1, "")
            if key in model.metadata:
                model.repeated.add(key)
            model.metadata[key] = entry.get(2, "")
        elif number == MODEL_FUNCTIONS:
            model.has_functions = True
        elif number == MODEL_GRAPH and wire == 2:
            graphs.append(value)
    for graph in graphs:  # protobuf merges repeated messages
        read_graph(model, graph)
    return model


def read_graph(model: OnnxModel, span: tuple) -> None:
    data = model.data
    for number, wire, value, (first, last) in fields(data, *span):
        if wire != 2:
            continue
        if number == GRAPH_NODE:
            strings = {NODE_INPUT: [], NODE_OUTPUT: [], NODE_NAME: [""], NODE_OP: [""], NODE_DOMAIN: [""]}
            for n, w, v, _ in fields(data, *value):
                if n in strings and w == 2:
                    strings[n] = strings[n] + [text(data, v)] if n in (NODE_INPUT, NODE_OUTPUT) else [text(data, v)]
            model.nodes.append(Node(strings[NODE_OP][0], strings[NODE_DOMAIN][0], strings[NODE_NAME][0],
                                    strings[NODE_INPUT], strings[NODE_OUTPUT], data[first:last]))
        elif number == GRAPH_INITIALIZER:
            name, external = "", False
            for n, w, v, _ in fields(data, *value):
                if n == TENSOR_NAME and w == 2:
                    name = text(data, v)
                elif n == TENSOR_EXTERNAL or (n == TENSOR_LOCATION and w == 0 and v == 1):
                    external = True
            if name in model.weights:
                model.repeated_weights.add(name)
            model.weights[name] = Tensor(name, data[first:last], data[value[0]:value[1]], external)
        elif number == GRAPH_SPARSE_INITIALIZER:
            model.has_sparse = True
        elif number in (GRAPH_INPUT, GRAPH_OUTPUT):
            names = [text(data, v) for n, w, v, _ in fields(data, *value) if n == NAMED_NAME and w == 2]
            (model.inputs if number == GRAPH_INPUT else model.outputs)[names[-1] if names else ""] = data[first:last]


def tensor_array(tensor: Tensor, wanted: int = FLOAT) -> np.ndarray:
    """A weight of type `wanted` as an array: float32 from raw_data or
    float_data, uint8, int8 or int32 (data, not weights) from raw_data."""
    data = tensor.data
    dims, kind, raw, floats = [], None, None, []
    for n, w, v, _ in fields(data):
        if n == TENSOR_DIMS and w == 0:
            dims.append(v)
        elif n == TENSOR_DIMS and w == 2:  # packed
            at = v[0]
            while at < v[1]:
                dim, at = varint(data, at, v[1])
                dims.append(dim)
        elif n == TENSOR_TYPE and w == 0:
            kind = v
        elif n == TENSOR_RAW and w == 2:
            raw = data[v[0]:v[1]]
        elif n == TENSOR_FLOATS and w == 2:  # packed
            floats.append(data[v[0]:v[1]])
        elif n == TENSOR_FLOATS and w == 5:
            floats.append(v.to_bytes(4, "little"))
    if kind != wanted:
        raise ValueError(f"weight {tensor.name!r} is not {np.dtype(DTYPES[wanted]).name}")
    if wanted != FLOAT and raw is None:
        raise ValueError(f"weight {tensor.name!r} keeps its values outside raw_data")
    values = np.frombuffer(raw if raw is not None else b"".join(floats), DTYPES[wanted])
    if any(d >= MAX_DIM for d in dims) or values.size != int(np.prod(dims, dtype=object)):
        raise ValueError(f"weight {tensor.name!r} has {values.size} values for shape {tuple(dims)}")
    return values.reshape(dims).astype(np.dtype(DTYPES[wanted]).newbyteorder("="))  # native order, a copy


def entry(number: int, payload: bytes) -> bytes:
    """One length-delimited field."""
    return encode_varint(number << 3 | 2) + encode_varint(len(payload)) + payload


def encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def with_metadata(data: bytes, props: dict) -> bytes:
    """The model's bytes with its metadata_props replaced by `props` (str -> str),
    every other field copied as it is."""
    kept = b"".join(data[first:last] for number, _, _, (first, last) in fields(data) if number != MODEL_METADATA)
    return kept + b"".join(entry(MODEL_METADATA, entry(1, key.encode()) + entry(2, value.encode()))
                           for key, value in props.items())


def stage_bytes(model: OnnxModel, nodes: list, weights: list, inputs: list, outputs: list) -> bytes:
    """A model of the given nodes, weights and graph inputs and outputs (names),
    with the file's IR version and opsets: entries copied as they are."""
    graph = b"".join([*(n.entry for n in nodes), entry(2, b"stage"), *(model.weights[w].entry for w in weights),
                      *(model.inputs[i] for i in inputs), *(model.outputs[o] for o in outputs)])
    return encode_varint(MODEL_IR_VERSION << 3) + encode_varint(model.ir_version) + b"".join(model.opsets) \
        + entry(MODEL_GRAPH, graph)
