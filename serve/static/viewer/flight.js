// The world mode's camera (viewer/world.js): the keys, the mouse and
// fingers fly it, or walk it over the ground. A frame loop draws while it
// moves; otherwise a frame is drawn when something in view changes.
//
//   steer({ side, height, walk, ground, moved })  fly over a world (null: the keys and the view are the page's again)
//   aim(yaw, pitch)                               look that way; wake() draws the next frame
import * as THREE from 'three';
import { camera, frameTook, render, view } from './scene.js';

const KEYS = { // key -> [forward, right, up], in units of the speed
  w: [1, 0, 0], arrowup: [1, 0, 0], s: [-1, 0, 0], arrowdown: [-1, 0, 0], a: [0, -1, 0], d: [0, 1, 0],
  e: [0, 0, 1], ' ': [0, 0, 1], q: [0, 0, -1], c: [0, 0, -1],
};
const TURNS = { arrowleft: 1, arrowright: -1 }; // radians per second of yaw
const LOOK = 0.005; // radians of turn per pixel dragged
const EYES = 0.08; // walking, the eyes' height over the ground, in a tile's shorter sides

// The world flown over: { side: a tile's shorter side, height: the world's (in the view's
// units), walk: keep to the ground, ground: the group of meshes to stand on, moved(): after
// each move (the world's origin follows the camera) }.
let craft = null;
let pose = { yaw: 0, pitch: 0 };
let speed = 1; // the wheel's factor on the speeds
const held = new Set(); // movement keys down
const pointers = new Map(); // pointer id -> its last { x, y }, while pressed on the view
const raycaster = new THREE.Raycaster();
const down = new THREE.Vector3(0, -1, 0);
let looping = false, last = 0, drawn = null; // drawn: the start of the last frame drawn and not yet timed

/** Fly over `world` (the keys and the pointers move the camera), or (null) over nothing. */
export function steer(world) {
  craft = world;
  held.clear();
  pointers.clear();
}

/** Look along `yaw` (radians about the view's vertical; 0 looks along -z) and `pitch` (up from level). */
export function aim(yaw, pitch) {
  pose = { yaw: 0, pitch: 0 };
  turn(yaw, pitch);
}

function turn(yaw, pitch) {
  pose.yaw += yaw;
  pose.pitch = Math.min(1.5, Math.max(-1.5, pose.pitch + pitch));
  camera.quaternion.setFromEuler(new THREE.Euler(pose.pitch, pose.yaw, 0, 'YXZ'));
}

/** Move by [forward, right, up] in the view's units: forward and right level, whichever way the view tilts. */
function move([forward, right, up]) {
  const { yaw } = pose;
  camera.position.add(new THREE.Vector3(-Math.sin(yaw) * forward + Math.cos(yaw) * right, 0, -Math.cos(yaw) * forward - Math.sin(yaw) * right));
  if (!craft.walk) camera.position.y = Math.min(craft.height + 40 * craft.side, Math.max(-craft.height, camera.position.y + up));
  craft.moved();
  settle();
}

/** After a move: walking, the eyes a little over the ground under the camera (where its tile is made); a frame drawn. */
export function settle() {
  if (craft.walk) {
    raycaster.set(camera.position.clone().setY(craft.height * 2 + 1), down);
    const [hit] = raycaster.intersectObjects(craft.ground.children, false);
    if (hit) camera.position.y = hit.point.y + craft.side * EYES;
  }
  wake();
}

function loop(now) {
  if (!craft) {
    looping = false;
    return;
  }
  timeFrame(now);
  const seconds = Math.min(0.1, (now - last) / 1000);
  last = now;
  const step = [0, 0, 0];
  let yaw = 0;
  for (const key of held) {
    (KEYS[key] ?? [0, 0, 0]).forEach((v, a) => { step[a] += v; });
    yaw += TURNS[key] ?? 0;
  }
  if (yaw) turn(yaw * seconds, 0);
  const unit = craft.side * (craft.walk ? 0.4 : 1) * speed * (held.has('shift') ? 4 : 1) * seconds; // flying, a tile a second
  if (step.some((v) => v)) move(step.map((v) => v * unit));
  render();
  drawn = now;
  if (held.size) requestAnimationFrame(loop);
  else {
    looping = false;
    requestAnimationFrame(timeFrame); // a frame drawn alone (a tile come, a look around) is timed too
  }
}

/** The last frame drawn took from its start until `now`, the next frame's start: scene.js's resolution
 * follows (a frame is drawn at a new one). */
function timeFrame(now) {
  const changed = drawn !== null && frameTook(now - drawn);
  drawn = null;
  if (changed) wake();
}

/** Draw the next frame, and go on drawing while a key moves the camera. */
export function wake() {
  if (looping || !craft) return;
  looping = true;
  last = performance.now();
  requestAnimationFrame(loop);
}

const typing = (event) => event.target.closest?.('input, select, textarea');

document.addEventListener('keydown', (event) => {
  const key = event.key.toLowerCase();
  if (!craft || typing(event) || event.ctrlKey || event.metaKey || !(key in KEYS || key in TURNS || key === 'shift')) return;
  event.preventDefault();
  held.add(key);
  wake();
});
document.addEventListener('keyup', (event) => held.delete(event.key.toLowerCase()));
window.addEventListener('blur', () => held.clear());

// The mouse, or one finger: drag to look around. Two fingers: drag to move (up the screen is
// forward), pinch to rise or sink (walking: to move forward and back).
view.addEventListener('pointerdown', (event) => {
  if (!craft) return;
  view.setPointerCapture(event.pointerId);
  pointers.set(event.pointerId, { x: event.clientX, y: event.clientY });
});
view.addEventListener('pointermove', (event) => {
  const before = pointers.get(event.pointerId);
  if (!craft || !before) return;
  const [first, second] = [...pointers.values()];
  const spread = second ? Math.hypot(first.x - second.x, first.y - second.y) : 0;
  pointers.set(event.pointerId, { x: event.clientX, y: event.clientY });
  const dx = event.clientX - before.x, dy = event.clientY - before.y;
  if (pointers.size === 1) {
    turn(-dx * LOOK, -dy * LOOK);
    wake();
    return;
  }
  const [a, b] = [...pointers.values()];
  const pinch = Math.hypot(a.x - b.x, a.y - b.y) - spread;
  const unit = (craft.side / view.clientHeight) * 2 * speed; // a swipe the view's height: two tiles
  move(craft.walk ? [(pinch - dy / 2) * unit, (-dx / 2) * unit, 0] : [(-dy / 2) * unit, (-dx / 2) * unit, pinch * unit]);
});
for (const type of ['pointerup', 'pointercancel']) view.addEventListener(type, (event) => pointers.delete(event.pointerId));
view.addEventListener('wheel', (event) => {
  if (!craft) return;
  event.preventDefault();
  speed = Math.min(16, Math.max(1 / 16, speed * (event.deltaY < 0 ? 1.25 : 0.8)));
}, { passive: false });
