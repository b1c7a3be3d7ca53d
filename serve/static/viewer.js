// The sinshape page: pick a model and a seed, see the sample in 3-D, download it,
// and edit it (docs/EDITING.md): keep a box of it and take the rest from another
// seed, grow it, or edit its coarse layout as blocks. Each change
// of the shape is a step that undo and redo walk; the state lives in the URL's
// query string, so a view, edits included, can be shared.
// A sample is made on the server (its API) or in this browser (the JavaScript
// runtime in sinshape/, on onnxruntime-web); a static site from
// `sinrun export-web` (body data-site="static") has no server and samples in
// the browser only.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import * as layouts from './layout.js';

const $ = (id) => document.getElementById(id);
// An x,y,z row of the page (class xyz) holds its x input; the y and z inputs
// are copies of it, with x in their id, name and title turned to their axis.
for (const x of document.querySelectorAll('.xyz > input')) {
  for (const axis of ['z', 'y']) {
    const input = x.cloneNode();
    input.id = x.id.replace('x', axis);
    if (x.name) input.name = x.name.replace('x', axis);
    input.title = x.title.replace(/\bx\b/g, axis);
    x.after(input);
  }
}
const FIELDS = ['model', 'where', 'seed', 'size', 'scale', 'smooth', 'up', 'format'];
// Each edit's fields, in the URL after `edit`: box (6 percentages x0,y0,z0,x1,y1,z1
// of the sample, from the seed's sample) and other (the seed of the rest); grow
// and anchor (3 factors, 3 fractions); cells (layout.js's text of the edited cells).
const EDITS = { keep: ['box', 'other'], grow: ['grow', 'anchor'], layout: ['cells'] };
const EDIT_DEFAULTS = { edit: '', box: '0,0,0,50,100,100', other: '', grow: '2,1,1', anchor: '0,0,0', cells: '' };
// What makes the shape: a step of the undo history when one of these changes.
const SHAPE_FIELDS = ['model', 'seed', 'size', 'scale', 'smooth', 'edit', 'box', 'other', 'grow', 'anchor', 'cells'];
const STATIC_SITE = document.body.dataset.site === 'static';

// ---- the 3-D view: one scene, one shape at a time, drawn on demand
const view = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20242a);
const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 1000);
// Light: a soft sky-and-ground fill, and a key light from above and to the
// left of the viewer. The key light and its target ride with the camera, so
// whichever side is turned to the viewer is lit the same way and shaded by its form.
scene.add(new THREE.HemisphereLight(0xf4f6ff, 0x3a3630, 0.8));
const key = new THREE.DirectionalLight(0xffffff, 2.8);
key.position.set(-0.8, 1.2, 0.4);
key.target.position.set(0, 0, -1);
camera.add(key, key.target);
scene.add(camera);
const controls = new OrbitControls(camera, renderer.domElement);
controls.addEventListener('change', draw);
// Front faces only: the meshes are closed and wound outwards (normals out), so
// back faces are never seen from outside; drawing them too (DoubleSide) made
// dark lines where they fought the front faces in the depth buffer.
const material = new THREE.MeshStandardMaterial({ color: 0xd8c8a8, roughness: 0.85, side: THREE.FrontSide });
const holder = new THREE.Group(); // turned so the model's up axis points up on screen
const shapeGroup = new THREE.Group(); // the sample
const extras = new THREE.Group(); // what the editor draws over it: a box's wireframe, the layout's blocks
holder.add(shapeGroup, extras);
scene.add(holder);
const loader = new GLTFLoader();
const boxLines = new THREE.LineBasicMaterial({ color: 0xffd54a });
const selectLines = new THREE.LineBasicMaterial({ color: 0xff5a36 });
const blockMaterial = new THREE.MeshStandardMaterial({ color: 0x7fb0e8, roughness: 0.8 });
let framed = ''; // what the camera was last framed for: a new extent frames it again, an edit inside it does not

function draw() {
  renderer.render(scene, camera);
}

function resize() {
  const { clientWidth: w, clientHeight: h } = view;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  draw();
}

function orient(up) {
  holder.rotation.set(up === 'z' ? -Math.PI / 2 : 0, 0, 0);
  holder.updateMatrixWorld(true);
}

function frame() {
  // Aim at the shape's box from a three-quarter view that fits it.
  const box = new THREE.Box3().setFromObject(shapeGroup);
  if (box.isEmpty()) return draw();
  const centre = box.getCenter(new THREE.Vector3());
  const radius = box.getSize(new THREE.Vector3()).length() / 2;
  // The narrower of the two fields of view: a tall view (a phone) fits the shape's width too.
  const half = THREE.MathUtils.degToRad(camera.fov / 2);
  const fit = Math.min(half, Math.atan(Math.tan(half) * camera.aspect));
  const distance = radius / Math.sin(fit) * 1.05;
  camera.position.copy(centre).add(new THREE.Vector3(0.8, 0.55, 1).normalize().multiplyScalar(distance));
  camera.near = distance / 100;
  camera.far = distance * 10;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
  draw();
}

function showMesh({ positions, faces }) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  geometry.setIndex(new THREE.BufferAttribute(faces, 1));
  geometry.computeVertexNormals();
  shapeGroup.clear();
  shapeGroup.add(new THREE.Mesh(geometry, material));
  shown();
}

