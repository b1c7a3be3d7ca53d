// Making a sample, behind one call for both back ends:
//
//   sample(where, name, request, { progress, signal }) -> { positions, faces, status, file, ... }
//
// where 'server' asks the server's HTTP API (the Python runtime), 'browser'
// this browser's runtime (sinshape/, in a module worker started on first
// use, so the server mode never fetches onnxruntime-web's 14 MB of WASM and
// a sample never freezes the page). `info` and `layout` give what the editor
// draws from the same place: a model's grids, frame and up axis, a seed's
// layout; `tile` a tile of a world, for the world mode (viewer/world.js),
// from the server only: the browser's runtime makes geometry, no worlds.
// An aborted `signal` gives up a request (the server stops making it); in
// the browser a request waits for the one before it, and is skipped if a
// newer one aborted it meanwhile. `stop` ends the worker (cancel).
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OPTIONS } from '../sinshape/options.js';
import { voxBytes } from './layout-cells.js';

/** A request given up: nothing to report. */
class Cancelled extends Error {
  constructor() { super('cancelled'); }
}

const models = new Map(); // name -> { url or bytes, file, loaded: a promise of the worker's { backend, threads, seconds, sizes, origin, spacing, up, arrange } }

/** A model the browser may load: from `url`, or the bytes of a file opened on the page. */
export function addModel(name, { url = null, bytes = null, file }) {
  models.set(name, { url, bytes, file });
}

// ---- the server: its routes (docs/SERVE.md)
const loader = new GLTFLoader();
const infos = new Map(); // model name -> a promise of { sizes, origin, spacing, up, arrange }
const modelRoute = (name) => `api/models/${encodeURIComponent(name)}`;

async function answer(response) {
  if (response.ok) return response;
  const body = await response.json().catch(() => ({}));
  throw new Error(body.detail || `${response.status} ${response.statusText}`);
}

// Each route takes every option of its kind of request (runtime/options.py; a
// sample's edits are a sample's) as a query parameter of the option's name
// (tests/test_options.py holds the routes to the table), but these, sent
// otherwise; an option of another kind given other than its default is
// refused here, not sent without it.
const SENT_OTHERWISE = ['tile', 'layout', 'heights', 'keep']; // i and j, a POST's body, a parameter a part
const ALWAYS_SENT = { sample: ['seed', 'size', 'scale', 'smooth'], tile: ['seed', 'scale'] }; // the links read so
const takes = (route, { goes_with: goes }) => goes.some((kind) => kind === route || (route === 'sample' && kind !== 'tile'));
const isDefault = (request, { name, default: value }) => JSON.stringify(request[name]) === JSON.stringify(value);

/** The options each route takes, by name: { sample: [...], tile: [...] }. */
export const ROUTE_TAKES = Object.freeze(Object.fromEntries(['sample', 'tile'].map((route) => [
  route, OPTIONS.filter((option) => takes(route, option)).map(({ name }) => name)])));

/**
 * The server's request for a sample request, as a file of `format`: { url,
 * init } for fetch. The sample route's query; a layout goes as the body of
 * a POST to it, written as .vox; a tile, the tile route's query. The sample
 * route takes kept parts as text, and neither route an option of the other
 * kind: a request that needs more is refused here.
 */
export function serverRequest(name, request, format, faces = null) {
  const asset = format === 'asset' ? assetQuery(faces) : null;
  if (asset) format = 'glb';
  const route = request.tile ? 'tile' : 'sample';
  const unsent = OPTIONS.filter((option) => !takes(route, option) && !isDefault(request, option)).map(({ name }) => name);
  if (route === 'sample' && request.keep.some((part) => typeof part !== 'string')) unsent.push('keep');
  if (unsent.length) throw new Error(`the ${route} route cannot take this request's ${unsent.join(', ')}`);
  const query = new URLSearchParams(request.tile ? { i: request.tile[0], j: request.tile[1] } : {});
  for (const field of ALWAYS_SENT[route]) query.set(field, request[field] ?? 0n);
  if (request.recon) query.delete('seed'); // the training shape has none
  query.set('format', format);
  for (const option of OPTIONS) {
    const sent = takes(route, option) && !ALWAYS_SENT[route].includes(option.name) && !SENT_OTHERWISE.includes(option.name);
    if (!sent || isDefault(request, option)) continue;
    if (option.type === 'models') for (const other of request.models) query.append('models', other); // models=a&models=b
    else query.set(option.name, option.type === 'models_map' ? modelMapText(request.models_map) : request[option.name]);
  }
  if (request.tile) {
    if (asset) throw new Error('the page offers a tile as a mesh; sinrun world --lods writes tiles as assets');
    const init = request.heights ? { method: 'POST', body: npyBytes(request.heights), headers: { 'Content-Type': 'application/octet-stream' } } : {};
    return { url: `${modelRoute(name)}/tile?${query}`, init };
  }
  for (const part of request.keep) query.append('keep', part);
  if (request.layout?.resample) query.set('resample_layout', 'true');
  if (asset) for (const [key, value] of Object.entries(asset)) query.set(key, value);
  const url = `${modelRoute(name)}/sample?${query}`;
  if (!request.layout) return { url, init: {} };
  const body = voxBytes(request.layout.grid, request.layout.shape);
  return { url, init: { method: 'POST', body, headers: { 'Content-Type': 'application/octet-stream' } } };
}

