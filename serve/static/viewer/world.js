// The world mode (docs/WORLDS.md, "In the browser"): fly or walk over the
// endless world of the model and seed. Tiles are made around the camera,
// nearest first, by the page's back end (the tile route, or the worker's
// world.js), and dropped behind it, their GPU buffers disposed, so memory
// stays bounded however far one goes. The origin floats: the scene's
// origin is the lowest corner of the camera's tile, every tile is placed
// relative to it and the camera stays within its tile, so a tile a billion
// tiles out is drawn as precisely as tile (0, 0). The camera's motion is
// viewer/flight.js's.
//
//   show({ where, name, seed, scale, tile, info, reach, walk }, report)  the world from `tile`; report(status) as it changes
//   stop()                                                               drop it all, and give the view back to the shape
import * as THREE from 'three';
import { sampleRequest } from '../sinshape/request.js';
import { worldLayout } from '../sinshape/world.js';
import { aim, settle, steer, wake } from './flight.js';
import * as sampling from './sampling.js';
import { camera, paint, scene, worldView } from './scene.js';

const SLOTS = { server: 2, browser: 1 }; // tiles asked for at once: the worker makes one at a time
const HOLD = 1; // tiles kept this far past the reach before they are dropped: a step back makes none again
const sky = new THREE.Color(0xaab8c4); // a haze the far tiles fade into, as the background
let background = null; // the shape's, while the world is shown

const group = new THREE.Group(); // the world's tiles, turned so the model's up points up on screen
group.visible = false;
scene.add(group);
let run = null; // the world in view
const keyOf = (i, j) => `${i},${j}`; // a tile's name

/**
 * Fly over the world of `seed` (a BigInt) of model `name`, made `where`
 * ('server' or 'browser') at `scale`, from tile `tile` ([i, j] BigInts);
 * `info` is the model's { sizes, spacing, up }, `reach` how many tiles to
 * make on each side of the camera's, `walk` whether to keep to the ground.
 * The same world again keeps its tiles and the camera, unless `tile` is
 * another than the camera's (a jump). report({ at, shown, waiting, made,
 * dropped, complete, error }) follows the work.
 */
export function show({ where, name, seed, scale, tile, info, reach, walk }, report) {
  const key = `${where}|${name}|${seed}|${scale}`;
  const jump = !run || run.key !== key || tile[0] !== run.origin[0] || tile[1] !== run.origin[1];
  if (run?.key !== key) {
    stop(false);
    const layout = worldLayout(info);
    const [h0, h1] = layout.horizontal;
    run = {
      key, where, name, seed, scale, layout, report, origin: tile, tiles: new Map(), making: 0, made: 0, dropped: 0, error: null,
      size: [layout.stride[h0] * info.spacing[h0], layout.stride[h1] * info.spacing[h1]], // a tile's sides, in the input's units
      height: layout.stride[layout.up] * info.spacing[layout.up],
    };
    group.rotation.set(layout.up === 2 ? -Math.PI / 2 : 0, 0, 0); // the model's up along the view's y
    group.updateMatrixWorld(true);
  }
  Object.assign(run, { reach, walk, report });
  steer({ side: Math.min(...run.size), height: run.height, walk, ground: group, moved: rebase });
  worldView(true);
  group.visible = true;
  const far = (reach + 0.5) * Math.min(...run.size) + run.height;
  scene.fog = new THREE.Fog(sky, far * 0.5, far); // the ring's edge fades out instead of ending
  if (scene.background !== sky) [background, scene.background] = [scene.background, sky];
  camera.near = Math.min(...run.size) / 200;
  camera.far = far * 1.5 + run.height;
  camera.updateProjectionMatrix();
  if (jump) place(tile);
  refresh();
  wake();
}

/** The camera over the middle of tile `tile`, above the world's top, looking along its first horizontal axis and down. */
function place(tile) {
  run.origin = tile;
  for (const entry of run.tiles.values()) drop(entry);
  const start = new THREE.Vector3();
  start.setComponent(run.layout.horizontal[0], run.size[0] / 2);
  start.setComponent(run.layout.horizontal[1], run.size[1] / 2);
  start.setComponent(run.layout.up, run.height + Math.min(...run.size));
  camera.position.copy(group.localToWorld(start));
  const along = new THREE.Vector3().setComponent(run.layout.horizontal[0], 1).applyQuaternion(group.quaternion);
  aim(Math.atan2(-along.x, -along.z), -0.5);
}

