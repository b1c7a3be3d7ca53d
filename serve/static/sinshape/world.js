// Endless worlds, as runtime/world.py (docs/WORLDS.md): tile (i, j) of the
// world of a seed, made of samples arranged one of two ways. blend: the
// decoder's head applied to four windows' hidden vectors (ordinary samples
// of the training extent with their own noise, keyed by (seed, a, b) at
// lattice point (a, b)), blended with smoothstep weights that sum to one,
// contrast kept. scatter: whole samples, one in most cells of a coarser
// lattice at a drawn place, on a ground, the largest occupancy; of several
// models, each cell's object is a sample of the model a model map names there
// (the first model sets the tiles, ground and axes; cells widen only where a
// larger model needs room). A height map raises a blend world's columns, and
// a scatter world's ground and objects.
// A tile depends on the windows that reach into it only, so it costs the
// same anywhere and whatever was made before; a coarser tile (lod) reads an
// earlier level and hangs a skirt from its sides. A format-5 model's
// full-detail tile reads each vertex's colour from the example by
// correspondence, in the window that weighs most there (or its object).
// The field is computed element-wise, in one fixed order, at positions
// that are small numbers relative to the tile, so two neighbouring tiles
// compute their shared face (and the normals there: the field's gradient)
// the same way: the same floats, to the bit (within this runtime; against
// Python's, within the runtimes' 1e-4).
//
//   const layout = worldLayout(model.manifest);                         // horizontal axes, up, stride S per axis
//   const options = worldOptions({ arrange: 'scatter', lod: 1 });       // as world.WorldOptions
//   const mixed = worldOptions({ arrange: 'scatter', models: [tower], models_map: ModelMap.of([0, 1, 1, 0], [2, 2]) });  // two models
//   const grid = await tileOccupancy(model, 3n, [5n, -2n], 1, options);  // { data: Float32Array (X, Y, Z), shape }
//   const mesh = await tileMesh(model, 3n, [5n, -2n], 1, options);       // { positions (voxels from the corner), faces }
//   const surface = await tileSurface(model, 3n, [5n, -2n], 1, options); // ... and normals, colours, a coarser tile's skirt
import { InputError, formatG, pyRepr, pyTuple } from './errors.js';
import { checkSeed, drawNoise, roundHalfEven, scaledSizes, triplane } from './generate.js';
import { marchingCubes } from './mesh.js';
import { GOLDEN, mix64Big, streamKey } from './noise.js';
import { PLANE_AXES, TAB_BYTES, addBilinear, headColour, project } from './query.js';

export const WORLD_STREAM = 2; // world.WORLD_STREAM: (WORLD_STREAM, a, b) keys window (a, b)'s noise, after the seed
export const SCATTER_STREAM = 3; // world.SCATTER_STREAM: (SCATTER_STREAM, a, b) keys scatter cell (a, b)'s draws
export const MAX_TILE = 2n ** 62n; // world.MAX_TILE: |i|, |j| below it
export const MIN_STRIDE = 4; // voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
export const UP_AXIS = { y: 1, z: 2 };
export const ARRANGEMENTS = ['blend', 'scatter']; // world.ARRANGEMENTS
export const BLEND = 1.0; // world.BLEND
export const PITCH = 3; // world.PITCH: a scatter cell's side, in strides
export const PRESENCE = 0.6; // world.PRESENCE: the share of scatter cells holding an object
export const GROUND = 1.0; // world.GROUND: voxels of ground over the map under a scatter world's objects
export const GROUND_SLOPE = 1.0; // world.GROUND_SLOPE: the ground's (and a ceiling's) logit per voxel
export const NORMAL_STEP = 0.25; // world.NORMAL_STEP: voxels of a normal's differences
export const PLATEAU = 0.5; // world.PLATEAU: voxels either side of a lattice line where its window holds the whole weight
export const SKIRT = 2.0; // world.SKIRT: a coarser tile's skirt, in its grid's steps along up
export const GROUND_COLOUR = [0.5, 0.5, 0.5]; // world.GROUND_COLOUR
export const MAX_MAP_SIDE = 1 << 12; // world.MAX_MAP_SIDE
export const MAX_RELIEF = 1 << 14; // world.MAX_RELIEF
export const MAX_MODELS = 256; // world.MAX_MODELS: models in one world (a model map's pixel is a byte)
export const MAX_POINTS = 1 << 14; // per axis of a tile, as world.check_world_scale
export const MAX_ABSOLUTE = 2n ** 18n; // world.MAX_ABSOLUTE: voxels from the origin that float32 still places to 1/64

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

// ---- the world's options

/** A designer's map of heights in voxels at the centres of tiles (r, c), as world.HeightMap.of: { shape, data: Float32Array }. */
export const HeightMap = {
  of(values, shape) {
    const sides = Array.isArray(shape) && shape.length === 2 && shape.every((n) => Number.isInteger(n));
    if (!(sides && Math.min(...shape) > 0 && Math.max(...shape) <= MAX_MAP_SIDE)) {
      throw new InputError(`a height map is a 2-D array of 1 to ${MAX_MAP_SIDE} pixels a side, got shape ${pyTuple(shape)}`, 'heights');
    }
    if (values?.length !== shape[0] * shape[1]) {
      throw new InputError(`a height map of ${shape.join('x')} pixels needs ${shape[0] * shape[1]} values, got ${values?.length}`, 'heights');
    }
    if (!Array.from(values).every((v) => typeof v === 'number' && Number.isFinite(v) && Math.abs(v) <= MAX_RELIEF)) {
      throw new InputError(`a height map holds values in voxels within +-${MAX_RELIEF}: no NaN or infinities`, 'heights');
    }
    return Object.freeze({ shape: [...shape], data: Float32Array.from(values) });
  },
  /** The lowest and highest heights, rounded out to whole voxels, as HeightMap.bounds. */
  bounds(map) {
    let low = Infinity, high = -Infinity;
    for (const v of map.data) { low = Math.min(low, v); high = Math.max(high, v); }
    return [Math.floor(low), Math.ceil(high)];
  },
};

/**
 * A designer's map of which model goes where in a scattered world, as
 * world.ModelMap.of: a model's index (0 the world's first) per tile (r, c), r
 * along the first horizontal axis, from tile (0, 0); beyond its edges, its
 * edge. { shape, data: Uint8Array (R, C) in C order }.
 */
