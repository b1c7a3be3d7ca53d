// Layouts, as runtime/layout.py (docs/EDITING.md, "Layouts"): a sample's
// occupancy area-averaged to one level's grid, and generating from an edited
// one: the planes of the layout's level and of every finer level are fitted
// to it by gradient descent through the decoder (a hinge, Adam), each plane
// only where its lines were edited. The steps are runtime/layout.py's, in
// the same order and in float32 (Math.fround after each operation, where
// numpy rounds), the hidden layer's sums 4 units at a time in lanes
// (decode.wat) as Python's, and the sigmoid in float64 as Python's: given
// the same planes, the fit's are Python's to the bit (tests/test_mirror.py).
//
// Grids are Float32Array or Uint8Array (a layout: 1 full, 0 empty) in C
// order (x slowest, z fastest), with their shape.
import { InputError } from './errors.js';
import { checkSeed, drawNoise, resizeWeights, sample, scaledSizes, triplane } from './generate.js';
import { PLANE_AXES, dense } from './query.js';
import { DECODE_WASM } from './decode-wasm.js';

// The fit's constants: they mirror runtime/layout.py's (which says why each is what it is).
export const FIT_STEPS = 30; // at the layout's level
export const FINER_STEPS = 10; // at each finer level
export const HOLD_STEPS = 20; // at the last level
export const FIT_RATE = 0.5; // Adam's step, in plane units
export const PULL = 0.001; // weight of the change's mean square
export const MARGIN = 0.1; // how far past 0.5 an edited cell is fitted, on the layout's side
export const KEEP_WEIGHT = 0.2; // an unedited cell's weight, against an edited cell's 1
export const SLOPE_FLOOR = 0.1; // the sigmoid's slope in the fit's gradient, at least
export const SHARE = 0.4; // a plane cell may change where more than this share of its line was edited

const product = (shape) => shape.reduce((a, b) => a * b, 1);
const f32 = Math.fround;

/** (nOut, nIn) as { data, rows, cols }: cell i of nOut averages the part of the nIn cells it covers, as area_weights. */
export function areaWeights(nIn, nOut) {
  const data = new Float32Array(nOut * nIn), overlap = new Float64Array(nIn), step = nIn / nOut;
  for (let i = 0; i < nOut; i++) {
    let total = 0;
    for (let c = 0; c < nIn; c++) {
      overlap[c] = Math.max(0, Math.min((i + 1) * step, c + 1) - Math.max(i * step, c));
      total += overlap[c];
    }
    for (let c = 0; c < nIn; c++) data[i * nIn + c] = overlap[c] / total;
  }
  return { data, rows: nOut, cols: nIn };
}

/** (nOut, nIn) linear interpolation, align_corners, as generate.py's resize_matrix. */
function resizeMatrix(nIn, nOut) {
  const { low, high, wLow, wHigh } = resizeWeights(nIn, nOut);
  const data = new Float32Array(nOut * nIn);
  for (let i = 0; i < nOut; i++) {
    data[i * nIn + low[i]] += wLow[i];
    data[i * nIn + high[i]] += wHigh[i];
  }
  return { data, rows: nOut, cols: nIn };
}

function transpose({ data, rows, cols }) {
  const out = new Float32Array(data.length);
  for (let i = 0; i < rows; i++) for (let j = 0; j < cols; j++) out[j * rows + i] = data[i * cols + j];
  return { data: out, rows: cols, cols: rows };
}

