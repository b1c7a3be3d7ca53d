// Endless worlds, as runtime/world.py (docs/WORLDS.md): tile (i, j) of the
// world of a seed is the decoder's head applied to four windows' hidden
// vectors, blended with smoothstep weights that sum to one. A window is an
// ordinary sample of the training extent with its own noise, keyed by
// (seed, a, b) at its lattice point (a, b); a tile depends on its four
// windows only, so it costs the same anywhere and whatever was made before.
// The blend and the head are element-wise, in one fixed order, so two
// neighbouring tiles compute their shared face from the same window at
// weight exactly 1 by the same arithmetic: the same floats, to the bit
// (within this runtime; against Python's, within the runtimes' 1e-4).
//
//   const layout = worldLayout(model.manifest);             // horizontal axes, up, stride S per axis
//   const grid = await tileOccupancy(model, 3n, [5n, -2n]);  // { data: Float32Array (X, Y, Z), shape }
//   const mesh = await tileMesh(model, 3n, [5n, -2n]);       // { positions (voxels from the corner), faces }
//   const rgb = await tileColours(model, 3n, [5n, -2n], mesh.positions);  // a coloured model's sRGB at its vertices
import { InputError, formatG, pyRepr } from './errors.js';
import { checkSeed, drawNoise, roundHalfEven, scaledSizes, triplane } from './generate.js';
import { marchingCubes } from './mesh.js';
import { streamKey } from './noise.js';
import { PLANE_AXES, addBilinear, headColour, project } from './query.js';

const WORLD_STREAM = 2; // world.WORLD_STREAM: (WORLD_STREAM, a, b) keys window (a, b)'s noise, after the seed
const MAX_TILE = 2n ** 62n; // world.MAX_TILE: |i|, |j| below it
const MIN_STRIDE = 4; // voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
const UP_AXIS = { y: 1, z: 2 };
const BLEND = 1.0; // world.BLEND
const MAX_POINTS = 1 << 14; // per axis of a tile, as world.check_world_scale
const MAX_BYTES = 2 * 2 ** 30; // a tile's grid and interpolated planes in a browser tab
const MAX_ABSOLUTE = 2n ** 18n; // world.MAX_ABSOLUTE: voxels from the origin that float32 still places to 1/64

/**
 * The world's cut for a model's manifest ({ sizes, up }), as world.world_layout:
 * { horizontal: the two horizontal axes, up, stride: [3] voxels per tile (the
 * up axis's entry its whole height - 1), factors: a window's size factors }.
 */
export function worldLayout({ sizes, up: upName = 'y' }) {
  const finest = sizes.at(-1), up = UP_AXIS[upName];
  const horizontal = [0, 1, 2].filter((a) => a !== up);
  const stride = [0, 0, 0];
  for (const axis of horizontal) {
    stride[axis] = Math.floor((finest[axis] - 1) / 2);
    if (stride[axis] < MIN_STRIDE) {
      throw new InputError(`the model is ${finest[axis]} voxels along ${'xyz'[axis]}, a horizontal axis: a world `
        + `needs windows of at least ${2 * MIN_STRIDE + 1} to blend`);
    }
  }
  stride[up] = finest[up] - 1;
  const factors = [0, 1, 2].map((a) => (a === up ? 1 : (2 * stride[a] + 1) / finest[a]));
  return { horizontal, up, stride, factors };
}

/** The noise seed of window (a, b) of the world of `seed`: a 64-bit key (BigInt), as world.window_seed. */
export function windowSeed(seed, a, b) {
  return streamKey(seed, WORLD_STREAM, BigInt.asUintN(64, BigInt(a)), BigInt.asUintN(64, BigInt(b)));
}

// Windows kept for the next tiles (a tile shares each of its four with a
// neighbour; a view of 7 x 7 tiles made nearest first, or a row of them
// made as the view moves, reuses all it can with 64). A cache, not state:
// a window is the same array whether it is made or found.
const WINDOWS_KEPT = 64;
let modelCount = 0;
const windows = new Map(); // "model|seed|a|b" -> a promise of the window's planes, oldest use first
const modelIds = new WeakMap(); // model -> a number naming it in the keys