export const ModelMap = {
  of(values, shape) {
    const sides = Array.isArray(shape) && shape.length === 2 && shape.every((n) => Number.isInteger(n));
    if (!(sides && Math.min(...shape) > 0 && Math.max(...shape) <= MAX_MAP_SIDE)) {
      throw new InputError(`a model map is a 2-D array of 1 to ${MAX_MAP_SIDE} pixels a side, got shape ${pyTuple(shape)}`, 'models_map');
    }
    if (values?.length !== shape[0] * shape[1]) {
      throw new InputError(`a model map of ${shape.join('x')} pixels needs ${shape[0] * shape[1]} values, got ${values?.length}`, 'models_map');
    }
    if (!Array.from(values).every((v) => Number.isInteger(v) && v >= 0 && v < MAX_MODELS)) {
      throw new InputError(`a model map holds models' indices, whole numbers 0 to ${MAX_MODELS - 1}`, 'models_map');
    }
    return Object.freeze({ shape: [...shape], data: Uint8Array.from(values) });
  },
  /** The index at tile (r, c) (BigInts), the edge's beyond the map, as ModelMap.at. */
  at(map, r, c) {
    const clamp = (t, n) => Number(t < 0n ? 0n : t > BigInt(n - 1) ? BigInt(n - 1) : t);
    return map.data[clamp(r, map.shape[0]) * map.shape[1] + clamp(c, map.shape[1])];
  },
};

/**
 * How a world is made and how finely one of its tiles is, checked as
 * world.WorldOptions: { arrange, heights, lod, models (a scattered world's
 * models after its first: 1, 2, ...), models_map (a ModelMap: which of them
 * each scatter cell draws its object from) }.
 */
export function worldOptions({ arrange = 'blend', heights = null, lod = 0, models = [], models_map: map = null } = {}) {
  if (!ARRANGEMENTS.includes(arrange)) throw new InputError(`unknown arrange ${pyRepr(arrange)}; choose ${ARRANGEMENTS.join(' or ')}`, 'arrange');
  if (heights !== null && !(heights?.data instanceof Float32Array && Array.isArray(heights.shape))) {
    throw new InputError('heights must be a world.HeightMap (HeightMap.of(array))', 'heights');
  }
  if (!(Number.isInteger(lod) && lod >= 0)) throw new InputError(`lod must be a whole number of levels, 0 or more, got ${pyRepr(lod)}`, 'lod');
  if (!(Array.isArray(models) && models.length < MAX_MODELS)) {
    throw new InputError(`models is a tuple of at most ${MAX_MODELS - 1} models after the first`, 'models');
  }
  const options = Object.freeze({ arrange, heights, lod, models: Object.freeze([...models]), models_map: map });
  if (map === null) {
    if (models.length) throw new InputError('several models need a model map saying which goes where', 'models_map');
    return options;
  }
  if (!(map?.data instanceof Uint8Array && Array.isArray(map.shape))) {
    throw new InputError('models_map must be a world.ModelMap (ModelMap.of(array))', 'models_map');
  }
  if (arrange !== 'scatter') {
    throw new InputError("a model map places whole objects: it is for a scatter world (blended models' tiles, voxels and "
      + 'heights differ)', 'models_map');
  }
  const named = map.data.findIndex((v) => v > models.length);
  if (named >= 0) {
    const [r, c] = [Math.floor(named / map.shape[1]), named % map.shape[1]];
    throw new InputError(`the model map's pixel for tile (${r}, ${c}) names model ${map.data[named]}, and the world has `
      + `${models.length + 1} (0 to ${models.length})`, 'models_map');
  }
  return options;
}

const PLAIN = worldOptions();

/** The level a tile of `lod` reads its detail from, as world.check_lod. */
function checkLod(manifest, lod) {
  const levels = manifest.sizes.length;
  if (lod >= levels) throw new InputError(`lod must be 0 to ${levels - 1} (the model has ${levels} levels), got ${lod}`, 'lod');
  return levels - 1 - lod;
}

// ---- windows and objects

/** Every level's size of a window (blend) or an object (scatter), as world.window_sizes. */
const windowSizes = (manifest, layout, arrange) => scaledSizes(manifest.sizes, arrange === 'blend' ? layout.factors : [1, 1, 1]);

// Windows kept for the next tiles (a tile shares each of its four with a
// neighbour; a view of 7 x 7 tiles made nearest first, or a row of them
// made as the view moves, reuses all it can with 64), and a format-5
// model's windows' colourings likewise. A cache, not state: a window is the
// same array, and its colouring the same matches, whether made or found.
export const WINDOWS_KEPT = 64; // world.WINDOWS_KEPT
let modelCount = 0;
const windows = new Map(); // "model|seed|arrange|level|a|b" -> a promise of the window, oldest use first
const colourings = new Map(); // "model|seed|arrange|a|b" -> a promise of the window's colouring, oldest use first
const modelIds = new WeakMap(); // model -> a number naming it in the keys

/** What `cache` keeps under "model|key" (a promise), else make() kept there; the oldest use dropped past WINDOWS_KEPT. */
function kept(cache, model, key, make) {
  if (!modelIds.has(model)) modelIds.set(model, ++modelCount);
  key = `${modelIds.get(model)}|${key}`;
  let made = cache.get(key);
  if (made) {
    cache.delete(key); // to the end: the newest use
  } else {
    made = make();
    made.catch(() => cache.delete(key)); // a failure is not kept
  }
  cache.set(key, made);
  while (cache.size > WINDOWS_KEPT) cache.delete(cache.keys().next().value);
  return made;
}

/**
 * Window (a, b) (or scatter cell (a, b)'s object), its chain stopped at
 * `level`, as world.window: { planes: 3 x { data, dims: [H, W, D] } (times
 * the decoder's first layer), mean: (U, D) its mean over its horizontal
 * extent at each height, cells: [3] level cells per finest voxel, chain: the
 * generator's planes at the level, which a finer level of it goes on from }.
 */
export function windowAt(model, layout, seed, a, b, level, arrange) {
  const named = (l) => `${seed}|${arrange}|${l}|${a}|${b}`;
  return kept(windows, model, named(level), async () => {
    const sizes = windowSizes(model.manifest, layout, arrange).slice(0, level + 1);
    // A coarser level of the window made before (a far tile come nearer) is gone on
    // from: the same planes as the whole chain, the levels below not run again.
    let start = null;
    for (let coarser = level - 1; coarser >= 0 && !start; coarser--) {
      const found = windows.get(`${modelIds.get(model)}|${named(coarser)}`);
      if (found) start = { level: coarser, planes: (await found).chain };
    }
    const noise = drawNoise(windowSeed(seed, a, b), sizes, model.manifest.channels, start ? start.level + 1 : 0);
    const tri = await triplane(model, noise, sizes, undefined, start);
    const { planes } = await project(model, tri);
    return { planes, mean: windowMean(planes, layout, sizes[level][layout.up], model.manifest.hidden), chain: tri.planes,
             cells: [0, 1, 2].map((axis) => (sizes[level][axis] - 1) / (windowSizes(model.manifest, layout, arrange).at(-1)[axis] - 1)) };
  });
}

/**
 * A format-5 window's (or object's) colour at points in its finest cells, as
 * world.window_colouring: its own sample's colour by correspondence
 * (colour.js's planesColouring on its finest planes), matched once and kept.
 * A promise of (cells Float64Array (n, 3), footprint) -> Float32Array (n, 3) sRGB.
 */
