// The 3-D view: one scene, one shape at a time and what the editor draws
// over it, drawn on demand by `render`. What a new shape or overlay
// replaces is disposed, so the GPU holds one shape's buffers however many
// samples the page shows.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

export const view = document.getElementById('view');

/** A renderer drawing into a canvas of its own in the view. */
function canvasRenderer(antialias) {
  const made = new THREE.WebGLRenderer({ antialias, preserveDrawingBuffer: true });
  made.setPixelRatio(window.devicePixelRatio);
  view.appendChild(made.domElement);
  return made;
}
const shapeRenderer = canvasRenderer(true);
export let renderer = shapeRenderer; // the one drawing now: a world's (worldRenderer) while one is shown

/** Whether WebGL is drawn on the CPU: chromium's SwiftShader, Mesa's llvmpipe or softpipe, Windows' WARP. */
function drawnInSoftware(gl) {
  const named = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(named ? named.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  return /swiftshader|llvmpipe|softpipe|software|basic render driver/i.test(name);
}
// A world is drawn without multisampling where WebGL is drawn in software: nearly free on a GPU, it is
// most of a frame on a CPU (a world turning in place on SwiftShader drew 20 to 24 frames a second with it, 34 to 41
// without; docs/WORLDS.md). It needs a canvas of its own, made when a world is first shown; the shape's
// view, drawn only when it changes, keeps its smoothed edges.
const software = drawnInSoftware(shapeRenderer.getContext());
let plainRenderer = null;
const worldRenderer = () => (software ? (plainRenderer ??= canvasRenderer(false)) : shapeRenderer);

/** Draw with `next` (its canvas shown, the other's hidden), sized to the view. */
function drawWith(next) {
  if (next === renderer) return;
  renderer.domElement.style.display = 'none';
  renderer = next;
  renderer.domElement.style.display = '';
  renderer.setSize(view.clientWidth, view.clientHeight, false);
}
export const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20242a);
const FOV = 35; // degrees, vertically
export const camera = new THREE.PerspectiveCamera(FOV, 1, 0.01, 1000);
// Light: a soft sky-and-ground fill, and a key light from above and to the
// left of the viewer. The key light and its target ride with the camera, so
// whichever side is turned to the viewer is lit the same way and shaded by its form.
scene.add(new THREE.HemisphereLight(0xf4f6ff, 0x3a3630, 0.8));
const key = new THREE.DirectionalLight(0xffffff, 2.8);
key.position.set(-0.8, 1.2, 0.4);
key.target.position.set(0, 0, -1);
camera.add(key, key.target);
scene.add(camera);
const controls = new OrbitControls(camera, shapeRenderer.domElement);
controls.addEventListener('change', render);
// Front faces only: the meshes are closed and wound outwards (normals out), so
// back faces are never seen from outside; drawing them too (DoubleSide) made
// dark lines where they fought the front faces in the depth buffer.
// Materials are made once and shared by every shape and overlay: none is replaced.
export const material = new THREE.MeshStandardMaterial({ color: 0xd8c8a8, roughness: 0.85, side: THREE.FrontSide });
// A coloured model's shapes: white lit by each vertex's colour.
export const colouredMaterial = new THREE.MeshStandardMaterial({ vertexColors: true, roughness: 0.85, side: THREE.FrontSide });
// A world's tiles: Lambert's diffuse light, which a rough surface's standard shading nearly is, at
// about two thirds of its cost per pixel where no GPU draws (a software renderer).
const worldMaterials = [new THREE.MeshLambertMaterial({ color: material.color, side: THREE.FrontSide }),
                        new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.FrontSide })];