/** Window (a, b)'s final planes times the decoder's first layer: 3 x { data, dims: [H, W, D] }. */
function windowPlanes(model, layout, seed, a, b) {
  if (!modelIds.has(model)) modelIds.set(model, ++modelCount);
  const key = `${modelIds.get(model)}|${seed}|${a}|${b}`;
  let made = windows.get(key);
  if (made) {
    windows.delete(key); // to the end: the newest use
  } else {
    made = (async () => {
      const sizes = scaledSizes(model.manifest.sizes, layout.factors);
      const tri = await triplane(model, drawNoise(windowSeed(seed, a, b), sizes, model.manifest.channels), sizes);
      return (await project(model, tri)).planes;
    })();
    made.catch(() => windows.delete(key));
  }
  windows.set(key, made);
  while (windows.size > WINDOWS_KEPT) windows.delete(windows.keys().next().value);
  return made;
}

/** How many windows are kept now, at most WINDOWS_KEPT. */
export const keptWindows = () => windows.size;

/** Forget the windows kept (the tests' fresh start). */
export function dropWindows() {
  windows.clear();
}

const smoothstep = (f) => f * f * (3 - 2 * f);

/**
 * A tile's grid along `axis`, as world.tile_axis: { points, cells, weights }.
 * Horizontal: m + 1 points over the stride S (m = S scale, rounded), point p
 * at p S / m, and for the tile's two windows (the one before, the one behind)
 * their cell positions and weights; along up, one window spanning it all.
 */
function tileAxis(layout, axis, scale) {
  const stride = layout.stride[axis];
  if (axis === layout.up) {
    const m = Math.max(2, roundHalfEven((stride + 1) * scale)); // as a sample's grid: m points over the height
    return { points: m, cells: [Float64Array.from({ length: m }, (_, p) => p * (stride / (m - 1)))], weights: [new Float32Array(m).fill(1)] };
  }
  const m = Math.max(1, roundHalfEven(stride * scale));
  const behind = new Float32Array(m + 1), before = new Float32Array(m + 1);
  for (let p = 0; p <= m; p++) {
    behind[p] = smoothstep(Math.min(Math.max((p / m - 0.5) / BLEND + 0.5, 0), 1)); // window i (p = 0 at its start)
    before[p] = 1 - behind[p]; // window i - 1: exactly 1 - behind, in float32
  }
  const cells = [Float64Array.from({ length: m + 1 }, (_, p) => ((m + p) * stride) / m),
    Float64Array.from({ length: m + 1 }, (_, p) => (p * stride) / m)];
  return { points: m + 1, cells, weights: [before, behind] };
}

/** Per position, the two grid points around it and the weight of the upper one, as world.interpolate's `along`. */
function taps(positions, n) {
  const low = new Int32Array(positions.length), high = new Int32Array(positions.length), frac = new Float32Array(positions.length);
  positions.forEach((at, k) => {
    low[k] = Math.min(Math.max(Math.floor(at), 0), Math.max(n - 2, 0));
    high[k] = Math.min(low[k] + 1, n - 1);
    frac[k] = at - low[k];
  });
  return { low, high, frac };
}

/**
 * A (H, W, D) plane at every (row, col) of two position lists, element-wise
 * (bilinear, align_corners), as world.interpolate: (rows, cols, D)
 * Float32Array. Two tiles asking for the same position get the same bits.
 */
function interpolate(plane, rows, cols) {
  const [h, w, d] = plane.dims, src = plane.data;
  const r = taps(rows, h), c = taps(cols, w);
  const along = new Float32Array(rows.length * w * d); // along the rows first: (rows, W, D)
  for (let i = 0; i < rows.length; i++) {
    const a0 = r.low[i] * w * d, a1 = r.high[i] * w * d, f = r.frac[i], at = i * w * d;
    for (let t = 0; t < w * d; t++) along[at + t] = src[a0 + t] * (1 - f) + src[a1 + t] * f;
  }
  const out = new Float32Array(rows.length * cols.length * d);
  for (let i = 0; i < rows.length; i++) {
    for (let j = 0; j < cols.length; j++) {
      const b0 = (i * w + c.low[j]) * d, b1 = (i * w + c.high[j]) * d, f = c.frac[j], at = (i * cols.length + j) * d;
      for (let k = 0; k < d; k++) out[at + k] = along[b0 + k] * (1 - f) + along[b1 + k] * f;
    }
  }
  return out;
}

/** A tile of a world, (i, j): two integers of magnitude below 2**62, as world.check_tile; frozen BigInts. */
export function checkTile(tile) {
  const whole = (t) => typeof t === 'bigint' || Number.isInteger(t);
  if (!(Array.isArray(tile) && tile.length === 2 && tile.every((t) => whole(t) && -MAX_TILE < BigInt(t) && BigInt(t) < MAX_TILE))) {
    throw new InputError(`a tile is two integers (i, j) of magnitude below 2**62, got ${pyRepr(tile)}`, 'tile');
  }
  return Object.freeze(tile.map(BigInt));
}

