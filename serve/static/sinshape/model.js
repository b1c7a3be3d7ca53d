// Load a sinshape .onnx file in the browser: check it as runtime/load.py does
// (the same refusals, in one line each), cut it into one onnxruntime-web
// session per stage, and read the decoder head's occupancy weights. The
// browser makes geometry only: a model's colour and relief (its colour head,
// its tiles) are read by the Python runtime alone (docs/WEB.md, "One
// runtime"), so this reads the manifest's word for them and not their
// tensors.
import * as ort from '../vendor/onnxruntime-web/ort.wasm.min.mjs';
import { unseal } from './seal.js';
import { FLOAT, FormatError, readModel, stageModel, tensorArray } from './onnx.js';
import { InputError, pyTuple } from './errors.js';

export { InputError };

export const FORMAT_NAME = 'sinshape';
export const FORMAT_VERSION = 3;  // 3 seals the file's bytes (seal.js); the page reads no older one
export const COLOUR_VERSION = 4;  // 3 with a colour head (manifest `colour`)
export const TILES_VERSION = 5;  // the example's surface as tiles, read by correspondence (`colour.tiles`, or `relief.tiles` alone)
export const READ_VERSION = TILES_VERSION; // the newest version this code reads
export const COLOUR_SPACE = { space: 'srgb' }; // manifest `colour`: values are sRGB-encoded in [0, 1]
export const MAX_TILE_SIDE = 64;
export const METADATA_KEY = 'sinshape.manifest';
export const NOISE_SCHEME = 'splitmix64-boxmuller-v1';
export const PLANES = ['xy', 'xz', 'yz'];
export const HEAD_WEIGHTS = ['decoder_head.bias1', 'decoder_head.weight2', 'decoder_head.bias2'];
export const MAX_LEVELS = 64;
export const MIN_LEVEL_SIDE = 8;
export const MAX_LEVEL_SIDE = 4096;
export const MIN_SPACING = 1e-9;
export const MAX_MODEL_BYTES = 512 * 1024 * 1024;
export const MAX_MANIFEST_CHARS = 2 ** 20;
export const MAX_DEPTH = 16;
export const MAX_NOISE_AMP = 100;
export const CONTRAST = 1.3; // core.manifest.CONTRAST: a blended world's contrast exponent, unless the model records one
export const CONTRAST_RANGE = [0.5, 4];
export const OBJECT_SCALE_RANGE = [0.0625, 16]; // core.manifest.OBJECT_SCALE_RANGE: 1/16 to 16
export const MAX_COORD = 1e12;
// core/manifest.py's messages print these with Python's '%g'.
export const MAX_COORD_TEXT = '1e+12', SPACING_TEXT = '[1e-09, 2.44141e+08]';
export const ALLOWED_OPS = new Set(['Conv', 'InstanceNormalization', 'LeakyRelu', 'Transpose', 'MatMul', 'Add', 'Relu', 'Sigmoid']);

/** Input and output tensor names of every stage (core/manifest.py: stage_names); a coloured model's head has a second output. */
export function stageNames(levels, colour = false) {
  const io = (stage) => ({ inputs: PLANES.map((p) => `${stage}.${p}`), outputs: PLANES.map((p) => `${stage}.${p}.out`) });
  return {
    projection: io('projection'),
    levels: Array.from({ length: levels }, (_, i) => io(`level${i}`)),
    decoder_planes: io('decoder_planes'),
    decoder_head: { inputs: PLANES.map((p) => `decoder_head.${p}`), outputs: ['decoder_head.occupancy', ...(colour ? ['decoder_head.colour'] : [])] },
  };
}

const isInt = (v, low, high) => Number.isInteger(v) && v >= low && v <= high;
const isNumber = (v) => typeof v === 'number' && Number.isFinite(v);
/** obj[key] where obj has it, as Python's dict.get: a null value stays null. */
const get = (obj, key, fallback) => (Object.hasOwn(obj, key) ? obj[key] : fallback);
const isObject = (v) => v !== null && typeof v === 'object' && !Array.isArray(v);
const sameJson = (a, b) => JSON.stringify(a) === JSON.stringify(b);