// A software renderer (SwiftShader) compiles code of its own for each way of drawing, at the first draw
// that needs it. A triangle of each of the shape's kinds, plain and coloured (indexed, with normals), drawn
// once as the page loads, while it waits for its first sample, takes that off the sample's first frame,
// which it held 117 to 150 ms (50 to 100 after; docs/BENCHMARKS.md, "In the browser"). Cleared at once:
// it is never seen.
{
  const triangle = (coloured) => {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array([0, 0, -1, 0.01, 0, -1, 0, 0.01, -1]), 3));
    geometry.setIndex(new THREE.BufferAttribute(new Uint32Array([0, 1, 2]), 1));
    geometry.computeVertexNormals();
    if (coloured) geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(9), 3));
    return new THREE.Mesh(geometry, coloured ? colouredMaterial : material);
  };
  const drawn = [triangle(false), triangle(true)];
  scene.add(...drawn);
  shapeRenderer.render(scene, camera);
  scene.remove(...drawn);
  for (const mesh of drawn) mesh.geometry.dispose();
  shapeRenderer.clear();
}

/** A mesh's material (a world's tile's when `tile`) and, for a coloured model's, its 'color' attribute: the
 * runtime's sRGB turned linear, which three.js's colour management expects of vertex colours.
 * colours: Float32Array (V, 3) or null. */
export function paint(geometry, colours, tile = false) {
  const [plain, coloured] = tile ? worldMaterials : [material, colouredMaterial];
  if (!colours) return plain;
  const linear = colours.map((c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4));
  geometry.setAttribute('color', new THREE.BufferAttribute(linear, 3));
  return coloured;
}
const holder = new THREE.Group(); // turned so the model's up axis points up on screen
const shape = new THREE.Group(); // the sample
const overlay = new THREE.Group(); // what the editor draws over it: a box's wireframe, the layout's blocks
holder.add(shape, overlay);
scene.add(holder);
const raycaster = new THREE.Raycaster();
let framed = ''; // what the camera was last framed for: a new extent frames it again, an edit inside it does not

/** Draw the scene: the page's one render call, made whenever something in view changes. */
export function render() {
  renderer.render(scene, camera);
}

// A world's frames where no GPU draws: a software renderer takes 100 ms or more to draw a ring of
// tiles at full resolution, and a frame that long makes flying stall. While a world is shown, the
// drawing resolution follows the frame time: fewer pixels (the canvas's scaled up) when a frame
// takes longer than FRAME_BUDGET, a step more again after FRAMES_AT_EASE frames well within it
// (seldom: resizing the canvas costs a software renderer a slow frame of its own).
const FRAME_BUDGET = 40; // ms
const FRAMES_AT_EASE = 30;
const STEPS = 20; // a resolution is a whole number of twentieths of the device's pixel ratio: a canvas resized seldom
const LOWEST = 8; // twentieths
let resolution = STEPS, atEase = 0;

/** A world's frame took `ms` (from its start to the next's): the drawing resolution follows. Whether it
 * changed (the canvas, resized, is blank until drawn again). */
export function frameTook(ms) {
  let next = resolution;
  atEase = ms < FRAME_BUDGET / 2 ? atEase + 1 : 0;
  if (ms > FRAME_BUDGET) next = Math.max(LOWEST, Math.floor(resolution * Math.sqrt(FRAME_BUDGET / ms)));
  else if (atEase >= FRAMES_AT_EASE) next = Math.min(STEPS, resolution + 1);
  if (next === resolution) return false;
  setResolution(next);
  return true;
}

/** Draw at `twentieths` of the device's pixel ratio (all of it, as the shape's view always is, by default). */
export function setResolution(twentieths = STEPS) {
  resolution = twentieths;
  atEase = 0;
  renderer.setPixelRatio((window.devicePixelRatio * twentieths) / STEPS);
}

function resize() {
  const { clientWidth: w, clientHeight: h } = view;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  render();
}
new ResizeObserver(resize).observe(view);

/** Turn the model so that its `up` axis ('y' or 'z') points up on screen. */
export function orient(up) {
  holder.rotation.set(up === 'z' ? -Math.PI / 2 : 0, 0, 0);
  holder.updateMatrixWorld(true);
}

/** Aim at the shape's box from a three-quarter view that fits it. */
export function frame() {
  const box = new THREE.Box3().setFromObject(shape);
  if (box.isEmpty()) return render();
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
  render();
}

