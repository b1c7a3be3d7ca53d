// The world mode (docs/WORLDS.md, "In the browser"): fly or walk over the
// endless world of the model and seed. Tiles are made around the camera,
// those ahead of it first, by the server's tile route (the Python runtime
// makes worlds; the browser's runtime makes none), coarser the farther they are (a tile's level of
// detail follows its distance, and it is made again finer as the camera comes nearer; until the
// view has filled once, a tile not shown yet comes first at the coarsest level, a sketch, so the
// view fills in a fraction of the time, then sharpens as the finer tiles come; a tile that a
// flight brings in later comes at the ring's edge, deep in the haze, whose colour a missing tile
// shows too: it is made at its level at once; each hangs a skirt, so that no crack shows between
// tiles of two levels), and
// dropped behind it, their GPU buffers disposed, so memory stays bounded
// however far one goes. Each tile comes with its normals, the field's
// gradient, which agree across its borders. The origin floats: the scene's
// origin is the lowest corner of the camera's tile, every tile is placed
// relative to it and the camera stays within its tile, so a tile a billion
// tiles out is drawn as precisely as tile (0, 0). The camera's motion is
// viewer/flight.js's.
//
//   show({ name, request, info, others, reach, walk }, report)  the world of the tile request `request`, from its tile
//   stop()                                                                                drop it all, and give the view back to the shape
import * as THREE from 'three';
import { sampleRequest } from '../sinshape/request.js';
import { worldTiling } from '../sinshape/world.js';
import { aim, settle, steer, wake } from './flight.js';
import * as sampling from './sampling.js';
import { camera, paint, scene, worldView } from './scene.js';

const SLOTS = 2; // tiles asked of the server at once
const HOLD = 1; // tiles kept this far past the reach before they are dropped: a step back makes none again
const FINE = 1; // tiles this far from the camera's (and its own) at the finest level; each tile farther, a level coarser
const AHEAD = 1.5; // tiles: the point ahead of the camera, along its view, that the nearest tiles are counted from
const sky = new THREE.Color(0xaab8c4); // a haze the far tiles fade into, as the background
let background = null; // the shape's, while the world is shown

const group = new THREE.Group(); // the world's tiles, turned so the model's up points up on screen
group.visible = false;
scene.add(group);
let run = null; // the world in view
const keyOf = (i, j) => `${i},${j}`; // a tile's name

/**
 * Fly over the world of `request` (a tile request: its seed, scale, detail,
 * arrangement, maps and other models make every tile) of model `name`, made by the server, from the request's tile;
 * `info` is the model's { sizes, spacing, up } (`others`, the world's other
 * models', whose objects may stand taller), `reach` how many tiles to
 * make on each side of the camera's, `walk` whether to keep to the ground.
 * The same world again keeps its tiles and the camera, unless its tile
 * is another than the camera's (a jump). report({ at, shown, waiting, made,
 * dropped, complete, error }) follows the work.
 */