export function windowColouring(model, layout, seed, a, b, arrange) {
  return kept(colourings, model, `${seed}|${arrange}|${a}|${b}`, async () => {
    const { planesColouring } = await import('./colour.js'); // not before it is needed: the page imports this module
    const found = await windowAt(model, layout, seed, a, b, model.manifest.sizes.length - 1, arrange);
    return planesColouring(model, found.planes, windowSizes(model.manifest, layout, arrange).at(-1));
  });
}

/** A window's mean hidden sum at each of its heights: Float32Array (U, D), as world.window's. */
function windowMean(planes, layout, heights, d) {
  const mean = new Float64Array(heights * d);
  planes.forEach((plane, k) => {
    const [r, c] = PLANE_AXES[k], [h, w] = plane.dims, src = plane.data;
    if (r !== layout.up && c !== layout.up) {
      const flat = new Float64Array(d);
      for (let p = 0; p < h * w; p++) for (let e = 0; e < d; e++) flat[e] += src[p * d + e];
      for (let u = 0; u < heights; u++) for (let e = 0; e < d; e++) mean[u * d + e] += Math.fround(flat[e] / (h * w));
    } else {
      const upFirst = r === layout.up, along = upFirst ? w : h;
      for (let u = 0; u < heights; u++) {
        for (let e = 0; e < d; e++) {
          let sum = 0;
          for (let n = 0; n < along; n++) sum += src[(upFirst ? u * w + n : n * w + u) * d + e];
          mean[u * d + e] += Math.fround(sum / along);
        }
      }
    }
  });
  return Float32Array.from(mean);
}

/** BigInt floor division (BigInt's own truncates towards zero). */
const floorDiv = (a, b) => (a % b !== 0n && (a < 0n) !== (b < 0n) ? a / b - 1n : a / b);

/** Scatter cell (a, b)'s draws, as world.scatter_cell: { present, offset: [2], mirror: [2] }. */
function scatterCell(seed, a, b, room) {
  const mask = (1n << 64n) - 1n;
  const key = streamKey(seed, SCATTER_STREAM, BigInt.asUintN(64, a), BigInt.asUintN(64, b));
  const draw = [0n, 1n, 2n, 3n].map((n) => mix64Big((key + GOLDEN * (n + 1n)) & mask));
  return { present: (draw[0] >> 11n) < BigInt(PRESENCE * 2 ** 53), offset: [Number(draw[1] % BigInt(room[0] + 1)), Number(draw[2] % BigInt(room[1] + 1))],
           mirror: [(draw[3] & 1n) !== 0n, (draw[3] & 2n) !== 0n] };
}

/** A scattered world's model `index` (0 the first, `model`) and its own cut, as world.object_model: [model, layout]. */
function objectModel(model, options, index) {
  if (!index) return [model, worldLayout(model.manifest)];
  const other = options.models[index - 1];
  try {
    return [other, worldLayout(other.manifest)];
  } catch (error) {
    if (error instanceof InputError) throw new InputError(`model ${index} of the world: ${error.message}`, 'models');
    throw error;
  }
}

/**
 * A scatter world's cell side per horizontal axis (PITCH strides, or room for
 * its largest model's objects and half a stride) and each model's object
 * extent E - 1 along the world's two horizontal axes, as world.scatter_geometry: [pitch, extents].
 */
function scatterGeometry(model, layout, options) {
  const extents = [];
  for (let index = 0; index <= options.models.length; index++) {
    const [each, own] = objectModel(model, options, index), finest = each.manifest.sizes.at(-1);
    extents.push([finest[own.horizontal[0]] - 1, finest[own.horizontal[1]] - 1]);
  }
  const pitch = layout.horizontal.map((h, n) => Math.max(PITCH * layout.stride[h], Math.max(...extents.map((extent) => extent[n]))
    + Math.floor(layout.stride[h] / 2)));
  return [pitch, extents];
}

/**
 * An object's model, that model's cut, and the object's planes at the first
 * model's `level` (in the object's model, as many levels from its finest, or
 * its coarsest), as world.object_window: [model, layout, window].
 */
async function objectWindow(model, options, seed, placed, level) {
  const [each, own] = objectModel(model, options, placed.model);
  level = Math.max(each.manifest.sizes.length - model.manifest.sizes.length + level, 0);
  return [each, own, await windowAt(each, own, seed, ...placed.cell, level, 'scatter')];
}

/**
 * The objects of a scatter world that reach into tile (i, j), in a fixed
 * order, as world.objects_near (their planes not made): each from the model
 * its cell's centre's pixel of the model map names.
 */
function objectsNear(model, layout, seed, [i, j], level, options) {
  const { heights, models_map: map } = options, [h0, h1] = layout.horizontal;
  const [pitch, extents] = scatterGeometry(model, layout, options);
  const [p0, p1] = pitch.map(BigInt), s0 = BigInt(layout.stride[h0]), s1 = BigInt(layout.stride[h1]);
  const found = [];
  for (let a = floorDiv(i * s0, p0) - 1n; a < floorDiv((i + 1n) * s0, p0) + 1n; a++) {
    for (let b = floorDiv(j * s1, p1) - 1n; b < floorDiv((j + 1n) * s1, p1) + 1n; b++) {
      const index = map === null ? 0 : ModelMap.at(map, floorDiv(2n * a * p0 + p0, 2n * s0), floorDiv(2n * b * p1 + p1, 2n * s1)); // exact, anywhere
      const [e0, e1] = extents[index];
      const cell = scatterCell(seed, a, b, [Number(p0) - e0, Number(p1) - e1]);
      const low = [a * p0 + BigInt(cell.offset[0]), b * p1 + BigInt(cell.offset[1])];
      if (!cell.present || low[0] > (i + 1n) * s0 || low[0] + BigInt(e0) < i * s0 || low[1] > (j + 1n) * s1
          || low[1] + BigInt(e1) < j * s1) continue;
      const height = heights === null ? 0 : objectHeight(heights, layout, low, [e0, e1]);
      found.push({ cell: [a, b], corner: [Number(low[0] - i * s0), Number(low[1] - j * s1)], extent: [e0, e1], mirror: cell.mirror, height,
                   model: index });
    }
  }
  return found;
}

// ---- the height map, read anywhere

/** The uniform cubic B-spline's four weights at a fraction t, as world.spline_weights. */
function splineWeights(t) {
  const s = 1 - t;
  return [s * s * s / 6, (3 * t * t * t - 6 * t * t + 4) / 6, (-3 * t * t * t + 3 * t * t + 3 * t + 1) / 6, t * t * t / 6];
}

/** Where a point u voxels past tile `tile`'s corner falls among `count` pixels, clamped, as world.map_coordinates. */
function mapCoordinate(count, tile, u, stride) {
  const near = Number(tile < -4n ? -4n : tile > BigInt(count + 4) ? BigInt(count + 4) : tile);
  return Math.min(Math.max((near - 0.5) + u / stride, -2), count + 1);
}

