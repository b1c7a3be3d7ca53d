// The page's state: the values of its controls as text, read from the URL's
// query string and written back to it (so a view, edits included, can be
// shared); the undo history of the shapes made; and the one sample request
// the state stands for, which either back end makes.
import { parseNumber, parseSize, parseTriple } from '../sinshape/generate.js';
import { OPTION } from '../sinshape/options.js';
import { Layout, sampleRequest } from '../sinshape/request.js';

export const STATIC_SITE = document.body.dataset.site === 'static';
// The options of a sample request (runtime/options.py) the page sets, in its
// modes and edits (world.js makes each tile's lod, skirt and underside), and those it leaves at
// their defaults: tests/test_options.py holds the two to the table, so that an
// option added there is placed here too.
export const PAGE_OPTIONS = Object.freeze({
  set: ['seed', 'size', 'scale', 'smooth', 'detail', 'frame', 'keep', 'grow', 'anchor', 'layout', 'tile', 'arrange', 'heights', 'lod', 'skirt', 'underside',
    'density', 'spacing', 'models', 'models_map'],
  left: ['recon', 'smoother', 'largest'],
});
// The options the page offers as one control each, made from their records
// (form.js): a sample's (those that go with a tile too are the world's
// as well) and a scattered world's. A plain option (a number, a whole
// number, a flag, a choice) is offered in the page by naming it here.
export const TABLE_CONTROLS = Object.freeze({ sample: ['scale', 'smooth', 'detail'], scatter: ['density', 'spacing'] });
const TABLE_DEFAULTS = Object.fromEntries([...TABLE_CONTROLS.sample, ...TABLE_CONTROLS.scatter].map((name) => [name, String(OPTION[name].default)]));
const FIELDS = ['model', 'where', 'seed', 'size', ...TABLE_CONTROLS.sample, 'up', 'format'];
// Each edit's fields, in the URL after `edit`: box (6 percentages x0,y0,z0,x1,y1,z1
// of the sample, from the seed's sample) and other (the seed of the rest); grow
// and anchor (3 factors, 3 fractions); cells (layout-cells.js's text of the edited cells).
// The world mode's too (not an edit: the world of the seed, flown over): at (the
// camera's tile i,j), travel (fly or walk), reach (tiles made on each side), arrange
// (blend or scatter; empty: what the model records), the scattered world's
// TABLE_CONTROLS and models (the world's other models' names,
// models 1, 2, ... of its model map, parted by ','); its height map and model map,
// files the user opened, are not in the URL.
const EDITS = { keep: ['box', 'other'], grow: ['grow', 'anchor'], layout: ['cells'],
  world: ['at', 'travel', 'reach', 'arrange', ...TABLE_CONTROLS.scatter, 'models'] };
const EDIT_DEFAULTS = { edit: '', box: '0,0,0,50,100,100', other: '', grow: '2,1,1', anchor: '0,0,0', cells: '', at: '0,0', travel: 'fly', reach: '3',
  arrange: '', models: '' };
// What makes the shape: a step of the undo history when one of these changes.
const SHAPE_FIELDS = ['model', 'seed', 'size', ...TABLE_CONTROLS.sample, 'edit', 'box', 'other', 'grow', 'anchor', 'cells'];

export const state = {
  model: '', where: STATIC_SITE ? 'browser' : 'server', seed: 0, size: '1,1,1', up: 'y', format: 'glb',
  ...TABLE_DEFAULTS, ...EDIT_DEFAULTS,
  heights: null, // the world's height map (world.js's HeightMap), read from a file the user opened
  modelsMap: null, // the world's model map (world.js's ModelMap), likewise
};

/** The seed after `seed` (text; BigInt: seeds go to 2^63, past what a Number holds exactly). */
export const nextSeed = (seed) => (/^\d+$/.test(seed) && BigInt(seed) < 2n ** 63n - 1n ? String(BigInt(seed) + 1n) : '1');

/** The world mode is the server's: the browser's runtime makes no worlds (docs/WEB.md, "One runtime"). */
export function keepToBackEnd() {
  if (state.edit === 'world' && state.where === 'browser') state.edit = '';
}

export function readUrl() {
  const query = new URLSearchParams(location.search);
  for (const key of [...FIELDS, ...Object.keys(EDIT_DEFAULTS), ...TABLE_CONTROLS.scatter]) if (query.has(key)) state[key] = query.get(key);
  if (STATIC_SITE || !['server', 'browser'].includes(state.where)) state.where = STATIC_SITE ? 'browser' : 'server';
  if (!(state.edit in EDITS)) state.edit = '';
  keepToBackEnd();
  if (state.edit === 'keep' && !state.other) state.other = nextSeed(String(state.seed));
}

export function writeUrl() {
  const query = new URLSearchParams();
  for (const key of FIELDS) query.set(key, state[key]);
  if (state.edit) {
    query.set('edit', state.edit);
    for (const key of EDITS[state.edit]) query.set(key, state[key]);
  }
  history.replaceState(null, '', `${location.pathname}?${query}`);
}

// ---- undo and redo: every shape the page made, a step; undo shows the previous one again
const steps = []; // snapshots of the state's SHAPE_FIELDS
let stepAt = -1;
const shapeKey = (snapshot) => JSON.stringify(SHAPE_FIELDS.map((key) => String(snapshot[key])));