/** The deepest nesting of brackets outside strings (core/manifest.py: _depth). */
function depth(text) {
  let now = 0, deepest = 0;
  for (const [t] of text.matchAll(/"(?:[^"\\]|\\.)*"|[[{]|[\]}]/g)) {
    if (t === '[' || t === '{') deepest = Math.max(deepest, ++now);
    else if (t === ']' || t === '}') now--;
  }
  return deepest;
}

/** An object of keys to values of the given typeof names, or lists of them, or null (manifest.py: _plain). */
function plain(value, types) {
  const ok = (v) => (Array.isArray(v) ? v.every(ok) : v === null || (types.includes(typeof v) && (typeof v !== 'number' || Number.isFinite(v))));
  return isObject(value) && Object.values(value).every(ok);
}

function need(ok, message) {
  if (!ok) throw new InputError(`bad model manifest: ${message}`);
}

/** Check a manifest's JSON text, as core/manifest.py's parse: the fields the runtime uses, and raw. */
export function parseManifest(textValue) {
  need(typeof textValue === 'string' && textValue.length <= MAX_MANIFEST_CHARS, `not JSON text of at most ${MAX_MANIFEST_CHARS} characters`);
  need(depth(textValue) <= MAX_DEPTH, `JSON nested deeper than ${MAX_DEPTH}`);
  let raw;
  try {
    raw = JSON.parse(textValue);
  } catch {
    throw new InputError('bad model manifest: not valid JSON');
  }
  need(raw !== null && typeof raw === 'object' && !Array.isArray(raw), 'not a JSON object');
  need(raw.format === FORMAT_NAME, `format is ${JSON.stringify(raw.format ?? null)}, not '${FORMAT_NAME}'`);
  const version = raw.format_version;
  need(isInt(version, 1, 1e6), `format_version ${JSON.stringify(version ?? null)} is not a positive integer`);
  if (version > READ_VERSION) {
    throw new InputError(`model format version ${version} is newer than this sinshape reads (${READ_VERSION}); upgrade sinshape`);
  }
  let colour = version >= COLOUR_VERSION;
  let tiles = null;
  if (version >= TILES_VERSION) {
    // A coloured model's tiles are under `colour`, a relief-only model's under `relief`: one of the two.
    const kind = 'colour' in raw ? 'colour' : 'relief';
    const field = get(raw, kind, null);
    tiles = isObject(field) ? get(field, 'tiles', null) : null;
    const keys = (obj) => JSON.stringify(Object.keys(obj).sort());
    need(!('colour' in raw && 'relief' in raw), `format ${TILES_VERSION} has colour or relief, not both`);
    need(isObject(field) && keys(field) === (kind === 'colour' ? '["space","tiles"]' : '["tiles"]') && (field.space ?? 'srgb') === 'srgb'
      && isObject(tiles) && keys(tiles) === '["count","side"]'
      && isInt(tiles.count, 1, 2 ** 31 - 1) && isInt(tiles.side, 1, MAX_TILE_SIDE) && (tiles.side & (tiles.side - 1)) === 0,
    `format ${TILES_VERSION} needs colour {"space": "srgb", "tiles": {"count": N, "side": T}} or `
      + `relief {"tiles": {"count": N, "side": T}}, T a power of two up to ${MAX_TILE_SIDE}`);
    colour = kind === 'colour';
    tiles = [tiles.count, tiles.side];
  } else {
    need(colour ? sameJson(get(raw, 'colour', null), COLOUR_SPACE) : get(raw, 'colour', null) === null,
      `colour must be {"space": "srgb"} in format ${COLOUR_VERSION} and absent before it`);
    need(!('relief' in raw), `relief is read from format ${TILES_VERSION} on, not ${version}`);
  }
  if (version === 2) {
    need(typeof raw.checksum === 'string' && /^sha256:[0-9a-f]{64}$/.test(raw.checksum), "checksum must be 'sha256:' and 64 hex digits");
  }
  need(sameJson(raw.planes ?? [], PLANES), `planes must be ${JSON.stringify(PLANES)}`);
  need(raw.noise === NOISE_SCHEME, `noise scheme ${JSON.stringify(raw.noise ?? null)} is not '${NOISE_SCHEME}'`);
  for (const key of ['channels', 'pool_bins', 'mlp_hidden']) need(isInt(raw[key], 1, 1024), `${key} must be an integer in [1, 1024]`);
  // recon_seed may exceed 2^53: read its digits from the text, not the parsed number.
  const seedText = /"recon_seed"\s*:\s*(\d+)\s*[,}]/.exec(textValue)?.[1];
  need(seedText !== undefined && BigInt(seedText) < 2n ** 64n, 'recon_seed must be an integer in [0, 2**64)');

  const levels = raw.levels;
  need(Array.isArray(levels) && levels.length >= 1 && levels.length <= MAX_LEVELS, `levels must be a list of 1..${MAX_LEVELS}`);
  const sizes = [], amps = [];
  levels.forEach((level, i) => {
    need(level !== null && typeof level === 'object', `level ${i} is not an object`);
    const size = level.size;
    need(Array.isArray(size) && size.length === 3 && size.every((n) => isInt(n, MIN_LEVEL_SIDE, MAX_LEVEL_SIDE)),
      `level ${i} size must be 3 integers in [${MIN_LEVEL_SIDE}, ${MAX_LEVEL_SIDE}]`);
    need(i === 0 || size.every((n, axis) => sizes[i - 1][axis] <= n),
      `level ${i} size [${size.join(', ')}] is smaller than level ${i - 1}'s along an axis (levels grow)`);
    need(isNumber(level.noise_amp) && level.noise_amp >= 0 && level.noise_amp <= MAX_NOISE_AMP,
      `level ${i} noise_amp must be a number in [0, ${MAX_NOISE_AMP}]`);
    sizes.push([...size]);
    amps.push(level.noise_amp);
  });
  need(['y', 'z'].includes(raw.up ?? 'y'), 'up must be one of y, z');
  need(['blend', 'scatter'].includes(raw.arrange ?? 'blend'), 'arrange must be one of blend, scatter');
  const contrast = get(raw, 'contrast', CONTRAST);
  need(isNumber(contrast) && contrast >= CONTRAST_RANGE[0] && contrast <= CONTRAST_RANGE[1],
    `contrast must be a number in [${CONTRAST_RANGE[0]}, ${CONTRAST_RANGE[1]}]`);
  const objectScale = get(raw, 'object_scale', 1); // read by worlds, which are the server's: checked as Python checks it
  need(isNumber(objectScale) && objectScale >= OBJECT_SCALE_RANGE[0] && objectScale <= OBJECT_SCALE_RANGE[1],
    `object_scale must be a number in [${OBJECT_SCALE_RANGE[0]}, ${OBJECT_SCALE_RANGE[1]}]`);
  const frame = raw.frame;
  need(frame !== null && typeof frame === 'object', 'frame is missing');
  need(Array.isArray(frame.origin) && frame.origin.length === 3 && frame.origin.every((v) => isNumber(v) && Math.abs(v) <= MAX_COORD),
    `frame origin must be 3 numbers within +-${MAX_COORD_TEXT}`);
  need(Array.isArray(frame.spacing) && frame.spacing.length === 3
    && frame.spacing.every((s) => isNumber(s) && s >= MIN_SPACING && s * MAX_LEVEL_SIDE <= MAX_COORD),
    `frame spacing must be 3 numbers in ${SPACING_TEXT}`);
  const step = Math.max(...frame.origin.map(Math.abs)) * 2 ** -23;  // float32's step at the origin
  need(frame.spacing.every((s) => s > step),
    "frame spacing is below float32's step at the frame's origin: every vertex would land on the same points");
  need(get(raw, 'created_by', null) === null || typeof raw.created_by === 'string', 'created_by must be a string');
  const source = get(raw, 'source', {});
  need(isObject(source) && ['name', 'sha256', 'kind'].every((k) => typeof get(source, k, '') === 'string'),
    'source must be an object of strings name, sha256, kind');
  const config = get(raw, 'config', {}), training = get(raw, 'training', {});
  need(plain(config, ['string', 'number', 'boolean']), 'config must be an object of plain values');
  need(plain(training, ['string', 'number', 'boolean']), 'training must be an object of plain values');
  need(isInt(get(config, 'res', 2), 1, MAX_LEVEL_SIDE), `config res must be an integer in [1, ${MAX_LEVEL_SIDE}]`);
  const levelSeconds = get(training, 'level_seconds', null) || [];
  need(isNumber(get(training, 'seconds', 0)) && Array.isArray(levelSeconds) && levelSeconds.every(isNumber),
    'training seconds must be numbers');
  need(sameJson(raw.stages, stageNames(levels.length, colour)), 'stages do not name the standard tensors for this level count');
  return {
    sizes, noiseAmps: amps, channels: raw.channels, poolBins: raw.pool_bins, hidden: raw.mlp_hidden,
    reconSeed: BigInt(seedText), origin: frame.origin, spacing: frame.spacing, stages: raw.stages, up: raw.up ?? 'y', arrange: raw.arrange ?? 'blend', contrast, colour, tiles, raw,
  };
}