/** The map's cubic B-spline at map coordinates (q0, q1), summed in world.spline's order. */
function spline(map, q0, q1) {
  const [rows, cols] = map.shape, b0 = Math.floor(q0), b1 = Math.floor(q1);
  const w0 = splineWeights(q0 - b0), w1 = splineWeights(q1 - b1);
  let out = 0;
  for (let m = 0; m < 4; m++) {
    const r = Math.min(Math.max(b0 + m - 1, 0), rows - 1);
    let row = 0;
    for (let n = 0; n < 4; n++) row += w1[n] * map.data[r * cols + Math.min(Math.max(b1 + n - 1, 0), cols - 1)];
    out += w0[m] * row;
  }
  return out;
}

/** The map's height at a point of tile [i, j] (u0, u1 voxels from its corner), as world.map_heights. */
const mapHeight = (map, layout, u0, u1, [i, j]) => spline(map, mapCoordinate(map.shape[0], i, u0, layout.stride[layout.horizontal[0]]),
  mapCoordinate(map.shape[1], j, u1, layout.stride[layout.horizontal[1]]));

/** The map's height under an object's centre (its lowest corner `low` in world voxels, BigInts), as world.object_height. */
function objectHeight(map, layout, low, extent) {
  const q = low.map((c, k) => Math.min(Math.max(Number(2n * c + BigInt(extent[k])) / (2 * layout.stride[layout.horizontal[k]]) - 0.5, -2), map.shape[k] + 1));
  return spline(map, q[0], q[1]);
}

// ---- a tile's grid and field

const smoothstep = (f) => f * f * (3 - 2 * f);
/** The weight of the window behind a point u voxels past its lattice point, as world.behind_weight (in float32). */
function behindWeight(u, stride) {
  const f = Math.min(Math.max((u - PLATEAU) / (stride - 2 * PLATEAU), 0), 1);
  return Math.fround(smoothstep(Math.min(Math.max((f - 0.5) / BLEND + 0.5, 0), 1)));
}

/**
 * A tile's grid at `scale` and `lod`, as world.tile_grid: per model axis the
 * positions (horizontal: from the tile's corner; up: from the floor, to the
 * world's tallest model's top).
 */
function tileGrid(model, layout, scale, options) {
  const { sizes } = model.manifest, level = checkLod(model.manifest, options.lod);
  return [0, 1, 2].map((axis) => {
    const ratio = (sizes[level][axis] - 1) / (sizes.at(-1)[axis] - 1), stride = layout.stride[axis];
    if (axis === layout.up) {
      const m = Math.max(2, roundHalfEven((stride + 1) * scale * ratio)), step = stride / (m - 1);
      const [low, mapped] = options.heights ? HeightMap.bounds(options.heights) : [0, 0];
      const cuts = options.models.map((_, k) => objectModel(model, options, k + 1)[1]);
      const high = mapped + Math.max(0, ...cuts.map((cut) => cut.stride[cut.up] - stride)); // a taller model's objects
      const count = m + Math.ceil((high - low) / step);
      return Float64Array.from({ length: count }, (_, k) => low + k * step);
    }
    const m = Math.max(1, roundHalfEven(stride * scale * ratio));
    return Float64Array.from({ length: m + 1 }, (_, p) => (p * stride) / m); // exact at the faces: m S / m = S
  });
}

/** A tile of a world, (i, j): two integers of magnitude below 2**62, as world.check_tile; frozen BigInts. */
export function checkTile(tile) {
  const whole = (t) => typeof t === 'bigint' || Number.isInteger(t);
  if (!(Array.isArray(tile) && tile.length === 2 && tile.every((t) => whole(t) && -MAX_TILE < BigInt(t) && BigInt(t) < MAX_TILE))) {
    throw new InputError(`tile must be two integers (i, j) of magnitude below 2**62, got ${pyRepr(tile)}`, 'tile');
  }
  return Object.freeze(tile.map(BigInt));
}

/** A tile's grid refused where it is too large for the page, as world.check_world_scale. */
function checkGrid(grid, scale, hidden) {
  if (!(typeof scale === 'number' && scale > 0 && scale < Infinity)) throw new InputError(`scale must be a positive number, got ${scale}`, 'scale');
  const points = grid.map((p) => p.length);
  if (Math.max(...points) > MAX_POINTS) {
    throw new InputError(`scale ${formatG(scale)} makes a tile of ${points.join('x')} points; at most ${MAX_POINTS} per axis`, 'scale');
  }
  const bytes = points[0] * points[1] * points[2] * 4 + 4 * hidden * 4 * PLANE_AXES.reduce((n, [a, b]) => n + points[a] * points[b], 0);
  if (bytes > TAB_BYTES) throw new InputError(`a ${points.join('x')} tile needs more memory than a page should take`, 'scale');
}

/** Per position, the two cells around it and the weight of the upper one, as world.along's. */
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
 * A window's planes read on a tile's grid, as world.hidden_on_grid does
 * before its reads along up: the horizontal plane at every (c0, c1),
 * (X, Y, D); each vertical plane along its horizontal axis, (N, U, D), with
 * which of the two grid axes N runs along.
 */
function readPlanes(found, layout, c0, c1) {
  const [h0, h1] = layout.horizontal, cells = { [h0]: c0, [h1]: c1 };
  let flat = null;
  const vertical = [];
  found.planes.forEach((plane, k) => {
    const [r, c] = PLANE_AXES[k], [h, w, d] = plane.dims, src = plane.data;
    if (r !== layout.up && c !== layout.up) { // the horizontal plane: (rows, cols, D), then (X, Y, D)
      const rows = cells[r], cols = cells[c], tr = taps(rows, h), tc = taps(cols, w);
      const along = new Float32Array(rows.length * w * d);
      for (let i = 0; i < rows.length; i++) {
        const a0 = tr.low[i] * w * d, a1 = tr.high[i] * w * d, f = tr.frac[i], at = i * w * d;
        for (let t = 0; t < w * d; t++) along[at + t] = src[a0 + t] * (1 - f) + src[a1 + t] * f;
      }
      const swap = r !== h0, nx = swap ? cols.length : rows.length, ny = swap ? rows.length : cols.length;
      flat = { data: new Float32Array(nx * ny * d), ny };
      for (let i = 0; i < rows.length; i++) {
        for (let j = 0; j < cols.length; j++) {
          const b0 = (i * w + tc.low[j]) * d, b1 = (i * w + tc.high[j]) * d, f = tc.frac[j];
          const at = (swap ? j * ny + i : i * ny + j) * d;
          for (let e = 0; e < d; e++) flat.data[at + e] = along[b0 + e] * (1 - f) + along[b1 + e] * f;
        }
      }
    } else { // a vertical plane: along its horizontal axis, (N, U, D)
      const upFirst = r === layout.up, hAxis = upFirst ? c : r, positions = cells[hAxis];
      const t = taps(positions, upFirst ? w : h), count = upFirst ? h : w;
      const data = new Float32Array(positions.length * count * d);
      for (let n = 0; n < positions.length; n++) {
        const f = t.frac[n];
        for (let u = 0; u < count; u++) {
          const a0 = (upFirst ? u * w + t.low[n] : t.low[n] * w + u) * d, a1 = (upFirst ? u * w + t.high[n] : t.high[n] * w + u) * d;
          const at = (n * count + u) * d;
          for (let e = 0; e < d; e++) data[at + e] = src[a0 + e] * (1 - f) + src[a1 + e] * f;
        }
      }
      vertical.push({ data, count, alongFirst: hAxis === h0 });
    }
  });
  return { flat, vertical };
}