/** Drop the world: its tiles and their GPU buffers, and any tile being made; `giveBack` shows the shape again. */
export function stop(giveBack = true) {
  if (!run) return;
  for (const entry of run.tiles.values()) drop(entry);
  run = null;
  group.visible = false;
  scene.fog = null;
  scene.background = background;
  steer(null);
  if (giveBack) worldView(false);
}

function drop(entry) {
  entry.controller?.abort();
  for (const key of entry.borders ?? []) {
    const left = borders.get(key).filter((vertex) => vertex.entry !== entry);
    if (left.length) borders.set(key, left);
    else borders.delete(key);
  }
  if (entry.mesh) {
    group.remove(entry.mesh);
    entry.mesh.geometry.dispose();
    run.dropped++;
  }
  run.tiles.delete(entry.key);
}

/** Where the camera is in the world's frame: the model's axes, from the camera's tile's lowest corner. */
const cameraInModel = () => group.worldToLocal(camera.position.clone());

/** Tiles within the reach of the camera's wanted; those past it and the hold dropped. */
function refresh() {
  const { origin: [oi, oj], reach, tiles } = run;
  for (const entry of [...tiles.values()]) {
    const away = Math.max(Math.abs(Number(entry.i - oi)), Math.abs(Number(entry.j - oj)));
    if (away > reach + HOLD || (away > reach && entry.state === 'wanted')) drop(entry);
  }
  for (let di = -reach; di <= reach; di++) {
    for (let dj = -reach; dj <= reach; dj++) {
      const i = oi + BigInt(di), j = oj + BigInt(dj), key = keyOf(i, j);
      if (!tiles.has(key)) tiles.set(key, { key, i, j, state: 'wanted', mesh: null, controller: null });
    }
  }
  pump();
}

/** Start making the wanted tiles nearest the camera, as many as the back end takes at once. */
function pump() {
  const r = run;
  const at = cameraInModel(), [h0, h1] = r.layout.horizontal;
  const distance = (e) => ((Number(e.i - r.origin[0]) + 0.5) * r.size[0] - at.getComponent(h0)) ** 2
    + ((Number(e.j - r.origin[1]) + 0.5) * r.size[1] - at.getComponent(h1)) ** 2;
  while (r.making < SLOTS[r.where]) {
    let next = null;
    for (const entry of r.tiles.values()) if (entry.state === 'wanted' && (!next || distance(entry) < distance(next))) next = entry;
    if (!next) break;
    make(r, next);
  }
  tell();
}

async function make(r, entry) {
  r.making++;
  entry.state = 'making';
  entry.controller = new AbortController();
  try {
    const request = sampleRequest({ seed: r.seed, scale: r.scale, tile: [entry.i, entry.j], frame: 'tile' });
    const { positions, faces, colours } = await sampling.tile(r.where, r.name, request, { signal: entry.controller.signal });
    if (r.tiles.get(entry.key) !== entry) return; // dropped meanwhile
    entry.state = 'done';
    entry.order = ++r.made;
    if (faces.length) {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
      geometry.setAttribute('normal', new THREE.BufferAttribute(new Float32Array(positions.length), 3));
      geometry.setIndex(new THREE.BufferAttribute(faces, 1));
      entry.mesh = new THREE.Mesh(geometry, paint(geometry, colours));
      entry.mesh.name = entry.key;
      shade(r, entry);
      put(r, entry);
      group.add(entry.mesh);
      wake();
    }
  } catch (error) {
    if (r.tiles.get(entry.key) !== entry) return;
    entry.state = 'failed'; // not asked for again until the world is shown again
    r.error = error;
  } finally {
    r.making--;
    if (run === r) pump();
  }
}

// ---- normals: a tile's own faces give a vertex on its border half of the faces around it, which
// would shade every tile's sides as a crease; the tiles beside it give the rest. Each border
// vertex's sum of face normals (area-weighted, as three.js's computeVertexNormals) is kept
// under where it lies on the lattice (its position there is the same bits from both sides),
// and its normal is the sum over all the tiles there.
const borders = new Map(); // lattice key -> [{ entry, vertex, sum }]