/** The state's shape, as a step after the one shown (the steps after it are dropped), unless it is that one. */
export function record() {
  const snapshot = Object.fromEntries(SHAPE_FIELDS.map((key) => [key, state[key]]));
  if (stepAt >= 0 && shapeKey(steps[stepAt]) === shapeKey(snapshot)) return;
  steps.splice(stepAt + 1);
  steps.push(snapshot);
  stepAt = steps.length - 1;
}

/** The state `delta` steps back (-1, undo) or on (+1, redo): false where there is none. */
export function walk(delta) {
  const to = stepAt + delta;
  if (to < 0 || to >= steps.length) return false;
  stepAt = to;
  Object.assign(state, steps[to]);
  return true;
}

export const canWalk = (delta) => stepAt + delta >= 0 && stepAt + delta < steps.length;

// ---- the request: the state's text read as the server reads its query

/** The box's 6 percentages, checked: [x0, y0, z0, x1, y1, z1] as the strings given. */
function parseBox(text) {
  const values = String(text).split(',').map((v) => v.trim());
  const numbers = values.map(Number);
  if (values.length !== 6 || values.some((v) => v === '') || !numbers.every((v) => Number.isFinite(v) && v >= 0 && v <= 100)) {
    throw new Error(`box '${text}': give 6 percentages of the sample in 0..100, x0,y0,z0,x1,y1,z1`);
  }
  for (let a = 0; a < 3; a++) {
    if (!(numbers[a] < numbers[a + 3])) throw new Error(`box: along ${'xyz'[a]} it runs from ${values[a]}% to ${values[a + 3]}%; the first must be less`);
  }
  return values;
}

const seedOf = (text) => (/^\d+$/.test(String(text).trim()) ? BigInt(String(text).trim()) : String(text)); // not digits: the request says why
const numberOf = (text) => parseNumber(text) ?? String(text);
// A table control's text as its option's value: a flag's 'true' or 'false', a number's digits; else the text (the request says why).
const valueOf = ({ type }, text) => (type === 'bool' ? { true: true, false: false }[text] ?? text : ['int', 'number'].includes(type) ? numberOf(text) : text);
/** The request's fields of the table controls `names` that go with `kind` (sample or tile); an empty one, its default. */
const tableFields = (names, kind) => Object.fromEntries(names.filter((name) => OPTION[name].goes_with.includes(kind) && state[name] !== '')
  .map((name) => [name, valueOf(OPTION[name], state[name])]));

/**
 * The sample request the state stands for (request.js's checks: an
 * InputError naming a bad field), with `layout` ({ grid, shape, edits }: the
 * layout in view, the seed's own with the state's edits) for a layout edit.
 * The box kept is the seed's, the rest the other seed's: that seed is the request's.
 */
export function requestOf(layout = null) {
  if (state.edit === 'world') { // the tile under the camera, as the tile route takes it
    const tile = String(state.at).split(',').map((t) => (/^\s*-?\d+\s*$/.test(t) ? BigInt(t) : t));
    const scattered = state.arrange === 'scatter' ? tableFields(TABLE_CONTROLS.scatter, 'tile') : {}; // else the defaults
    return sampleRequest({ seed: seedOf(state.seed), tile, frame: 'tile', arrange: state.arrange || 'blend', ...tableFields(TABLE_CONTROLS.sample, 'tile'),
                           ...scattered, heights: state.heights, models: state.models ? state.models.split(',') : [], models_map: state.modelsMap });
  }
  const fields = { seed: seedOf(state.seed), size: parseSize(state.size), ...tableFields(TABLE_CONTROLS.sample, 'sample') };
  if (state.edit === 'keep') {
    const box = parseBox(state.box).map((v) => `${v}%`);
    Object.assign(fields, { seed: seedOf(state.other), keep: [`${state.seed}:${box.slice(0, 3).join(',')}:${box.slice(3).join(',')}`] });
  } else if (state.edit === 'grow') {
    fields.grow = parseTriple(state.grow, (f) => f >= 1 && f < Infinity, 'one or three factors of at least 1, like 2 or 2,1,1', 'grow');
    fields.anchor = parseTriple(state.anchor, (a) => a >= 0 && a <= 1, 'three fractions in [0, 1], like 0.5,0,0', 'anchor');
  } else if (state.edit === 'layout' && layout?.edits) {
    fields.layout = Layout.of(layout.grid, layout.shape);
  }
  return sampleRequest(fields);
}

const MAX_REACH = 5; // tiles on each side of the camera's: 11 x 11 of them, as the page's choices go

/** The world mode's view: { reach: tiles made on each side of the camera's, walk }. */
export function worldOptions() {
  const reach = Number(state.reach);
  if (!(Number.isInteger(reach) && reach >= 1 && reach <= MAX_REACH)) throw new Error(`reach '${state.reach}': give 1 to ${MAX_REACH} tiles`);
  if (!['fly', 'walk'].includes(state.travel)) throw new Error(`travel '${state.travel}': give fly or walk`);
  return { reach, walk: state.travel === 'walk' };
}

/** A download's name: the model, the seeds and the edit. */
export function fileStem() {
  const tag = { keep: `_keep${state.seed}_rest${state.other}`, grow: `_grow${String(state.grow).replaceAll(',', 'x')}`,
    layout: state.cells ? '_layout' : '' }[state.edit] ?? '';
  return `${state.model}_seed${state.seed}${tag}`;
}