export function show({ name, request, info, others = [], reach, walk }, report) {
  const { tile, heights } = request;
  const key = worldKey(name, request);
  const jump = !run || run.key !== key || tile[0] !== run.origin[0] || tile[1] !== run.origin[1];
  if (run?.key !== key) {
    stop(false);
    const tiling = worldTiling(info);
    const [h0, h1] = tiling.horizontal, top = Math.max(...[info, ...others].map((each) => {
      const cut = worldTiling(each);
      return (cut.stride[cut.up] * (each.objectScale ?? 1)) / (info.objectScale ?? 1); // another model's at its object scale
    }));
    run = {
      key, name, request, tiling, report, origin: tile, tiles: new Map(), making: 0, made: 0, dropped: 0, error: null,
      filled: false, // every tile of the view shown once: new tiles no longer come as sketches first
      coarsest: info.sizes.length - 1,
      size: [tiling.stride[h0] * info.spacing[h0], tiling.stride[h1] * info.spacing[h1]], // a tile's sides, in the input's units
      height: (top + (heights ? Math.max(...heights.data) : 0)) * info.spacing[tiling.up], // a voxel of any model is one of the world's
    };
    group.rotation.set(tiling.up === 2 ? -Math.PI / 2 : 0, 0, 0); // the model's up along the view's y
    group.updateMatrixWorld(true);
  }
  if (reach > run.reach) run.filled = false; // a wider view fills with sketches first too
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
  run.filled = false;
  for (const entry of run.tiles.values()) drop(entry);
  const start = new THREE.Vector3();
  start.setComponent(run.tiling.horizontal[0], run.size[0] / 2);
  start.setComponent(run.tiling.horizontal[1], run.size[1] / 2);
  start.setComponent(run.tiling.up, run.height + Math.min(...run.size));
  camera.position.copy(group.localToWorld(start));
  const along = new THREE.Vector3().setComponent(run.tiling.horizontal[0], 1).applyQuaternion(group.quaternion);
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

const mapIds = new WeakMap(); // a height map or model map -> a number naming it in a world's key
let mapCount = 0;
const mapId = (heights) => { if (!mapIds.has(heights)) mapIds.set(heights, ++mapCount); return mapIds.get(heights); };
/** What names a world: its model and its request's fields but the tile (a map, by mapId; a BigInt, as its digits). */
const worldKey = (name, request) => JSON.stringify([name, Object.entries(request).filter(([field]) => field !== 'tile').map(([field, value]) => [
  field, ['heights', 'models_map'].includes(field) && value !== null ? mapId(value) : typeof value === 'bigint' ? String(value) : value])]);

function drop(entry) {
  entry.controller?.abort();
  if (entry.mesh) {
    group.remove(entry.mesh);
    entry.mesh.geometry.dispose();
    run.dropped++;
  }
  run.tiles.delete(entry.key);
}

/** Where the camera is in the world's frame: the model's axes, from the camera's tile's lowest corner. */
const cameraInModel = () => group.worldToLocal(camera.position.clone());

/**
 * The level of detail a tile this many tiles from the camera's is made at,
 * down to world.farthest_lod: never the coarsest, a sketch (world.planes_level)
 * that only fills the view until a tile comes at its level, unless the model
 * has no other (two levels).
 */
const detail = (away) => Math.min(run.coarsest > 1 ? run.coarsest - 1 : run.coarsest, Math.max(0, away - FINE));

/**
 * Tiles within the reach of the camera's wanted, at the level of detail
 * their distance asks for (one shown coarser is made again, and shown
 * until then); those past the reach and the hold dropped.
 */
function refresh() {
  const { origin: [oi, oj], reach, tiles } = run;
  for (const entry of [...tiles.values()]) {
    const away = Math.max(Math.abs(Number(entry.i - oi)), Math.abs(Number(entry.j - oj)));
    if (away > reach + HOLD || (away > reach && entry.state === 'wanted')) drop(entry);
    else if (away <= reach) {
      entry.want = detail(away);
      // Made again only to be finer: a tile farther than it was made for keeps its mesh (drawing a finer tile
      // costs less than making a coarser one, and the tiles a flight leaves behind are out of view).
      if (entry.state === 'done' && entry.lod > entry.want) entry.state = 'wanted';
      else if (entry.state === 'wanted' && entry.lod <= entry.want) entry.state = 'done';
    }
  }
  for (let di = -reach; di <= reach; di++) {
    for (let dj = -reach; dj <= reach; dj++) {
      const i = oi + BigInt(di), j = oj + BigInt(dj), key = keyOf(i, j);
      if (!tiles.has(key)) tiles.set(key, { key, i, j, state: 'wanted', mesh: null, controller: null, want: detail(Math.max(Math.abs(di), Math.abs(dj))) });
    }
  }
  pump();
}

/**
 * Start making the wanted tiles, as many as the back end takes at once:
 * those not made at all first (at the coarsest level), then those shown at
 * another level of detail, each nearest first to a point ahead of the
 * camera along its view.
 */
function pump() {
  const r = run;
  const ahead = camera.getWorldDirection(new THREE.Vector3()).setY(0);
  if (ahead.lengthSq() > 0) ahead.setLength(AHEAD * Math.min(...r.size));
  const at = group.worldToLocal(camera.position.clone().add(ahead)), [h0, h1] = r.tiling.horizontal;
  const distance = (e) => ((Number(e.i - r.origin[0]) + 0.5) * r.size[0] - at.getComponent(h0)) ** 2
    + ((Number(e.j - r.origin[1]) + 0.5) * r.size[1] - at.getComponent(h1)) ** 2;
  const before = (e, other) => (e.lod === undefined) !== (other.lod === undefined) ? e.lod === undefined : distance(e) < distance(other);
  while (r.making < SLOTS) {
    let next = null;
    for (const entry of r.tiles.values()) if (entry.state === 'wanted' && (!next || before(entry, next))) next = entry;
    if (!next) break;
    make(r, next);
  }
  tell();
}

async function make(r, entry) {
  r.making++;
  entry.state = 'making';
  entry.controller = new AbortController();
  const lod = entry.lod === undefined && !r.filled ? r.coarsest : entry.want; // a sketch first; its windows' chains go on from there
  try {
    // With a skirt, hidden beside a coarser neighbour from either side; open underneath, which no view from above sees.
    const request = sampleRequest({ ...r.request, tile: [entry.i, entry.j], lod, skirt: true, underside: false });
    const { positions, faces, normals, colours } = await sampling.tile('server', r.name, request, { signal: entry.controller.signal });
    if (r.tiles.get(entry.key) !== entry) return; // dropped meanwhile
    entry.state = lod <= entry.want ? 'done' : 'wanted'; // the camera came nearer meanwhile: made again finer
    entry.order = ++r.made;
    entry.lod = lod;
    if (entry.mesh) { // the tile at its old level of detail, replaced
      group.remove(entry.mesh);
      entry.mesh.geometry.dispose();
      entry.mesh = null;
    }
    if (faces.length) {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
      geometry.setAttribute('normal', new THREE.BufferAttribute(normals, 3));
      geometry.setIndex(new THREE.BufferAttribute(faces, 1));
      entry.mesh = new THREE.Mesh(geometry, paint(geometry, colours, true));
      entry.mesh.name = entry.key;
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

/** A tile's mesh where it lies from the camera's tile (a small number, whatever the tile). */
function put(r, entry) {
  const [h0, h1] = r.tiling.horizontal;
  entry.mesh.position.setComponent(h0, Number(entry.i - r.origin[0]) * r.size[0]);
  entry.mesh.position.setComponent(h1, Number(entry.j - r.origin[1]) * r.size[1]);
}

/** The camera crossed into another tile: that tile becomes the origin, and the camera and the tiles move by as much. */
function rebase() {
  const at = cameraInModel(), [h0, h1] = run.tiling.horizontal;
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
  run.filled ||= all.every((e) => e.lod !== undefined);
  const waiting = all.filter((e) => e.state === 'wanted' || e.state === 'making').length;
  run.report({
    at: run.origin, shown: all.filter((e) => e.mesh).length, waiting, made: run.made, dropped: run.dropped,
    complete: waiting === 0, error: run.error,
  });
}

/**
 * For the tests and the console: the world in view (the camera's tile, the tiles made as [i, j,
 * faces, the order they were made in, their level of detail], how many are shown at some level, the camera's
 * place, the farthest tile's from the scene's origin and how many tiles show vertex colours), and the camera
 * moved by whole tiles (a scripted flight).
 */
export const view = {
  status: () => run && {
    at: run.origin.map(String), made: run.made, dropped: run.dropped, size: run.size,
    shown: [...run.tiles.values()].filter((e) => e.lod !== undefined).length,
    tiles: [...run.tiles.values()].filter((e) => e.state === 'done').map((e) => [String(e.i), String(e.j), e.mesh ? e.mesh.geometry.index.count / 3 : 0, e.order, e.lod]),
    camera: camera.position.toArray(), farthest: Math.max(0, ...group.children.map((m) => m.position.length())),
    coloured: group.children.filter((m) => m.geometry.attributes.color && m.material.vertexColors).length,
  },
  moveBy(d0, d1) {
    const shift = new THREE.Vector3().setComponent(run.tiling.horizontal[0], d0 * run.size[0]).setComponent(run.tiling.horizontal[1], d1 * run.size[1]);
    camera.position.add(shift.applyQuaternion(group.quaternion));
    rebase();
    settle();
  },
};