/** Check the file's seal, then parse its bytes as ONNX, refusing what could
 * reach beyond it or is not a sinshape graph (runtime/load.py's read_model and read_manifest). */
export function readChecked(bytes, name) {
  if (bytes.length > MAX_MODEL_BYTES) throw new InputError(`${name}: ${(bytes.length / 2 ** 20).toFixed(0)} MB is too large for a sinshape model`);
  const { sealed, intact } = unseal(bytes);
  if (sealed && !intact) throw new InputError(`${name}: corrupt model: its bytes do not match the SHA-256 sealed at its end`);
  let model;
  try {
    model = readModel(bytes);
  } catch (error) {
    if (error instanceof FormatError) throw new InputError(`${name}: not an ONNX file (truncated or corrupt)`);
    throw error;
  }
  const { graph } = model;
  if (graph.nodes.length === 0) throw new InputError(`${name}: not a sinshape model (an empty or non-ONNX file)`);
  if (graph.initializers.some((t) => t.external)) {
    throw new InputError(`${name}: refers to external data files; sinshape models are self-contained`);
  }
  if (graph.sparse || model.functions) {
    throw new InputError(`${name}: has sparse initializers or functions, which sinshape models never do`);
  }
  const bad = [...new Set(graph.nodes.filter((n) => !['', 'ai.onnx'].includes(n.domain) || !ALLOWED_OPS.has(n.opType))
    .map((n) => n.opType))].sort();
  if (bad.length) throw new InputError(`${name}: uses ops a sinshape model never has (${bad.slice(0, 5).join(', ')})`);
  const names = graph.initializers.map((t) => t.name).sort(); // ONNX names each initializer once: which copy is it? neither
  const twice = names.find((n, i) => i > 0 && names[i - 1] === n);
  if (twice !== undefined) throw new InputError(`${name}: corrupt model: it holds the weight ${twice} twice`);
  if (model.repeated.has(METADATA_KEY)) throw new InputError(`${name}: corrupt model: it holds ${METADATA_KEY} twice`);
  if (!(METADATA_KEY in model.metadata)) {
    throw new InputError(`${name}: an ONNX model, but not a sinshape model (no ${METADATA_KEY} metadata)`);
  }
  let manifest;
  try {
    manifest = parseManifest(model.metadata[METADATA_KEY]);
  } catch (error) {
    if (!(error instanceof InputError)) throw error;
    throw new InputError(`${name}: ${error.message}${sealed ? '' : ' (or a corrupt file: it has no seal)'}`);
  }
  const version = manifest.raw.format_version;
  if (version >= 3 && !sealed) throw new InputError(`${name}: corrupt model: format ${version} ends with a seal, and this file does not`);
  if (version < 3 && sealed) throw new InputError(`${name}: corrupt model: a seal on a format ${version} file`);
  if (version < 3) {
    throw new InputError(`${name}: a format ${version} model; the browser reads formats 3 to 5, which \`sinrun serve\` `
      + 'and `sinrun export-web` write from it');
  }
  return { model, manifest };
}

