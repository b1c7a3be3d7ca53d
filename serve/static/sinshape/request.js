// One sample request, as runtime/request.py: which sample (a seed, or the
// training shape), its size, how its surface is made and at most one edit
// (parts kept from other samples, a grown extent, or a layout). Making one
// checks it, field for field as Python's SampleRequest does, with the same
// messages: a bad value is an InputError naming its field, values that do
// not go together a ConflictError naming them all. The page builds one for
// either back end; the worker makes a sample's tri-plane with `make`. A
// tile of a world is the server's to make (world.js checks its fields).
//
//   const request = sampleRequest({ seed: 7n, size: [2, 1, 1], keep: ['3:0%,0%,0%:50%,100%,100%'] });
//   const tri = await make(model, request);                          // as request.make
import { ConflictError, InputError, pyRepr, pyStr, pyTuple } from './errors.js';
import { OPTION, OPTIONS, admits } from './options.js';
import { sample, scaledSizes } from './generate.js';
import { checkPart, compose, grow, parsePart } from './edit.js';
import { fromLayout } from './layout.js';
import { checkTile, worldOptions } from './world.js';

const DEFAULTS = Object.fromEntries(OPTIONS.map(({ name, default: value }) => [name, value]));
const { high: MAX_SMOOTH } = OPTION.smooth, { choices: SMOOTHERS } = OPTION.smoother, { choices: FRAMES } = OPTION.frame;
const MAX_PARTS = OPTION.keep.high; // boxes kept in one sample: each runs a whole chain of its own
const isNumber = (v) => typeof v === 'number';

/** A coarse layout to generate from: a grid (0/1, C order) of `shape`, as request.Layout.of. */
export const Layout = {
  of(grid, shape, resample = false) {
    if (!(Array.isArray(shape) && shape.length === 3 && shape.every((n) => Number.isInteger(n) && n > 0))) {
      throw new InputError(`a layout is a 3-D grid, got shape ${pyTuple(shape)}`, 'layout');
    }
    if (grid?.length !== shape[0] * shape[1] * shape[2]) {
      throw new InputError(`a layout of ${shape.join('x')} cells needs ${shape[0] * shape[1] * shape[2]} values, got ${grid?.length}`, 'layout');
    }
    return Object.freeze({ shape: [...shape], grid: Uint8Array.from(grid, (v) => (v > 0.5 ? 1 : 0)), resample: Boolean(resample) });
  },
};

/** One number for all three axes, or three: numbers passing `valid`, as request.per_axis. */
function perAxis(value, field, valid, wanted) {
  const values = isNumber(value) ? [value, value, value] : value;
  if (!(Array.isArray(values) && values.length === 3 && values.every((v) => isNumber(v) && valid(v)))) {
    throw new InputError(`${field} must be ${wanted}, got ${pyRepr(value)}`, field);
  }
  return Object.freeze([...values]);
}

/** The names of the edits a request gives. */
const edits = (request) => ['keep', 'grow', 'layout'].filter((name) => (name === 'keep' ? request.keep.length : request[name] !== null));

/**
 * The request of `fields` (any of DEFAULTS' names; seed a BigInt or an
 * integer Number, keep a part's text or { seed, low, high }, or a list of
 * them, layout Layout.of's value), checked: a frozen plain object with every
 * field, in request.SampleRequest's form (seed a BigInt or null, size, grow
 * and anchor three numbers).
 */
