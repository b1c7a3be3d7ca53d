// A world's part of a sample request, as runtime/world.py checks it
// (docs/WORLDS.md): the tile, the arrangement, the height and model maps,
// the level of detail, and the world's cut of a model (its tiles' stride).
// The page builds its requests with these for either back end; the tiles
// themselves are made by the Python runtime alone (`sinrun serve`'s tile
// route: docs/WEB.md, "One runtime"), so a change to how worlds are made is
// made once.
//
//   const tiling = worldTiling(info);                                   // horizontal axes, up, stride S per axis
//   const options = worldOptions({ arrange: 'scatter', models: ['tower'], models_map: ModelMap.of([0, 1, 1, 0], [2, 2]) });
import { InputError, pyRepr, pyTuple } from './errors.js';
import { OPTION, admits } from './options.js';

export const MAX_TILE = 2n ** 62n; // world.MAX_TILE: |i|, |j| below it
export const MIN_STRIDE = 4; // voxels: a window of fewer than 2 * 4 + 1 along an axis has no room to blend
export const UP_AXIS = { y: 1, z: 2 };
export const ARRANGEMENTS = ['blend', 'scatter']; // world.ARRANGEMENTS
export const MAX_MAP_SIDE = 1 << 12; // world_maps.MAX_MAP_SIDE
export const MAX_RELIEF = 1 << 14; // world_maps.MAX_RELIEF
export const MAX_MODELS = 256; // world_maps.MAX_MODELS: models in one world (a model map's pixel is a byte)

/**
 * The world's cut for a model's manifest ({ sizes, up }), as world.world_tiling:
 * { horizontal: the two horizontal axes, up, stride: [3] voxels per tile (the
 * up axis's entry its whole height - 1), factors: a window's size factors }.
 */
export function worldTiling({ sizes, up: upName = 'y' }) {
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


// ---- the world's options

/** A designer's map of heights in voxels at the centres of tiles (r, c), as world_maps.HeightMap.of: { shape, data: Float32Array }. */
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
 * world_maps.ModelMap.of: a model's index (0 the world's first) per tile (r, c), r
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
};

/**
 * How a world is made and how finely one of its tiles is, checked as
 * world.WorldOptions: { arrange, heights, lod, density and spacing (a
 * scattered world's share of cells holding an object and cell side in
 * tiles), models (a scattered world's
 * models after its first: 1, 2, ...), models_map (a ModelMap: which of them
 * each scatter cell draws its object from) }.
 */
export function worldOptions({ arrange = 'blend', heights = null, lod = 0, density = OPTION.density.default, spacing = OPTION.spacing.default,
  models = [], models_map: map = null } = {}) {
  if (!ARRANGEMENTS.includes(arrange)) throw new InputError(`unknown arrange ${pyRepr(arrange)}; choose ${ARRANGEMENTS.join(' or ')}`, 'arrange');
  for (const [name, value, wanted] of [['density', density, 'above 0 and at most 1'], ['spacing', spacing, `1 to ${OPTION.spacing.high} tiles`]]) {
    if (!(typeof value === 'number' && admits(OPTION[name], value))) throw new InputError(`${name} must be ${wanted}, got ${pyRepr(value)}`, name);
    if (arrange !== 'scatter' && value !== OPTION[name].default) throw new InputError(`${name} places whole objects: it is for a scatter world`, name);
  }
  if (heights !== null && !(heights?.data instanceof Float32Array && Array.isArray(heights.shape))) {
    throw new InputError('heights must be a world_maps.HeightMap (HeightMap.of(array))', 'heights');
  }
  if (!(Number.isInteger(lod) && lod >= 0)) throw new InputError(`lod must be a whole number of levels, 0 or more, got ${pyRepr(lod)}`, 'lod');
  if (!(Array.isArray(models) && models.length < MAX_MODELS)) {
    throw new InputError(`models is a tuple of at most ${MAX_MODELS - 1} models after the first`, 'models');
  }
  const options = Object.freeze({ arrange, heights, lod, density, spacing, models: Object.freeze([...models]), models_map: map });
  if (map === null) {
    if (models.length) throw new InputError('several models need a model map saying which goes where', 'models_map');
    return options;
  }
  if (!(map?.data instanceof Uint8Array && Array.isArray(map.shape))) {
    throw new InputError('models_map must be a world_maps.ModelMap (ModelMap.of(array))', 'models_map');
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


/** A tile of a world, (i, j): two integers of magnitude below 2**62, as world.check_tile; frozen BigInts. */
export function checkTile(tile) {
  const whole = (t) => typeof t === 'bigint' || Number.isInteger(t);
  if (!(Array.isArray(tile) && tile.length === 2 && tile.every((t) => whole(t) && -MAX_TILE < BigInt(t) && BigInt(t) < MAX_TILE))) {
    throw new InputError(`tile must be two integers (i, j) of magnitude below 2**62, got ${pyRepr(tile)}`, 'tile');
  }
  return Object.freeze(tile.map(BigInt));
}