/**
 * The query of a game asset of a sample of `faces` triangles: levels of
 * 20000, 5000 and 1200 triangles, each at most half the one before (the
 * first, half the sample's), and maps sized to the sample. A sample's triangle
 * count is known once it is shown: before that, an error.
 */
export function assetQuery(faces) {
  if (!faces) throw new Error('an asset is offered once its sample is shown');
  const lods = [];
  for (const wanted of [20000, 5000, 1200]) {
    const count = Math.min(wanted, Math.floor((lods.at(-1) ?? faces) / 2));
    if (count >= 4) lods.push(count);
  }
  return { lods: lods.join(',') };
}

/** A height map ({ shape, data: Float32Array }) as the bytes of a .npy file: the tile route's POST body. */
function npyBytes({ shape, data }) {
  let header = `{'descr': '<f4', 'fortran_order': False, 'shape': (${shape[0]}, ${shape[1]}), }`;
  header += ' '.repeat(63 - ((10 + header.length) % 64)) + '\n'; // the data starts at a multiple of 64
  const bytes = new Uint8Array(10 + header.length + data.byteLength);
  bytes.set([0x93, ...new TextEncoder().encode('NUMPY'), 1, 0, header.length & 0xff, header.length >> 8]);
  bytes.set(new TextEncoder().encode(header), 10);
  bytes.set(new Uint8Array(data.buffer, data.byteOffset, data.byteLength), 10 + header.length);
  return bytes;
}

/** A model map ({ shape, data: Uint8Array }) as the tile route reads it (world.ModelMap.of_text): rows along the first
 * horizontal axis parted by ';', a row's pixels by ','. */
function modelMapText({ shape: [rows, cols], data }) {
  return Array.from({ length: rows }, (_, r) => data.subarray(r * cols, (r + 1) * cols).join(',')).join(';');
}

/** The one mesh of a .glb file trimesh wrote: { positions, faces, colours } (no normals, no
 * transform); colours, where it has COLOR_0 (linear, as glTF says), turned back to sRGB, else null. */
async function glbMesh(data) {
  let geometry = null;
  (await loader.parseAsync(data, '')).scene.traverse((node) => { if (node.isMesh) geometry ??= node.geometry; });
  const color = geometry?.attributes.color;
  const srgb = (c) => (c <= 0.0031308 ? c * 12.92 : 1.055 * c ** (1 / 2.4) - 0.055);
  const colours = color ? Float32Array.from({ length: 3 * color.count }, (_, i) => srgb(color.getComponent(Math.floor(i / 3), i % 3))) : null;
  return { positions: geometry?.attributes.position.array ?? new Float32Array(), faces: geometry?.index.array ?? new Uint32Array(),
           normals: geometry?.attributes.normal?.array ?? null, colours };
}

