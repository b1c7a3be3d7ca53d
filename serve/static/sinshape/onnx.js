// A minimal reader and writer of the ONNX protobuf: enough to read a model's
// metadata and graph, refuse what a sinshape model never holds, and cut the
// graph into one small model per stage (onnxruntime feeds every input and runs
// the whole graph on each call, so stages must be separate models).
//
// Only the fields below are decoded; a node, initializer or value-info is kept
// as its raw bytes and copied unchanged into the stage models it belongs to.
// Field numbers: onnx/onnx.proto (ModelProto, GraphProto, NodeProto, TensorProto,
// ValueInfoProto, StringStringEntryProto).

import { pyRepr, pyTuple } from './errors.js';

export class FormatError extends Error {}

const TEXT = new TextDecoder('utf-8', { fatal: false });

/** Protobuf fields of bytes[start, end): [{ field, wire, value } or { field, wire, start, end }]. */
export function readFields(bytes, start = 0, end = bytes.length) {
  const fields = [];
  let at = start;
  const varint = () => {
    let value = 0, scale = 1, byte;
    do {
      if (at >= end) throw new FormatError('truncated varint');
      byte = bytes[at++];
      value += (byte & 0x7f) * scale;
      scale *= 128;
      if (scale > 2 ** 70) throw new FormatError('varint too long');
    } while (byte & 0x80);
    return value;
  };
  while (at < end) {
    const tag = varint();
    const field = Math.floor(tag / 8), wire = tag % 8;
    if (field === 0) throw new FormatError('field number 0');
    if (wire === 0) fields.push({ field, wire, value: varint() });
    else if (wire === 1 || wire === 5) {
      const size = wire === 1 ? 8 : 4;
      if (at + size > end) throw new FormatError('truncated fixed field');
      fields.push({ field, wire, start: at, end: at + size });
      at += size;
    } else if (wire === 2) {
      const size = varint();
      if (at + size > end) throw new FormatError('truncated field');
      fields.push({ field, wire, start: at, end: at + size });
      at += size;
    } else throw new FormatError(`unsupported wire type ${wire}`);
  }
  return fields;
}

const text = (bytes, f) => TEXT.decode(bytes.subarray(f.start, f.end));

function nested(bytes, f) {
  if (f.wire !== 2) throw new FormatError(`field ${f.field} is not a message`);
  return readFields(bytes, f.start, f.end);
}

function readNode(bytes, f) {
  const node = { raw: bytes.subarray(f.start, f.end), inputs: [], outputs: [], name: '', opType: '', domain: '' };
  for (const g of nested(bytes, f)) {
    if (g.wire !== 2) continue;
    if (g.field === 1) node.inputs.push(text(bytes, g));
    else if (g.field === 2) node.outputs.push(text(bytes, g));
    else if (g.field === 3) node.name = text(bytes, g);
    else if (g.field === 4) node.opType = text(bytes, g);
    else if (g.field === 7) node.domain = text(bytes, g);
  }
  return node;
}

function readTensor(bytes, f) {
  const tensor = { raw: bytes.subarray(f.start, f.end), name: '', dims: [], dataType: 0, external: false, data: null, floats: [] };
  for (const g of nested(bytes, f)) {
    if (g.field === 8 && g.wire === 2) tensor.name = text(bytes, g);
    else if (g.field === 1 && g.wire === 0) tensor.dims.push(g.value);
    else if (g.field === 1 && g.wire === 2) tensor.dims.push(...readPacked(bytes, g));
    else if (g.field === 2 && g.wire === 0) tensor.dataType = g.value;
    else if (g.field === 13) tensor.external = true; // external_data entries
    else if (g.field === 14 && g.wire === 0 && g.value === 1) tensor.external = true; // data_location EXTERNAL
    else if (g.field === 9 && g.wire === 2) tensor.data = bytes.subarray(g.start, g.end);
    else if (g.field === 4 && g.wire === 2) tensor.floats.push(...floatsOf(bytes.subarray(g.start, g.end)));
    else if (g.field === 4 && g.wire === 5) tensor.floats.push(...floatsOf(bytes.subarray(g.start, g.end)));
  }
  return tensor;
}

function readPacked(bytes, f) {
  const values = [];
  let at = f.start;
  while (at < f.end) {
    let value = 0, scale = 1, byte;
    do { byte = bytes[at++]; value += (byte & 0x7f) * scale; scale *= 128; } while (byte & 0x80 && at < f.end);
    values.push(value);
  }
  return values;
}

function floatsOf(slice) {
  const view = new DataView(slice.buffer, slice.byteOffset, slice.byteLength);
  return Array.from({ length: slice.byteLength >> 2 }, (_, i) => view.getFloat32(4 * i, true));
}

export const FLOAT = 1, UINT8 = 2, INT8 = 3, INT32 = 6; // TensorProto.DataType
export const MAX_DIM = 2 ** 40; // a weight's side, below it (onnxfile.MAX_DIM)
export const ARRAYS = { [FLOAT]: ['float32', Float32Array], [UINT8]: ['uint8', Uint8Array], [INT8]: ['int8', Int8Array], [INT32]: ['int32', Int32Array] };

/**
 * A tensor of type `wanted` as a typed array in C order (runtime/onnxfile.py:
 * tensor_array): float32 from raw_data or float_data, uint8 or int32 (data,
 * not weights) from raw_data. Throws FormatError with tensor_array's words.
 */
