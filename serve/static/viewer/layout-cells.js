// A layout on the page (docs/EDITING.md, "Layouts"): a grid of cells, a
// Uint8Array in C order (x slowest, z fastest) with its shape; MagicaVoxel
// .vox files as runtime/layout.py writes and reads them; and the text of an
// edit kept in the URL: the cells that differ from the seed's own layout,
// 'a' for a cell added and 'r' for one removed, like "a3.4.5,r10.2.0".
export const MAX_SIDE = 256; // MagicaVoxel's limit per axis, as runtime/layout_files.py's MAX_LAYOUT_SIDE
export const VOX_VERSION = 150;
export const VOX_COLOUR = 1; // the palette index cells are written with (any non-zero index reads as full)

/** A message for the user: a file or a URL that is not a layout. */
export class LayoutError extends Error {}

export const cellIndex = ([, y, z], [i, j, k]) => (i * y + j) * z + k;
export const inside = (shape, cell) => cell.every((c, a) => Number.isInteger(c) && c >= 0 && c < shape[a]);
export const cellCount = (shape) => shape[0] * shape[1] * shape[2];

/** Every full cell [i, j, k], in C order. */
export function fullCells(grid, [x, y, z]) {
  const out = [];
  for (let i = 0; i < x; i++) for (let j = 0; j < y; j++) for (let k = 0; k < z; k++) {
    if (grid[(i * y + j) * z + k]) out.push([i, j, k]);
  }
  return out;
}

/** The .vox file of a layout: MAIN holding SIZE and XYZI, byte for byte as runtime/layout_files.py's vox_bytes. */
export function voxBytes(grid, shape) {
  if (Math.max(...shape) > MAX_SIDE) throw new LayoutError(`a ${shape.join('x')} layout; .vox holds at most ${MAX_SIDE} cells per axis`);
  const cells = fullCells(grid, shape);
  const xyzi = 4 + 4 * cells.length;
  const children = 12 + 12 + 12 + xyzi;
  const out = new DataView(new ArrayBuffer(20 + children));
  const tag = (at, text) => { for (let i = 0; i < 4; i++) out.setUint8(at + i, text.charCodeAt(i)); };
  const int = (at, value) => out.setInt32(at, value, true);
  tag(0, 'VOX '); int(4, VOX_VERSION);
  tag(8, 'MAIN'); int(12, 0); int(16, children);
  tag(20, 'SIZE'); int(24, 12); int(28, 0); shape.forEach((n, a) => int(32 + 4 * a, n));
  tag(44, 'XYZI'); int(48, xyzi); int(52, 0); int(56, cells.length);
  cells.forEach(([i, j, k], n) => {
    const at = 60 + 4 * n;
    out.setUint8(at, i); out.setUint8(at + 1, j); out.setUint8(at + 2, k); out.setUint8(at + 3, VOX_COLOUR);
  });
  return new Uint8Array(out.buffer);
}

/** The one model of a .vox file: { grid, shape }, checked as runtime/layout_files.py's read_vox checks it. */
export function readVox(bytes, name) {
  const corrupt = (why) => new LayoutError(`${name}: not a readable MagicaVoxel file (${why})`);
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const tagAt = (at) => String.fromCharCode(...bytes.subarray(at, at + 4));
  if (bytes.length < 20 || tagAt(0) !== 'VOX ' || tagAt(8) !== 'MAIN') throw corrupt("no 'VOX ' header and MAIN chunk");
  let shape = null, voxels = null, models = 0;
  let at = 20 + view.getInt32(12, true);
  while (at < bytes.length) {
    if (at + 12 > bytes.length) throw corrupt('a chunk runs past the end');
    const chunk = tagAt(at), content = view.getInt32(at + 4, true), children = view.getInt32(at + 8, true);
    if (content < 0 || children < 0 || at + 12 + content + children > bytes.length) throw corrupt(`chunk '${chunk}' runs past the end`);
    const body = at + 12;
    if (chunk === 'SIZE') {
      models += 1;
      if (content < 12) throw corrupt('a SIZE chunk too short');
      shape = [0, 1, 2].map((a) => view.getInt32(body + 4 * a, true));
      if (!shape.every((n) => n >= 1 && n <= MAX_SIDE)) {
        throw new LayoutError(`${name}: a model of ${shape.join('x')} voxels; a layout has 1 to ${MAX_SIDE} per axis`);
      }
    } else if (chunk === 'XYZI') {
      const count = content >= 4 ? view.getInt32(body, true) : -1;
      if (!(count >= 0 && count <= Math.floor((content - 4) / 4))) throw corrupt('an XYZI chunk whose count does not fit it');
      voxels = bytes.subarray(body + 4, body + 4 + 4 * count);
    }
    at += 12 + content + children;
  }
  if (models !== 1 || voxels === null) throw new LayoutError(`${name}: holds ${models} models; a layout is one`);
  const grid = new Uint8Array(cellCount(shape));
  for (let v = 0; v < voxels.length; v += 4) {
    const cell = [voxels[v], voxels[v + 1], voxels[v + 2]];
    if (!inside(shape, cell)) throw corrupt('a voxel outside its model\'s size');
    grid[cellIndex(shape, cell)] = voxels[v + 3] > 0 ? 1 : 0;
  }
  return { grid, shape };
}

/** The text of the cells where `grid` differs from `base` (C order, so equal grids give equal text). */
export function encodeEdits(grid, base, shape) {
  const out = [];
  const [x, y, z] = shape;
  for (let i = 0; i < x; i++) for (let j = 0; j < y; j++) for (let k = 0; k < z; k++) {
    const n = (i * y + j) * z + k;
    if (grid[n] !== base[n]) out.push(`${grid[n] ? 'a' : 'r'}${i}.${j}.${k}`);
  }
  return out.join(',');
}

/** `base` with the edits of `text` (encodeEdits's form) applied: a new grid. */
export function applyEdits(base, shape, text) {
  const grid = Uint8Array.from(base);
  for (const token of String(text ?? '').split(',').filter(Boolean)) {
    const match = /^([ar])(\d+)\.(\d+)\.(\d+)$/.exec(token.trim());
    const cell = match ? match.slice(2).map(Number) : null;
    if (!match) throw new LayoutError(`layout edit '${token}': give a cell as a (added) or r (removed) and x.y.z, like a3.4.5`);
    if (!inside(shape, cell)) throw new LayoutError(`layout edit '${token}': the cell is outside this layout of ${shape.join('x')} cells`);
    grid[cellIndex(shape, cell)] = match[1] === 'a' ? 1 : 0;
  }
  return grid;
}

/**
 * Where cell [i, j, k] lies in the model's frame: { low, high } corners. A
 * layout cell is the area average of the finest voxels it covers (cell c of
 * n covers voxels c N / n to (c + 1) N / n), and voxel v sits at origin + v spacing.
 */
export function cellBox(cell, shape, finest, origin, spacing) {
  const corner = (a, c) => origin[a] + spacing[a] * ((c * finest[a]) / shape[a] - 0.5);
  return { low: cell.map((c, a) => corner(a, c)), high: cell.map((c, a) => corner(a, c + 1)) };
}
