// Compose a sample from boxes of other samples, or grow one, as
// runtime/edit.py does (docs/EDITING.md): after each level, the result's
// planes take each part's planes deeper than MARGIN cells inside the box's
// rectangle, the base's further than MARGIN outside, and keep their own in
// between (the join); the noise is the part's inside the rectangle.
import { InputError, formatG, pyRepr } from './errors.js';
import { chain, checkSeed, drawNoise, parseNumber, planeSizes, roundHalfEven, scaledSizes, triplane } from './generate.js';
import { PLANE_AXES } from './query.js';

export const MARGIN = 4;

/**
 * 'SEED:X0,Y0,Z0:X1,Y1,Z1' -> a part of a sample of finest size `size`, as
 * edit.parse_part: corners in the model's frame (manifest's origin and
 * spacing), or percentages of the sample's extent ('50%').
 */
export function parsePart(text, manifest, size) {
  const part = readPart(text, manifest, size);
  // A figure in the units the box was written in along an axis, beside the voxels, as edit.parse_part's in_units.
  const inUnits = (axis, voxels, length = false) => (part.percent[axis]
    ? `${formatG((voxels / Math.max(size[axis] - 1, 1)) * 100)}%`
    : formatG(voxels * manifest.spacing[axis] + (length ? 0 : manifest.origin[axis])));
  return checkPart(part, size, inUnits);
}

/** parsePart's reading of the text, { seed, low, high }, before its box is checked (the page draws it as typed). */
export function readPart(text, manifest, size) {
  const pieces = text.split(':');
  if (pieces.length !== 3) throw new InputError(`part ${pyRepr(text)}: give SEED:X0,Y0,Z0:X1,Y1,Z1, like 3:0%,0%,0%:50%,100%,100%`, 'keep');
  if (!/^\s*[+-]?\d+\s*$/.test(pieces[0])) throw new InputError(`part ${pyRepr(text)}: the seed ${pyRepr(pieces[0])} is not an integer`, 'keep');
  const percent = [false, false, false];
  const [low, high] = pieces.slice(1).map((corner) => {
    const values = corner.split(',');
    if (values.length !== 3) throw new InputError(`part ${pyRepr(text)}: a corner needs 3 values, got ${pyRepr(corner)}`, 'keep');
    return values.map((value, axis) => {
      const inPercent = value.trim().endsWith('%');
      const number = parseNumber(inPercent ? value.trim().slice(0, -1) : value);
      if (number === null) throw new InputError(`part ${pyRepr(text)}: ${pyRepr(value)} is not a number or a percentage`, 'keep');
      if (inPercent) percent[axis] = true;
      return inPercent ? (number / 100) * (size[axis] - 1) : (number - manifest.origin[axis]) / manifest.spacing[axis];
    });
  });
  return { seed: BigInt(pieces[0].trim()), low, high, percent };
}

/** Check a part { seed, low, high, offset, factors } against a sample of finest size `size`, as edit.check_part. */
export function checkPart(part, size, inUnits = null) {
  checkSeed(part.seed);
  const corners = [part.low, part.high];
  if (!corners.every((c) => Array.isArray(c) && c.length === 3 && c.every(Number.isFinite))) {
    throw new InputError(`a box needs two corners of 3 finite numbers, got ${pyRepr(part.low)}, ${pyRepr(part.high)}`, 'keep');
  }
  const also = (axis, voxels, length = false) => (inUnits ? ` (${inUnits(axis, voxels, length)})` : '');
  for (let axis = 0; axis < 3; axis++) {
    const [lo, hi, n, name] = [part.low[axis], part.high[axis], size[axis], 'xyz'[axis]];
    if (!(lo < hi)) {
      throw new InputError(`the box is empty or inverted along ${name} (${formatG(lo)}${also(axis, lo)} to `
        + `${formatG(hi)}${also(axis, hi)} voxels)`, 'keep');
    }
    if (lo < 0 || hi > n - 1) {
      throw new InputError(`the box (${formatG(lo)}${also(axis, lo)} to ${formatG(hi)}${also(axis, hi)} voxels along ${name}) `
        + `leaves the sample, whose voxels run 0 to ${n - 1}${also(axis, n - 1)} along ${name}`, 'keep');
    }
    const kept = (hi < n - 1 ? hi : Infinity) - (lo > 0 ? lo : -Infinity) - 2 * MARGIN;
    if (!(kept > 0)) {
      throw new InputError(`the box is ${formatG(hi - lo)}${also(axis, hi - lo, true)} voxels along ${name}: a kept box `
        + `needs more than ${2 * MARGIN}${also(axis, 2 * MARGIN, true)} (a ${MARGIN}-voxel join on each side inside the sample)`, 'keep');
    }
  }
  return { seed: part.seed, low: part.low, high: part.high, offset: part.offset ?? [0, 0, 0], factors: part.factors ?? null };
}