function show(gltf) {
  shapeGroup.clear();
  gltf.scene.traverse((node) => {
    if (node.isMesh) {
      if (!node.geometry.attributes.normal) node.geometry.computeVertexNormals();
      node.material = material;
    }
  });
  shapeGroup.add(gltf.scene);
  shown();
}

/** A new shape is in the view: frame it if its extent is new, else keep the user's camera. */
function shown() {
  orient(state.up);
  const extent = [state.model, state.size, state.edit === 'grow' ? `${state.grow}|${state.anchor}` : '', state.up].join('|');
  if (extent !== framed) frame();
  else draw();
  framed = extent;
}

/** The shape in view: faces, vertices, volume (the model's frame) and a digest of its
 * vertices and faces (FNV-1a of their bytes): what the tests compare, before and after an edit. */
function shapeSummary() {
  let faces = 0, vertices = 0, volume = 0, hash = 0x811c9dc5;
  const mix = (bytes) => { for (let i = 0; i < bytes.length; i++) hash = Math.imul(hash ^ bytes[i], 0x01000193) >>> 0; };
  shapeGroup.traverse((node) => {
    if (!node.isMesh) return;
    const p = node.geometry.attributes.position.array, f = node.geometry.index.array;
    mix(new Uint8Array(Float32Array.from(p).buffer));
    mix(new Uint8Array(Uint32Array.from(f).buffer));
    faces += f.length / 3;
    vertices += p.length / 3;
    for (let i = 0; i < f.length; i += 3) {
      const a = 3 * f[i], b = 3 * f[i + 1], c = 3 * f[i + 2];
      volume += p[a] * (p[b + 1] * p[c + 2] - p[b + 2] * p[c + 1]) - p[a + 1] * (p[b] * p[c + 2] - p[b + 2] * p[c])
        + p[a + 2] * (p[b] * p[c + 1] - p[b + 1] * p[c]);
    }
  });
  return { faces, vertices, volume: volume / 6, digest: hash.toString(16).padStart(8, '0') };
}

window.sinshapeView = { scene, camera, renderer, shape: shapeSummary }; // for the tests and the console

// ---- the state: read from the URL, written back to it
const state = {
  model: '', where: STATIC_SITE ? 'browser' : 'server', seed: 0, size: '1,1,1', scale: '1', smooth: '0', up: 'y', format: 'glb',
  ...EDIT_DEFAULTS,
};

function readUrl() {
  const query = new URLSearchParams(location.search);
  for (const key of [...FIELDS, ...Object.keys(EDIT_DEFAULTS)]) if (query.has(key)) state[key] = query.get(key);
  if (STATIC_SITE || !['server', 'browser'].includes(state.where)) state.where = STATIC_SITE ? 'browser' : 'server';
  if (!(state.edit in EDITS)) state.edit = '';
  if (state.edit === 'keep' && !state.other) state.other = nextSeed(String(state.seed));
}

function writeUrl() {
  const query = new URLSearchParams();
  for (const key of FIELDS) query.set(key, state[key]);
  if (state.edit) {
    query.set('edit', state.edit);
    for (const key of EDITS[state.edit]) query.set(key, state[key]);
  }
  history.replaceState(null, '', `${location.pathname}?${query}`);
}

// ---- undo and redo: every shape the page made, a step; undo shows the previous one again
const steps = []; // snapshots of the state's SHAPE_FIELDS
let stepAt = -1;
const shapeKey = (snapshot) => JSON.stringify(SHAPE_FIELDS.map((key) => String(snapshot[key])));

function record() {
  const snapshot = Object.fromEntries(SHAPE_FIELDS.map((key) => [key, state[key]]));
  if (stepAt >= 0 && shapeKey(steps[stepAt]) === shapeKey(snapshot)) return;
  steps.splice(stepAt + 1);
  steps.push(snapshot);
  stepAt = steps.length - 1;
  showSteps();
}

function showSteps() {
  $('undo').disabled = stepAt <= 0;
  $('redo').disabled = stepAt >= steps.length - 1;
}

function walk(delta) {
  const to = stepAt + delta;
  if (to < 0 || to >= steps.length) return;
  stepAt = to;
  Object.assign(state, steps[to]);
  toForm();
  showSteps();
  load({ replay: true });
}

function toForm() {
  $('model').value = state.model;
  $('seed').value = state.seed;
  const [x, y, z] = String(state.size).split(',');
  $('sx').value = x ?? 1;
  $('sy').value = y ?? x ?? 1;
  $('sz').value = z ?? x ?? 1;
  for (const key of ['where', 'scale', 'smooth', 'up', 'format', 'edit', 'other']) $(key).value = state[key];
  const box = String(state.box).split(',');
  ['bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1'].forEach((id, i) => { $(id).value = box[i] ?? ''; });
  const by = String(state.grow).split(','), anchor = String(state.anchor).split(',');
  ['gx', 'gy', 'gz'].forEach((id, i) => { $(id).value = by[i] ?? by[0] ?? ''; });
  ['ax', 'ay', 'az'].forEach((id, i) => { $(id).value = anchor[i] ?? anchor[0] ?? ''; });
  showMode();
}