/** A grid times an (nOut, nIn) matrix along `axis`: { data, shape }. */
function along(grid, shape, axis, { data: w, rows, cols }) {
  const outer = product(shape.slice(0, axis)), inner = product(shape.slice(axis + 1));
  const out = new Float32Array(outer * rows * inner);
  // Each row's nonzero weights (the matrices are resizes and area averages, a few per row), in column order.
  const first = new Int32Array(rows + 1), at = [], weight = [];
  for (let i = 0; i < rows; i++) {
    for (let c = 0; c < cols; c++) {
      if (w[i * cols + c] !== 0) { at.push(c); weight.push(w[i * cols + c]); }
    }
    first[i + 1] = at.length;
  }
  // Sums in float32, in the columns' order, as Python's along; by rows of the inner axes where they
  // are long, element by element where they are short.
  const sum = new Float32Array(inner);
  for (let o = 0; o < outer; o++) {
    for (let i = 0; i < rows; i++) {
      const to = (o * rows + i) * inner;
      if (inner < 16) {
        for (let t = 0; t < inner; t++) {
          let total = 0;
          for (let n = first[i]; n < first[i + 1]; n++) total = f32(total + f32(weight[n] * grid[(o * cols + at[n]) * inner + t]));
          out[to + t] = total;
        }
        continue;
      }
      sum.fill(0);
      for (let n = first[i]; n < first[i + 1]; n++) {
        const from = (o * cols + at[n]) * inner, by = weight[n];
        for (let t = 0; t < inner; t++) sum[t] += f32(by * grid[from + t]);
      }
      out.set(sum, to);
    }
  }
  return { data: out, shape: shape.with(axis, rows) };
}

/** One matrix applied along each axis of a grid, as separable: { data, shape }. */
const separable = (weights, grid, shape) => weights.reduce((g, w, axis) => along(g.data, g.shape, axis, w), { data: grid, shape });

/** A grid area-averaged down (or up) to shape `to`, as pool: Float32Array. */
export const pool = (grid, shape, to) => separable(shape.map((n, a) => areaWeights(n, to[a])), grid, shape).data;

const threshold = (grid) => Uint8Array.from(grid, (v) => (v > 0.5 ? 1 : 0));

function checkLevel(model, level) {
  const levels = model.manifest.sizes.length;
  if (!(Number.isInteger(level) && level >= 0 && level < levels - 1)) {
    throw new InputError(`level must be 0 to ${levels - 2} (a layout needs a finer level after it), got ${level}`);
  }
  return level;
}

// A seed's own layouts, per model, the last few: the page makes one to show
// the blocks, and every edit of them needs it again (a sample's worth of work).
const OWN_KEPT = 8;
const ownLayouts = new WeakMap();

/** The sample of `seed` (BigInt) area-averaged to `shape` and thresholded: Uint8Array, kept for the next call. */
async function own(model, seed, factors, shape, make) {
  const kept = ownLayouts.get(model) ?? new Map(), key = `${seed} ${factors} ${shape}`;
  ownLayouts.set(model, kept);
  if (!kept.has(key)) {
    const grid = await dense(model, await make());
    kept.set(key, threshold(pool(grid.data, grid.shape, shape)));
    if (kept.size > OWN_KEPT) kept.delete(kept.keys().next().value);
  }
  return kept.get(key);
}

/** The layout of the sample of `seed` at `level`: { grid: Uint8Array, shape }, as layout.layout. */
export async function layout(model, seed, level = 0, factors = [1, 1, 1]) {
  checkLevel(model, level);
  const shape = scaledSizes(model.manifest.sizes, factors)[level], value = checkSeed(seed);
  return { grid: Uint8Array.from(await own(model, value, factors, shape, () => sample(model, value, factors))), shape };
}

/** Each plane's block of the decoder's first layer, (C, D) Float32Array: stage decoder_planes on one-hot planes, as first_layer. */
export async function firstLayer(model) {
  const c = model.manifest.channels, eye = new Float32Array(c * c);
  for (let j = 0; j < c; j++) eye[j * c + j] = 1; // (1, C, 1, C): cell j holds channel j
  const outputs = await model.decoderPlanes.run([0, 1, 2].map(() => ({ data: eye, dims: [1, c, 1, c] })));
  return outputs.map((o) => o.data); // (1, 1, C, D)
}