/** Tensors as typed arrays ([FLOAT, ...] `kinds`), refused as a corrupt model where unreadable. */
function readArrays(tensors, kinds, name) {
  try {
    return tensors.map((t, k) => tensorArray(t, kinds[k]));
  } catch (error) {
    if (error instanceof FormatError) throw new InputError(`${name}: corrupt model: ${error.message}`);
    throw error;
  }
}

/** Initializers by name, each checked for its shape and finite values (runtime/load.py: read_weights). */
function readWeights(weights, names, shapes, name) {
  if (names.some((n) => !weights.has(n))) throw new InputError(`${name}: the decoder head lacks its weights (${names.join(', ')})`);
  const tensors = names.map((n) => weights.get(n));
  const arrays = readArrays(tensors, names.map(() => FLOAT), name);
  if (tensors.some((t, k) => !sameJson(t.dims, shapes[k]))) {
    throw new InputError(`${name}: decoder head weights have shapes ${tensors.map((t) => pyTuple(t.dims)).join(', ')}`);
  }
  if (!arrays.every((a) => a.every(Number.isFinite))) throw new InputError(`${name}: decoder head weights are not finite`);
  return arrays;
}

function readHead(model, manifest, name) {
  const weights = new Map(model.graph.initializers.map((t) => [t.name, t]));
  const hidden = manifest.hidden;
  const [bias1, weight2, bias2] = readWeights(weights, HEAD_WEIGHTS, [[hidden], [hidden, 1], [1]], name);
  return { bias1, weight2, bias2: bias2[0] };
}