export function sampleRequest(fields = {}) {
  for (const name of Object.keys(fields)) {
    if (!(name in DEFAULTS)) throw new InputError(`a sample request has no field ${pyRepr(name)}; its fields are ${Object.keys(DEFAULTS).join(', ')}`, name);
  }
  const given = { ...DEFAULTS, ...Object.fromEntries(Object.entries(fields).filter(([, v]) => v !== undefined)) };
  let { seed, scale, smooth, keep, layout } = given;
  if (seed !== null) {
    const whole = typeof seed === 'bigint' || Number.isInteger(seed);
    if (!(whole && BigInt(seed) >= BigInt(OPTION.seed.low) && BigInt(seed) < BigInt(OPTION.seed.high))) throw new InputError(`seed must be an integer in [0, 2**63), got ${pyRepr(seed)}`, 'seed');
    seed = BigInt(seed);
  }
  const size = perAxis(given.size, 'size', (f) => admits(OPTION.size, f), 'one or three positive factors');
  if (!(isNumber(scale) && admits(OPTION.scale, scale))) throw new InputError(`scale must be a positive number, got ${pyStr(scale)}`, 'scale');
  if (!(Number.isInteger(smooth) && smooth >= 0 && smooth <= MAX_SMOOTH)) throw new InputError(`smooth must be 0 to ${MAX_SMOOTH} iterations, got ${pyStr(smooth)}`, 'smooth');
  if (!SMOOTHERS.includes(given.smoother)) throw new InputError(`unknown smoother ${pyRepr(given.smoother)}; choose ${SMOOTHERS.join(' or ')}`, 'smoother');
  if (!FRAMES.includes(given.frame)) throw new InputError(`unknown frame ${pyRepr(given.frame)}; choose ${FRAMES.join(' or ')}`, 'frame');
  for (const option of OPTIONS.filter((o) => o.type === 'bool')) {
    if (typeof given[option.name] !== 'boolean') throw new InputError(`${option.name} is true or false, got ${pyRepr(given[option.name])}`, option.name);
  }
  const isPart = (part) => typeof part === 'string' || (part !== null && typeof part === 'object' && 'low' in part && 'high' in part);
  keep = isPart(keep) ? [keep] : keep;
  if (!(Array.isArray(keep) && keep.length <= MAX_PARTS && keep.every(isPart))) {
    throw new InputError(`keep takes at most ${MAX_PARTS} parts, each a Part or its text SEED:X0,Y0,Z0:X1,Y1,Z1`, 'keep');
  }
  const grown = given.grow === null ? null : perAxis(given.grow, 'grow', (f) => admits(OPTION.grow, f), 'one or three factors of at least 1');
  const anchor = given.anchor === null ? null : perAxis(given.anchor, 'anchor', (a) => admits(OPTION.anchor, a), 'three fractions in [0, 1]');
  if (layout !== null) {
    if (!(typeof layout === 'object' && 'grid' in layout && 'shape' in layout)) throw new InputError('layout must be a request.Layout (Layout.of(grid))', 'layout');
    layout = Layout.of(layout.grid, layout.shape, layout.resample);
  }
  const tile = given.tile === null ? null : checkTile(given.tile);
  const models = typeof given.models === 'string' ? [given.models] : given.models;
  if (!(Array.isArray(models) && models.every((name) => typeof name === 'string'))) {
    throw new InputError("models is the world's other models' files, as paths", 'models');
  }
  const world = worldOptions({ arrange: given.arrange, heights: given.heights, lod: given.lod, density: given.density, spacing: given.spacing,
    models, models_map: given.models_map });
  const request = Object.freeze({
    ...given, // every option, in the table's order: one this file does not check yet as given (make refuses it)
    seed, size, scale, smooth, smoother: given.smoother,
    frame: given.frame, keep: Object.freeze([...keep]), grow: grown, anchor, layout, tile, ...world,
  });
  checkTogether(request);
  return request;
}