/** A tile's normals: its own faces', then each border vertex's with the tiles already beside it. */
function shade(r, entry) {
  const geometry = entry.mesh.geometry, p = geometry.attributes.position.array, f = geometry.index.array;
  const sums = new Float64Array(p.length);
  for (let k = 0; k < f.length; k += 3) {
    const [a, b, c] = [3 * f[k], 3 * f[k + 1], 3 * f[k + 2]];
    const u = [p[b] - p[a], p[b + 1] - p[a + 1], p[b + 2] - p[a + 2]], v = [p[c] - p[a], p[c + 1] - p[a + 1], p[c + 2] - p[a + 2]];
    const n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    for (const at of [a, b, c]) for (let axis = 0; axis < 3; axis++) sums[at + axis] += n[axis];
  }
  const normals = geometry.attributes.normal.array;
  const normalise = (sum, at, out) => {
    const length = Math.hypot(sum[0], sum[1], sum[2]) || 1;
    for (let axis = 0; axis < 3; axis++) out[at + axis] = sum[axis] / length;
  };
  for (let v = 0; v < p.length; v += 3) normalise(sums.subarray(v, v + 3), v, normals);
  const [h0, h1] = r.layout.horizontal, up = r.layout.up;
  const ends = r.size.map(Math.fround); // a border vertex's coordinate: 0 or the tile's side, in float32
  const line = (at, end, index) => (at === 0 ? index : at === end ? index + 1n : null);
  entry.borders = new Set();
  const changed = new Set();
  for (let v = 0; v < p.length; v += 3) {
    const x = line(p[v + h0], ends[0], entry.i), y = line(p[v + h1], ends[1], entry.j);
    if (x === null && y === null) continue;
    const key = x !== null && y !== null ? `c${x},${y},${p[v + up]}` // on a corner's column: up to four tiles
      : x !== null ? `x${x},${entry.j},${p[v + h1]},${p[v + up]}` : `y${entry.i},${y},${p[v + h0]},${p[v + up]}`;
    const there = borders.get(key) ?? [];
    there.push({ entry, vertex: v, sum: sums.slice(v, v + 3) });
    borders.set(key, there);
    entry.borders.add(key);
    if (there.length > 1) changed.add(key);
  }
  for (const key of changed) {
    const there = borders.get(key), sum = [0, 0, 0];
    for (const { sum: part } of there) for (let axis = 0; axis < 3; axis++) sum[axis] += part[axis];
    for (const { entry: beside, vertex } of there) {
      normalise(sum, vertex, beside.mesh.geometry.attributes.normal.array);
      beside.mesh.geometry.attributes.normal.needsUpdate = true;
    }
  }
}

/** A tile's mesh where it lies from the camera's tile (a small number, whatever the tile). */
function put(r, entry) {
  const [h0, h1] = r.layout.horizontal;
  entry.mesh.position.setComponent(h0, Number(entry.i - r.origin[0]) * r.size[0]);
  entry.mesh.position.setComponent(h1, Number(entry.j - r.origin[1]) * r.size[1]);
}

/** The camera crossed into another tile: that tile becomes the origin, and the camera and the tiles move by as much. */
function rebase() {
  const at = cameraInModel(), [h0, h1] = run.layout.horizontal;
  const di = Math.floor(at.getComponent(h0) / run.size[0]), dj = Math.floor(at.getComponent(h1) / run.size[1]);
  if (!di && !dj) return;
  run.origin = [run.origin[0] + BigInt(di), run.origin[1] + BigInt(dj)];
  const shift = new THREE.Vector3().setComponent(h0, di * run.size[0]).setComponent(h1, dj * run.size[1]);
  camera.position.sub(shift.applyQuaternion(group.quaternion));
  for (const entry of run.tiles.values()) if (entry.mesh) put(run, entry);
  refresh();
}

function tell() {
  const all = [...run.tiles.values()];
  const waiting = all.filter((e) => e.state === 'wanted' || e.state === 'making').length;
  run.report({
    at: run.origin, shown: all.filter((e) => e.mesh).length, waiting, made: run.made, dropped: run.dropped,
    complete: waiting === 0, error: run.error,
  });
}

/**
 * For the tests and the console: the world in view (the camera's tile, the tiles made as [i, j,
 * faces, the order they were made in], the camera's place, the farthest tile's from the
 * scene's origin and how many tiles show vertex colours), and the camera moved by whole tiles (a scripted flight).
 */
export const view = {
  status: () => run && {
    at: run.origin.map(String), made: run.made, dropped: run.dropped, size: run.size,
    tiles: [...run.tiles.values()].filter((e) => e.state === 'done').map((e) => [String(e.i), String(e.j), e.mesh ? e.mesh.geometry.index.count / 3 : 0, e.order]),
    camera: camera.position.toArray(), farthest: Math.max(0, ...group.children.map((m) => m.position.length())),
    coloured: group.children.filter((m) => m.geometry.attributes.color && m.material.vertexColors).length,
  },
  moveBy(d0, d1) {
    const shift = new THREE.Vector3().setComponent(run.layout.horizontal[0], d0 * run.size[0]).setComponent(run.layout.horizontal[1], d1 * run.size[1]);
    camera.position.add(shift.applyQuaternion(group.quaternion));
    rebase();
    settle();
  },
};
