// The editor's drawing over the shape (docs/EDITING.md, "On the page"): the
// kept box, where a grown sample's old one sits, the layout's blocks; and
// the layout's edits, made by clicking blocks, by the buttons and by .vox
// files. An edit is the URL's text of the cells that differ from the seed's
// own layout (layout-cells.js), handed to `listen`'s callback.
import * as THREE from 'three';
import * as cells from './layout-cells.js';
import { $, report } from './form.js';
import { hitAt, onScreen, setOverlay } from './scene.js';
import { finestSize, keptBoxes } from './sizes.js';
import { fileStem, state } from './state.js';

const boxLines = new THREE.LineBasicMaterial({ color: 0xffd54a });
const selectLines = new THREE.LineBasicMaterial({ color: 0xff5a36 });
const blockMaterial = new THREE.MeshStandardMaterial({ color: 0x7fb0e8, roughness: 0.8 });
const unitBox = new THREE.BoxGeometry(1, 1, 1); // every block is this box, scaled and moved
const DIRECTIONS = { '+x': [1, 0, 0], '-x': [-1, 0, 0], '+y': [0, 1, 0], '-y': [0, -1, 0], '+z': [0, 0, 1], '-z': [0, 0, -1] };
const beside = (cell, step) => cell.map((c, a) => c + step[a]);

let drawn = { info: null, request: null }; // what the drawing is of: the model's { sizes, origin, spacing } and the request
let layoutNow = null; // { base, grid, shape, edits }: the layout in view
let selected = null; // the selected cell [i, j, k], for duplicate and move
let blocks = null, blockCells = []; // the blocks in view (an InstancedMesh) and the cell of each
let voxUrl = null;

function wireBox(low, high, lines) {
  const box = new THREE.BoxGeometry(...low.map((v, a) => Math.max(high[a] - v, 1e-6)));
  const wire = new THREE.LineSegments(new THREE.EdgesGeometry(box), lines);
  box.dispose();
  wire.position.set(...low.map((v, a) => (v + high[a]) / 2));
  return wire;
}

/** The blocks of the layout in view for a sample of `factors`, and the selected one's wireframe. */
function drawBlocks(info, factors) {
  const { grid, shape } = layoutNow;
  const finest = finestSize(info, factors);
  const objects = [];
  blockCells = cells.fullCells(grid, shape);
  if ($('blocks').checked) {
    blocks = new THREE.InstancedMesh(unitBox, blockMaterial, Math.max(1, blockCells.length));
    blocks.count = blockCells.length;
    const matrix = new THREE.Matrix4();
    blockCells.forEach((cell, n) => {
      const { low, high } = cells.cellBox(cell, shape, finest, info.origin, info.spacing);
      blocks.setMatrixAt(n, matrix.makeScale(...low.map((v, a) => 0.94 * (high[a] - v))).setPosition(...low.map((v, a) => (v + high[a]) / 2)));
    });
    blocks.computeBoundingBox();
    blocks.computeBoundingSphere();
    objects.push(blocks);
  }
  if (selected && cells.inside(shape, selected) && grid[cells.cellIndex(shape, selected)]) {
    const { low, high } = cells.cellBox(selected, shape, finest, info.origin, info.spacing);
    objects.push(wireBox(low, high, selectLines));
  }
  return objects;
}

/**
 * Draw the editor's part for a request (null: a bad value, nothing drawn) of
 * a model of `info` (null: none): the boxes it keeps, or the layout's blocks
 * in place of the shape (drawn together they hide each other).
 */
export function draw(request, info = drawn.info) {
  drawn = { info, request };
  blocks = null;
  let objects = [];
  try {
    if (info && request) objects = keptBoxes(info, request).map(({ low, high }) => wireBox(low, high, boxLines));
    if (info && request && state.edit === 'layout' && layoutNow) objects.push(...drawBlocks(info, request.size));
  } catch {
    objects = []; // a value the request has not checked yet (a box past the sample): the request will say why
    blocks = null;
  }
  setOverlay(objects, !blocks);
}

/** The seed's own layout `base` ({ shape, grid }) with the state's edits: the layout in view, its status line and its .vox link. */
export function showLayout(base) {
  const grid = cells.applyEdits(base.grid, base.shape, state.cells);
  const edits = cells.encodeEdits(grid, base.grid, base.shape);
  layoutNow = { base: base.grid, grid, shape: base.shape, edits: edits ? edits.split(',').length : 0 };
  showLayoutStatus();
  if (voxUrl) URL.revokeObjectURL(voxUrl);
  voxUrl = URL.createObjectURL(new Blob([cells.voxBytes(grid, base.shape)], { type: 'application/octet-stream' }));
  $('vox-export').href = voxUrl;
  $('vox-export').download = `${fileStem()}.vox`;
}

/** No layout in view (another edit). */
export function dropLayout() {
  layoutNow = null;
}

/** The layout in view ({ base, grid, shape, edits }), or null. */
export const layout = () => layoutNow;