/** Adds a (N, U, D) read's value at row n, height cell z (linear, as world.along_up), times `scale`, into out. */
function addUp(read, n, z, out, scale = 1) {
  const { data, count } = read, d = out.length;
  const low = Math.min(Math.max(Math.floor(z), 0), Math.max(count - 2, 0)), high = Math.min(low + 1, count - 1), f = Math.fround(z - low);
  const a = (n * count + low) * d, b = (n * count + high) * d;
  for (let e = 0; e < d; e++) out[e] += scale * (data[a + e] * (1 - f) + data[b + e] * f);
}

/** w2 . relu(h + b1) + b2 over the hidden width, in order, as world.head_logits. */
function headLogit({ bias1, weight2, bias2 }, hidden) {
  let s = bias2;
  for (let c = 0; c < hidden.length; c++) {
    const h = hidden[c] + bias1[c];
    if (h > 0) s += h * weight2[c];
  }
  return s;
}

/** A logit read above a window's top cut by a ceiling half a voxel up, as world.capped. */
const capped = (logit, above) => (above > 0 ? Math.min(logit, -GROUND_SLOPE * (above - 0.5)) : logit);

/** Tile (i, j)'s four windows in the order of the sum, with their offsets and which is behind along each axis, as world.blend_sources. */
async function blendSources(model, layout, seed, [i, j], level) {
  const [h0, h1] = layout.horizontal, sources = [];
  for (const [a, b] of [[i - 1n, j - 1n], [i - 1n, j], [i, j - 1n], [i, j]]) {
    sources.push({ window: await windowAt(model, layout, seed, a, b, level, 'blend'),
                   offset: [a < i ? layout.stride[h0] : 0, b < j ? layout.stride[h1] : 0], behind: [a === i, b === j] });
  }
  return sources;
}

/**
 * The head's logits on tile (i, j)'s grid, as world.tile_logits: { data:
 * Float32Array in the model's axes (X, Y, Z), C order, shape }.
 */
async function tileLogits(model, seed, [i, j], scale, options) {
  const { manifest } = model, d = manifest.hidden, layout = worldLayout(manifest), level = checkLod(manifest, options.lod);
  const grid = tileGrid(model, layout, scale, options);
  checkGrid(grid, scale, d);
  const [h0, h1] = layout.horizontal, up = layout.up, top = layout.stride[up];
  const shape = grid.map((p) => p.length), [u0, u1, z] = [grid[h0], grid[h1], grid[up]];
  const out = new Float32Array(shape[0] * shape[1] * shape[2]);
  const strides = [shape[1] * shape[2], shape[2], 1], sx = strides[h0], sy = strides[h1], sk = strides[up]; // tile order -> C order
  const nx = u0.length, ny = u1.length, nk = z.length;
  const rise = new Float64Array(nx * ny);
  if (options.heights) for (let x = 0; x < nx; x++) for (let y = 0; y < ny; y++) rise[x * ny + y] = mapHeight(options.heights, layout, u0[x], u1[y], [i, j]);
  if (options.arrange === 'scatter') {
    for (let x = 0; x < nx; x++) for (let y = 0; y < ny; y++) for (let k = 0; k < nk; k++) out[x * sx + y * sy + k * sk] = -GROUND_SLOPE * (z[k] - rise[x * ny + y] - GROUND);
    for (const placed of objectsNear(model, layout, seed, [i, j], level, options)) {
      await scatterInto(out, [sx, sy, sk], model, options, seed, level, placed, u0, u1, z);
    }
    return { data: out, shape };
  }
  const sources = await blendSources(model, layout, seed, [i, j], level);
  const reads = sources.map((s) => readPlanes(s.window, layout, u0.map((u) => (u + s.offset[0]) * s.window.cells[h0]),
    u1.map((u) => (u + s.offset[1]) * s.window.cells[h1])));
  const weights = sources.map((s) => [u0.map((u) => { const w = behindWeight(u, layout.stride[h0]); return s.behind[0] ? w : Math.fround(1 - w); }),
    u1.map((u) => { const w = behindWeight(u, layout.stride[h1]); return s.behind[1] ? w : Math.fround(1 - w); })]);
  // Every window of a tile is read at one level, so the four share their cells along up: each
  // point's two cells and weight along up are found once. Per window: its planes read along x and y.
  const cellsUp = sources[0].window.cells[up], count = reads[0].vertical[0].count, means = sources.map((s) => s.window.mean);
  const alongX = reads.map((r) => r.vertical.find((v) => v.alongFirst).data), alongY = reads.map((r) => r.vertical.find((v) => !v.alongFirst).data);
  const flats = reads.map((r) => r.flat.data);
  const hidden = new Float64Array(d), meanSum = new Float64Array(d), deviation = new Float64Array(d);
  for (let x = 0; x < nx; x++) {
    for (let y = 0; y < ny; y++) {
      const lift = rise[x * ny + y];
      for (let k = 0; k < nk; k++) {
        const cell = Math.min(Math.max(z[k] - lift, 0), top) * cellsUp;
        const low = Math.min(Math.max(Math.floor(cell), 0), Math.max(count - 2, 0)), high = Math.min(low + 1, count - 1);
        const f = Math.fround(cell - low), g = 1 - f;
        meanSum.fill(0);
        deviation.fill(0);
        let squares = 0;
        for (let n = 0; n < sources.length; n++) {
          const w = weights[n][0][x] * weights[n][1][y], flat = flats[n], ax = alongX[n], ay = alongY[n], mean = means[n];
          const at = (x * ny + y) * d, a0 = (x * count + low) * d, a1 = (x * count + high) * d;
          const b0 = (y * count + low) * d, b1 = (y * count + high) * d, m0 = low * d, m1 = high * d;
          for (let e = 0; e < d; e++) {
            const part = flat[at + e] + (ax[a0 + e] * g + ax[a1 + e] * f) + (ay[b0 + e] * g + ay[b1 + e] * f);
            const centre = mean[m0 + e] * g + mean[m1 + e] * f;
            meanSum[e] += w * centre;
            deviation[e] += w * (part - centre);
          }
          squares += w * w;
        }
        const scaleBy = squares ** (-model.manifest.contrast / 2);
        for (let e = 0; e < d; e++) hidden[e] = meanSum[e] + deviation[e] * scaleBy;
        out[x * sx + y * sy + k * sk] = capped(headLogit(model.head, hidden), z[k] - lift - top);
      }
    }
  }
  return { data: out, shape };
}

/**
 * One object's logits where they are the largest yet, on the part of a
 * tile's grid inside its box, as world.scatter_into: `out` in C order,
 * `strides` its steps along the tile's axes (h0, h1, up).
 */
