// The sinshape page: pick a model and a seed, see the sample in 3-D, download it.
// The state lives in the URL's query string, so a view can be shared.
// A sample is made on the server (its API) or in this browser (the JavaScript
// runtime in sinshape/, on onnxruntime-web); a static site from
// `sinrun export-web` (body data-site="static") has no server and samples in
// the browser only.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const FIELDS = ['model', 'where', 'seed', 'size', 'scale', 'smooth', 'up', 'format'];
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
scene.add(holder);
const loader = new GLTFLoader();
window.sinshapeView = { scene, camera, renderer }; // for the tests and the console

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
  const box = new THREE.Box3().setFromObject(holder);
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
  holder.clear();
  holder.add(new THREE.Mesh(geometry, material));
  orient(state.up);
  frame();
}

function show(gltf) {
  holder.clear();
  gltf.scene.traverse((node) => {
    if (node.isMesh) {
      if (!node.geometry.attributes.normal) node.geometry.computeVertexNormals();
      node.material = material;
    }
  });
  holder.add(gltf.scene);
  orient(state.up);
  frame();
}

// ---- the state: read from the URL, written back to it
const state = {
  model: '', where: STATIC_SITE ? 'browser' : 'server', seed: 0, size: '1,1,1', scale: '1', smooth: '0', up: 'y', format: 'glb',
};

function readUrl() {
  const query = new URLSearchParams(location.search);
  for (const key of FIELDS) if (query.has(key)) state[key] = query.get(key);
  if (STATIC_SITE || !['server', 'browser'].includes(state.where)) state.where = STATIC_SITE ? 'browser' : 'server';
}

function writeUrl() {
  const query = new URLSearchParams();
  for (const key of FIELDS) query.set(key, state[key]);
  history.replaceState(null, '', `${location.pathname}?${query}`);
}

function toForm() {
  $('model').value = state.model;
  $('seed').value = state.seed;
  const [x, y, z] = String(state.size).split(',');
  $('sx').value = x ?? 1;
  $('sy').value = y ?? x ?? 1;
  $('sz').value = z ?? x ?? 1;
  for (const key of ['where', 'scale', 'smooth', 'up', 'format']) $(key).value = state[key];
  showMode();
}

function showMode() {
  const browser = state.where === 'browser';
  $('where-label').hidden = STATIC_SITE;
  $('file-label').hidden = !browser;
  $('format').disabled = browser; // the browser writes .ply, and the box says so
  $('format').value = browser ? 'ply' : state.format;
  $('backend').hidden = !browser;
}

function fromForm() {
  state.model = $('model').value;
  state.seed = $('seed').value.trim();
  state.size = [$('sx').value, $('sy').value, $('sz').value].map((v) => v.trim()).join(',');
  for (const key of ['where', 'scale', 'smooth', 'up', 'format']) state[key] = $(key).value.trim();
}

function sampleUrl(format) {
  const query = new URLSearchParams({
    seed: state.seed, size: state.size, scale: state.scale, smooth: state.smooth, format,
  });
  return `api/models/${encodeURIComponent(state.model)}/sample?${query}`;
}

function report(error) {
  $('error').textContent = error;
  $('error').hidden = !error;
}

// ---- sampling in this browser: the runtime runs in a module worker
// (sinshape/worker.js), started on first use, so the server mode never fetches
// onnxruntime-web's 28 MB of WASM and a sample never freezes the page. Cancel
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
  const backend = model.backend === 'webgpu' ? 'onnxruntime-web on WebGPU' : `onnxruntime-web on WASM, ${threads}${isolation}`;
  return `${backend}; model loaded and checked in ${loadSeconds.toFixed(2)} s`;
}

function parseSeed(text) {
  if (!/^\d+$/.test(text)) throw new Error(`seed: give a whole number, got '${text}'`);
  return BigInt(text);
}

function parseFactors(text) {
  const values = String(text).split(',').map(Number);
  const factors = values.length === 1 ? [values[0], values[0], values[0]] : values;
  if (factors.length !== 3 || !factors.every((v) => v > 0 && Number.isFinite(v))) {
    throw new Error(`size '${text}': give one or three positive factors, like 2 or 2,1,0.5`);
  }
  return factors;
}

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
  await running.catch(() => {}); // the worker makes one sample at a time; newer requests skip the ones between
  if (ticket !== latest) return;
  const name = state.model;
  const job = (async () => {
    if (!browserModels.get(name)?.loaded) showProgress('loading the model');
    const model = await browserModel(name);
    if (ticket !== latest) throw new Cancelled(); // cancelled while the model loaded
    return [model, await call({ type: 'sample', name, seed: String(seed), factors, scale, smooth: steps },
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
  $('download').download = `${name}_seed${seed}.ply`;
  finish('ready');
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

async function load() {
  const ticket = ++latest;
  aborter?.abort();
  aborter = null;
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
  $('download').href = sampleUrl(state.format);
  $('download').download = '';
  const controller = aborter = new AbortController();
  try {
    const response = await fetch(sampleUrl('glb'), { signal: controller.signal });
    if (!response.ok) {
      const body = await response.json().catch(() => ({}));
      throw new Error(body.detail || `${response.status} ${response.statusText}`);
    }
    const data = await response.arrayBuffer();
    const gltf = await loader.parseAsync(data, '');
    if (ticket !== latest) return;
    show(gltf);
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
  for (const id of ['where', 'seed', 'sx', 'sy', 'sz', 'scale', 'smooth']) {
    $(id).addEventListener('change', () => { fromForm(); load(); });
  }
  $('up').addEventListener('change', () => { fromForm(); writeUrl(); orient(state.up); frame(); });
  $('format').addEventListener('change', () => { fromForm(); writeUrl(); $('download').href = sampleUrl(state.format); });
  new ResizeObserver(resize).observe(view);
  resize();
  load();
}

start();