/** Per plane, where a fit may change it, at the layout's resolution: 3 x Uint8Array (H, W), as plane_masks. */
export function planeMasks(edited, shape) {
  const [x, y, z] = shape;
  const dims = PLANE_AXES.map(([a, b]) => [shape[a], shape[b]]);
  const line = [(i, j) => i * y + j, (i, j, k) => i * z + k, (i, j, k) => j * z + k]; // plane k's cell of voxel (i, j, k)
  const counts = dims.map(([h, w]) => new Float64Array(h * w));
  const each = (visit) => { for (let i = 0; i < x; i++) for (let j = 0; j < y; j++) for (let k = 0; k < z; k++) visit(i, j, k, (i * y + j) * z + k); };
  each((i, j, k, n) => { if (edited[n]) line.forEach((at, p) => { counts[p][at(i, j, k)] += 1; }); });
  const shares = counts.map((c, p) => c.map((v) => v / shape[2 - p])); // plane p drops axis 2 - p
  const masks = dims.map(([h, w], p) => Uint8Array.from(shares[p], (s) => (s > SHARE ? 1 : 0)));
  each((i, j, k, n) => {
    if (!edited[n]) return;
    const lines = line.map((at, p) => shares[p][at(i, j, k)]);
    const best = lines.indexOf(Math.max(...lines)); // the plane of the most edited line through the cell (the first of equals)
    masks[best][line[best](i, j, k)] = 1;
  });
  return masks.map((mask, p) => { // then one cell more around
    const [h, w] = dims[p], grown = Uint8Array.from(mask);
    for (let a = 0; a < h; a++) for (let b = 0; b < w; b++) {
      if (!mask[a * w + b]) continue;
      if (a > 0) grown[(a - 1) * w + b] = 1;
      if (a < h - 1) grown[(a + 1) * w + b] = 1;
      if (b > 0) grown[a * w + b - 1] = 1;
      if (b < w - 1) grown[a * w + b + 1] = 1;
    }
    return grown;
  });
}

/** A (C, h, w) field of the layout's resolution resized onto a plane's cells by [rows, cols] matrices: rows @ d @ cols.T. */
function onPlane(field, dims, [rows, cols]) {
  const tall = along(field, dims, 1, rows);
  return along(tall.data, tall.shape, 2, cols).data;
}

/** Rows [r0, r1) and columns [c0, c1) of a matrix. */
function submatrix({ data, cols }, [r0, r1], [c0, c1]) {
  const out = new Float32Array((r1 - r0) * (c1 - c0));
  for (let i = r0; i < r1; i++) out.set(data.subarray(i * cols + c0, i * cols + c1), (i - r0) * (c1 - c0));
  return { data: out, rows: r1 - r0, cols: c1 - c0 };
}

/** The box [lo, hi) per axis of a 3-D grid. */
function crop(grid, shape, ranges) {
  const [[x0, x1], [y0, y1], [z0, z1]] = ranges, out = new grid.constructor((x1 - x0) * (y1 - y0) * (z1 - z0));
  let n = 0;
  for (let i = x0; i < x1; i++) for (let j = y0; j < y1; j++) for (let k = z0; k < z1; k++) out[n++] = grid[(i * shape[1] + j) * shape[2] + k];
  return out;
}

/**
 * The layout cells and voxels a fit can change, [lo, hi) per axis each, as
 * reach: every voxel reading a masked plane cell (masks on the planes'
 * cells), grown to whole layout cells. The fit decodes only these; the rest cannot move.
 */
