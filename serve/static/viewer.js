// The sinshape page: pick a model and a seed, see the sample in 3-D, download it,
// and edit it (docs/EDITING.md): keep a box of it and take the rest from another
// seed, grow it, or edit its coarse layout as blocks. Each change of the shape
// is a step that undo and redo walk; the state lives in the URL's query string.
// A sample is made on the server (its API) or in this browser (the JavaScript
// runtime in sinshape/, on onnxruntime-web); a static site from
// `sinrun export-web` (body data-site="static") has no server and samples in
// the browser only. The browser's runtime makes geometry: a model's colour and
// relief, and the world mode (the endless world of the model and seed, flown
// over), come from the server (docs/WEB.md, "One runtime"). This module wires the page's jobs together, one module each:
//
//   viewer/state.js     the state: the URL, undo and redo, the sample request it stands for
//   viewer/form.js      the controls and the status line
//   viewer/sampling.js  the two back ends behind one call, sample(where, name, request)
//   viewer/scene.js     the 3-D view: renderer, camera, controls, the shape, framing
//   viewer/editor.js    the kept box, the grown box, the layout's blocks and their edits
//   viewer/world.js     the world mode: tiles made around the camera and dropped behind it
//   viewer/flight.js    the world mode's camera: keys, the mouse and fingers fly it or walk it
//   viewer/sizes.js, viewer/layout-cells.js   pure helpers: where an edit lies, a layout's cells and files
import * as editor from './viewer/editor.js';
import { $, fail, finish, fromForm, report, showMode, showProgress, toForm, working } from './viewer/form.js';
import * as sampling from './viewer/sampling.js';
import { assetLevels, levelTriangles } from './viewer/asset.js';
import { camera, frame, memory, orient, renderer, scene, showAsset, showMesh, summary } from './viewer/scene.js';
import { STATIC_SITE, TABLE_CONTROLS, canWalk, fileStem, readUrl, record, requestOf, state, walk, worldOptions, writeUrl } from './viewer/state.js';
import * as world from './viewer/world.js';
import { readHeightMap, readModelMap } from './viewer/heights.js';

window.sinshapeView = { // for the tests and the console
  scene, camera, get renderer() { return renderer; }, shape: summary, memory, pick: editor.pick, facePoint: editor.facePoint,
  layout: () => editor.layout() && { ...editor.layout(), grid: Array.from(editor.layout().grid) }, world: world.view,
};

const ups = new Map(); // model name -> its up axis, recorded when it was trained
let latest = 0; // the newest request: whatever an older one finds, it shows nothing
let aborter = null; // gives up the request under way (the server stops making it)
let downloadUrl = null;
let shownFaces = 0; // the triangles of the sample shown: what an asset's levels are sized from

/** Read the controls into the state; another sample has no block selected. */
function readForm() {
  if (fromForm()) editor.deselect();
}

function showSteps() {
  $('undo').disabled = !canWalk(-1);
  $('redo').disabled = !canWalk(+1);
}

/** The download link: `href` (a route, or a Blob of the page's own) saved as `name` ('': the answer's own name). */
function offer(href, name = '') {
  if (href instanceof Blob) {
    if (downloadUrl) URL.revokeObjectURL(downloadUrl);
    href = downloadUrl = URL.createObjectURL(href);
  }
  $('download').href = href;
  $('download').download = name;
}

/** The state's request, made on its back end and shown (a newer request gives this one up). */
async function load({ replay = false } = {}) {
  const ticket = ++latest;
  aborter?.abort();
  const controller = aborter = new AbortController();
  const { signal } = controller, { where, model: name } = state;
  if (!replay) record();
  showSteps();
  writeUrl();
  showMode();
  working(where === 'server' ? 'sampling on the server' : 'sampling');
  $('download').removeAttribute('href');
  const progress = (stage, fraction) => { if (ticket === latest) showProgress(stage, fraction); };
  try {
    let request = requestOf(); // checked before any work: a bad value says so at once
    if (state.edit === 'world') {
      await showWorld(request, ticket, { progress, signal });
      return;
    }
    world.stop();
    const info = state.edit ? await sampling.info(where, name, { progress, signal }) : null;
    if (ticket !== latest) return;
    if (state.edit === 'layout') {
      editor.showLayout(await sampling.layout(where, name, request.seed, request.size, { signal }));
      if (ticket !== latest) return;
      request = requestOf(editor.layout());
    } else {
      editor.dropLayout();
    }
    editor.draw(request, info);
    if (where === 'server' && !request.layout && state.format !== 'asset') offer(sampling.serverRequest(name, request, state.format).url);
    const made = await sampling.sample(where, name, request, { progress, signal });
    if (ticket !== latest) return;
    shownFaces = made.faces.length / 3;
    const extent = [name, state.size, state.edit === 'grow' ? `${state.grow}|${state.anchor}` : '', state.up].join('|');
    showMesh(made, state.up, extent);
    $('status').textContent = made.status;
    $('backend').textContent = made.backend ?? '';
    if (made.file) offer(made.file, `${fileStem()}.${made.extension}`);
    if (where === 'server' && !request.layout && state.format === 'asset') {
      if (state.edit) offer(sampling.serverRequest(name, request, 'asset', shownFaces).url); // an edit draws on the sample's own frame
      else await showGameAsset(name, request, made.status, ticket, signal);
    }
    if (ticket === latest) finish('ready');
  } catch (error) {
    if (ticket !== latest) return;
    $('download').removeAttribute('href'); // it would fetch the failed request again
    fail(error);
  } finally {
    if (aborter === controller) aborter = null;
  }
}