export function tensorArray(tensor, wanted = FLOAT) {
  const [typeName, Type] = ARRAYS[wanted];
  const name = pyRepr(tensor.name);
  if (tensor.dataType !== wanted) throw new FormatError(`weight ${name} is not ${typeName}`);
  if (wanted !== FLOAT && !tensor.data) throw new FormatError(`weight ${name} keeps its values outside raw_data`);
  let values;
  if (tensor.data) {
    if (tensor.data.byteLength % Type.BYTES_PER_ELEMENT) throw new FormatError('buffer size must be a multiple of element size');
    values = new Type(tensor.data.byteLength / Type.BYTES_PER_ELEMENT);
    new Uint8Array(values.buffer).set(tensor.data); // a copy, aligned (little-endian, as every browser is)
  } else values = Float32Array.from(tensor.floats);
  if (tensor.dims.some((d) => d >= MAX_DIM) || values.length !== tensor.dims.reduce((a, b) => a * b, 1)) {
    throw new FormatError(`weight ${name} has ${values.length} values for shape ${pyTuple(tensor.dims)}`);
  }
  return values;
}

function readValueInfo(bytes, f) {
  const info = { raw: bytes.subarray(f.start, f.end), name: '' };
  for (const g of nested(bytes, f)) if (g.field === 1 && g.wire === 2) info.name = text(bytes, g);
  return info;
}

/**
 * Parse a model file: { irVersion, opsets (raw), metadata {key: value}, repeated (keys given twice), functions,
 * graph: { nodes, initializers, inputs, outputs, sparse } }. Throws FormatError.
 */
export function readModel(bytes) {
  const model = { irVersion: 0, opsets: [], metadata: {}, repeated: new Set(), functions: 0, graph: null };
  for (const f of readFields(bytes)) {
    if (f.field === 1 && f.wire === 0) model.irVersion = f.value;
    else if (f.field === 8 && f.wire === 2) model.opsets.push(bytes.subarray(f.start, f.end));
    else if (f.field === 7) model.graph = readGraph(bytes, f);
    else if (f.field === 14) {
      let key = '', value = '';
      for (const g of nested(bytes, f)) {
        if (g.field === 1 && g.wire === 2) key = text(bytes, g);
        else if (g.field === 2 && g.wire === 2) value = text(bytes, g);
      }
      if (key in model.metadata) model.repeated.add(key);
      model.metadata[key] = value;
    } else if (f.field === 25) model.functions += 1;
  }
  if (!model.graph) model.graph = { nodes: [], initializers: [], inputs: [], outputs: [], sparse: 0 };
  return model;
}

function readGraph(bytes, f) {
  const graph = { nodes: [], initializers: [], inputs: [], outputs: [], sparse: 0 };
  for (const g of nested(bytes, f)) {
    if (g.field === 1) graph.nodes.push(readNode(bytes, g));
    else if (g.field === 5) graph.initializers.push(readTensor(bytes, g));
    else if (g.field === 11) graph.inputs.push(readValueInfo(bytes, g));
    else if (g.field === 12) graph.outputs.push(readValueInfo(bytes, g));
    else if (g.field === 15) graph.sparse += 1;
  }
  return graph;
}

// ---- writing: a message is a list of chunks (Uint8Array), joined at the end
function varintBytes(value) {
  const out = [];
  do {
    let byte = value % 128;
    value = Math.floor(value / 128);
    if (value > 0) byte |= 0x80;
    out.push(byte);
  } while (value > 0);
  return Uint8Array.from(out);
}

function join(chunks) {
  const out = new Uint8Array(chunks.reduce((n, c) => n + c.length, 0));
  let at = 0;
  for (const c of chunks) { out.set(c, at); at += c.length; }
  return out;
}

const bytesField = (field, payload) => [varintBytes(field * 8 + 2), varintBytes(payload.length), payload];

/**
 * The serialized model computing `outputs` from `inputs`: the nodes between
 * them (in the file's order) and the initializers they read. Throws
 * FormatError naming what is missing.
 */
export function stageModel(model, inputs, outputs) {
  const { graph } = model;
  const producer = new Map();
  graph.nodes.forEach((node, i) => node.outputs.forEach((o) => producer.set(o, i)));
  const weights = new Map(graph.initializers.map((t) => [t.name, t]));
  const graphInputs = new Map(graph.inputs.map((v) => [v.name, v]));
  const graphOutputs = new Map(graph.outputs.map((v) => [v.name, v]));
  const missing = [...inputs.filter((n) => !graphInputs.has(n)), ...outputs.filter((n) => !graphOutputs.has(n))];
  if (missing.length) throw new FormatError(`the manifest names tensors the graph lacks (${missing.slice(0, 3).join(', ')})`);

  const nodes = new Set(), used = new Set(), seen = new Set(), todo = [...outputs];
  while (todo.length) { // walk back from the outputs to the stage's inputs
    const name = todo.pop();
    if (seen.has(name) || inputs.includes(name)) continue;
    seen.add(name);
    if (weights.has(name)) used.add(name);
    else if (producer.has(name)) {
      const i = producer.get(name);
      nodes.add(i);
      todo.push(...graph.nodes[i].inputs.filter(Boolean));
    } else throw new FormatError(`tensor '${name}' depends on something outside its stage`);
  }
  const chunks = [];
  for (const i of [...nodes].sort((a, b) => a - b)) chunks.push(...bytesField(1, graph.nodes[i].raw));
  chunks.push(...bytesField(2, new TextEncoder().encode('stage')));
  for (const name of [...used].sort()) chunks.push(...bytesField(5, weights.get(name).raw));
  for (const name of inputs) chunks.push(...bytesField(11, graphInputs.get(name).raw));
  for (const name of outputs) chunks.push(...bytesField(12, graphOutputs.get(name).raw));
  const graphBytes = join(chunks);
  const top = [varintBytes(1 * 8 + 0), varintBytes(model.irVersion)];
  for (const opset of model.opsets) top.push(...bytesField(8, opset));
  top.push(...bytesField(7, graphBytes));
  return join(top);
}