/** The rules of which fields go together, as SampleRequest.check_together. */
function checkTogether(request) {
  const given = edits(request);
  if (given.length > 1) throw new ConflictError(`give one of ${given.join(', ')}`, given);
  if (request.anchor !== null && request.grow === null) throw new ConflictError('anchor is for grow', ['anchor', 'grow']);
  if (request.recon) {
    if (request.seed !== null) throw new ConflictError('give seed or recon, not both', ['seed', 'recon']);
    if (given.length) {
      throw new ConflictError(`${given[0]} edits a new sample, and recon is the training shape: give seed, not recon`, [given[0], 'recon', 'seed']);
    }
    if (request.size.some((f) => f !== 1)) throw new InputError('the reconstruction exists only at the training size; drop size', 'size');
  }
  if (request.tile !== null) {
    const kept = [['recon', request.recon], ...given.map((edit) => [edit, true]), ['size', request.size.some((f) => f !== 1)],
      ['smooth', request.smooth], ['largest', request.largest]].filter(([, value]) => value).map(([name]) => name);
    if (kept.length) {
      throw new ConflictError(`a tile shares its border with its neighbours, which ${kept[0]} would break: give tile or ${kept.join(', ')}`, ['tile', ...kept]);
    }
  }
}

/** The world's fields given other than their defaults, as SampleRequest.world_fields. */
const worldFields = (request) => [['arrange', request.arrange !== DEFAULTS.arrange], ['heights', request.heights !== null], ['lod', request.lod],
  ['skirt', request.skirt], ['underside', !request.underside], ['density', request.density !== DEFAULTS.density], ['spacing', request.spacing !== DEFAULTS.spacing],
  ['models', request.models.length], ['models_map', request.models_map !== null]].filter(([, value]) => value).map(([name]) => name);

// The options this runtime makes. Any other given other than its default
// (Python's smoother 'taubin', largest, a sample's frame, a tile, an option
// added to the table later) is refused, never dropped. `detail` is taken
// and makes nothing here: a model's colour and relief are the Python
// runtime's (the worker's answer says what it left out).
export const MAKES = Object.freeze(['seed', 'recon', 'size', 'scale', 'smooth', 'detail', 'keep', 'grow', 'anchor', 'layout']);

/** Refuse what a request asks of an option this runtime does not make (an InputError naming it). */
function refuseUnmade(request) {
  for (const option of OPTIONS) {
    const { name, default: value } = option;
    if (MAKES.includes(name) || JSON.stringify(request[name]) === JSON.stringify(value)) continue;
    throw new InputError(`the browser runtime makes ${value === null ? `no ${name}` : `${name} ${value} only`}`, name);
  }
}

/** The seed whose noise makes the sample (null: the training shape). */
const sampleSeed = (request) => (request.recon ? null : request.seed ?? 0n);

/**
 * The tri-plane of the sample the request asks for, as request.make: the
 * plain sample, compose (keep), grow or fromLayout. progress(stage, null),
 * if given, names the work as it starts.
 */
export async function make(model, request, progress = null) {
  if (request.tile !== null) throw new InputError("the browser runtime makes no tile: a world's tiles come from sinrun serve", 'tile');
  if (request.frame === 'tile') {
    throw new InputError("frame tile (coordinates from a tile's corner) is for the tiles of a world; a sample is placed in frame input or model", 'frame');
  }
  const world = worldFields(request);
  if (world.length) throw new InputError(`${world[0]} is for the tiles of a world; a sample has none`, world[0]);
  refuseUnmade(request);
  const seed = sampleSeed(request), { size, layout } = request;
  if (layout) {
    if (layout.resample) throw new InputError('the browser fits a layout of one level\'s own size only; resample it with sinrun', 'layout');
    progress?.('fitting the layout', null);
    return fromLayout(model, seed, layout.grid, layout.shape, size);
  }
  if (request.grow) {
    progress?.('growing', null);
    return grow(model, seed, request.grow, request.anchor ?? [0, 0, 0], size);
  }
  if (request.keep.length) {
    progress?.('composing', null);
    const finest = scaledSizes(model.manifest.sizes, size).at(-1);
    const parts = request.keep.map((part) => (typeof part === 'string' ? parsePart(part, model.manifest, finest) : checkPart(part, finest)));
    return compose(model, seed, parts, size);
  }
  progress?.('sampling', null);
  return sample(model, seed, size);
}