/** The shown sample's game asset (levels sized from its triangles) in its place, its levels switched by the camera's
 * distance as an engine switches them (viewer/asset.js), and offered as the download. (While editing, the sample
 * stays: the editor draws in its frame, and the asset stands in its own, on its base.) */
async function showGameAsset(name, request, status, ticket, signal) {
  const { url } = sampling.serverRequest(name, request, 'asset', shownFaces);
  offer(url);
  working('making the game asset on the server');
  const lod = await assetLevels(await sampling.assetData(url, { signal }), camera.fov);
  if (ticket !== latest) return;
  showAsset(lod);
  const triangles = levelTriangles(lod).map((count) => count.toLocaleString('en')).join(' / ');
  $('status').textContent = `${status} · game asset: ${triangles} triangles, coarser as the camera draws back`;
}

/** The world of the state's model and seed, flown over from the request's tile (viewer/world.js). */
async function showWorld(request, ticket, options) {
  const { reach, walk: walking } = worldOptions();
  editor.dropLayout();
  const info = await sampling.info(state.where, state.model, options);
  const others = await Promise.all(request.models.map((name) => sampling.info(state.where, name, options))); // the world's other models
  if (ticket !== latest) return;
  if (!state.arrange) { // as the model records, shown and in the URL
    state.arrange = $('arrange').value = info.arrange ?? 'blend';
    showMode();
    writeUrl();
    request = requestOf();
  }
  if (document.activeElement === $('edit')) $('edit').blur(); // the keys fly now, not pick another mode
  world.show({ name: state.model, request, info, others, reach, walk: walking }, (status) => showWorldStatus(status, ticket));
}

/** The world's work so far: the camera's tile in the controls and the URL, what is shown and made. */
function showWorldStatus({ at, shown, waiting, made, complete, error }, ticket) {
  const here = at.join(',');
  if (state.at !== here) {
    state.at = $('at').value = here;
    writeUrl();
  }
  if (state.where === 'server' && state.format !== 'asset') offer(sampling.serverRequest(state.model, requestOf(), state.format).url); // the camera's tile
  $('status').textContent = `tile ${at.join(', ')} · ${shown} tiles shown · ${made} made${waiting ? `, ${waiting} to make` : ''}`;
  if (error) report(`a tile failed: ${error.message}`);
  if (ticket === latest && document.body.dataset.state === 'loading') {
    $('progress').value = made / (made + waiting);
    if (complete) finish('ready');
  }
}

/** Stop the sample being made: abort the server's request, or end the browser's worker. */
function cancel() {
  if (document.body.dataset.state !== 'loading') return;
  latest++; // whatever was under way answers no one now
  aborter?.abort();
  aborter = null;
  world.stop();
  sampling.stop();
  $('download').removeAttribute('href');
  $('status').textContent = 'cancelled';
  finish('cancelled');
}

function step(delta) {
  readForm();
  // BigInt: seeds go to 2^63, past what a Number holds exactly (2^53)
  const seed = /^\d+$/.test(state.seed) ? BigInt(state.seed) : 0n;
  const next = seed + BigInt(delta);
  state.seed = String(next < 0n ? 0n : next >= 2n ** 63n ? 2n ** 63n - 1n : next);
  toForm();
  load();
}

function walkSteps(delta) {
  if (!walk(delta)) return;
  toForm();
  load({ replay: true });
}

async function openFile(file) {
  // Named apart from the listed models, so a file called terrain.onnx replaces nothing.
  const name = `${file.name.replace(/\.onnx$/i, '')} (file)`;
  const ticket = ++latest;
  aborter?.abort();
  const controller = aborter = new AbortController();
  working(`checking ${file.name}`);
  try {
    await sampling.openFile(name, new Uint8Array(await file.arrayBuffer()), file.name, controller.signal);
  } catch (error) {
    if (ticket === latest) fail(error);
    return;
  }
  if (ticket !== latest) return;
  if (![...$('model').options].some((o) => o.value === name)) {
    $('model').add(new Option(name, name));
    $('models').add(new Option(name, name));
  }
  readForm();
  state.model = name;
  toForm();
  load();
}

const mapNames = { heights: '', modelsMap: '' }; // the maps' files