/** One runnable stage: a session and its tensor names, in plane order. */
export class Stage {
  constructor(session, inputs, outputs) {
    Object.assign(this, { session, inputs, outputs });
  }

  /** arrays: [{ data: Float32Array, dims }] per input -> [{ data, dims }] per output. */
  async run(arrays) {
    const feeds = {};
    this.inputs.forEach((name, i) => { feeds[name] = new ort.Tensor('float32', arrays[i].data, arrays[i].dims); });
    const results = await this.session.run(feeds);
    return this.outputs.map((name) => ({ data: results[name].data, dims: results[name].dims }));
  }
}

/** The numpy head of runtime/query.py: sigmoid(w2 . relu(h + b1) + b2) for one pre-activation vector. */
export function headValue(head, hidden, at = 0) {
  let sum = 0;
  for (let c = 0; c < head.bias1.length; c++) {
    const h = hidden[at + c] + head.bias1[c];
    if (h > 0) sum += h * head.weight2[c];
  }
  return 1 / (1 + Math.exp(-(sum + head.bias2)));
}

let configured = null;

/**
 * Set up onnxruntime-web once: where its files are (no CDN), and threads.
 * threads: null = all cores but one when the page is cross-origin isolated
 * (the one left draws the page: where no GPU draws, a world streaming on
 * every core held its frames back 300 ms and more), else 1.
 */
export function configure({ threads = null, wasmPaths = null } = {}) {
  if (configured) return configured;
  const isolated = globalThis.crossOriginIsolated === true;
  const wanted = threads ?? (isolated ? Math.min(Math.max(1, (navigator.hardwareConcurrency || 1) - 1), 8) : 1);
  ort.env.wasm.numThreads = isolated ? wanted : 1; // threads need SharedArrayBuffer
  ort.env.wasm.wasmPaths = wasmPaths ?? new URL('../vendor/onnxruntime-web/', import.meta.url).href;
  ort.env.logLevel = 'error';
  configured = { threads: ort.env.wasm.numThreads, isolated, version: ort.env.versions?.web ?? '' };
  return configured;
}

