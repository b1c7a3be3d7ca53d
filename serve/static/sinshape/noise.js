// Counter-based Gaussian noise (docs/FORMAT.md, "Noise"): the same values as
// core/noise.py, bit for bit. Every value is a pure function of
// (seed, stream, position), computed with unsigned 64-bit wrapping arithmetic.
// Keys (a few per sample) use BigInt; the bulk work uses 32-bit halves, which
// is about 50 times faster than BigInt per value.

export const MASK64 = (1n << 64n) - 1n;
export const GOLDEN = 0x9e3779b97f4a7c15n;
export const GOLDEN_HI = 0x9e3779b9;
export const GOLDEN_LO = 0x7f4a7c15;
const TWO32 = 4294967296;
export const COORD_BITS = 21;

export const Z0_STREAM = 0; // (Z0_STREAM,): the coarsest level's 3-D input noise z0
export const PLANE_STREAM = 1; // (PLANE_STREAM, level, plane, channel): noise added at a level

/** SplitMix64's finaliser on a BigInt in [0, 2**64), as core/noise.py's mix64. */
export function mix64Big(z) {
  z = ((z ^ (z >> 30n)) * 0xbf58476d1ce4e5b9n) & MASK64;
  z = ((z ^ (z >> 27n)) * 0x94d049bb133111ebn) & MASK64;
  return z ^ (z >> 31n);
}

/** The 64-bit key of one noise array: seed and stream ids absorbed (BigInt). */
export function streamKey(seed, ...ids) {
  let key = 0n;
  for (const v of [seed, ...ids]) {
    const value = BigInt(v);
    if (value < 0n || value > MASK64) throw new RangeError(`noise seed and stream ids must be in [0, 2**64), got ${v}`);
    key = mix64Big((key + GOLDEN * (value + 1n)) & MASK64);
  }
  return key;
}

// ---- 64-bit arithmetic on (hi, lo) pairs of uint32; results in hiOut / loOut
// (exported as live bindings: an importer reads them right after a call)
export let hiOut = 0;
export let loOut = 0;

/** (ah, al) * (bh, bl) mod 2^64, with 16-bit limbs for the high half of al * bl. */
export function mul64(ah, al, bh, bl) {
  const a0 = al & 0xffff, a1 = al >>> 16, b0 = bl & 0xffff, b1 = bl >>> 16;
  const p01 = a0 * b1, p10 = a1 * b0; // < 2^32, exact
  const carry = (((a0 * b0) >>> 16) + (p01 & 0xffff) + (p10 & 0xffff)) >>> 16;
  hiOut = (a1 * b1 + (p01 >>> 16) + (p10 >>> 16) + carry + Math.imul(ah, bl) + Math.imul(al, bh)) >>> 0;
  loOut = Math.imul(al, bl) >>> 0;
}

/** (ah, al) + (bh, bl) mod 2^64. */
export function add64(ah, al, bh, bl) {
  const low = al + bl;
  loOut = low >>> 0;
  hiOut = (ah + bh + (low >= TWO32 ? 1 : 0)) >>> 0;
}

/** SplitMix64's finaliser on (hi, lo). */
export function mix64(hi, lo) {
  lo = (lo ^ ((lo >>> 30) | (hi << 2))) >>> 0; // z ^= z >> 30
  hi = (hi ^ (hi >>> 30)) >>> 0;
  mul64(hi, lo, 0xbf58476d, 0x1ce4e5b9);
  hi = hiOut; lo = loOut;
  lo = (lo ^ ((lo >>> 27) | (hi << 5))) >>> 0; // z ^= z >> 27
  hi = (hi ^ (hi >>> 27)) >>> 0;
  mul64(hi, lo, 0x94d049bb, 0x133111eb);
  hi = hiOut; lo = loOut;
  loOut = (lo ^ ((lo >>> 31) | (hi << 1))) >>> 0; // z ^= z >> 31
  hiOut = (hi ^ (hi >>> 31)) >>> 0;
}

/** Box-Muller on the halves of h, in float64, rounded to float32. */
function normalFromBits(hi, lo) {
  const u1 = (hi + 0.5) / TWO32;
  const u2 = lo / TWO32;
  return Math.fround(Math.sqrt(-2.0 * Math.log(u1)) * Math.cos(2.0 * Math.PI * u2));
}

function checkShape(shape, offset) {
  if (shape.length !== offset.length || shape.length < 2 || shape.length > 3) {
    throw new RangeError(`noise blocks are 2-D or 3-D, got shape ${shape}, offset ${offset}`);
  }
  shape.forEach((s, i) => {
    if (offset[i] < 0 || offset[i] + s > 1 << COORD_BITS) throw new RangeError(`noise positions must be in [0, 2**${COORD_BITS}) per axis`);
  });
}

/**
 * Standard normal noise of one stream over a block of positions.
 * shape, offset: 2 or 3 integers (offset: where the block starts). Returns a
 * Float32Array in C order (the last axis fastest), as core/noise.py's normal.
 */
export function normal(seed, stream, shape, offset = null, out = null) {
  offset = offset ?? shape.map(() => 0);
  checkShape(shape, offset);
  const key = streamKey(seed, ...stream);
  const keyHi = Number(key >> 32n), keyLo = Number(key & 0xffffffffn);
  const [s0, s1, s2] = shape.length === 3 ? shape : [1, ...shape];
  const [o0, o1, o2] = offset.length === 3 ? offset : [0, ...offset];
  out = out ?? new Float32Array(s0 * s1 * s2);
  let i = 0;
  for (let a = o0; a < o0 + s0; a++) {
    for (let b = o1; b < o1 + s1; b++) {
      // n = (a << 42) | (b << 21) | c, in halves: bits 32.. are a << 10 | b >> 11
      const nHi = ((a << 10) | (b >>> 11)) >>> 0;
      const nLo = (((b & 0x7ff) << 21) | o2) >>> 0;
      // state = k + GOLDEN * (n + 1) for the row's first value; along the row n
      // grows by one (c is the lowest bits), so the state grows by GOLDEN.
      add64(nHi, nLo, 0, 1);
      mul64(hiOut, loOut, GOLDEN_HI, GOLDEN_LO);
      add64(keyHi, keyLo, hiOut, loOut);
      let sHi = hiOut, sLo = loOut;
      for (let c = 0; c < s2; c++) {
        mix64(sHi, sLo);
        out[i++] = normalFromBits(hiOut, loOut);
        add64(sHi, sLo, GOLDEN_HI, GOLDEN_LO);
        sHi = hiOut; sLo = loOut;
      }
    }
  }
  return out;
}

/** The coarsest level's 3-D input noise z0: (X, Y, Z) Float32Array. */
export function z0Noise(seed, size) {
  return normal(seed, [Z0_STREAM], size);
}

/** Noise added to one plane at one level: (channels, H, W) Float32Array. */
export function planeNoise(seed, level, plane, channels, shape) {
  const [h, w] = shape;
  const out = new Float32Array(channels * h * w);
  for (let c = 0; c < channels; c++) normal(seed, [PLANE_STREAM, level, plane, c], shape, null, out.subarray(c * h * w));
  return out;
}