function reach(masks, pools, size) {
  const touched = size.map((n) => new Uint8Array(n));
  PLANE_AXES.forEach(([a, b], k) => {
    const w = size[b];
    masks[k].forEach((on, i) => { if (on) [touched[a][Math.floor(i / w)], touched[b][i % w]] = [1, 1]; });
    if (masks[k].some((on) => on)) touched[3 - a - b].fill(1); // every voxel along the axis the plane drops reads it
  });
  const cells = [], voxels = [];
  pools.forEach(({ data, rows, cols }, a) => {
    const hit = [], read = [];
    for (let r = 0; r < rows; r++) if (touched[a].some((on, v) => on && data[r * cols + v] !== 0)) hit.push(r);
    const [r0, r1] = [hit[0], hit.at(-1) + 1]; // the cells covering a touched voxel, first to last
    for (let v = 0; v < cols; v++) for (let r = r0; r < r1; r++) if (data[r * cols + v] !== 0) { read.push(v); break; }
    cells.push([r0, r1]);
    voxels.push([read[0], read.at(-1) + 1]); // every voxel those cells cover
  });
  return { cells, voxels };
}

/** An (n, C) matrix times a (C, m) one: (n, m), summed in float32 over C in order, as Python's along. */
function times(left, right, n, c, m) {
  const out = new Float32Array(n * m), sum = new Float32Array(m);
  for (let i = 0; i < n; i++) {
    sum.fill(0);
    for (let k = 0; k < c; k++) {
      const by = left[i * c + k], row = k * m;
      if (by !== 0) for (let j = 0; j < m; j++) sum[j] += f32(by * right[row + j]);
    }
    out.set(sum, i * m);
  }
  return out;
}

/** times(left, right) where only the columns `used` of `right` (C, m) may be nonzero: the rest of the product is 0. */
function timesOn(left, right, n, c, m, used) {
  const k = used.length, packed = new Float32Array(c * k), out = new Float32Array(n * m);
  for (let r = 0; r < c; r++) for (let u = 0; u < k; u++) packed[r * k + u] = right[r * m + used[u]];
  const product = times(left, packed, n, c, k);
  for (let r = 0; r < n; r++) for (let u = 0; u < k; u++) out[r * m + used[u]] = product[r * k + u];
  return out;
}

/** The cells of a (h, w) field that rows @ field @ cols.T carries onto a `mask`ed cell: Int32Array. */
function feeding(mask, { data: rows, rows: hIn, cols: h }, { data: cols, rows: wIn, cols: w }) {
  const used = [];
  for (let u = 0; u < h; u++) for (let v = 0; v < w; v++) {
    let hit = false;
    for (let i = 0; i < hIn && !hit; i++) {
      if (rows[i * h + u] === 0) continue;
      for (let j = 0; j < wIn && !hit; j++) hit = mask[i * wIn + j] === 1 && cols[j * w + v] !== 0;
    }
    if (hit) used.push(u * w + v);
  }
  return Int32Array.from(used);
}

let decodeModule = null; // decode.wat, compiled once; an instance per fit, with a memory sized to it

/**
 * The decoder's hidden layer for the voxels of an (x, y, z) reach, in
 * WebAssembly (decode.wat; six times the plain loop), as Float32Arrays in its
 * memory: the planes' terms and their gradients, 3 x (cells, stride) with
 * stride a multiple of 4 that holds the D units; `live`, the voxels to
 * decode; `g`, each voxel's gradient at the hidden layer's output.
 * decode(all) -> each voxel's logit less bias2 (where live, or all);
 * backward() -> the terms' gradients from `g`.
 */