/** Shape the world with a height map (`which` 'heights') or place its models with a model map ('modelsMap') from a file;
 * the world mode shows it at once. */
async function openMap(which, input) {
  const [file] = input.files;
  input.value = ''; // the same file again is a change too
  try {
    state[which] = which === 'heights' ? await readHeightMap(file, await sampling.info(state.where, state.model, {})) : await readModelMap(file);
    mapNames[which] = file.name;
  } catch (error) {
    fail(error);
    return;
  }
  showMaps();
  readForm();
  load();
}

/** The maps' names on their buttons, and the buttons that drop them. */
function showMaps() {
  $('map-label').firstChild.textContent = state.heights ? `map: ${mapNames.heights}` : 'height map';
  $('map-clear').hidden = !state.heights;
  $('models-map-label').firstChild.textContent = state.modelsMap ? `model map: ${mapNames.modelsMap}` : 'model map';
  $('models-map-clear').hidden = !state.modelsMap;
}

async function start() {
  $('unserved').hidden = true; // the script runs: the page is served
  readUrl();
  try {
    const response = await fetch(STATIC_SITE ? 'models.json' : 'api/models');
    const models = await response.json();
    for (const m of models) {
      $('model').add(new Option(`${m.name} (${m.size.join('x')})`, m.name));
      $('models').add(new Option(m.name, m.name));
      sampling.addModel(m.name, { url: STATIC_SITE ? m.file : `api/models/${encodeURIComponent(m.name)}/onnx`, file: `${m.name}.onnx` });
      ups.set(m.name, m.up ?? 'y');
    }
    if (!models.some((m) => m.name === state.model)) state.model = models[0]?.name ?? '';
    // Which way is up is the model's (recorded when it was trained), unless the URL says otherwise.
    if (!new URLSearchParams(location.search).has('up')) state.up = ups.get(state.model) ?? 'y';
  } catch (error) {
    report(`cannot list the models: ${error.message}`);
    return;
  }
  toForm();
  $('controls').addEventListener('submit', (event) => { event.preventDefault(); readForm(); load(); });
  $('cancel').addEventListener('click', cancel);
  document.addEventListener('keydown', (event) => { if (event.key === 'Escape') cancel(); });
  $('prev').addEventListener('click', () => step(-1));
  $('next').addEventListener('click', () => step(+1));
  $('file').addEventListener('change', () => { if ($('file').files.length) openFile($('file').files[0]); });
  for (const [which, input, clear] of [['heights', 'map-file', 'map-clear'], ['modelsMap', 'models-map-file', 'models-map-clear']]) {
    $(input).addEventListener('change', () => { if ($(input).files.length) openMap(which, $(input)); });
    $(clear).addEventListener('click', () => { state[which] = null; showMaps(); load(); });
  }
  $('model').addEventListener('change', () => {
    readForm();
    state.up = ups.get(state.model) ?? state.up;
    $('up').value = state.up;
    state.arrange = ''; // another model's world is made as that model records...
    if (state.modelsMap) state.arrange = $('arrange').value = 'scatter'; // ...or, with a model map, scattered
    load();
  });
  const boxes = ['bx0', 'by0', 'bz0', 'bx1', 'by1', 'bz1', 'gx', 'gy', 'gz', 'ax', 'ay', 'az'];
  for (const id of ['where', 'seed', 'sx', 'sy', 'sz', ...TABLE_CONTROLS.sample, 'edit', 'other', 'at', 'travel', 'reach', 'arrange',
    ...TABLE_CONTROLS.scatter, 'models', ...boxes]) {
    $(id).addEventListener('change', () => { readForm(); load(); });
  }
  for (const id of boxes) { // the box follows as it is typed
    $(id).addEventListener('input', () => {
      readForm();
      try {
        editor.draw(requestOf(editor.layout()));
      } catch {
        editor.draw(null); // a value that does not read yet
      }
    });
  }
  // The editor: undo and redo, the layout's tools.
  $('undo').addEventListener('click', () => walkSteps(-1));
  $('redo').addEventListener('click', () => walkSteps(+1));
  document.addEventListener('keydown', (event) => {
    if (!(event.ctrlKey || event.metaKey) || event.target.closest?.('input, select, textarea')) return;
    const key = event.key.toLowerCase();
    if (key === 'z' || key === 'y') {
      event.preventDefault();
      walkSteps(key === 'y' || event.shiftKey ? +1 : -1);
    }
  });
  editor.listen(renderer.domElement, (cells) => { readForm(); state.cells = cells; load(); });
  $('up').addEventListener('change', () => { readForm(); writeUrl(); orient(state.up); frame(); });
  $('format').addEventListener('change', () => {
    readForm();
    writeUrl();
    try {
      offer(sampling.serverRequest(state.model, requestOf(editor.layout()), state.format, shownFaces).url);
    } catch {
      $('download').removeAttribute('href'); // a state that makes no request: nothing to download
    }
  });
  load();
}

start();