/** (H, W) level cells inside the box's rectangle on plane k (negative outside); edges of the sample are infinitely far. */
function depth(part, finest, levelSize, k) {
  const [a, b] = PLANE_AXES[k];
  const along = (axis) => {
    const n = finest[axis], cells = levelSize[axis], toLevel = n > 1 ? (cells - 1) / (n - 1) : 0;
    const lo = part.low[axis] > 0 ? part.low[axis] * toLevel : -Infinity;
    const hi = part.high[axis] < n - 1 ? part.high[axis] * toLevel : Infinity;
    return Float64Array.from({ length: cells }, (_, c) => Math.min(c - lo, hi - c));
  };
  const rows = along(a), cols = along(b);
  const out = new Float64Array(rows.length * cols.length);
  for (let i = 0; i < rows.length; i++) for (let j = 0; j < cols.length; j++) out[i * cols.length + j] = Math.min(rows[i], cols[j]);
  return out;
}

const clip01 = (v) => Math.min(1, Math.max(0, v));

function blend(base, made, parts, sources, finest, levelSize) {
  return made.map((plane, k) => {
    const [c, h, w] = plane.dims, cells = h * w;
    const depths = parts.map((part) => depth(part, finest, levelSize, k));
    const near = new Float64Array(cells).fill(1);
    for (const d of depths) for (let i = 0; i < cells; i++) near[i] *= 1 - clip01((d[i] + MARGIN) / MARGIN);
    const out = new Float32Array(c * cells);
    for (let ch = 0; ch < c; ch++) {
      for (let i = 0; i < cells; i++) {
        const at = ch * cells + i;
        let v = near[i] * base[k].data[at] + (1 - near[i]) * plane.data[at];
        depths.forEach((d, p) => { const inside = clip01(d[i] / MARGIN); v = inside * sources[p][k].data[at] + (1 - inside) * v; });
        out[at] = v;
      }
    }
    return { data: out, dims: plane.dims };
  });
}

/** Where each of `cells` composed cells lies in its source level: integer arithmetic, as runtime/edit.py's placement. */
function placement(cells, finest, sourceCells, sourceFinest, offset) {
  const low = new Int32Array(cells), frac = new Float64Array(cells), nearest = new Int32Array(cells);
  const den = BigInt(Math.max(1, (cells - 1) * (sourceFinest - 1)));
  const max = BigInt(sourceCells - 1) * den;
  for (let c = 0; c < cells; c++) {
    let num = (BigInt(c * (finest - 1)) - BigInt(offset * (cells - 1))) * BigInt(sourceCells - 1);
    num = num < 0n ? 0n : num > max ? max : num;
    low[c] = Number(num / den);
    frac[c] = Number(num - BigInt(low[c]) * den) / Number(den);
    nearest[c] = Number((2n * num + den) / (2n * den));
  }
  return { low, frac, nearest };
}

function placePlane(plane, rows, cols) {
  const [c, hIn, wIn] = plane.dims, h = rows.low.length, w = cols.low.length;
  const out = new Float32Array(c * h * w);
  for (let ch = 0; ch < c; ch++) {
    for (let i = 0; i < h; i++) {
      const r0 = rows.low[i], r1 = Math.min(r0 + 1, hIn - 1), fr = rows.frac[i];
      for (let j = 0; j < w; j++) {
        const c0 = cols.low[j], c1 = Math.min(c0 + 1, wIn - 1), fc = cols.frac[j];
        const at = (r, q) => plane.data[(ch * hIn + r) * wIn + q];
        // rows first, then columns, as (rows @ plane @ cols.T) does
        const left = (1 - fr) * at(r0, c0) + fr * at(r1, c0), right = (1 - fr) * at(r0, c1) + fr * at(r1, c1);
        out[(ch * h + i) * w + j] = (1 - fc) * left + fc * right;
      }
    }
  }
  return { data: out, dims: [c, h, w] };
}

async function place(model, part, sizes) {
  const sourceSizes = part.factors ? scaledSizes(model.manifest.sizes, part.factors) : sizes;
  const finest = sizes[sizes.length - 1], sourceFinest = sourceSizes[sourceSizes.length - 1];
  for (let axis = 0; axis < 3; axis++) {
    if (part.low[axis] - part.offset[axis] < 0 || part.high[axis] - part.offset[axis] > sourceFinest[axis] - 1) {
      throw new InputError(`the box reaches outside the sample of seed ${part.seed} along ${'xyz'[axis]}`);
    }
  }
  const noise = drawNoise(checkSeed(part.seed), sourceSizes, model.manifest.channels);
  const levels = await chain(model, noise, sourceSizes);
  const planes = [], noisePlanes = [null];
  sizes.forEach((size, level) => {
    const where = [0, 1, 2].map((a) => placement(size[a], finest[a], sourceSizes[level][a], sourceFinest[a], part.offset[a]));
    const levelPlanes = [], levelNoise = [];
    PLANE_AXES.forEach(([a, b], k) => {
      levelPlanes.push(placePlane(levels[level][k], where[a], where[b]));
      if (level > 0) {
        const src = noise.planes[level][k], [c, hIn, wIn] = [model.manifest.channels, ...planeSizes(sourceSizes[level])[k]];
        const h = size[a], w = size[b], out = new Float32Array(c * h * w);
        for (let ch = 0; ch < c; ch++) for (let i = 0; i < h; i++) for (let j = 0; j < w; j++) {
          out[(ch * h + i) * w + j] = src[(ch * hIn + where[a].nearest[i]) * wIn + where[b].nearest[j]];
        }
        levelNoise.push(out);
      }
    });
    planes.push(levelPlanes);
    if (level > 0) noisePlanes.push(levelNoise);
  });
  const near0 = [0, 1, 2].map((a) => placement(sizes[0][a], finest[a], sourceSizes[0][a], sourceFinest[a], part.offset[a]).nearest);
  const [sx, sy, sz] = sourceSizes[0], [x, y, z] = sizes[0];
  const z0 = new Float32Array(x * y * z);
  for (let i = 0; i < x; i++) for (let j = 0; j < y; j++) for (let q = 0; q < z; q++) {
    z0[(i * y + j) * z + q] = noise.z0[(near0[0][i] * sy + near0[1][j]) * sz + near0[2][q]];
  }
  return { planes, noise: { z0, planes: noisePlanes } };
}