function decoder(model, planeDims, [x, y, z]) {
  decodeModule ??= new WebAssembly.Module(Uint8Array.from(atob(DECODE_WASM), (ch) => ch.charCodeAt(0)));
  const { bias1, weight2 } = model.head, stride = Math.ceil(bias1.length / 4) * 4, voxels = x * y * z;
  const cells = planeDims.map(([h, w]) => h * w * stride);
  const floats = [...cells, ...cells, stride, stride, voxels, voxels];
  const memory = new WebAssembly.Memory({ initial: Math.ceil((floats.reduce((a, b) => a + b) * 4 + voxels) / 65536) });
  let at = 0;
  const [xy, xz, yz, dxy, dxz, dyz, bias, w2, logits, g] = floats.map((n) => {
    const view = new Float32Array(memory.buffer, at, n);
    at += n * 4;
    return view;
  });
  const live = new Uint8Array(memory.buffer, at, voxels);
  bias.set(bias1);
  w2.set(weight2);
  const kernels = new WebAssembly.Instance(decodeModule, { env: { memory } }).exports;
  const terms = [xy, xz, yz], gradients = [dxy, dxz, dyz], [pxy, pxz, pyz] = terms.map((t) => t.byteOffset);
  return {
    stride, terms, live, g,
    decode(all) {
      kernels.decode(pxy, pxz, pyz, bias.byteOffset, w2.byteOffset, live.byteOffset, all ? 1 : 0, logits.byteOffset, x, y, z, stride);
      return logits;
    },
    backward() {
      gradients.forEach((d) => d.fill(0));
      kernels.backward(pxy, pxz, pyz, bias.byteOffset, w2.byteOffset, g.byteOffset, dxy.byteOffset, dxz.byteOffset,
        dyz.byteOffset, x, y, z, stride);
      return gradients;
    },
  };
}

/**
 * Planes (3 x { data, dims: [C, H, W] }) changed so that their occupancy,
 * area-averaged to the layout's grid, is on the layout's side of 0.5 (by
 * MARGIN) in the `edited` cells and stays on its own side in the others
 * (with `hold`, on the layout's), after at most `steps`, as
 * runtime/layout.py's fit (`weights`: firstLayer's).
 */