/** Another sample: no block selected. */
export function deselect() {
  selected = null;
}

function showLayoutStatus() {
  if (!layoutNow) return;
  const { grid, shape, edits } = layoutNow;
  const full = grid.reduce((n, v) => n + v, 0);
  const chosen = selected && cells.inside(shape, selected) ? `; selected ${selected.join(',')}` : '';
  $('layout-status').textContent = `${shape.join('×')} cells, ${full} full, ${edits} edited${chosen}`;
}

/** The block under a point of the view (client coordinates) and the face hit: { cell, normal }, or null. */
export function pick(x, y) {
  const hit = blocks && hitAt(blocks, x, y);
  if (!hit) return null;
  const n = hit.face.normal; // the unit box's own axes: the model's, scaled and moved per block
  return { cell: blockCells[hit.instanceId], normal: [Math.round(n.x), Math.round(n.y), Math.round(n.z)] };
}

/** Where the centre of a block's face (normal [±1, 0, 0] and so on) is on the screen, for the tests. */
export function facePoint(cell, normal) {
  const { info, request } = drawn;
  if (!layoutNow || !info || !request) return null;
  const { low, high } = cells.cellBox(cell, layoutNow.shape, finestSize(info, request.size), info.origin, info.spacing);
  return onScreen(low.map((v, a) => (v + high[a]) / 2 + normal[a] * 0.47 * (high[a] - v)));
}

/** The edit text of the layout in view changed by `change(grid, shape)` on a copy (which throws a message where it cannot). */
function edited(change) {
  const grid = Uint8Array.from(layoutNow.grid);
  change(grid, layoutNow.shape);
  return cells.encodeEdits(grid, layoutNow.base, layoutNow.shape);
}

/** A click on a block with the chosen tool: an edit's text, or null (a selection). */
function clickBlock({ cell, normal }) {
  const tool = $('tool').value;
  if (tool === 'select') {
    selected = cell;
    showLayoutStatus();
    draw(drawn.request);
    return null;
  }
  return edited((grid, shape) => {
    if (tool === 'remove') {
      grid[cells.cellIndex(shape, cell)] = 0;
      return;
    }
    const target = beside(cell, normal);
    if (!cells.inside(shape, target)) throw new Error(`no room there: the layout is ${shape.join('×')} cells, and the new block would be at ${target.join(',')}`);
    grid[cells.cellIndex(shape, target)] = 1;
  });
}

/** Duplicate (keep: true) or move the selected block one cell in the chosen direction; the selection follows. */
function shiftSelected(keep) {
  if (!layoutNow) return null;
  const { grid, shape } = layoutNow;
  if (!selected || !cells.inside(shape, selected) || !grid[cells.cellIndex(shape, selected)]) {
    throw new Error('select a block first: set "a click on a block" to "selects it", then click one');
  }
  const target = beside(selected, DIRECTIONS[$('direction').value]);
  if (!cells.inside(shape, target)) throw new Error(`no room there: the layout is ${shape.join('×')} cells, and ${target.join(',')} is outside it`);
  const from = selected;
  selected = target;
  return edited((copy) => {
    if (!keep) copy[cells.cellIndex(shape, from)] = 0;
    copy[cells.cellIndex(shape, target)] = 1;
  });
}

async function importVox(file) {
  if (!layoutNow) throw new Error('the layout is not here yet: wait for it, then import');
  const { grid, shape } = cells.readVox(new Uint8Array(await file.arrayBuffer()), file.name);
  if (shape.join() !== layoutNow.shape.join()) {
    throw new Error(`${file.name}: a layout of ${shape.join('×')} cells; this sample's is ${layoutNow.shape.join('×')} (level 0 of ${state.model} at size ${state.size})`);
  }
  return edited((copy) => copy.set(grid));
}

/** The editor's controls and clicks on the view's blocks: `onEdit(text)` gets each layout edit; a refused one is reported. */
export function listen(canvas, onEdit) {
  const attempt = async (make) => {
    try {
      const text = await make();
      if (text !== null) onEdit(text);
    } catch (error) {
      report(error.message);
    }
  };
  $('duplicate').addEventListener('click', () => attempt(() => shiftSelected(true)));
  $('move').addEventListener('click', () => attempt(() => shiftSelected(false)));
  $('blocks').addEventListener('change', () => draw(drawn.request));
  $('vox-file').addEventListener('change', () => {
    const [file] = $('vox-file').files;
    if (file) attempt(() => importVox(file));
    $('vox-file').value = ''; // the same file again is a change too
  });
  let pressed = null; // a click on a block, not the end of a drag that turned the view
  canvas.addEventListener('pointerdown', (event) => { pressed = [event.clientX, event.clientY]; });
  canvas.addEventListener('pointerup', (event) => {
    const near = pressed && Math.hypot(event.clientX - pressed[0], event.clientY - pressed[1]) <= 4;
    pressed = null;
    const hit = near && state.edit === 'layout' && pick(event.clientX, event.clientY);
    if (hit) attempt(() => clickBlock(hit));
  });
}
