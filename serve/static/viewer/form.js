// The controls: the state shown in them and read back from them, which of
// them the state calls for, and the status line under them.
import { FORMATS, OPTION } from '../sinshape/options.js';
import { STATIC_SITE, TABLE_CONTROLS, keepToBackEnd, nextSeed, state } from './state.js';

export const $ = (id) => document.getElementById(id);

// The download's formats, before the game asset: core.files.OUTPUT_FORMATS.
$('format').prepend(...FORMATS.map((format) => new Option(format)));
$('seed').title = OPTION.seed.help;

/** The control of one of the table's options, made from its record (runtime/options.py): its name, help, range and default. */
function tableControl({ name, type, help, low, high, bounds, default: value, choices }) {
  const label = document.createElement('label');
  const input = document.createElement(type === 'choice' ? 'select' : 'input');
  if (type === 'choice') input.append(...choices.map((choice) => new Option(choice)));
  else if (type === 'bool') [input.type, label.className] = ['checkbox', 'check'];
  else if (['int', 'number'].includes(type)) {
    Object.assign(input, { type: 'number', step: type === 'int' ? '1' : 'any', inputMode: 'decimal', placeholder: value }); // empty: the default
    if (low !== null && bounds[0] === '[') input.min = low;
    if (high !== null && bounds[1] === ']') input.max = high;
  } else throw new Error(`option ${name}: a ${type} has no plain control; give it its own`);
  Object.assign(input, { id: name, name, title: help });
  label.id = `${name}-label`;
  const text = name.replaceAll('_', ' ');
  if (type === 'bool') label.append(input, ` ${text}`);
  else label.append(`${text} `, input);
  return label;
}
$('sample-options').append(...TABLE_CONTROLS.sample.map((name) => tableControl(OPTION[name])));
$('scatter-controls').append(...TABLE_CONTROLS.scatter.map((name) => tableControl(OPTION[name])));

// An x,y,z row of the page (class xyz) holds its x input; the y and z inputs
// are copies of it, with x in their id, name and title turned to their axis.
for (const x of document.querySelectorAll('.xyz > input')) {
  for (const axis of ['z', 'y']) {
    const input = x.cloneNode();
    input.id = x.id.replace('x', axis);
    if (x.name) input.name = x.name.replace('x', axis);
    input.title = x.title.replace(/\bx\b/g, axis);
    x.after(input);
  }
}
// The controls of one value each, as they are (a flag's 'true' or 'false').
const PLAIN = ['where', 'up', 'format', 'edit', 'other', 'at', 'travel', 'reach', 'arrange', ...TABLE_CONTROLS.sample, ...TABLE_CONTROLS.scatter];
const checkbox = (id) => $(id).type === 'checkbox';
const TRIPLES = { box: ['bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1'], grow: ['gx', 'gy', 'gz'], anchor: ['ax', 'ay', 'az'] };

export function toForm() {
  $('model').value = state.model;
  $('seed').value = state.seed;
  const [x, y, z] = String(state.size).split(',');
  $('sx').value = x ?? 1;
  $('sy').value = y ?? x ?? 1;
  $('sz').value = z ?? x ?? 1;
  for (const key of PLAIN) {
    if (checkbox(key)) $(key).checked = state[key] === 'true';
    else $(key).value = state[key];
  }
  const others = String(state.models).split(',');
  for (const option of $('models').options) option.selected = others.includes(option.value);
  for (const [key, ids] of Object.entries(TRIPLES)) {
    const values = String(state[key]).split(',');
    ids.forEach((id, i) => { $(id).value = values[i] ?? (key === 'box' ? '' : values[0] ?? ''); });
  }
  showMode();
}

/** Read the controls into the state: true when they name another sample (model, seed or size), whose layout edits are dropped. */
export function fromForm() {
  const sample = [state.model, state.seed, state.size].join('|');
  state.model = $('model').value;
  state.seed = $('seed').value.trim();
  state.size = [$('sx').value, $('sy').value, $('sz').value].map((v) => v.trim()).join(',');
  for (const key of PLAIN) state[key] = checkbox(key) ? String($(key).checked) : $(key).value.trim();
  keepToBackEnd();
  state.models = [...$('models').selectedOptions].map((option) => option.value).join(','); // in the list's order
  for (const [key, ids] of Object.entries(TRIPLES)) state[key] = ids.map((id) => $(id).value.trim()).join(',');
  if (state.edit === 'keep' && !state.other) $('other').value = state.other = nextSeed(state.seed);
  const another = [state.model, state.seed, state.size].join('|') !== sample;
  if (another) state.cells = '';
  return another;
}

/** Show the controls the state calls for: the browser's, the edit's, a download format the page can give. */
export function showMode() {
  const browser = state.where === 'browser';
  $('where-label').hidden = STATIC_SITE;
  $('file-label').hidden = !browser;
  const blob = browser || (state.edit === 'layout' && Boolean(state.cells)); // a download the page made itself
  $('format').disabled = blob; // the browser writes .ply, a shape from a layout comes as .glb, and the box says so
  $('format').value = browser ? 'ply' : blob ? 'glb' : state.format;
  $('backend').hidden = !browser;
  const worldMode = $('edit').querySelector('option[value="world"]');
  worldMode.disabled = browser;
  worldMode.title = browser ? "the server's: this browser's runtime makes a model's geometry, not its worlds" : '';
  for (const edit of ['keep', 'grow', 'layout', 'world']) $(`${edit}-controls`).hidden = state.edit !== edit;
  // A world has no size nor the sample's options a tile does not take (smoothing), its own up, and the world's controls, not orbiting.
  const sampleOnly = TABLE_CONTROLS.sample.filter((name) => !OPTION[name].goes_with.includes('tile')).map((name) => `${name}-label`);
  for (const id of ['size-label', ...sampleOnly, 'up-label', 'orbit-help']) $(id).hidden = state.edit === 'world';
  $('scatter-controls').hidden = state.arrange !== 'scatter'; // a scattered world's own
}

export function report(error) {
  $('error').textContent = error;
  $('error').hidden = !error;
}

export function showProgress(text, fraction = null) {
  $('status').textContent = fraction === null ? `${text}…` : `${text}… ${Math.floor(fraction * 100)}%`;
  if (fraction === null) $('progress').removeAttribute('value'); // a bar that says "working", no figure
  else $('progress').value = fraction;
}

/** The page is working on a request: its bar, and the cancel button. */
export function working(text) {
  document.body.dataset.state = 'loading';
  $('working').hidden = false;
  showProgress(text);
}

/** The end of a request: the page's state, the cancel button and the bar put away. */
export function finish(result) {
  document.body.dataset.state = result;
  $('working').hidden = true;
  if (result !== 'error') report('');
}

export function fail(error) {
  $('status').textContent = '';
  report(error.message);
  finish('error');
}