export function fit(model, weights, planes, target, shape, steps, edited, hold = false) {
  if (!edited.some((e) => e)) return planes;
  const { bias1, bias2 } = model.head;
  const c = planes[0].dims[0], d = bias1.length;
  const size = [planes[0].dims[1], planes[0].dims[2], planes[1].dims[2]];
  const grow = PLANE_AXES.map(([a, b]) => [resizeMatrix(shape[a], size[a]), resizeMatrix(shape[b], size[b])]);
  const fieldDims = PLANE_AXES.map(([a, b]) => [c, shape[a], shape[b]]);
  const masks = planeMasks(edited, shape).map((m, p) => Uint8Array.from(onPlane(m, fieldDims[p].with(0, 1), grow[p]), (v) => (v > 0 ? 1 : 0)));
  // Within reach: cells (the layout's) and voxels (x, y, z from `low`); a voxel's plane cells by plane.
  const fullPools = size.map((n, a) => areaWeights(n, shape[a]));
  const { cells, voxels } = reach(masks, fullPools, size);
  const pools = fullPools.map((w, a) => submatrix(w, cells[a], voxels[a])), back = pools.map(transpose);
  const box = cells.map(([lo, hi]) => hi - lo), low = voxels.map(([lo]) => lo), [x, y, z] = voxels.map(([lo, hi]) => hi - lo);
  [target, edited] = [crop(target, shape, cells), crop(edited, shape, cells)];
  const planeCell = PLANE_AXES.map(([a, b]) => (i, j) => (low[a] + i) * size[b] + low[b] + j); // (i, j) of the reach
  const planeDims = PLANE_AXES.map(([a, b]) => [[x, y, z][a], [x, y, z][b]]);
  // The first layer is linear, so a plane's term is its start's plus the mask
  // times the change's term resized: the change goes through the layer at the
  // layout's resolution (several times fewer cells than a plane's), and so does its gradient.
  const growIn = PLANE_AXES.map(([a, b], k) => [submatrix(grow[k][0], voxels[a], [0, shape[a]]), submatrix(grow[k][1], voxels[b], [0, shape[b]])]);
  const shrinkIn = growIn.map((matrices) => matrices.map(transpose));
  const moving = planeDims.map(([h, w], k) => { // the mask within reach
    const out = new Uint8Array(h * w);
    for (let i = 0; i < h; i++) for (let j = 0; j < w; j++) out[i * w + j] = masks[k][planeCell[k](i, j)];
    return out;
  });
  // Only the change's cells that reach a masked cell move (the others' gradient is 0), so only those go through the layer.
  const used = moving.map((mask, k) => feeding(mask, ...growIn[k]));
  const start = planes.map((p, k) => { // einsum chw,cd->hwd over the voxels in reach: (h * w, D)
    const [h, w] = planeDims[k], area = p.dims[1] * p.dims[2], cells = new Float32Array(h * w * c);
    for (let i = 0; i < h; i++) for (let j = 0; j < w; j++) {
      for (let ch = 0; ch < c; ch++) cells[(i * w + j) * c + ch] = p.data[ch * area + planeCell[k](i, j)];
    }
    return times(cells, weights[k], h * w, c, d);
  });
  const weightsT = weights.map((w) => transpose({ data: w, rows: c, cols: d }).data); // (D, C)
  const { stride, terms, live, g, decode, backward } = decoder(model, planeDims, [x, y, z]); // terms: (h * w, stride)
  terms.forEach((term, k) => { for (let n = 0; n < term.length / stride; n++) term.set(start[k].subarray(n * d, n * d + d), n * stride); });
  for (let i = 0; i < x; i++) for (let j = 0; j < y; j++) for (let k = 0; k < z; k++) {
    live[(i * y + j) * z + k] = moving[0][i * y + j] | moving[1][i * z + k] | moving[2][j * z + k];
  }
  const change = fieldDims.map((dims) => new Float32Array(product(dims)));
  const moments = change.map((field) => [new Float32Array(field.length), new Float32Array(field.length)]);
  const occupancy = new Float32Array(x * y * z);
  const count = edited.reduce((n, e) => n + e, 0);
  let side = null, need = null, weight = null;
  for (let step = 1; step <= steps; step++) {
    if (step > 1) terms.forEach((term, k) => { // step 1: no change yet
      if (!used[k].length) return; // a plane the fit may not change
      const [, h, w] = fieldDims[k], [hIn, wIn] = planeDims[k], area = hIn * wIn;
      const moved = onPlane(timesOn(weightsT[k], change[k], d, c, h * w, used[k]), [d, h, w], growIn[k]); // (D, h, w) of the reach
      for (let n = 0; n < area; n++) {
        if (!moving[k][n]) continue;
        for (let e = 0; e < d; e++) term[n * stride + e] = start[k][n * d + e] + moved[e * area + n];
      }
    });
    const logits = decode(step === 1);
    for (let n = 0; n < occupancy.length; n++) if (step === 1 || live[n]) occupancy[n] = 1 / (1 + Math.exp(-f32(logits[n] + bias2)));
    const pooled = separable(pools, occupancy, [x, y, z]).data;
    if (side === null) { // the unedited cells keep the side these planes put them on (with hold, the layout's)
      side = Float32Array.from(pooled, (v, n) => ((edited[n] || hold ? target[n] : v > 0.5) ? 1 : -1));
      need = Float32Array.from(edited, (e) => (e ? MARGIN : 0));
      weight = Float32Array.from(edited, (e) => (e ? 1 : f32(KEEP_WEIGHT)) / count);
    }
    const hinge = new Float32Array(target.length); // its gradient in the cells short of their side
    let short = false;
    for (let n = 0; n < target.length; n++) {
      if (f32(need[n] - f32(side[n] * f32(pooled[n] - 0.5))) > 0) [hinge[n], short] = [-side[n] * weight[n], true];
    }
    if (!short || step === steps) break;
    // The hinge's gradient, back through the pooling, the sigmoid and the ReLU.
    const dOccupancy = separable(back, hinge, box).data;
    for (let n = 0; n < g.length; n++) { // a voxel reading no masked cell moves nothing
      g[n] = live[n] ? dOccupancy[n] * Math.max(f32(occupancy[n] * f32(1 - occupancy[n])), f32(SLOPE_FLOOR)) : 0;
    }
    const dA = backward(); // (h * w, stride) per plane
    change.forEach((field, k) => {
      if (!used[k].length) return; // its gradient is 0: it stays 0
      const [, h, w] = fieldDims[k], [hIn, wIn] = planeDims[k], area = hIn * wIn;
      const masked = new Float32Array(d * area); // (D, h, w) of the reach: mask * dA
      for (let n = 0; n < area; n++) if (moving[k][n]) for (let e = 0; e < d; e++) masked[e * area + n] = dA[k][n * stride + e];
      const onLayout = onPlane(masked, [d, hIn, wIn], shrinkIn[k]); // (D, h, w) of the layout
      const grad = timesOn(weights[k], onLayout, c, d, h * w, used[k]), [m, v] = moments[k]; // einsum hwd,cd->chw
      const pull = f32(2 * PULL / field.length), m1 = f32(1 - 0.9 ** step), v1 = f32(1 - 0.999 ** step);
      for (let i = 0; i < field.length; i++) { // Adam, beta1 0.9, beta2 0.999
        const g = f32(grad[i] + f32(pull * field[i]));
        m[i] += f32(f32(0.1) * f32(g - m[i]));
        v[i] += f32(f32(0.001) * f32(f32(g * g) - v[i]));
        field[i] -= f32(f32(FIT_RATE * f32(m[i] / m1)) / f32(f32(Math.sqrt(f32(v[i] / v1))) + f32(1e-8)));
      }
    });
  }
  return planes.map((p, k) => { // the start plus the mask times the change resized
    const moved = onPlane(change[k], fieldDims[k], grow[k]), area = p.dims[1] * p.dims[2], mask = masks[k];
    const data = new Float32Array(p.data.length);
    for (let at = 0; at < data.length; at += area) {
      for (let i = 0; i < area; i++) data[at + i] = p.data[at + i] + mask[i] * moved[at + i];
    }
    return { data, dims: p.dims };
  });
}