async function scatterInto(out, [sx, sy, sk], model, options, seed, level, placed, u0, u1, z) {
  const inside = [u0, u1].map((u, k) => {
    const chosen = [], cells = [];
    u.forEach((at, n) => {
      const position = at - placed.corner[k];
      if (position >= 0 && position <= placed.extent[k]) { chosen.push(n); cells.push(placed.mirror[k] ? placed.extent[k] - position : position); }
    });
    return { chosen, cells };
  });
  if (!inside[0].chosen.length || !inside[1].chosen.length) return;
  const [each, own, found] = await objectWindow(model, options, seed, placed, level);
  const [h0, h1] = own.horizontal, up = own.up, top = own.stride[up], d = each.manifest.hidden; // the object's axes, along the world's
  const c0 = Float64Array.from(inside[0].cells, (c) => c * found.cells[h0]), c1 = Float64Array.from(inside[1].cells, (c) => c * found.cells[h1]);
  const read = readPlanes(found, own, c0, c1), m1 = inside[1].chosen.length, hidden = new Float64Array(d);
  inside[0].chosen.forEach((x, n0) => inside[1].chosen.forEach((y, n1) => {
    for (let k = 0; k < z.length; k++) {
      const cell = Math.min(Math.max(z[k] - placed.height, 0), top) * found.cells[up];
      for (let e = 0; e < d; e++) hidden[e] = read.flat.data[(n0 * m1 + n1) * d + e];
      for (const v of read.vertical) addUp(v, v.alongFirst ? n0 : n1, cell, hidden);
      const logit = capped(headLogit(each.head, hidden), z[k] - placed.height - top), where = x * sx + y * sy + k * sk;
      if (logit > out[where]) out[where] = logit;
    }
  }));
}

/**
 * Occupancy on tile (i, j)'s grid, as world.tile_occupancy: { data:
 * Float32Array (X, Y, Z) in C order, shape }, its points along each
 * horizontal axis from the tile's lattice point to the next (both included:
 * the faces it shares), along up the world's heights.
 */
export async function tileOccupancy(model, seed, tile, scale = 1, options = PLAIN) {
  seed = checkSeed(seed);
  const logits = await tileLogits(model, seed, checkTile(tile), scale, options);
  return { data: logits.data.map((s) => 1 / (1 + Math.exp(-s))), shape: logits.shape };
}

// ---- the field at any points of a tile

/**
 * The logits and hidden vectors at points of tile (i, j) (voxels from its
 * corner along the horizontal axes, from the floor along up), each read in
 * the tile it falls in, as world.point_field: { logits: Float64Array (n),
 * hidden: Float64Array (n, D), ground: Uint8Array (n) }. With an array
 * `sources`, also what each point reads most, as point_field's: per window
 * or object, { window: [a, b, arrange, model], index: Int32Array of points, cells:
 * Float64Array (m, 3) theirs in it }; a blend's window that weighs most (its
 * float32 weight, as numpy's; the first of equals in the order of the sum),
 * a scatter world's object whose logit won (none on the ground).
 */
export async function pointField(model, seed, [i, j], points, options, sources = null) {
  const { manifest } = model, d = manifest.hidden, layout = worldLayout(manifest), level = checkLod(manifest, options.lod);
  const [h0, h1] = layout.horizontal, up = layout.up, top = layout.stride[up], n = points.length / 3, width = hiddenWidth(model, options);
  const logits = new Float64Array(n), hidden = new Float64Array(n * width), ground = new Uint8Array(n);
  const groups = new Map(); // "t0,t1" -> point indices
  for (let p = 0; p < n; p++) {
    const key = `${Math.floor(points[3 * p + h0] / layout.stride[h0])},${Math.floor(points[3 * p + h1] / layout.stride[h1])}`;
    if (!groups.has(key)) groups.set(key, []);
    groups.get(key).push(p);
  }
  const at = [0, 0, 0], cell = [0, 0, 0], part = new Float64Array(d), total = new Float64Array(d), deviation = new Float64Array(d);
  for (const key of [...groups.keys()].sort()) {
    const [t0, t1] = key.split(',').map(Number), tile = [i + BigInt(t0), j + BigInt(t1)], members = groups.get(key);
    const local = (p, axis) => points[3 * p + axis] - (axis === h0 ? t0 * layout.stride[h0] : axis === h1 ? t1 * layout.stride[h1] : 0);
    // Only the windows or objects some point of the group reads are made: a point just past a face
    // reads the face's own windows alone (PLATEAU), so a tile's normals make none of its neighbour's.
    const found = [];
    if (options.arrange === 'scatter') {
      for (const placed of objectsNear(model, layout, seed, tile, level, options)) {
        const reads = members.some((p) => [h0, h1].every((axis, k) => { const position = local(p, axis) - placed.corner[k]; return position >= 0 && position <= placed.extent[k]; }));
        if (!reads) continue;
        const [each, own, window] = await objectWindow(model, options, seed, placed, level);
        found.push({ ...placed, each, own, window, part: new Float64Array(each.manifest.hidden) });
      }
    } else {
      for (const [a, b] of [[tile[0] - 1n, tile[1] - 1n], [tile[0] - 1n, tile[1]], [tile[0], tile[1] - 1n], [tile[0], tile[1]]]) {
        const behind = [a === tile[0], b === tile[1]];
        const weighs = members.some((p) => [h0, h1].every((axis, k) => { const w = behindWeight(local(p, axis), layout.stride[axis]); return (behind[k] ? w : Math.fround(1 - w)) !== 0; }));
        if (weighs) {
          found.push({ window: await windowAt(model, layout, seed, a, b, level, 'blend'), behind, cell: [a, b], model: 0,
                       offset: [behind[0] ? 0 : layout.stride[h0], behind[1] ? 0 : layout.stride[h1]] });
        }
      }
    }
    // Per member, the source it reads most (an index into found, -1: none) and its cells there.
    const owner = sources && new Int32Array(members.length).fill(-1), ownerCells = sources && new Float64Array(3 * members.length);
    for (const [m, p] of members.entries()) {
      for (let a = 0; a < 3; a++) at[a] = points[3 * p + a];
      at[h0] -= t0 * layout.stride[h0]; // exact: a power-of-two step from an integer
      at[h1] -= t1 * layout.stride[h1];
      const rise = options.heights ? mapHeight(options.heights, layout, at[h0], at[h1], tile) : 0;
      if (options.arrange === 'scatter') {
        logits[p] = -GROUND_SLOPE * (at[up] - rise - GROUND);
        ground[p] = 1;
        for (const [n, placed] of found.entries()) {
          const { each, own, window: win, part } = placed, ownTop = own.stride[own.up];
          let inside = true;
          own.horizontal.forEach((axis, k) => { // the object's axes, along the world's
            const position = at[layout.horizontal[k]] - placed.corner[k];
            inside &&= position >= 0 && position <= placed.extent[k];
            cell[axis] = (placed.mirror[k] ? placed.extent[k] - position : position) * win.cells[axis];
          });
          if (!inside) continue;
          cell[own.up] = Math.min(Math.max(at[up] - placed.height, 0), ownTop) * win.cells[own.up];
          part.fill(0);
          PLANE_AXES.forEach(([a, b], k) => addBilinear(win.planes[k], cell[a], cell[b], part));
          const logit = capped(headLogit(each.head, part), at[up] - placed.height - ownTop);
          if (logit > logits[p]) {
            logits[p] = logit; ground[p] = 0;
            hidden.fill(0, p * width, p * width + width); // a narrower model's vector leaves the rest zero
            hidden.set(part, p * width);
            if (sources) { owner[m] = n; ownerCells.set(cell, 3 * m); }
          }
        }
        continue;
      }
      const height = Math.min(Math.max(at[up] - rise, 0), top);
      const behind0 = behindWeight(at[h0], layout.stride[h0]), behind1 = behindWeight(at[h1], layout.stride[h1]);
      total.fill(0);
      deviation.fill(0);
      let squares = 0, heaviest = -1;
      for (const [n, s] of found.entries()) {
        const { window: win, offset } = s;
        const w = (s.behind[0] ? behind0 : Math.fround(1 - behind0)) * (s.behind[1] ? behind1 : Math.fround(1 - behind1));
        cell[h0] = (at[h0] + offset[0]) * win.cells[h0];
        cell[h1] = (at[h1] + offset[1]) * win.cells[h1];
        cell[up] = height * win.cells[up];
        if (sources && Math.fround(w) > heaviest) { heaviest = Math.fround(w); owner[m] = n; ownerCells.set(cell, 3 * m); }
        part.fill(0);
        for (let k = 0; k < 3; k++) addBilinear(win.planes[k], cell[PLANE_AXES[k][0]], cell[PLANE_AXES[k][1]], part);
        const count = win.mean.length / d, low = Math.min(Math.max(Math.floor(cell[up]), 0), Math.max(count - 2, 0));
        const high = Math.min(low + 1, count - 1), f = Math.fround(cell[up] - low), m0 = low * d, m1 = high * d;
        for (let e = 0; e < d; e++) {
          const centre = win.mean[m0 + e] * (1 - f) + win.mean[m1 + e] * f;
          total[e] += w * centre;
          deviation[e] += w * (part[e] - centre);
        }
        squares += w * w;
      }
      const scaleBy = squares ** (-model.manifest.contrast / 2);
      for (let e = 0; e < d; e++) hidden[p * d + e] = total[e] + deviation[e] * scaleBy;
      logits[p] = capped(headLogit(model.head, hidden.subarray(p * d, p * d + d)), at[up] - rise - top);
    }
    if (!sources) continue;
    found.forEach((s, n) => {
      const chosen = members.flatMap((p, m) => (owner[m] === n ? [m] : []));
      sources.push({ window: [...s.cell, options.arrange, s.model], index: Int32Array.from(chosen, (m) => members[m]),
                     cells: Float64Array.from({ length: 3 * chosen.length }, (_, k) => ownerCells[3 * chosen[Math.floor(k / 3)] + k % 3]) });
    });
  }
  return { logits, hidden, ground };
}