const server = {
  info(name) {
    if (!infos.has(name)) {
      infos.set(name, (async () => {
        const body = await (await answer(await fetch(modelRoute(name)))).json();
        return { sizes: body.sizes, origin: body.frame.origin, spacing: body.frame.spacing, up: body.up, arrange: body.arrange,
                 objectScale: body.object_scale };
      })());
      infos.get(name).catch(() => infos.delete(name));
    }
    return infos.get(name);
  },

  async layout(name, seed, size) {
    const query = new URLSearchParams({ seed, size });
    const body = await (await answer(await fetch(`${modelRoute(name)}/layout?${query}`))).json();
    return { shape: body.shape, grid: Uint8Array.from(body.occupancy, (c) => (c === '1' ? 1 : 0)) };
  },

  async sample(name, request, { signal }) {
    const started = performance.now();
    const { url, init } = serverRequest(name, request, 'glb');
    const response = await answer(await fetch(url, { ...init, signal }));
    const data = await response.arrayBuffer();
    const seconds = ((performance.now() - started) / 1000).toFixed(2);
    const cached = response.headers.get('X-Cache') === 'hit' ? ' (cached)' : '';
    return {
      ...await glbMesh(data),
      status: `${Number(response.headers.get('X-Faces')).toLocaleString('en')} faces · ${seconds} s${cached}`,
      file: request.layout ? new Blob([data], { type: 'model/gltf-binary' }) : null, // else the route is the link
      extension: 'glb',
    };
  },

  async tile(name, request, { signal }) {
    const { url, init } = serverRequest(name, request, 'glb');
    const response = await fetch(url, { ...init, signal });
    // A tile with no surface (all empty or all full there) is refused as a file: here it is nothing to show.
    if (response.status === 400 && / has no surface /.test((await response.clone().json().catch(() => ({}))).detail)) {
      return { positions: new Float32Array(), faces: new Uint32Array(), normals: null, colours: null };
    }
    return glbMesh(await (await answer(response)).arrayBuffer());
  },
};

// ---- this browser: the runtime in a module worker (sinshape/worker.js; its header gives the messages)
let worker = null;
const jobs = new Map(); // id -> { resolve, reject, progress }
let jobIds = 0;
let running = Promise.resolve(); // the worker's work in progress: one thing at a time

function startWorker() {
  if (worker) return worker;
  worker = new Worker(new URL('../sinshape/worker.js', import.meta.url), { type: 'module' });
  worker.onmessage = ({ data }) => {
    const job = jobs.get(data.id);
    if (!job) return;
    if (data.type === 'progress') return job.progress?.(data.stage, data.fraction);
    jobs.delete(data.id);
    if (data.type === 'error') job.reject(new Error(data.message));
    else job.resolve(data);
  };
  worker.onerror = (event) => { // the worker's script did not load or threw outside a job
    event.preventDefault?.();
    stopWorker(new Error(`the browser runtime stopped: ${event.message || 'its script did not load'}`));
  };
  return worker;
}

/** End the worker: its jobs fail with `reason`, and every model must be loaded again. */
function stopWorker(reason) {
  worker?.terminate();
  worker = null;
  for (const job of jobs.values()) job.reject(reason);
  jobs.clear();
  for (const entry of models.values()) entry.loaded = null;
}

function call(message, progress = null) {
  const id = ++jobIds;
  return new Promise((resolve, reject) => {
    jobs.set(id, { resolve, reject, progress });
    startWorker().postMessage({ id, ...message });
  });
}

/** `work()` once the worker's earlier work is done, unless `signal` was aborted by then. */
function inTurn(signal, work) {
  const turn = running.catch(() => {}).then(() => {
    if (signal?.aborted) throw new Cancelled();
    return work();
  });
  running = turn;
  return turn;
}

/** The model loaded and checked in the worker (once; its bytes are fetched once and kept for a fresh worker). */
async function loaded(name, progress = null) {
  const entry = models.get(name);
  if (!entry) throw new Error(`unknown model '${name}'`);
  if (!entry.loaded) progress?.('loading the model', null);
  entry.loaded ??= (async () => {
    if (!entry.bytes) {
      const response = await fetch(entry.url);
      if (!response.ok) throw new Error(`cannot fetch ${entry.url}: ${response.status} ${response.statusText}`);
      entry.bytes = new Uint8Array(await response.arrayBuffer());
    }
    return call({ type: 'load', name, bytes: entry.bytes, file: entry.file });
  })();
  const loading = entry.loaded;
  try {
    return await loading;
  } catch (error) {
    if (entry.loaded === loading) entry.loaded = null; // a later try loads again
    throw error;
  }
}