function showMode() {
  const browser = state.where === 'browser';
  $('where-label').hidden = STATIC_SITE;
  $('file-label').hidden = !browser;
  const blob = browser || (state.edit === 'layout' && Boolean(state.cells)); // a download the page made itself
  $('format').disabled = blob; // the browser writes .ply, a shape from a layout comes as .glb, and the box says so
  $('format').value = browser ? 'ply' : blob ? 'glb' : state.format;
  $('backend').hidden = !browser;
  for (const [edit, id] of [['keep', 'keep-controls'], ['grow', 'grow-controls'], ['layout', 'layout-controls']]) {
    $(id).hidden = state.edit !== edit;
  }
}

function fromForm() {
  const layoutOf = [state.model, state.seed, state.size].join('|');
  state.model = $('model').value;
  state.seed = $('seed').value.trim();
  state.size = [$('sx').value, $('sy').value, $('sz').value].map((v) => v.trim()).join(',');
  for (const key of ['where', 'scale', 'smooth', 'up', 'format', 'edit', 'other']) state[key] = $(key).value.trim();
  state.box = ['bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1'].map((id) => $(id).value.trim()).join(',');
  state.grow = ['gx', 'gy', 'gz'].map((id) => $(id).value.trim()).join(',');
  state.anchor = ['ax', 'ay', 'az'].map((id) => $(id).value.trim()).join(',');
  if (state.edit === 'keep' && !state.other) $('other').value = state.other = nextSeed(state.seed);
  if ([state.model, state.seed, state.size].join('|') !== layoutOf) { // another sample: its own layout, unedited
    state.cells = '';
    selected = null;
  }
}

const nextSeed = (seed) => (/^\d+$/.test(seed) && BigInt(seed) < 2n ** 63n - 1n ? String(BigInt(seed) + 1n) : '1');

/** The box's 6 percentages, checked: [x0, y0, z0, x1, y1, z1] as the strings given (the server parses them itself). */
function parseBox(text) {
  const values = String(text).split(',').map((v) => v.trim());
  const numbers = values.map(Number);
  if (values.length !== 6 || values.some((v) => v === '') || !numbers.every((v) => Number.isFinite(v) && v >= 0 && v <= 100)) {
    throw new Error(`box '${text}': give 6 percentages of the sample in 0..100, x0,y0,z0,x1,y1,z1`);
  }
  for (let a = 0; a < 3; a++) {
    if (!(numbers[a] < numbers[a + 3])) throw new Error(`box: along ${'xyz'[a]} it runs from ${values[a]}% to ${values[a + 3]}%; the first must be less`);
  }
  return values;
}

function parseAnchor(text) {
  const values = String(text).split(',').map(Number);
  const anchor = values.length === 1 ? [values[0], values[0], values[0]] : values;
  if (anchor.length !== 3 || !anchor.every((v) => v >= 0 && v <= 1)) throw new Error(`anchor '${text}': give three fractions in [0, 1], like 0.5,0,0`);
  return anchor;
}

function sampleUrl(format) {
  const query = new URLSearchParams({
    seed: state.seed, size: state.size, scale: state.scale, smooth: state.smooth, format,
  });
  if (state.edit === 'keep') {
    // The box is the seed's; the rest is the other seed's: that seed is the request's base.
    const box = String(state.box).split(',');
    query.set('seed', state.other);
    query.append('keep', `${state.seed}:${box.slice(0, 3).map((v) => `${v}%`).join(',')}:${box.slice(3).map((v) => `${v}%`).join(',')}`);
  } else if (state.edit === 'grow') {
    query.set('grow', state.grow);
    query.set('anchor', state.anchor);
  }
  return `api/models/${encodeURIComponent(state.model)}/sample?${query}`;
}

function report(error) {
  $('error').textContent = error;
  $('error').hidden = !error;
}

// ---- sampling in this browser: the runtime runs in a module worker
// (sinshape/worker.js), started on first use, so the server mode never fetches
// onnxruntime-web's 14 MB of WASM and a sample never freezes the page. Cancel
// ends the worker; the next sample starts a fresh one, which loads its model again.
class Cancelled extends Error {
  constructor() { super('cancelled'); }
}

const browserModels = new Map(); // name -> { url or bytes, file, up, loaded: a promise of { backend, threads, seconds } in this worker }
let worker = null;
const jobs = new Map(); // id -> { resolve, reject, progress }
let jobIds = 0;
let downloadUrl = null;

function startWorker() {
  if (worker) return worker;
  worker = new Worker(new URL('./sinshape/worker.js', import.meta.url), { type: 'module' });
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
  for (const entry of browserModels.values()) entry.loaded = null;
}

function call(message, progress = null) {
  const id = ++jobIds;
  return new Promise((resolve, reject) => {
    jobs.set(id, { resolve, reject, progress });
    startWorker().postMessage({ id, ...message });
  });
}