/**
 * Unit normals at a tile's vertices (positions as tileMesh gives them), as
 * world.tile_normals: the field's gradient by differences over NORMAL_STEP
 * voxels along each axis, out of the solid. Float32Array (V, 3).
 */
export async function tileNormals(model, seed, tile, positions, options = PLAIN) {
  seed = checkSeed(seed);
  const step = NORMAL_STEP, n = positions.length / 3, probes = new Float64Array(12 * n);
  for (let v = 0; v < n; v++) {
    for (let k = 0; k < 4; k++) for (let a = 0; a < 3; a++) probes[12 * v + 3 * k + a] = positions[3 * v + a] + (k === a + 1 ? step : 0);
  }
  const { logits } = await pointField(model, seed, checkTile(tile), probes, options);
  const up = worldLayout(model.manifest).up, normals = new Float32Array(3 * n);
  for (let v = 0; v < n; v++) {
    const g = [1, 2, 3].map((k) => logits[4 * v + k] - logits[4 * v]), length = Math.hypot(...g);
    for (let a = 0; a < 3; a++) normals[3 * v + a] = length > 0 ? -g[a] / length : a === up ? 1 : 0;
  }
  return normals;
}

/** Some vertices' colours (`index`: their numbers; out, in place) made the example's nearest: each as
 * Python's bytes (mesh.colour_bytes: clipped, times 255 in float32, rounded half to even), then colour.js's
 * nearestInPalette, once per distinct colour. */
async function snapToExample(tiles, out, index) {
  const { examplePalette, nearestInPalette } = await import('./colour.js');
  const palette = examplePalette(tiles), found = new Map();
  const byte = (x) => roundHalfEven(Math.fround(Math.min(Math.max(x, 0), 1) * 255));
  for (const v of index) {
    const [r, g, b] = [byte(out[3 * v]), byte(out[3 * v + 1]), byte(out[3 * v + 2])], key = (r << 16) | (g << 8) | b;
    if (!found.has(key)) found.set(key, nearestInPalette(palette, r, g, b));
    const p = found.get(key);
    out[3 * v] = (p >> 16) / 255;
    out[3 * v + 1] = ((p >> 8) & 255) / 255;
    out[3 * v + 2] = (p & 255) / 255;
  }
}

/**
 * A coloured model's sRGB colour at a tile's mesh vertices (tileMesh's
 * positions), as world.tile_colours: a format-5 model's read from the
 * example by correspondence in the window that weighs most there (a scatter
 * world's: in the object there), each the colour around it (`footprint`
 * voxels: a tile's mesh at `scale`, 1 / scale); a format-4 model's (and a
 * coarser tile's, lod > 0) the colour head of the hidden vector there,
 * blended as the occupancy is, a format-5 model's coarser tile then the
 * example's nearest colour (colour.js's examplePalette: its tiles' means).
 * In a world of several models each object is coloured by its own model (a
 * model without colour is grey). A scatter world's ground is grey. Returns
 * Float32Array (V, 3) in [0, 1] (Python's gives them as bytes).
 */
/** A model's tiles where they hold colour (a coloured format-5 model), else null (relief alone, or none):
 * runtime/load.py's Model.colour_tiles. */
const colourTiles = (model) => (model.manifest.colour ? model.tiles : null);