/** A binary PLY file of a mesh (as the Python runtime writes one without colour). */
function plyBlob({ positions, faces }) {
  const vertices = positions.length / 3, stride = 12;
  const header = `ply\nformat binary_little_endian 1.0\nelement vertex ${vertices}\n`
    + 'property float x\nproperty float y\nproperty float z\n'
    + `element face ${faces.length / 3}\nproperty list uchar int vertex_indices\nend_header\n`;
  const body = new DataView(new ArrayBuffer(vertices * stride + (faces.length / 3) * 13));
  for (let v = 0; v < vertices; v++) {
    for (let k = 0; k < 3; k++) body.setFloat32(v * stride + 4 * k, positions[3 * v + k], true);
  }
  let at = vertices * stride;
  for (let f = 0; f < faces.length; f += 3) {
    body.setUint8(at, 3);
    for (let k = 0; k < 3; k++) body.setInt32(at + 1 + 4 * k, faces[f + k], true);
    at += 13;
  }
  return new Blob([header, body], { type: 'application/octet-stream' });
}

const browser = {
  info: (name, { progress, signal } = {}) => inTurn(signal, () => loaded(name, progress)),

  layout: (name, seed, size, { signal } = {}) => inTurn(signal, async () => {
    await loaded(name);
    const { shape, grid } = await call({ type: 'layout', name, seed: String(seed), factors: size });
    return { shape, grid };
  }),

  sample: (name, request, { progress, signal }) => inTurn(signal, async () => {
    const model = await loaded(name, progress);
    const mesh = await call({ type: 'sample', name, request }, (stage, fraction) => { if (!signal?.aborted) progress?.(stage, fraction); });
    const faces = (mesh.faces.length / 3).toLocaleString('en');
    const threads = model.threads === 1 ? '1 thread' : `${model.threads} threads`;
    const isolation = crossOriginIsolated ? '' : ' (the page is not cross-origin isolated, so WASM runs single-threaded)';
    const left = mesh.without.length ? ` · without its ${mesh.without.join(' and ')}: sinrun serve makes them` : '';
    return {
      ...mesh, colours: null, status: `${faces} faces · ${mesh.seconds.toFixed(2)} s · in this browser${left}`, file: plyBlob(mesh), extension: 'ply',
      backend: `onnxruntime-web on WASM, ${threads}${isolation}; model loaded and checked in ${model.seconds.toFixed(2)} s`,
    };
  }),
};

/** Open a model file in the browser: checked in the worker, then listed; a refused file leaves the list as it was. */
export async function openFile(name, bytes, file, signal) {
  const previous = models.get(name);
  addModel(name, { bytes, file });
  try {
    await inTurn(signal, () => loaded(name));
  } catch (error) {
    if (previous) models.set(name, previous);
    else models.delete(name);
    throw error;
  }
}

/** Stop the browser's work: the worker ends with its jobs, and the next request starts a fresh one. */
export function stop() {
  if (worker && jobs.size) stopWorker(new Cancelled());
  running = Promise.resolve();
}

const backends = { server, browser };
const layouts = new Map(); // "where|model|seed|size" -> a promise of a seed's layout { shape, grid }

/** A model's grids, frame, up axis and world's arrangement: { sizes, origin, spacing, up, arrange, objectScale (the server's) }. */
export const info = (where, name, options) => backends[where].info(name, options);

/** The sample of a request: { positions, faces, status, file (a Blob to download, or null), extension,
 * backend (how the browser ran it) }. */
export const sample = (where, name, request, options) => backends[where].sample(name, request, options);

/** A game asset's .glb from the server's route `url` (serverRequest's, format 'asset'): its bytes. The server keeps
 * the finished file, so the download link's request for it again is answered from there. */
export async function assetData(url, { signal }) {
  return (await answer(await fetch(url, { signal }))).arrayBuffer();
}

/** The tile of a tile request (frame 'tile'): { positions, faces, normals, colours, corner }, none where the tile
 * has no surface. The server makes it: the browser's runtime makes no worlds. */
export const tile = (where, name, request, options) => {
  if (where !== 'server') throw new Error("a world's tiles come from sinrun serve: the browser runtime makes no worlds");
  return server.tile(name, request, options);
};

/** The seed's own layout (level 0 at `size`): { shape, grid }, kept once made. */
export function layout(where, name, seed, size, options) {
  const key = `${where}|${name}|${seed}|${size}`;
  if (!layouts.has(key)) {
    layouts.set(key, backends[where].layout(name, seed, size, options));
    layouts.get(key).catch(() => layouts.delete(key));
  }
  return layouts.get(key);
}