function composeNoise(base, parts, placed, sizes) {
  const finest = sizes[sizes.length - 1];
  const z0 = Float32Array.from(base.z0), [x, y, z] = sizes[0];
  parts.forEach((part, p) => {
    const range = [0, 1, 2].map((a) => {
      const toLevel = finest[a] > 1 ? (sizes[0][a] - 1) / (finest[a] - 1) : 0;
      return [Math.ceil(part.low[a] * toLevel), Math.floor(part.high[a] * toLevel)];
    });
    for (let i = range[0][0]; i <= Math.min(range[0][1], x - 1); i++) for (let j = range[1][0]; j <= Math.min(range[1][1], y - 1); j++) {
      for (let q = range[2][0]; q <= Math.min(range[2][1], z - 1); q++) z0[(i * y + j) * z + q] = placed[p].noise.z0[(i * y + j) * z + q];
    }
  });
  const planes = [null];
  for (let level = 1; level < sizes.length; level++) {
    const merged = base.planes[level].map((n) => Float32Array.from(n));
    parts.forEach((part, p) => {
      for (let k = 0; k < 3; k++) {
        const d = depth(part, finest, sizes[level], k), cells = d.length, src = placed[p].noise.planes[level][k];
        for (let ch = 0; ch < merged[k].length / cells; ch++) for (let i = 0; i < cells; i++) if (d[i] >= 0) merged[k][ch * cells + i] = src[ch * cells + i];
      }
    });
    planes.push(merged);
  }
  return { z0, planes };
}

/** The sample of `seed` with each part's box from the part's own sample, as runtime.compose. */
export async function compose(model, seed, parts, factors = [1, 1, 1]) {
  const m = model.manifest;
  const sizes = scaledSizes(m.sizes, factors);
  const checked = parts.map((part) => checkPart(part, sizes[sizes.length - 1]));
  if (!checked.length) throw new InputError('give at least one part to keep');
  const baseNoise = drawNoise(checkSeed(seed), sizes, m.channels);
  const placed = [];
  for (const part of checked) placed.push(await place(model, part, sizes));
  const base = await chain(model, baseNoise, sizes);
  const finest = sizes[sizes.length - 1];
  const made = await triplane(model, composeNoise(baseNoise, checked, placed, sizes), sizes, (level, planes) => blend(
    base[level], planes, checked, placed.map((p) => p.planes[level]), finest, sizes[level]));
  // Its parts, each placed on this grid, so that deep in a kept box the colour is the part's own (runtime.edit.compose).
  return { ...made, kept: checked.map((part, i) => ({ low: part.low, high: part.high, tri: { planes: placed[i].planes.at(-1), size: finest } })) };
}

/**
 * The part `grow` keeps: the sample of `seed` at size `factors`, placed at
 * `anchor` of the sample `by` times larger ({ part, grown }: grown, that
 * sample's factors), as edit.grow places it. The page draws its box.
 */
export function grownPart(sizes, seed, by, anchor = [0, 0, 0], factors = [1, 1, 1]) {
  if (!(by.length === 3 && by.every((f) => f >= 1 && f < Infinity))) throw new InputError(`grow factors must be 3 numbers of at least 1, got ${pyRepr(by)}`, 'grow');
  if (!(anchor.length === 3 && anchor.every((a) => a >= 0 && a <= 1))) throw new InputError(`an anchor is 3 numbers in [0, 1], got ${pyRepr(anchor)}`, 'anchor');
  const old = scaledSizes(sizes, factors).at(-1), grown = factors.map((f, a) => f * by[a]);
  const size = scaledSizes(sizes, grown).at(-1);
  const offset = anchor.map((a, i) => roundHalfEven(a * (size[i] - old[i])));  // Python's round()
  return { part: { seed, low: offset, high: offset.map((v, i) => v + old[i] - 1), offset, factors }, grown };
}

/** The sample of `seed` grown `by` times, keeping what it had at `anchor`, as runtime.edit.grow. */
export async function grow(model, seed, by, anchor = [0, 0, 0], factors = [1, 1, 1]) {
  const { part, grown } = grownPart(model.manifest.sizes, seed, by, anchor, factors);
  return compose(model, seed, [part], grown);
}
