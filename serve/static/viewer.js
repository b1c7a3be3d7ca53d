// The sinshape page: pick a model and a seed, see the sample in 3-D, download it.
// The state lives in the URL's query string, so a view can be shared.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const FIELDS = ['model', 'seed', 'size', 'scale', 'smooth', 'up', 'format'];

// ---- the 3-D view: one scene, one shape at a time, drawn on demand
const view = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20242a);
const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 1000);
scene.add(new THREE.HemisphereLight(0xffffff, 0x404048, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 2.2);
sun.position.set(0.5, 1, 0.8);
camera.add(sun); // the light moves with the camera: every side can be lit
scene.add(camera);
const controls = new OrbitControls(camera, renderer.domElement);
controls.addEventListener('change', draw);
const material = new THREE.MeshStandardMaterial({ color: 0xd8c8a8, roughness: 0.8, side: THREE.DoubleSide });
const holder = new THREE.Group(); // turned so the model's up axis points up on screen
scene.add(holder);
const loader = new GLTFLoader();

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
  const distance = radius / Math.sin(THREE.MathUtils.degToRad(camera.fov / 2)) * 1.05;
  camera.position.copy(centre).add(new THREE.Vector3(0.8, 0.55, 1).normalize().multiplyScalar(distance));
  camera.near = distance / 100;
  camera.far = distance * 10;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
  draw();
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
const state = { model: '', seed: 0, size: '1,1,1', scale: '1', smooth: '0', up: 'y', format: 'glb' };

function readUrl() {
  const query = new URLSearchParams(location.search);
  for (const key of FIELDS) if (query.has(key)) state[key] = query.get(key);
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
  for (const key of ['scale', 'smooth', 'up', 'format']) $(key).value = state[key];
}

function fromForm() {
  state.model = $('model').value;
  state.seed = $('seed').value.trim();
  state.size = [$('sx').value, $('sy').value, $('sz').value].map((v) => v.trim()).join(',');
  for (const key of ['scale', 'smooth', 'up', 'format']) state[key] = $(key).value.trim();
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

// ---- fetching a sample: the newest request wins
let latest = 0;

async function load() {
  const ticket = ++latest;
  writeUrl();
  $('download').href = sampleUrl(state.format);
  document.body.dataset.state = 'loading';
  $('status').textContent = 'sampling…';
  const started = performance.now();
  try {
    const response = await fetch(sampleUrl('glb'));
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
    report('');
    document.body.dataset.state = 'ready';
  } catch (error) {
    if (ticket !== latest) return;
    $('status').textContent = '';
    report(error.message);
    document.body.dataset.state = 'error';
  }
}

function step(delta) {
  fromForm();
  const seed = Number.parseInt(state.seed, 10);
  state.seed = String(Math.max(0, (Number.isFinite(seed) ? seed : 0) + delta));
  toForm();
  load();
}

async function start() {
  readUrl();
  try {
    const response = await fetch('api/models');
    const models = await response.json();
    for (const m of models) $('model').add(new Option(`${m.name} (${m.size.join('x')})`, m.name));
    if (!models.some((m) => m.name === state.model)) state.model = models[0]?.name ?? '';
  } catch (error) {
    report(`cannot list the models: ${error.message}`);
    return;
  }
  toForm();
  $('controls').addEventListener('submit', (event) => { event.preventDefault(); fromForm(); load(); });
  $('prev').addEventListener('click', () => step(-1));
  $('next').addEventListener('click', () => step(+1));
  for (const id of ['model', 'seed', 'sx', 'sy', 'sz', 'scale', 'smooth']) {
    $(id).addEventListener('change', () => { fromForm(); load(); });
  }
  $('up').addEventListener('change', () => { fromForm(); writeUrl(); orient(state.up); frame(); });
  $('format').addEventListener('change', () => { fromForm(); writeUrl(); $('download').href = sampleUrl(state.format); });
  new ResizeObserver(resize).observe(view);
  resize();
  load();
}

start();