/** Empty a group, disposing what its children hold on the GPU (not the shared materials, nor a shared geometry;
 * a game asset's levels, their own materials and maps too). */
function clear(group) {
  for (const node of group.children) {
    if (node.isInstancedMesh) node.dispose(); // its instance buffers; the unit box it instances is shared
    else if (node.isLOD) node.traverse(disposeAssetMesh);
    else node.geometry?.dispose();
  }
  group.clear();
}

function disposeAssetMesh(node) {
  if (!node.isMesh) return;
  node.geometry.dispose();
  for (const value of Object.values(node.material)) if (value?.isTexture) value.dispose();
  node.material.dispose();
}

/**
 * Show a mesh { positions, faces, colours } (the model's frame; colours, a coloured model's sRGB per
 * vertex, or none) in place of the last, with `up` up; frame it when `extent` (what sets its size)
 * is new, else keep the user's camera.
 */
export function showMesh({ positions, faces, colours = null }, up, extent) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  geometry.setIndex(new THREE.BufferAttribute(faces, 1));
  geometry.computeVertexNormals();
  clear(shape);
  shape.add(new THREE.Mesh(geometry, paint(geometry, colours)));
  orient(up);
  if (extent !== framed) frame();
  else render();
  framed = extent;
}

/** Show a game asset's levels (viewer/asset.js's LOD, glTF's frame: y up, on its base) in place of the last
 * shape, framed: the camera's distance picks the level drawn. */
export function showAsset(lod) {
  clear(shape);
  shape.add(lod);
  orient('y');
  framed = '';
  frame();
}

/** The world mode's view (viewer/world.js) in place of the shape's, or (false) the shape again, framed
 * and at full resolution: the world flies the camera itself, so orbiting is off and the shape and its
 * overlay are hidden. */
export function worldView(on) {
  if (!on) setResolution();
  drawWith(on ? worldRenderer() : shapeRenderer);
  controls.enabled = !on;
  holder.visible = !on;
  camera.fov = on ? 60 : FOV; // a wider view to fly with, as a game's
  camera.updateProjectionMatrix();
  if (!on) frame();
}

/** The editor's drawing, in place of the last (nothing: none); `showShape` false hides the shape under it. */
export function setOverlay(objects = [], showShape = true) {
  clear(overlay);
  if (objects.length) overlay.add(...objects);
  shape.visible = showShape;
  render();
}

/** The first hit of `object` (in the overlay) under a point of the view (client coordinates), or undefined. */
export function hitAt(object, x, y) {
  const rect = renderer.domElement.getBoundingClientRect();
  raycaster.setFromCamera(new THREE.Vector2(((x - rect.left) / rect.width) * 2 - 1, -((y - rect.top) / rect.height) * 2 + 1), camera);
  return raycaster.intersectObject(object)[0];
}

/** Where a point of the model's frame is on the screen: { x, y } in client coordinates. */
export function onScreen([px, py, pz]) {
  const point = new THREE.Vector3(px, py, pz).applyMatrix4(holder.matrixWorld).project(camera);
  const rect = renderer.domElement.getBoundingClientRect();
  return { x: rect.left + ((point.x + 1) / 2) * rect.width, y: rect.top + ((1 - point.y) / 2) * rect.height };
}

/** The shape in view: faces, vertices, volume (the model's frame) and a digest of its
 * vertices and faces (FNV-1a of their bytes): what the tests compare, before and after an edit. */
export function summary() {
  let faces = 0, vertices = 0, volume = 0, hash = 0x811c9dc5;
  const mix = (bytes) => { for (let i = 0; i < bytes.length; i++) hash = Math.imul(hash ^ bytes[i], 0x01000193) >>> 0; };
  shape.traverse((node) => {
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

/** What the GPU holds: three.js's count of geometries and textures, flat however many samples were shown. */
export const memory = () => {
  const held = [shapeRenderer, plainRenderer].filter(Boolean).map((each) => each.info.memory); // the world's, if made
  return { geometries: held.reduce((n, m) => n + m.geometries, 0), textures: held.reduce((n, m) => n + m.textures, 0) };
};
