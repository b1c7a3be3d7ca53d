// Generate a tri-plane: chain the level stages with noise injection, as
// runtime/generate.py does, in the same float32 operation order where it
// matters (pooling sums in float64, noise scaled then added in float32).
//
// Planes are { data: Float32Array (C, H, W), dims: [C, H, W] }, in the order
// xy (X, Y), xz (X, Z), yz (Y, Z).
import { planeNoise, z0Noise } from './noise.js';
import { InputError, pyRepr } from './errors.js';

export const MIN_SIDE = 2; // a sample's coarsest grid may not shrink below this many voxels per axis
const MAX_BYTES = 4 * 2 ** 30; // a WASM memory holds at most 4 GiB: the browser's own bound

/** Plane sizes of a grid (X, Y, Z): [(X, Y), (X, Z), (Y, Z)]. */
export const planeSizes = ([x, y, z]) => [[x, y], [x, z], [y, z]];

// Python's round(): halves go to the even neighbour.
export function roundHalfEven(v) {
  const r = Math.round(v);
  return Math.abs(v % 1) === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

// A number as Python's float() reads text: digits, a point, an exponent, inf or nan, spaces around.
const FLOAT_TEXT = /^[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?|inf|infinity|nan)$/i;

/** Text as Python's float() reads it: a number, or null where float() refuses it. */
export function parseNumber(text) {
  const t = String(text).trim();
  if (!FLOAT_TEXT.test(t)) return null;
  return /nan/i.test(t) ? NaN : /inf/i.test(t) ? (t.startsWith('-') ? -Infinity : Infinity) : Number(t);
}

/** 'a,b,c', or one value for all three axes -> three numbers passing `valid`, as generate.parse_triple.
 * The text form of per-axis values, shared by the page and the web API. */
export function parseTriple(text, valid, example, name = 'size') {
  let values = String(text).split(',').map(parseNumber);
  if (values.includes(null)) values = [];
  if (values.length === 1) values = [values[0], values[0], values[0]];
  if (values.length !== 3 || !values.every(valid)) throw new InputError(`${name} ${pyRepr(text)}: give ${example}`);
  return values;
}

/** '2' or '2,1,0.5' -> three finite positive size factors, one per axis, as generate.parse_size. */
export const parseSize = (text) => parseTriple(text, (f) => f > 0 && f < Infinity, 'one or three positive factors, like 2 or 2,1,0.5');

/** Every level's grid for a sample `factors` times the training size per axis. */
export function scaledSizes(sizes, factors = [1, 1, 1]) {
  if (factors.length !== 3 || !factors.every((f) => f > 0 && Number.isFinite(f))) {
    throw new InputError(`size factors must be 3 positive numbers, got (${factors.join(', ')})`);
  }
  return sizes.map((size) => size.map((n, i) => Math.max(MIN_SIDE, roundHalfEven(n * factors[i]))));
}

/**
 * Average-pool a (X, Y, Z) volume into `bins` slabs along each plane's dropped
 * axis: [(bins, X, Y), (bins, X, Z), (bins, Y, Z)]. Bin k of n covers
 * floor(k n / bins) .. ceil((k + 1) n / bins), as torch's adaptive pooling.
 */
export function adaptivePool(volume, [sx, sy, sz], bins) {
  const strides = [sy * sz, sz, 1], shape = [sx, sy, sz];
  return [2, 1, 0].map((axis) => {
    const n = shape[axis];
    const [a, b] = [0, 1, 2].filter((i) => i !== axis); // the plane's axes, in order
    const na = shape[a], nb = shape[b];
    const out = new Float32Array(bins * na * nb);
    const cumsum = new Float64Array(n + 1);
    for (let i = 0; i < na; i++) {
      for (let j = 0; j < nb; j++) {
        const base = i * strides[a] + j * strides[b];
        for (let t = 0; t < n; t++) cumsum[t + 1] = cumsum[t] + volume[base + t * strides[axis]];
        for (let k = 0; k < bins; k++) {
          const start = Math.floor((k * n) / bins), end = Math.ceil(((k + 1) * n) / bins);
          out[(k * na + i) * nb + j] = (cumsum[end] - cumsum[start]) / (end - start);
        }
      }
    }
    return { data: out, dims: [bins, na, nb] };
  });
}

/** Linear interpolation from n_in to n_out points, align_corners=True: per output, (low, high, wLow, wHigh) in float32. */
export function resizeWeights(nIn, nOut) {
  const low = new Int32Array(nOut), high = new Int32Array(nOut);
  const wLow = new Float32Array(nOut), wHigh = new Float32Array(nOut);
  const ratio = nOut > 1 ? (nIn - 1) / (nOut - 1) : 0;
  for (let i = 0; i < nOut; i++) {
    const src = i * ratio;
    low[i] = Math.min(Math.floor(src), nIn - 1);
    high[i] = Math.min(low[i] + 1, nIn - 1);
    const frac = Math.fround(src - low[i]);
    wLow[i] = Math.fround(1 - frac);
    wHigh[i] = frac;
    if (high[i] === low[i]) { wLow[i] = Math.fround(wLow[i] + wHigh[i]); wHigh[i] = 0; }
  }
  return { low, high, wLow, wHigh };
}

/** Bilinear resize (align_corners=True) of a (C, H, W) plane to (h, w). */
export function resizePlane(plane, [h, w]) {
  const [c, hIn, wIn] = plane.dims;
  if (hIn === h && wIn === w) return plane;
  const rows = resizeWeights(hIn, h), cols = resizeWeights(wIn, w);
  const out = new Float32Array(c * h * w);
  const src = plane.data;
  for (let ch = 0; ch < c; ch++) {
    const base = ch * hIn * wIn;
    for (let i = 0; i < h; i++) {
      const r0 = base + rows.low[i] * wIn, r1 = base + rows.high[i] * wIn, a = rows.wLow[i], b = rows.wHigh[i];
      const at = (ch * h + i) * w;
      for (let j = 0; j < w; j++) {
        const c0 = cols.low[j], c1 = cols.high[j];
        const top = Math.fround(a * src[r0 + c0] + b * src[r1 + c0]);
        const bottom = Math.fround(a * src[r0 + c1] + b * src[r1 + c1]);
        out[at + j] = cols.wLow[j] * top + cols.wHigh[j] * bottom;
      }
    }
  }
  return { data: out, dims: [c, h, w] };
}

/** The noise a seed stands for: { z0, planes: [null, [3 x (C, H, W)] per level > 0] }, from level
 * `first` on (a chain resumed past level 0 needs none before it: null), as generate.draw_noise. */
export function drawNoise(seed, sizes, channels, first = 0) {
  const planes = sizes.map((size, level) => (level === 0 || level < first ? null
    : planeSizes(size).map((shape, k) => planeNoise(seed, level, k, channels, shape))));
  return { z0: first === 0 ? z0Noise(seed, sizes[0]) : null, planes };
}

const batch = (plane) => ({ data: plane.data, dims: [1, ...plane.dims] });
const unbatch = (t) => ({ data: t.data, dims: Array.from(t.dims).slice(1) });

/**
 * Chain the levels with the given noise: the final tri-plane { planes, size }.
 * afterLevel(level, planes), if given, returns the planes the chain goes on
 * from (editing blends parts in), as runtime/generate.py's after_level.
 * start, { level, planes }: that level's planes, made before, to go on from
 * (a world's window made finer), as its `start`.
 */
export async function triplane(model, noise, sizes, afterLevel = (level, planes) => planes, start = null) {
  const m = model.manifest, amps = m.noiseAmps;
  let planes = start?.planes;
  if (!start) {
    const z0 = noise.z0.map((v) => Math.fround(amps[0] * v));
    const pooled = adaptivePool(z0, sizes[0], m.poolBins);
    const projected = await model.projection.run(pooled.map(batch));
    planes = afterLevel(0, (await model.levels[0].run(projected)).map(unbatch));
  }
  for (let level = start ? start.level + 1 : 1; level < sizes.length; level++) {
    const upsampled = planes.map((p, k) => resizePlane(p, planeSizes(sizes[level])[k]));
    let inputs = upsampled;
    if (noise.planes[level]) {
      const amp = amps[level];
      inputs = upsampled.map((u, k) => {
        const n = noise.planes[level][k];
        return { data: u.data.map((v, i) => v + Math.fround(amp * n[i])), dims: u.dims };
      });
    }
    const residuals = await model.levels[level].run(inputs.map(batch));
    planes = afterLevel(level, upsampled.map((u, k) => ({ data: u.data.map((v, i) => v + residuals[k].data[i]), dims: u.dims })));
  }
  return { planes, size: sizes[sizes.length - 1] };
}

/** Every level's planes of one sample, coarsest first. */
export async function chain(model, noise, sizes) {
  const levels = [];
  await triplane(model, noise, sizes, (level, planes) => { levels.push(planes); return planes; });
  return levels;
}

export function checkSeed(seed) {
  let value;
  try {
    value = BigInt(seed);
  } catch {
    value = -1n;
  }
  if (value < 0n || value >= 2n ** 63n) throw new InputError(`seed must be an integer in [0, 2**63), got ${seed}`, 'seed');
  return value;
}

/**
 * The tri-plane of one sample: a seed (Number, BigInt or digit string), or
 * null for the training shape; factors scale the training size per axis.
 */
export async function sample(model, seed = null, factors = [1, 1, 1]) {
  const m = model.manifest;
  const sizes = scaledSizes(m.sizes, factors);
  const z0Bytes = sizes[0].reduce((a, b) => a * b) * 16;
  const planeBytes = Math.max(...sizes.map((s) => planeSizes(s).reduce((n, [h, w]) => n + h * w, 0))) * m.channels * 4 * 6;
  if (z0Bytes + planeBytes > MAX_BYTES) {
    throw new InputError(`a sample of size ${factors.join('x')} needs about ${((z0Bytes + planeBytes) / 2 ** 30).toFixed(1)} GiB of memory`);
  }
  if (seed === null) {
    if (JSON.stringify(sizes) !== JSON.stringify(m.sizes)) throw new InputError('the reconstruction exists only at the training size; drop --size');
    return triplane(model, { z0: z0Noise(m.reconSeed, sizes[0]), planes: sizes.map(() => null) }, sizes);
  }
  return triplane(model, drawNoise(checkSeed(seed), sizes, m.channels), sizes);
}