async function browserModel(name) {
  const entry = browserModels.get(name);
  if (!entry) throw new Error(`unknown model '${name}'`);
  entry.loaded ??= (async () => {
    if (!entry.bytes) {
      const response = await fetch(entry.url);
      if (!response.ok) throw new Error(`cannot fetch ${entry.url}: ${response.status} ${response.statusText}`);
      entry.bytes = new Uint8Array(await response.arrayBuffer()); // kept: a fresh worker loads it again
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

function backendText(model, loadSeconds) {
  const threads = model.threads === 1 ? '1 thread' : `${model.threads} threads`;
  const isolation = crossOriginIsolated ? '' : ' (the page is not cross-origin isolated, so WASM runs single-threaded)';
  return `onnxruntime-web on WASM, ${threads}${isolation}; model loaded and checked in ${loadSeconds.toFixed(2)} s`;
}

function parseSeed(text) {
  if (!/^\d+$/.test(text)) throw new Error(`seed: give a whole number, got '${text}'`);
  return BigInt(text);
}

function parseFactors(text, name = 'size', atLeastOne = false) {
  const values = String(text).split(',').map((v) => (v.trim() === '' ? NaN : Number(v)));
  const factors = values.length === 1 ? [values[0], values[0], values[0]] : values;
  if (factors.length !== 3 || !factors.every((v) => (atLeastOne ? v >= 1 : v > 0) && Number.isFinite(v))) {
    throw new Error(atLeastOne ? `${name} '${text}': give one or three factors of at least 1, like 2 or 2,1,1`
      : `${name} '${text}': give one or three positive factors, like 2 or 2,1,0.5`);
  }
  return factors;
}

// Python's round(): halves go to the even neighbour (as generate.js; the
// runtime's modules are not imported here, they would fetch onnxruntime-web).
function roundHalfEven(v) {
  const r = Math.round(v);
  return Math.abs(v % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

/** The finest grid of a sample `factors` times the training size, as runtime.generate.scaled_sizes. */
const finestSize = (sizes, factors) => sizes.at(-1).map((n, a) => Math.max(2, roundHalfEven(n * factors[a])));

/** A binary PLY file of a mesh. */
function plyBlob({ positions, faces }) {
  const header = `ply\nformat binary_little_endian 1.0\nelement vertex ${positions.length / 3}\n`
    + 'property float x\nproperty float y\nproperty float z\n'
    + `element face ${faces.length / 3}\nproperty list uchar int vertex_indices\nend_header\n`;
  const body = new DataView(new ArrayBuffer(positions.length * 4 + (faces.length / 3) * 13));
  positions.forEach((v, i) => body.setFloat32(4 * i, v, true));
  let at = positions.length * 4;
  for (let f = 0; f < faces.length; f += 3) {
    body.setUint8(at, 3);
    for (let k = 0; k < 3; k++) body.setInt32(at + 1 + 4 * k, faces[f + k], true);
    at += 13;
  }
  return new Blob([header, body], { type: 'application/octet-stream' });
}

function showProgress(text, fraction = null) {
  $('status').textContent = fraction === null ? `${text}…` : `${text}… ${Math.floor(fraction * 100)}%`;
  if (fraction === null) $('progress').removeAttribute('value'); // a bar that says "working", no figure
  else $('progress').value = fraction;
}

let running = Promise.resolve(); // the browser's sample in progress: one at a time

async function sampleHere(ticket) {
  // Checked here, so a bad value says so before any work.
  const seed = parseSeed(String(state.seed).trim());
  const factors = parseFactors(state.size);
  const scale = Number(state.scale);
  if (!(scale > 0 && Number.isFinite(scale))) throw new Error(`scale: give a positive number, got '${state.scale}'`);
  const steps = Number(state.smooth);
  if (!(Number.isInteger(steps) && steps >= 0 && steps <= 100)) throw new Error(`smooth: give a whole number of steps in 0..100, got '${state.smooth}'`);
  // The edits edit.js makes; a layout's (layout.js) once the worker has made the seed's layout.
  const keep = state.edit === 'keep' ? { base: String(parseSeed(String(state.other).trim())), box: parseBox(state.box) } : undefined;
  const grow = state.edit === 'grow' ? { by: parseFactors(state.grow, 'grow', true), anchor: parseAnchor(state.anchor) } : undefined;
  if (state.edit !== 'layout') layoutNow = null;
  await running.catch(() => {}); // the worker makes one sample at a time; newer requests skip the ones between
  if (ticket !== latest) return;
  const name = state.model;
  const job = (async () => {
    if (!browserModels.get(name)?.loaded) showProgress('loading the model');
    const model = await browserModel(name);
    if (ticket !== latest) throw new Cancelled(); // cancelled while the model loaded
    if (state.edit === 'layout') await showLayout();
    if (ticket !== latest) throw new Cancelled();
    drawExtras(model);
    const layout = layoutNow?.edits ? { grid: layoutNow.grid, shape: layoutNow.shape } : undefined;
    return [model, await call({ type: 'sample', name, seed: String(seed), factors, scale, smooth: steps, keep, grow, layout },
      (stage, fraction) => { if (ticket === latest) showProgress(stage, fraction); })];
  })();
  running = job;
  const [model, mesh] = await job;
  if (ticket !== latest) return;
  showMesh(mesh);
  const faces = (mesh.faces.length / 3).toLocaleString('en');
  $('status').textContent = `${faces} faces · ${mesh.seconds.toFixed(2)} s · in this browser`;
  $('backend').textContent = backendText(model, model.seconds);
  if (downloadUrl) URL.revokeObjectURL(downloadUrl);
  downloadUrl = URL.createObjectURL(plyBlob(mesh));
  $('download').href = downloadUrl;
  $('download').download = `${fileStem(name)}.ply`;
  finish('ready');
}

/** A download's name: the model, the seeds and the edit. */
function fileStem(name) {
  const tag = { keep: `_keep${state.seed}_rest${state.other}`, grow: `_grow${String(state.grow).replaceAll(',', 'x')}`,
    layout: state.cells ? '_layout' : '' }[state.edit] ?? '';
  return `${name}_seed${state.seed}${tag}`;
}

// ---- fetching a sample: the newest request wins, and the one it replaces is
// given up (a server request aborted: the server stops making it)
let latest = 0;
let aborter = null;

/** The end of a request: the page's state, the cancel button and the bar put away. */
function finish(result) {
  document.body.dataset.state = result;
  $('working').hidden = true;
  if (result !== 'error') report('');
}

function fail(error) {
  $('status').textContent = '';
  report(error.message);
  finish('error');
}

async function load({ replay = false } = {}) {
  const ticket = ++latest;
  aborter?.abort();
  aborter = null;
  if (!replay) record();
  writeUrl();
  showMode();
  document.body.dataset.state = 'loading';
  $('working').hidden = false;
  if (state.where === 'browser') {
    $('download').removeAttribute('href');
    showProgress('sampling');
    try {
      await sampleHere(ticket);
    } catch (error) {
      if (ticket === latest) fail(error);
    }
    return;
  }
  showProgress('sampling on the server');
  const started = performance.now();
  const controller = aborter = new AbortController();
  try {
    let url = sampleUrl('glb'), options = { signal: controller.signal }, made = false;
    if (state.edit) {
      if (state.edit === 'keep') { parseSeed(String(state.other).trim()); parseBox(state.box); }
      if (state.edit === 'grow') parseAnchor(state.anchor);
      const info = await modelInfo(state.model);
      if (ticket !== latest) return;
      if (state.edit === 'layout') {
        await showLayout(info);
        if (ticket !== latest) return;
        if (layoutNow.edits) { // the shape of the edited layout: the same query, POST with the layout as .vox
          options = { ...options, method: 'POST', body: layouts.voxBytes(layoutNow.grid, layoutNow.shape),
                      headers: { 'Content-Type': 'application/octet-stream' } };
          made = true;
        }
      } else {
        layoutNow = null;
      }
      drawExtras(info);
    } else {
      layoutNow = null;
      drawExtras(null);
    }
    if (made) $('download').removeAttribute('href'); // a file of the page's own, once it is here
    else { $('download').href = sampleUrl(state.format); $('download').download = ''; }
    const response = await fetch(url, options);
    if (!response.ok) {
      const body = await response.json().catch(() => ({}));
      throw new Error(body.detail || `${response.status} ${response.statusText}`);
    }
    const data = await response.arrayBuffer();
    const gltf = await loader.parseAsync(data, '');
    if (ticket !== latest) return;
    show(gltf);
    if (made) {
      if (downloadUrl) URL.revokeObjectURL(downloadUrl);
      downloadUrl = URL.createObjectURL(new Blob([data], { type: 'model/gltf-binary' }));
      $('download').href = downloadUrl;
      $('download').download = `${fileStem(state.model)}.glb`;
    }
    const faces = Number(response.headers.get('X-Faces')).toLocaleString('en');
    const seconds = ((performance.now() - started) / 1000).toFixed(2);
    const cached = response.headers.get('X-Cache') === 'hit' ? ' (cached)' : '';
    $('status').textContent = `${faces} faces · ${seconds} s${cached}`;
    finish('ready');
  } catch (error) {
    if (ticket !== latest) return;
    $('download').removeAttribute('href');  // it would fetch the failed request again
    fail(error);
  } finally {
    if (aborter === controller) aborter = null;
  }
}

// ---- the editor's drawing: the kept box, where a grown sample's old one sits, the layout's blocks
const infos = new Map(); // model name -> a promise of { sizes, origin, spacing } from the server
let currentInfo = null;

async function modelInfo(name) {
  if (state.where === 'browser') return browserModel(name); // the worker's answer carries them
  if (!infos.has(name)) {
    infos.set(name, (async () => {
      const response = await fetch(`api/models/${encodeURIComponent(name)}`);
      const body = await response.json().catch(() => ({}));
      if (!response.ok) throw new Error(body.detail || `${response.status} ${response.statusText}`);
      return { sizes: body.sizes, origin: body.frame.origin, spacing: body.frame.spacing };
    })());
    infos.get(name).catch(() => infos.delete(name));
  }
  return infos.get(name);
}

/** Voxels of the finest grid -> the model's frame, where the meshes are. */
const toFrame = (info, voxel) => voxel.map((v, a) => info.origin[a] + info.spacing[a] * v);

function wireBox(low, high, lines) {
  const size = low.map((v, a) => Math.max(high[a] - v, 1e-6));
  const box = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(...size)), lines);
  box.position.set(...low.map((v, a) => (v + high[a]) / 2));
  return box;
}

/** The editor's drawing over the shape, for the state as it is (nothing where a value is bad: the request says why). */
function drawExtras(info) {
  currentInfo = info;
  extras.clear();
  blocksMesh = null;
  shapeGroup.visible = true;
  try {
    if (!info || !state.edit) return;
    const factors = parseFactors(state.size);
    if (state.edit === 'keep') {
      const finest = finestSize(info.sizes, factors), box = parseBox(state.box).map(Number);
      const corner = (at) => [0, 1, 2].map((a) => (box[at + a] / 100) * (finest[a] - 1));
      extras.add(wireBox(toFrame(info, corner(0)), toFrame(info, corner(3)), boxLines));
    } else if (state.edit === 'grow') {
      const by = parseFactors(state.grow, 'grow', true), anchor = parseAnchor(state.anchor);
      const old = finestSize(info.sizes, factors), grown = finestSize(info.sizes, factors.map((f, a) => f * by[a]));
      const offset = [0, 1, 2].map((a) => roundHalfEven(anchor[a] * (grown[a] - old[a])));
      extras.add(wireBox(toFrame(info, offset), toFrame(info, offset.map((v, a) => v + old[a] - 1)), boxLines));
    } else if (state.edit === 'layout' && layoutNow) {
      drawBlocks(info, factors);
    }
  } catch {
    extras.clear();
  } finally {
    draw();
  }
}

// ---- layouts: the seed's layout (from the server, or the worker's), the user's edits on it
const layoutBases = new Map(); // "where|model|seed|size" -> a promise of { shape, grid }
let layoutNow = null; // { base, grid, shape, edits }: the layout in view
let selected = null; // the selected cell [i, j, k], for duplicate and move
let blocksMesh = null, blockCells = [];
const unitBox = new THREE.BoxGeometry(1, 1, 1);
const raycaster = new THREE.Raycaster();
let voxUrl = null;

function layoutBase(name, seed, size) {
  const key = `${state.where}|${name}|${seed}|${size}`;
  if (!layoutBases.has(key)) {
    layoutBases.set(key, (async () => {
      if (state.where === 'browser') { // the worker's runtime.layout.layout (layout.js)
        await browserModel(name);
        const { shape, grid } = await call({ type: 'layout', name, seed: String(parseSeed(seed)), factors: parseFactors(size) });
        return { shape, grid };
      }
      const query = new URLSearchParams({ seed, size });
      const response = await fetch(`api/models/${encodeURIComponent(name)}/layout?${query}`);
      const body = await response.json().catch(() => ({}));
      if (!response.ok) throw new Error(body.detail || `${response.status} ${response.statusText}`);
      return { shape: body.shape, grid: Uint8Array.from(body.occupancy, (c) => (c === '1' ? 1 : 0)) };
    })());
    layoutBases.get(key).catch(() => layoutBases.delete(key));
  }
  return layoutBases.get(key);
}

/** The seed's layout with the state's edits: layoutNow, its status line and its .vox link. */
async function showLayout() {
  const base = await layoutBase(state.model, state.seed, state.size);
  const grid = layouts.applyEdits(base.grid, base.shape, state.cells);
  const edits = layouts.encodeEdits(grid, base.grid, base.shape);
  layoutNow = { base: base.grid, grid, shape: base.shape, edits: edits ? edits.split(',').length : 0 };
  showLayoutStatus();
  if (voxUrl) URL.revokeObjectURL(voxUrl);
  voxUrl = URL.createObjectURL(new Blob([layouts.voxBytes(grid, base.shape)], { type: 'application/octet-stream' }));
  $('vox-export').href = voxUrl;
  $('vox-export').download = `${fileStem(state.model)}.vox`;
}

function showLayoutStatus() {
  if (!layoutNow) return;
  const { grid, shape, edits } = layoutNow;
  const full = grid.reduce((n, v) => n + v, 0);
  const chosen = selected && layouts.inside(shape, selected) ? `; selected ${selected.join(',')}` : '';
  $('layout-status').textContent = `${shape.join('×')} cells, ${full} full, ${edits} edited${chosen}`;
}

function drawBlocks(info, factors) {
  const { grid, shape } = layoutNow;
  const finest = finestSize(info.sizes, factors);
  const cells = layouts.fullCells(grid, shape);
  const mesh = new THREE.InstancedMesh(unitBox, blockMaterial, Math.max(1, cells.length));
  mesh.count = cells.length;
  const matrix = new THREE.Matrix4();
  cells.forEach((cell, n) => {
    const { low, high } = layouts.cellBox(cell, shape, finest, info.origin, info.spacing);
    matrix.makeScale(...low.map((v, a) => 0.94 * (high[a] - v))).setPosition(...low.map((v, a) => (v + high[a]) / 2));
    mesh.setMatrixAt(n, matrix);
  });
  mesh.computeBoundingBox();
  mesh.computeBoundingSphere();
  mesh.visible = $('blocks').checked;
  shapeGroup.visible = !mesh.visible; // the blocks or the shape: drawn together they hide each other
  blocksMesh = mesh;
  blockCells = cells;
  extras.add(mesh);
  if (selected && layouts.inside(shape, selected) && grid[layouts.cellIndex(shape, selected)]) {
    const { low, high } = layouts.cellBox(selected, shape, finest, info.origin, info.spacing);
    extras.add(wireBox(low, high, selectLines));
  }
}

/** The block under a point of the view (client coordinates) and the face hit: { cell, normal }, or null. */
function pick(x, y) {
  if (!blocksMesh?.visible) return null;
  const rect = renderer.domElement.getBoundingClientRect();
  raycaster.setFromCamera(new THREE.Vector2(((x - rect.left) / rect.width) * 2 - 1, -((y - rect.top) / rect.height) * 2 + 1), camera);
  const [hit] = raycaster.intersectObject(blocksMesh);
  if (!hit) return null;
  const n = hit.face.normal; // the unit box's own axes: the model's, scaled and moved per block
  return { cell: blockCells[hit.instanceId], normal: [Math.round(n.x), Math.round(n.y), Math.round(n.z)] };
}

/** Where the centre of a block's face (normal [±1, 0, 0] and so on) is on the screen, for the tests. */
function facePoint(cell, normal) {
  if (!layoutNow || !currentInfo) return null;
  const finest = finestSize(currentInfo.sizes, parseFactors(state.size));
  const { low, high } = layouts.cellBox(cell, layoutNow.shape, finest, currentInfo.origin, currentInfo.spacing);
  const point = new THREE.Vector3(...low.map((v, a) => (v + high[a]) / 2 + normal[a] * 0.47 * (high[a] - v)));
  point.applyMatrix4(holder.matrixWorld).project(camera);
  const rect = renderer.domElement.getBoundingClientRect();
  return { x: rect.left + ((point.x + 1) / 2) * rect.width, y: rect.top + ((1 - point.y) / 2) * rect.height };
}

Object.assign(window.sinshapeView, { pick, facePoint, layout: () => layoutNow && { ...layoutNow, grid: Array.from(layoutNow.grid) } });

/** One edit of the layout: `change(grid, shape)` alters a copy; the result is a step, and its shape is made. */
function editLayout(change) {
  if (!layoutNow) return;
  const grid = Uint8Array.from(layoutNow.grid);
  try {
    change(grid, layoutNow.shape);
  } catch (error) {
    report(error.message);
    return;
  }
  fromForm();
  state.cells = layouts.encodeEdits(grid, layoutNow.base, layoutNow.shape);
  load();
}

const DIRECTIONS = { '+x': [1, 0, 0], '-x': [-1, 0, 0], '+y': [0, 1, 0], '-y': [0, -1, 0], '+z': [0, 0, 1], '-z': [0, 0, -1] };
const beside = (cell, step) => cell.map((c, a) => c + step[a]);

function clickBlock({ cell, normal }) {
  const tool = $('tool').value;
  if (tool === 'select') {
    selected = cell;
    showLayoutStatus();
    drawExtras(currentInfo);
    return;
  }
  editLayout((grid, shape) => {
    if (tool === 'remove') {
      grid[layouts.cellIndex(shape, cell)] = 0;
      return;
    }
    const target = beside(cell, normal);
    if (!layouts.inside(shape, target)) throw new Error(`no room there: the layout is ${shape.join('×')} cells, and the new block would be at ${target.join(',')}`);
    grid[layouts.cellIndex(shape, target)] = 1;
  });
}

/** Duplicate (keep: true) or move the selected block one cell in the chosen direction; the selection follows. */
function shiftSelected(keep) {
  if (!layoutNow) return;
  const { grid, shape } = layoutNow;
  if (!selected || !layouts.inside(shape, selected) || !grid[layouts.cellIndex(shape, selected)]) {
    report('select a block first: set "a click on a block" to "selects it", then click one');
    return;
  }
  const target = beside(selected, DIRECTIONS[$('direction').value]);
  if (!layouts.inside(shape, target)) {
    report(`no room there: the layout is ${shape.join('×')} cells, and ${target.join(',')} is outside it`);
    return;
  }
  const from = selected;
  selected = target;
  editLayout((edited) => {
    if (!keep) edited[layouts.cellIndex(shape, from)] = 0;
    edited[layouts.cellIndex(shape, target)] = 1;
  });
}

async function importVox(file) {
  try {
    if (!layoutNow) throw new Error('the layout is not here yet: wait for it, then import');
    const { grid, shape } = layouts.readVox(new Uint8Array(await file.arrayBuffer()), file.name);
    if (shape.join() !== layoutNow.shape.join()) {
      throw new Error(`${file.name}: a layout of ${shape.join('×')} cells; this sample's is ${layoutNow.shape.join('×')} (level 0 of ${state.model} at size ${state.size})`);
    }
    editLayout((edited) => edited.set(grid));
  } catch (error) {
    report(error.message);
  }
}

/** Stop the sample being made: abort the server's request, or end the browser's worker. */
function cancel() {
  if (document.body.dataset.state !== 'loading') return;
  latest++; // whatever was under way answers no one now
  aborter?.abort();
  aborter = null;
  if (worker && jobs.size) stopWorker(new Cancelled());
  running = Promise.resolve();
  $('download').removeAttribute('href');
  $('status').textContent = 'cancelled';
  finish('cancelled');
}

function step(delta) {
  fromForm();
  // BigInt: seeds go to 2^63, past what a Number holds exactly (2^53)
  const seed = /^\d+$/.test(state.seed) ? BigInt(state.seed) : 0n;
  const next = seed + BigInt(delta);
  state.seed = String(next < 0n ? 0n : next >= 2n ** 63n ? 2n ** 63n - 1n : next);
  toForm();
  load();
}

async function openFile(file) {
  // Named apart from the listed models, so a file called terrain.onnx replaces nothing.
  const name = `${file.name.replace(/\.onnx$/i, '')} (file)`;
  const previous = browserModels.get(name);
  browserModels.set(name, { bytes: new Uint8Array(await file.arrayBuffer()), file: file.name });
  const ticket = ++latest;
  await running.catch(() => {});
  document.body.dataset.state = 'loading';
  $('working').hidden = false;
  showProgress(`checking ${file.name}`);
  try {
    running = browserModel(name);
    await running;
  } catch (error) {
    if (previous) browserModels.set(name, previous);
    else browserModels.delete(name);
    if (ticket === latest) fail(error);
    return;
  }
  if (ticket !== latest) return;
  if (![...$('model').options].some((o) => o.value === name)) $('model').add(new Option(name, name));
  fromForm();
  state.model = name;
  toForm();
  load();
}

async function start() {
  $('unserved').hidden = true;  // the script runs: the page is served
  readUrl();
  try {
    const response = await fetch(STATIC_SITE ? 'models.json' : 'api/models');
    const models = await response.json();
    for (const m of models) {
      $('model').add(new Option(`${m.name} (${m.size.join('x')})`, m.name));
      const url = STATIC_SITE ? m.file : `api/models/${encodeURIComponent(m.name)}/onnx`;
      browserModels.set(m.name, { url, file: `${m.name}.onnx`, up: m.up ?? 'y' });
    }
    if (!models.some((m) => m.name === state.model)) state.model = models[0]?.name ?? '';
    // Which way is up is the model's (recorded when it was trained), unless the URL says otherwise.
    if (!new URLSearchParams(location.search).has('up')) state.up = browserModels.get(state.model)?.up ?? 'y';
  } catch (error) {
    report(`cannot list the models: ${error.message}`);
    return;
  }
  toForm();
  $('controls').addEventListener('submit', (event) => { event.preventDefault(); fromForm(); load(); });
  $('cancel').addEventListener('click', cancel);
  document.addEventListener('keydown', (event) => { if (event.key === 'Escape') cancel(); });
  $('prev').addEventListener('click', () => step(-1));
  $('next').addEventListener('click', () => step(+1));
  $('file').addEventListener('change', () => { if ($('file').files.length) openFile($('file').files[0]); });
  $('model').addEventListener('change', () => {
    fromForm();
    state.up = browserModels.get(state.model)?.up ?? state.up;
    $('up').value = state.up;
    load();
  });
  for (const id of ['where', 'seed', 'sx', 'sy', 'sz', 'scale', 'smooth', 'edit', 'other',
    'bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1', 'gx', 'gy', 'gz', 'ax', 'ay', 'az']) {
    $(id).addEventListener('change', () => { fromForm(); load(); });
  }
  for (const id of ['bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1', 'gx', 'gy', 'gz', 'ax', 'ay', 'az']) {
    $(id).addEventListener('input', () => { fromForm(); drawExtras(currentInfo); }); // the box follows as it is typed
  }
  // The editor: undo and redo, the layout's tools.
  $('undo').addEventListener('click', () => walk(-1));
  $('redo').addEventListener('click', () => walk(+1));
  document.addEventListener('keydown', (event) => {
    if (!(event.ctrlKey || event.metaKey) || event.target.closest?.('input, select, textarea')) return;
    const key = event.key.toLowerCase();
    if (key === 'z' || key === 'y') {
      event.preventDefault();
      walk(key === 'y' || event.shiftKey ? +1 : -1);
    }
  });
  $('duplicate').addEventListener('click', () => shiftSelected(true));
  $('move').addEventListener('click', () => shiftSelected(false));
  $('blocks').addEventListener('change', () => {
    if (blocksMesh) blocksMesh.visible = $('blocks').checked;
    shapeGroup.visible = !blocksMesh?.visible;
    draw();
  });
  $('vox-file').addEventListener('change', () => {
    if ($('vox-file').files.length) importVox($('vox-file').files[0]);
    $('vox-file').value = ''; // the same file again is a change too
  });
  let pressed = null; // a click on a block, not the end of a drag that turned the view
  renderer.domElement.addEventListener('pointerdown', (event) => { pressed = [event.clientX, event.clientY]; });
  renderer.domElement.addEventListener('pointerup', (event) => {
    const near = pressed && Math.hypot(event.clientX - pressed[0], event.clientY - pressed[1]) <= 4;
    pressed = null;
    if (!near || state.edit !== 'layout') return;
    const hit = pick(event.clientX, event.clientY);
    if (hit) clickBlock(hit);
  });
  $('up').addEventListener('change', () => { fromForm(); writeUrl(); orient(state.up); frame(); });
  $('format').addEventListener('change', () => { fromForm(); writeUrl(); $('download').href = sampleUrl(state.format); });
  new ResizeObserver(resize).observe(view);
  resize();
  load();
}

start();