/** A tile's grid per axis at `scale`, refused where it is too large for the page, as world.check_world_scale. */
function tileAxes(layout, scale, hidden) {
  if (!(typeof scale === 'number' && scale > 0 && scale < Infinity)) throw new InputError(`scale must be a positive number, got ${scale}`, 'scale');
  const axes = [0, 1, 2].map((a) => tileAxis(layout, a, scale));
  const points = axes.map((a) => a.points);
  if (Math.max(...points) > MAX_POINTS) {
    throw new InputError(`scale ${formatG(scale)} makes a tile of ${points.join('x')} points; at most ${MAX_POINTS} per axis`, 'scale');
  }
  const bytes = points[0] * points[1] * points[2] * 4 + 4 * hidden * 4 * PLANE_AXES.reduce((n, [a, b]) => n + points[a] * points[b], 0);
  if (bytes > MAX_BYTES) throw new InputError(`a ${points.join('x')} tile needs more memory than a page should take`, 'scale');
  return axes;
}

/**
 * Occupancy on tile (i, j)'s grid, as world.tile_occupancy: { data:
 * Float32Array (X, Y, Z) in C order, shape }, its points along each
 * horizontal axis from the tile's lattice point to the next (both included:
 * the faces it shares), along up the model's height.
 */
export async function tileOccupancy(model, seed, tile, scale = 1) {
  seed = checkSeed(seed);
  const [i, j] = checkTile(tile);
  const { hidden } = model.manifest;
  const layout = worldLayout(model.manifest);
  const axes = tileAxes(layout, scale, hidden);
  const [h0, h1] = layout.horizontal;
  const sources = []; // per window, in a fixed order (the sum's): its interpolated planes and weights
  for (const [a, b] of [[i - 1n, j - 1n], [i - 1n, j], [i, j - 1n], [i, j]]) {
    const index = [0, 0, 0];
    index[h0] = Number(a - i + 1n);
    index[h1] = Number(b - j + 1n);
    const cells = axes.map((axis, n) => axis.cells[index[n]]);
    const planes = (await windowPlanes(model, layout, seed, a, b)).map((plane, k) => interpolate(plane, cells[PLANE_AXES[k][0]], cells[PLANE_AXES[k][1]]));
    sources.push({ planes, weights: axes.map((axis, n) => axis.weights[index[n]]) });
  }
  const shape = axes.map((a) => a.points), [mx, my, mz] = shape;
  const { bias1, weight2, bias2 } = model.head;
  const out = new Float32Array(mx * my * mz);
  const total = new Float64Array(hidden);
  for (let x = 0; x < mx; x++) {
    for (let y = 0; y < my; y++) {
      for (let z = 0; z < mz; z++) {
        total.fill(0);
        for (const { planes: [xy, xz, yz], weights: [wx, wy, wz] } of sources) {
          const weight = wx[x] * wy[y] * wz[z];
          const a = (x * my + y) * hidden, b = (x * mz + z) * hidden, e = (y * mz + z) * hidden;
          for (let c = 0; c < hidden; c++) total[c] += weight * (xy[a + c] + xz[b + c] + yz[e + c]);
        }
        let s = bias2; // the head: sigmoid(w2 . relu(h + b1) + b2), over the hidden width in order
        for (let c = 0; c < hidden; c++) {
          const h = total[c] + bias1[c];
          if (h > 0) s += h * weight2[c];
        }
        out[(x * my + y) * mz + z] = 1 / (1 + Math.exp(-s));
      }
    }
  }
  return { data: out, shape };
}

/**
 * Tile (i, j)'s surface, as world.tile_mesh: { positions: Float32Array (V, 3)
 * in voxels from the tile's lowest corner, faces: Uint32Array (F, 3) }.
 * Closed at the top and bottom, open on the four sides it shares with its
 * neighbours, whose border vertices it shares exactly.
 */
export async function tileMesh(model, seed, tile, scale = 1) {
  const grid = await tileOccupancy(model, seed, tile, scale);
  const layout = worldLayout(model.manifest);
  const pad = [[0, 0], [0, 0], [0, 0]];
  pad[layout.up] = [1, 1];
  const { positions, faces } = marchingCubes(grid, 0.5, null, pad);
  for (let v = 0; v < positions.length; v += 3) {
    for (let axis = 0; axis < 3; axis++) {
      positions[v + axis] = (positions[v + axis] - pad[axis][0]) * layout.stride[axis] / (grid.shape[axis] - 1); // exact at the faces: m S / m = S
    }
  }
  return { positions, faces };
}