/** The level whose grid a layout of `shape` is. */
function layoutLevel(sizes, shape) {
  const level = sizes.slice(0, -1).findIndex((size) => size.join() === shape.join());
  if (level < 0) {
    const grids = sizes.slice(0, -1).map((size) => size.join('x')).join(', ');
    throw new InputError(`the layout is ${shape.join('x')}, and this sample's levels are ${grids}; resample it to level 0's grid, or export one with \`layout\``);
  }
  return level;
}

/**
 * The tri-plane of the sample of `seed` with the structure of the layout
 * `target` (0/1 of one level's `shape`, found by its shape), as
 * layout.from_layout: structure from the layout, detail from the model and the seed.
 */
export async function fromLayout(model, seed, target, shape, factors = [1, 1, 1]) {
  const sizes = scaledSizes(model.manifest.sizes, factors);
  const level = layoutLevel(sizes, shape);
  if (target.length !== product(shape)) throw new InputError(`a layout of ${shape.join('x')} cells needs ${product(shape)} values, got ${target.length}`);
  const wanted = threshold(target);
  const value = checkSeed(seed), noise = drawNoise(value, sizes, model.manifest.channels);
  // The cells the user edited: where the layout differs from the seed's own.
  const seedLayout = await own(model, value, factors, shape, () => triplane(model, noise, sizes));
  const edited = wanted.map((v, n) => (v !== seedLayout[n] ? 1 : 0));
  const weights = await firstLayer(model);
  const last = sizes.length - 1;
  return triplane(model, noise, sizes, (i, planes) => (i < level ? planes
    : fit(model, weights, planes, wanted, shape, i === level ? FIT_STEPS : i === last ? HOLD_STEPS : FINER_STEPS, edited, i === last)));
}