/**
 * Load and check a model from its bytes (Uint8Array). Its stages run on
 * onnxruntime-web's WASM backend, on `threads` threads (configure's default
 * when null). Returns { name, manifest, projection, levels, decoderPlanes,
 * decoderHead, head, backend: 'wasm', threads }.
 */
export async function loadModel(bytes, { name = 'model.onnx', threads = null } = {}) {
  const { model, manifest } = readChecked(bytes, name);
  const head = readHead(model, manifest, name);
  const setup = configure({ threads });
  const sessions = []; // released if a stage fails
  const make = async (names) => {
    let data;
    try {
      data = stageModel(model, names.inputs, names.outputs);
    } catch (error) {
      if (error instanceof FormatError) throw new InputError(`${name}: ${error.message}`);
      throw error;
    }
    const session = await ort.InferenceSession.create(data, { executionProviders: ['wasm'], graphOptimizationLevel: 'all' });
    sessions.push(session);
    return new Stage(session, names.inputs, names.outputs);
  };
  try {
    const stages = manifest.stages;
    const loaded = {
      name, manifest, head, backend: 'wasm', threads: setup.threads,
      projection: await make(stages.projection),
      levels: [],
      decoderPlanes: await make(stages.decoder_planes),
      decoderHead: await make(stages.decoder_head),
    };
    for (const names of stages.levels) loaded.levels.push(await make(names));
    await checkStages(loaded);
    return loaded;
  } catch (error) {
    await Promise.allSettled(sessions.map((session) => session.release()));
    if (error instanceof InputError) throw error;
    const message = String(error?.message ?? error).split('\n')[0].slice(0, 200);
    throw new InputError(`${name}: onnxruntime cannot load a stage (${message})`);
  }
}

/** Run every stage once on a small input: the file is coherent, or refused (runtime/load.py: check_stages). */
async function checkStages(model) {
  const m = model.manifest, c = m.channels, h = m.hidden;
  const zeros = (dims) => Array(3).fill({ data: new Float32Array(dims.reduce((a, b) => a * b)), dims });
  const probes = [
    [model.projection, zeros([1, m.poolBins, 4, 5]), [1, c, 4, 5]],
    ...model.levels.map((level) => [level, zeros([1, c, 4, 5]), [1, c, 4, 5]]),
    [model.decoderPlanes, zeros([1, c, 4, 5]), [1, 4, 5, h]],
  ];
  for (const [stage, arrays, shape] of probes) {
    let outputs;
    try {
      outputs = await stage.run(arrays);
    } catch (error) {
      throw new InputError(`${model.name}: stage ${stage.inputs[0].split('.')[0]} does not run (${String(error.message ?? error).split('\n')[0].slice(0, 200)})`);
    }
    // The first wrong output: another output's shape would read as a match.
    const wrong = outputs.find((o) => !sameJson(Array.from(o.dims), shape));
    if (wrong) {
      throw new InputError(`${model.name}: stage ${stage.inputs[0].split('.')[0]} gives shape (${wrong.dims}), expected (${shape})`);
    }
  }
  // The head evaluated here must be the graph's head (its occupancy: the colour a coloured head adds is Python's to read).
  const n = 16, hidden = Array.from({ length: 3 }, (_, k) => Float32Array.from({ length: n * h }, (_, i) => Math.sin(i * 1.7 + k)));
  const [graph] = await model.decoderHead.run(hidden.map((data) => ({ data, dims: [n, 1, 1, h] })));
  const sum = new Float32Array(n * h).map((_, i) => hidden[0][i] + hidden[1][i] + hidden[2][i]);
  for (let i = 0; i < n; i++) {
    if (Math.abs(graph.data[i] - headValue(model.head, sum, i * h)) > 1e-5) {
      throw new InputError(`${model.name}: the decoder head graph does not match its weights`);
    }
  }
}