/** A window's weight along a horizontal axis at a fraction f of the stride from its lattice point, as tileAxis's `behind`. */
const behindWeight = (f) => smoothstep(Math.min(Math.max((f - 0.5) / BLEND + 0.5, 0), 1));

/**
 * A coloured model's sRGB colour at a tile's mesh vertices (tileMesh's
 * positions, voxels from the tile's corner), as world.tile_colours: the
 * four windows' hidden vectors blended at each vertex with the weights the
 * tile's grid gives there, then the colour head. A vertex on a shared face
 * takes one window at weight exactly 1, so neighbours agree on its colour.
 * Returns Float32Array (V, 3) in [0, 1] (Python's gives them as bytes).
 */
export async function tileColours(model, seed, tile, positions) {
  seed = checkSeed(seed);
  const [i, j] = checkTile(tile);
  const { hidden: d } = model.manifest;
  const layout = worldLayout(model.manifest), { stride, up } = layout, [h0, h1] = layout.horizontal;
  const windows = [];
  for (const [a, b] of [[i - 1n, j - 1n], [i - 1n, j], [i, j - 1n], [i, j]]) {
    windows.push({ behind: [a === i, b === j], planes: await windowPlanes(model, layout, seed, a, b) });
  }
  const n = positions.length / 3, out = new Float32Array(3 * n), total = new Float64Array(d), part = new Float64Array(d);
  const at = [0, 0, 0], cell = [0, 0, 0];
  for (let v = 0; v < n; v++) {
    for (let axis = 0; axis < 3; axis++) at[axis] = positions[3 * v + axis];
    cell[up] = at[up];
    total.fill(0);
    for (const { behind, planes } of windows) {
      let weight = 1;
      [h0, h1].forEach((axis, k) => {
        const w = behindWeight(at[axis] / stride[axis]);
        weight *= behind[k] ? w : 1 - w;
        cell[axis] = behind[k] ? at[axis] : at[axis] + stride[axis];
      });
      if (weight === 0) continue;
      part.fill(0);
      PLANE_AXES.forEach(([a, b], k) => addBilinear(planes[k], cell[a], cell[b], part));
      for (let c = 0; c < d; c++) total[c] += weight * part[c];
    }
    headColour(model.head, total, 0, out, 3 * v);
  }
  return out;
}

/** Tile (i, j)'s lowest corner in voxels, as world.tile_corner: three BigInts (exact for any tile). */
export function tileCorner(layout, tile) {
  const [i, j] = checkTile(tile);
  const corner = [0n, 0n, 0n];
  corner[layout.horizontal[0]] = i * BigInt(layout.stride[layout.horizontal[0]]);
  corner[layout.horizontal[1]] = j * BigInt(layout.stride[layout.horizontal[1]]);
  return corner;
}

/** A tile far from the world's origin is placed in its own frame only, as world.check_placement. */
export function checkPlacement(manifest, tile, frame) {
  const far = tileCorner(worldLayout(manifest), tile).reduce((most, c) => (c < 0n ? -c : c) > most ? (c < 0n ? -c : c) : most, 0n);
  if (frame !== 'tile' && far > MAX_ABSOLUTE) {
    throw new InputError(`tile (${tile.join(', ')}) lies ${far} voxels from the world's origin, where float32 `
      + "coordinates lose the shape's detail: give frame tile (coordinates from the tile's corner)", 'frame');
  }
}

/**
 * A tile's positions (voxels from its corner) in a request's frame, in place,
 * as world.placed: 'tile' (the input's units from the tile's corner), 'model'
 * (voxels) or 'input' (the training mesh's frame), the last two from the
 * world's origin.
 */
export function placed(manifest, tile, positions, frame) {
  checkPlacement(manifest, tile, frame);
  const corner = tileCorner(worldLayout(manifest), tile).map(Number), { origin, spacing } = manifest;
  for (let v = 0; v < positions.length; v += 3) {
    for (let axis = 0; axis < 3; axis++) {
      const at = positions[v + axis], absolute = corner[axis] + at; // exact on shared borders: integers plus the same offsets
      positions[v + axis] = frame === 'tile' ? at * spacing[axis] : frame === 'model' ? absolute : origin[axis] + absolute * spacing[axis];
    }
  }
  return positions;
}