export async function tileColours(model, seed, tile, positions, options = PLAIN, footprint = null) {
  seed = checkSeed(seed);
  const points = Float64Array.from(positions), n = points.length / 3, out = new Float32Array(3 * n);
  if (!options.models.length && (!colourTiles(model) || options.lod)) {
    const { hidden, ground } = await pointField(model, seed, checkTile(tile), points, options);
    const d = model.manifest.hidden;
    for (let v = 0; v < n; v++) {
      if (ground[v]) out.set(GROUND_COLOUR, 3 * v);
      else headColour(model.head, hidden, v * d, out, 3 * v);
    }
    if (colourTiles(model)) await snapToExample(colourTiles(model), out, Int32Array.from({ length: n }, (_, v) => v).filter((v) => !ground[v]));
    return out;
  }
  // Each vertex its heaviest window's (or its object's) colour, read from the example or its model's head.
  const sources = [], palettes = [], width = hiddenWidth(model, options);
  const { hidden, ground } = await pointField(model, seed, checkTile(tile), points, options, sources);
  for (const { window: [a, b, arrange, k], index, cells } of sources) {
    const [each, own] = objectModel(model, options, k);
    if (!index.length) continue;
    if (colourTiles(each) && !options.lod) {
      const read = (await windowColouring(each, own, seed, a, b, arrange))(cells, footprint);
      index.forEach((v, m) => out.set(read.subarray(3 * m, 3 * m + 3), 3 * v));
    } else if (each.manifest.colour) {
      for (const v of index) headColour(each.head, hidden, v * width, out, 3 * v);
      if (colourTiles(each)) palettes.push([index, colourTiles(each)]);
    } else {
      for (const v of index) out.set(GROUND_COLOUR, 3 * v);
    }
  }
  for (let v = 0; v < n; v++) if (ground[v]) out.set(GROUND_COLOUR, 3 * v);
  for (const [index, tiles] of palettes) await snapToExample(tiles, out, index);
  return out;
}

/** Whether a world's tiles carry colour: any of its models has it, as world.coloured. */
const coloured = (model, options) => [model, ...options.models].some((each) => each.manifest.colour);

/** The hidden vectors' width a world's points hold: its widest model's, as world.hidden_width. */
const hiddenWidth = (model, options) => Math.max(...[model, ...options.models].map((each) => each.manifest.hidden));

// ---- a tile's surface

/**
 * Tile (i, j)'s surface, as world.tile_mesh: { positions: Float32Array (V, 3)
 * in voxels from the tile's lowest corner (along up, from the floor), faces:
 * Uint32Array (F, 3) }. Closed at the top and bottom, open on the four sides
 * it shares with its neighbours, whose border vertices it shares exactly.
 */
export async function tileMesh(model, seed, tile, scale = 1, options = PLAIN) {
  const grid = await tileOccupancy(model, seed, tile, scale, options);
  const layout = worldLayout(model.manifest), positions = tileGrid(model, layout, scale, options);
  const pad = [[0, 0], [0, 0], [0, 0]];
  pad[layout.up] = [1, 1];
  const mesh = marchingCubes(grid, 0.5, null, pad);
  const low = positions[layout.up][0], step = positions[layout.up][1] - positions[layout.up][0];
  for (let v = 0; v < mesh.positions.length; v += 3) {
    for (let axis = 0; axis < 3; axis++) {
      const at = mesh.positions[v + axis] - pad[axis][0];
      mesh.positions[v + axis] = axis === layout.up ? low + at * step
        : (at * layout.stride[axis]) / (grid.shape[axis] - 1); // exact at the faces: m S / m = S
    }
  }
  return { positions: mesh.positions, faces: mesh.faces };
}

/**
 * A tile's mesh with a skirt, as world.skirted: each edge on one of the
 * tile's four sides gets a quad hanging `depth` below it. Returns {
 * positions, faces, source: the vertex each vertex copies }.
 */
function skirted({ positions, faces }, layout, depth) {
  const count = new Map(), key = (a, b) => (a < b ? `${a},${b}` : `${b},${a}`);
  for (let f = 0; f < faces.length; f += 3) {
    for (let k = 0; k < 3; k++) count.set(key(faces[f + k], faces[f + (k + 1) % 3]), (count.get(key(faces[f + k], faces[f + (k + 1) % 3])) ?? 0) + 1);
  }
  const onSide = (a, b) => layout.horizontal.some((axis) => [0, layout.stride[axis]].some((end) => positions[3 * a + axis] === end && positions[3 * b + axis] === end));
  const hanging = new Map(), added = [], extra = [];
  const lower = (v) => {
    if (!hanging.has(v)) { hanging.set(v, positions.length / 3 + added.length); added.push(v); }
    return hanging.get(v);
  };
  for (let f = 0; f < faces.length; f += 3) {
    for (let k = 0; k < 3; k++) {
      const a = faces[f + k], b = faces[f + (k + 1) % 3];
      if (count.get(key(a, b)) === 1 && onSide(a, b)) extra.push(b, a, lower(a), b, lower(a), lower(b));
    }
  }
  const out = new Float32Array(positions.length + 3 * added.length);
  out.set(positions);
  added.forEach((v, n) => {
    for (let axis = 0; axis < 3; axis++) out[positions.length + 3 * n + axis] = positions[3 * v + axis] - (axis === layout.up ? depth : 0);
  });
  const joined = new Uint32Array(faces.length + extra.length);
  joined.set(faces);
  joined.set(extra, faces.length);
  return { positions: out, faces: joined, source: Uint32Array.from({ length: positions.length / 3 + added.length }, (_, k) => (k < positions.length / 3 ? k : added[k - positions.length / 3])) };
}

/**
 * Tile (i, j) as its file holds it, as world.tile_surface: { positions,
 * faces, normals (unit, the field's gradient), colours (a coloured model's,
 * each vertex's standing for 1 / scale voxels, or null) }, and at lod > 0 a
 * skirt SKIRT grid steps deep, its vertices taking the normal and colour of
 * the vertex above.
 */
export async function tileSurface(model, seed, tile, scale = 1, options = PLAIN) {
  const mesh = await tileMesh(model, seed, tile, scale, options);
  let normals = await tileNormals(model, seed, tile, mesh.positions, options);
  let colours = coloured(model, options) ? await tileColours(model, seed, tile, mesh.positions, options, 1 / scale) : null;
  if (!options.lod || !mesh.faces.length) return { ...mesh, normals, colours };
  const layout = worldLayout(model.manifest), grid = tileGrid(model, layout, scale, options);
  const skirt = skirted(mesh, layout, SKIRT * (grid[layout.up][1] - grid[layout.up][0]));
  const copy = (values) => { const out = new Float32Array(3 * skirt.source.length); skirt.source.forEach((v, n) => out.set(values.subarray(3 * v, 3 * v + 3), 3 * n)); return out; };
  normals = copy(normals);
  colours = colours && copy(colours);
  return { positions: skirt.positions, faces: skirt.faces, normals, colours };
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

/** Normals in voxel units turned into a frame's (its spacing may differ per axis), in place, as world.frame_normals. */
export function frameNormals(manifest, normals, frame) {
  if (frame === 'model') return normals;
  for (let v = 0; v < normals.length; v += 3) {
    const n = [0, 1, 2].map((a) => normals[v + a] / manifest.spacing[a]), length = Math.hypot(...n);
    for (let a = 0; a < 3; a++) normals[v + a] = n[a] / length;
  }
  return normals;
}

/** How many windows are kept now, at most WINDOWS_KEPT. */
export const keptWindows = () => windows.size;

/** Forget the windows (and their colourings) kept (the tests' fresh start). */
export function dropWindows() {
  windows.clear();
  colourings.clear();
}
