// A sample's colour, as runtime/colour.py: read from the example by
// correspondence (format 5), or from the decoder's colour head (format 4).
//
// A voxel of the sample's surface band is matched to an example voxel J(u)
// coarse to fine: blocks of 2^LEVELS voxels by PatchMatch (seeded and
// randomised by the block's own content), then by halves, each child starting
// from its parent's match; a point p reads the example's colour tile at
// J(u) + (p - u), u = round(p). Each function below is its Python namesake's
// mirror, step for step, so that a sample has the same colours here as in
// Python:
// - hidden sums, logits and tile coordinates are float32 where Python's are
//   (Math.fround after every operation numpy does in float32), the bilinear
//   blend float64 where numpy's is;
// - patches are integers (each plane rounded as numpy's rint: halves to even,
//   blocks' means rounded down), so distances are exact in any order of summation;
// - every random choice is SplitMix64's output (noise.js's 32-bit halves),
//   reduced modulo a count exactly (uint64 % count, 16 bits at a time);
// - candidates are tried in Python's order and only a strictly nearer one
//   replaces a match, so ties keep the first.
// Arrays are flat typed arrays in C order: voxels Int32Array (n, 3), hidden
// sums Float32Array (n, D), patches Float32Array (n, 7 D).
import { InputError } from './errors.js';
import { roundHalfEven, sample } from './generate.js';
import { GOLDEN_HI, GOLDEN_LO, add64, hiOut, loOut, mix64, mul64, streamKey } from './noise.js';
import { TAB_BYTES, project, projectedColours } from './query.js';

// The patch: a voxel and its six neighbours.
export const PATCH = [[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]];
export const QUANTUM = 256; // hidden sums are compared in steps of 1/QUANTUM
export const KEY_VALUES = 8, KEY_QUANTUM = 4; // a block's random choices are keyed by its first 8 hidden sums in steps of 1/4
export const LEVELS = 3; // matched first on blocks of 2^LEVELS voxels a side, then refined by halves down to voxels
export const ITERATIONS = 4; // PatchMatch's rounds on the coarsest blocks
export const REFINE = 2; // rounds at each finer level
export const PROPAGATION = [1]; // neighbours this many blocks away along each axis offer their match
export const SEARCH = [8, 4, 2, 1]; // random candidates within this many blocks of the current match
export const SEED_RATE = 32; // about one block in this many searches the whole example
export const COHERENT = 0.5; // a match continued (a parent's, a neighbour's) is weighed at this share of its distance
// The six steps of one block along the axes, in the order +x, -x, +y, -y, +z, -z (Python's axis_steps).
export const AXIS_STEPS = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]];
export const MATCH_STREAM = 2; // noise.js's stream id of the matching's random choices
export const DEPTH_RANGE = 0.5; // a tile's depth byte spans this many voxels either side of its centre
export const DISTANCE_STEP = 1 / 63.5; // voxels per unit of the signed distance grid
// A point reads the tiles of each direction of its voxel and of those this many voxels away along the tile's
// axis: the surface nearest it wins, a tile counted TURN voxels farther per unit its axis turns from the normal.
export const REACH_ORDER = [0, -1, 1];
export const TURN = 0.25;
// A vertex moves by the example's relief at most RELIEF voxels, on a mesh at least RELIEF_SCALE times finer.
export const RELIEF = 1.0, RELIEF_SCALE = 2;
export const FACING = [0.7, 0.95]; // relief in full where the tile read faces the normal this much (cosine), none below
export const ACROSS = [[1, 2], [0, 2], [0, 1]]; // a tile's rows and columns run along these axes, by its axis
// reads_along: the voxels along a tile's axis whose tile a voxel without its own reads, by the side it looks from.
export const ALONG = { positive: [-1, 1, -2, 2], negative: [1, -1, 2, -2] };
// A voxel outside the band takes the match of the first voxel beside it that has one, in this order.
export const STEPS = [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]];
// A kept box's matches are the part's own deeper than this inside it (Python's KEPT_MARGIN).
export const KEPT_MARGIN = 5;

const f32 = Math.fround;

function checkBytes(bytes, what) {
  if (bytes > TAB_BYTES) throw new InputError(`${what} needs more memory than a page should take`);
}

/** The example's colour as the runtime reads it: directional tiles of its surface voxels, for every voxel near
 * the surface the tile of each direction it reads, its own tiles, and the example's signed distance. */
export class Tiles {
  /** voxels Int32Array (N, 3); directions Uint8Array (N,); mips [RGB Uint8Array (N, t, t, 3) for t = T, T/2,
   * ..., 1]; depth Uint8Array (N, T, T); slopes Float64Array (N, 2); along and own Int32Array (X, Y, Z, 6);
   * distance Float32Array (X, Y, Z) in voxels; size [X, Y, Z]; side T. */
  constructor(voxels, directions, mips, depth, slopes, along, own, distance, size, side) {
    Object.assign(this, { voxels, directions, mips, depth, slopes, along, own, distance, size, side });
  }

  /** images: Uint8Array (N, T, T, 4), RGB and depth, or (N, T, T, 1) depth alone, of side T; distance:
   * Int8Array (X, Y, Z). A relief-only model's tiles have no mips. */
  static of(voxels, directions, images, distance, size, side) {
    const count = directions.length, channels = images.length / (count * side * side);
    const rgb = channels === 4 ? new Uint8Array(count * side * side * 3) : null, depth = new Uint8Array(count * side * side);
    for (let t = 0; t < count * side * side; t++) {
      if (rgb) {
        rgb[3 * t] = images[4 * t];
        rgb[3 * t + 1] = images[4 * t + 1];
        rgb[3 * t + 2] = images[4 * t + 2];
      }
      depth[t] = images[channels * t + channels - 1];
    }
    const [X, Y, Z] = size, own = new Int32Array(X * Y * Z * 6).fill(-1);
    for (let t = 0; t < count; t++) own[6 * ((voxels[3 * t] * Y + voxels[3 * t + 1]) * Z + voxels[3 * t + 2]) + directions[t]] = t;
    const step = f32(DISTANCE_STEP);
    return new Tiles(voxels, directions, rgb ? mipLevels(rgb, count, side) : [], depth, slopes(depth, count, side), readsAlong(own, size),
      own, Float32Array.from(distance, (v) => f32(v * step)), size, side);
  }

  /** Memory of `count` tiles of `side` read for a finest level of `size`. */
  static bytes(count, side, size) {
    return count * side * side * 5 + size[0] * size[1] * size[2] * (12 * 4 + 4);
  }

  /** Voxel (x, y, z)'s own tile of `direction`, -1 for none (outside the grid: none). */
  ownTile(x, y, z, direction) {
    const [X, Y, Z] = this.size;
    return x < 0 || y < 0 || z < 0 || x >= X || y >= Y || z >= Z ? -1 : this.own[6 * ((x * Y + y) * Z + z) + direction];
  }

  /** The voxels (m, 3) where a match may land: every voxel with a tile to read. */
  band() {
    const [X, Y, Z] = this.size, out = [];
    for (let v = 0; v < X * Y * Z; v++) {
      for (let d = 0; d < 6; d++) {
        if (this.along[6 * v + d] >= 0) { out.push(Math.floor(v / (Y * Z)), Math.floor(v / Z) % Y, v % Z); break; }
      }
    }
    return Int32Array.from(out);
  }

  /** The tiles (n, 6) each (n, 3) voxel reads, -1 for none (outside the grid: none). */
  read(voxels) {
    const [X, Y, Z] = this.size, n = voxels.length / 3, out = new Int32Array(6 * n).fill(-1);
    for (let i = 0; i < n; i++) {
      const x = voxels[3 * i], y = voxels[3 * i + 1], z = voxels[3 * i + 2];
      if (x < 0 || y < 0 || z < 0 || x >= X || y >= Y || z >= Z) continue;
      out.set(this.along.subarray(6 * ((x * Y + y) * Z + z), 6 * ((x * Y + y) * Z + z) + 6), 6 * i);
    }
    return out;
  }
}

/** Per voxel and direction (axis a, side s), the tile of that direction of the voxel itself, else of the
 * nearest voxel along a that has one, up to two away, the side the tile looks from first. (X, Y, Z, 6) Int32Array. */
export function readsAlong(own, size) {
  const [X, Y, Z] = size, strides = [Y * Z, Z, 1];
  const along = own.slice();
  for (let direction = 0; direction < 6; direction++) {
    const axis = direction >> 1, steps = direction & 1 ? ALONG.positive : ALONG.negative;
    for (let v = 0; v < X * Y * Z; v++) {
      if (along[6 * v + direction] >= 0) continue;
      const at = [Math.floor(v / (Y * Z)), Math.floor(v / Z) % Y, v % Z][axis];
      for (const step of steps) { // the voxel `step` away along the axis
        if (at + step < 0 || at + step >= size[axis]) continue;
        const tile = own[6 * (v + step * strides[axis]) + direction];
        if (tile >= 0) { along[6 * v + direction] = tile; break; }
      }
    }
  }
  return along;
}

/** The least-squares slope of each tile's depth across it, (N, T, T) -> (N, 2) Float64Array: voxels of depth
 * per voxel along rows and columns, from sums of integers over runtime/colour.py's fixed denominator. */
export function slopes(depth, count, side) {
  const out = new Float64Array(2 * count);
  let squares = 0;
  for (let k = 0; k < side; k++) squares += (2 * k - (side - 1)) ** 2;
  const scale = (127.5 * squares) / (2 * DEPTH_RANGE);
  for (let t = 0; t < count; t++) {
    let rows = 0, columns = 0;
    for (let r = 0; r < side; r++) {
      for (let c = 0; c < side; c++) {
        const value = depth[(t * side + r) * side + c];
        rows += value * (2 * r - (side - 1));
        columns += value * (2 * c - (side - 1));
      }
    }
    out[2 * t] = rows / scale;
    out[2 * t + 1] = columns / scale;
  }
  return out;
}

/** Box-filtered halvings of (N, T, T, 3) tiles down to 1 x 1, each texel the rounded mean of four. */
export function mipLevels(images, count, side) {
  const levels = [images];
  for (let n = side; n > 1; n >>= 1) {
    const src = levels[levels.length - 1], h = n >> 1, out = new Uint8Array(count * h * h * 3);
    for (let t = 0; t < count; t++) {
      for (let i = 0; i < h; i++) {
        for (let j = 0; j < h; j++) {
          for (let c = 0; c < 3; c++) {
            const texel = (a, b) => src[((t * n + a) * n + b) * 3 + c];
            const total = texel(2 * i, 2 * j) + texel(2 * i + 1, 2 * j) + texel(2 * i, 2 * j + 1)
              + texel(2 * i + 1, 2 * j + 1);
            out[((t * h + i) * h + j) * 3 + c] = (total + 2) >> 2;
          }
        }
      }
    }
    levels.push(out);
  }
  return levels;
}

/** Hidden pre-activations (b1 added) at the grid points of scale 1 of projected planes spanning `size`, as a
 * function of (n, 3) voxels -> (n, D) Float32Array, clamped to the grid: ((xy + xz) + yz) + b1 in float32. */
export function gridHidden(model, planes, size) {
  const [xy, xz, yz] = planes.map((p) => p.data), bias = model.head.bias1;
  return perVoxel(size, bias.length, (a, b, e, c) => f32(f32(f32(xy[a] + xz[b]) + yz[e]) + bias[c]));
}

/** A function of (n, 3) voxels, clamped to a grid of `size`, -> (n, D) Float32Array: channel c of each voxel is
 * value(a, b, e, c), given the places of channel c of the voxel's cells in its xy, xz and yz planes (each
 * (., ., D) in C order). */
function perVoxel(size, d, value) {
  const [X, Y, Z] = size;
  return (voxels) => {
    const n = voxels.length / 3, out = new Float32Array(n * d);
    for (let v = 0; v < n; v++) {
      const i = Math.min(Math.max(voxels[3 * v], 0), X - 1), j = Math.min(Math.max(voxels[3 * v + 1], 0), Y - 1);
      const k = Math.min(Math.max(voxels[3 * v + 2], 0), Z - 1);
      const a = (i * Y + j) * d, b = (i * Z + k) * d, e = (j * Z + k) * d;
      for (let c = 0; c < d; c++) out[v * d + c] = value(a + c, b + c, e + c, c);
    }
    return out;
  };
}

/** Where hidden sums (n, D) (b1 added) are inside the shape: sum_c relu(h_c) w2_c + b2 > 0, in float32 in the
 * order of c. Uint8Array (n,). */
export function inside(model, hidden) {
  const { weight2, bias2 } = model.head, d = weight2.length, n = hidden.length / d, out = new Uint8Array(n);
  for (let v = 0; v < n; v++) {
    let logit = f32(bias2);
    for (let c = 0; c < d; c++) logit = f32(logit + f32(Math.max(hidden[v * d + c], 0) * weight2[c]));
    out[v] = logit > 0 ? 1 : 0;
  }
  return out;
}

/** The voxels (n, 3) of a grid of scale 1 within one voxel of a change between inside and outside along an
 * axis (beyond the grid is outside: a mesh closes there): where a mesh's vertices round to. */
export function surfaceBand(model, hiddenAt, size) {
  const [X, Y, Z] = size, strides = [Y * Z, Z, 1], count = X * Y * Z;
  const solid = new Uint8Array(count);
  const rows = Math.max(1, Math.floor((1 << 18) / (Y * Z)));
  for (let x0 = 0; x0 < X; x0 += rows) {
    const x1 = Math.min(x0 + rows, X), voxels = new Int32Array((x1 - x0) * Y * Z * 3);
    for (let v = 0; v < (x1 - x0) * Y * Z; v++) {
      voxels[3 * v] = x0 + Math.floor(v / (Y * Z));
      voxels[3 * v + 1] = Math.floor(v / Z) % Y;
      voxels[3 * v + 2] = v % Z;
    }
    solid.set(inside(model, hiddenAt(voxels)), x0 * Y * Z);
  }
  const at = (v, axis) => [Math.floor(v / (Y * Z)), Math.floor(v / Z) % Y, v % Z][axis];
  // A change: a voxel unlike the one before or after it along an axis, beyond the grid empty (Python's padding).
  const beside = (v, axis, step) => {
    const place = at(v, axis) + step;
    return place >= 0 && place < size[axis] ? solid[v + step * strides[axis]] : 0;
  };
  const change = new Uint8Array(count);
  for (let axis = 0; axis < 3; axis++) {
    for (let v = 0; v < count; v++) if (solid[v] !== beside(v, axis, -1) || solid[v] !== beside(v, axis, 1)) change[v] = 1;
  }
  const band = change.slice();
  for (let axis = 0; axis < 3; axis++) { // grown by one voxel along each axis
    for (let v = 0; v < count; v++) {
      if (at(v, axis) + 1 < size[axis]) {
        if (change[v + strides[axis]]) band[v] = 1;
        if (change[v]) band[v + strides[axis]] = 1;
      }
    }
  }
  const out = [];
  for (let v = 0; v < count; v++) if (band[v]) out.push(at(v, 0), at(v, 1), at(v, 2));
  return Int32Array.from(out);
}

/** Hidden sums (b1 added) of projected planes spanning `size` as integers, at voxels (level 0) and at blocks
 * of 2^level voxels a side, as Python's Pyramid: each plane rounded to steps of 1/QUANTUM (halves to even), a
 * block's value the floor of its mean (the planes' sums over its faces, past the grid's end its last voxels). */
export class Pyramid {
  constructor(planes, bias, size) {
    this.size = size;
    this.d = bias.length;
    this.planes = planes.map((p) => Float64Array.from(p.data, (v) => roundHalfEven(f32(v * QUANTUM))));
    this.bias = Float64Array.from(bias, (v) => roundHalfEven(f32(v * QUANTUM)));
    this.pooled = new Map();
  }

  /** The hidden sums of level `level`'s blocks, as a function of (n, 3) blocks -> (n, D) Float32Array, clamped
   * to that level's grid. */
  at(level) {
    const side = 1 << level, d = this.d, blocks = this.size.map((n) => Math.ceil(n / side));
    if (!this.pooled.has(level)) {
      this.pooled.set(level, [[0, 1], [0, 2], [1, 2]].map(([a, b], p) => {
        const plane = this.planes[p], A = this.size[a], B = this.size[b], out = new Float64Array(blocks[a] * blocks[b] * d);
        for (let i = 0; i < blocks[a] * side; i++) {
          for (let j = 0; j < blocks[b] * side; j++) {
            const from = (Math.min(i, A - 1) * B + Math.min(j, B - 1)) * d, to = (Math.floor(i / side) * blocks[b] + Math.floor(j / side)) * d;
            for (let c = 0; c < d; c++) out[to + c] += plane[from + c];
          }
        }
        return out;
      }));
    }
    const [xy, xz, yz] = this.pooled.get(level), area = side * side, bias = this.bias;
    return perVoxel(blocks, d, (a, b, e, c) => Math.floor((xy[a] + xz[b] + yz[e] + bias[c] * area) / area));
  }
}

/** A sample's (or the reconstruction's) Pyramid. */
export function pyramid(model, planes, size) {
  return new Pyramid(planes, model.head.bias1, size);
}

/** The patch of each voxel, (n, 3) -> (n, 7 D) Float32Array: its integer hidden sums and its six neighbours',
 * so squared distances are exact in any order of summation. */
export function patches(hiddenAt, voxels) {
  const n = voxels.length / 3, shifted = new Int32Array(voxels.length);
  let out = null, d = 0;
  PATCH.forEach((offset, o) => {
    for (let i = 0; i < voxels.length; i++) shifted[i] = voxels[i] + offset[i % 3];
    const hidden = hiddenAt(shifted);
    if (!out) { d = hidden.length / Math.max(n, 1); out = new Float32Array(n * PATCH.length * d); }
    for (let v = 0; v < n; v++) out.set(hidden.subarray(v * d, (v + 1) * d), (v * PATCH.length + o) * d);
  });
  return out;
}

/** A key per block from its own integer hidden sums (n, D): its first KEY_VALUES sums in steps of
 * 1/KEY_QUANTUM (rounded down), as int64 then uint64: the random choices made for a block follow what is
 * there, not where. Uint32Array (n, 2): high and low halves. */
export function contentKeys(hidden, n) {
  const d = hidden.length / Math.max(n, 1), start = streamKey(0, MATCH_STREAM);
  const startHi = Number(start >> 32n), startLo = Number(start & 0xffffffffn), out = new Uint32Array(2 * n);
  for (let v = 0; v < n; v++) {
    let hi = startHi, lo = startLo;
    for (let c = 0; c < KEY_VALUES; c++) {
      const value = Math.floor(hidden[v * d + c] / (QUANTUM / KEY_QUANTUM)); // an integer: its two's complement halves
      add64(Math.floor(value / 2 ** 32) >>> 0, value >>> 0, 0, 1);
      mul64(hiOut, loOut, GOLDEN_HI, GOLDEN_LO);
      add64(hi, lo, hiOut, loOut);
      mix64(hiOut, loOut);
      hi = hiOut; lo = loOut;
    }
    out[2 * v] = hi;
    out[2 * v + 1] = lo;
  }
  return out;
}

/** The random bits of draw `slot` for each block's key: SplitMix64's output number key + 1 from state `slot`
 * (noise.js's bits). Uint32Array (n, 2). */
export function draw(keys, slot) {
  const out = new Uint32Array(keys.length);
  for (let v = 0; v < keys.length; v += 2) {
    add64(keys[v], keys[v + 1], 0, 1);
    mul64(hiOut, loOut, GOLDEN_HI, GOLDEN_LO);
    add64(0, slot, hiOut, loOut);
    mix64(hiOut, loOut);
    out[v] = hiOut;
    out[v + 1] = loOut;
  }
  return out;
}

/** (hi * 2^32 + lo) % m, exactly, for m below 2^31: 16 bits at a time. */
export function modulo(hi, lo, m) {
  let r = hi % m;
  r = (r * 65536 + (lo >>> 16)) % m;
  return (r * 65536 + (lo & 0xffff)) % m;
}

/** Squared distance of patch row `a` of `first` to row `b` of `second` (K values each): exact integers. Stops
 * early once it reaches `bound` (it can only grow), returning a value at least `bound`. */
function squaredDistance(first, a, second, b, k, bound = Infinity) {
  let total = 0;
  for (let c = 0; c < k; c += 8) {
    for (let e = c; e < Math.min(c + 8, k); e++) {
      const diff = first[a * k + e] - second[b * k + e];
      total += diff * diff;
    }
    if (total >= bound) return total;
  }
  return total;
}

/** Voxels (n, 3) in lexicographic order, once each, as numpy's unique(axis=0) gives them (all within `size`). */
function uniqueVoxels(voxels, size) {
  const [, Y, Z] = size, keys = [];
  for (let i = 0; i < voxels.length; i += 3) keys.push((voxels[i] * Y + voxels[i + 1]) * Z + voxels[i + 2]);
  const sorted = Float64Array.from(new Set(keys)).sort(), out = new Int32Array(3 * sorted.length);
  sorted.forEach((key, r) => { out[3 * r] = Math.floor(key / (Y * Z)); out[3 * r + 1] = Math.floor(key / Z) % Y; out[3 * r + 2] = key % Z; });
  return out;
}

/** The blocks of level `level` holding voxels (n, 3): each coordinate shifted right by `level` bits. */
function blocksOf(voxels, level) {
  return Int32Array.from(voxels, (v) => v >> level);
}

/** One level of the example's side of matching: the blocks a match may land in and the reconstruction's
 * patch at each (Python's Level). */
export class Level {
  constructor(band, referenceAt, size) {
    this.band = band; // (B, 3)
    this.size = size;
    const [X, Y, Z] = size, count = band.length / 3;
    this.row = new Int32Array(X * Y * Z).fill(-1);
    for (let r = 0; r < count; r++) this.row[(band[3 * r] * Y + band[3 * r + 1]) * Z + band[3 * r + 2]] = r;
    this.reference = patches(referenceAt, band); // (B, K)
    this.width = this.reference.length / Math.max(count, 1); // K
  }

  /** The band row of example block (x, y, z), -1 outside the band. */
  rowOf(x, y, z) {
    const [X, Y, Z] = this.size;
    return x < 0 || y < 0 || z < 0 || x >= X || y >= Y || z >= Z ? -1 : this.row[(x * Y + y) * Z + z];
  }

  /** The band row of each (n, 3) example block, -1 outside the band. */
  rows(voxels) {
    const n = voxels.length / 3;
    return Int32Array.from({ length: n }, (_, i) => this.rowOf(voxels[3 * i], voxels[3 * i + 1], voxels[3 * i + 2]));
  }

  /** Patch distances of sample patches (n, K) to candidate example blocks (n, 3); infinite where a candidate is
   * outside the band. Float64Array (n,). */
  distance(sample, candidates) {
    const rows = this.rows(candidates);
    return Float64Array.from(rows, (r, i) => (r < 0 ? Infinity : squaredDistance(sample, i, this.reference, r, this.width)));
  }

  /** The nearest band block of each patch (n, K) of all: (n, 3), the first of equals. Python takes the
   * argmin of |r|^2 - 2 s.r, which is |s - r|^2 - |s|^2 in exact integers: the same order and the same
   * ties as |s - r|^2, which is measured here, a candidate given up once it is no nearer. */
  nearest(sample) {
    const n = sample.length / this.width, k = this.width, count = this.band.length / 3, out = new Int32Array(3 * n);
    for (let i = 0; i < n; i++) {
      let best = Infinity, arg = 0;
      for (let r = 0; r < count; r++) {
        const value = squaredDistance(sample, i, this.reference, r, k, best);
        if (value < best) { best = value; arg = r; }
      }
      out.set(this.band.subarray(3 * arg, 3 * arg + 3), 3 * i);
    }
    return out;
  }

  /** One block's candidate (x, y, z), tried against its current match: only a strictly nearer one replaces
   * it. A candidate outside the band (Python's distance: infinite) and one equal to the current match (exactly
   * as far) cannot, so neither is measured. A match continued is weighed at COHERENT of its distance (Python
   * multiplies, then compares); the early stop's bound is widened a hair so that a distance it stops is one
   * that loses in Python too. */
  offer(sample, current, best, v, x, y, z, coherent) {
    if (x === current[3 * v] && y === current[3 * v + 1] && z === current[3 * v + 2]) return;
    const row = this.rowOf(x, y, z);
    if (row < 0) return;
    const bound = coherent ? (best[v] / COHERENT) * (1 + 1e-12) : best[v];
    let d = squaredDistance(sample, v, this.reference, row, this.width, bound);
    if (d >= bound) return;
    if (coherent) d *= COHERENT;
    if (d < best[v]) { best[v] = d; current[3 * v] = x; current[3 * v + 1] = y; current[3 * v + 2] = z; }
  }

  /** PatchMatch: the example block J(u) of each block u (n, 3) of a sample, whose hidden sums `sampleAt`
   * gives: (n, 3) Int32Array. */
  search(sampleAt, blocks) {
    const n = blocks.length / 3, count = this.band.length / 3, k = this.width, band = this.band;
    const sample = patches(sampleAt, blocks);
    const keys = contentKeys(sampleAt(blocks), n);
    const lookup = voxelLookup(blocks);
    const current = new Int32Array(3 * n);
    let bits = draw(keys, 0);
    for (let v = 0; v < n; v++) {
      const r = modulo(bits[2 * v], bits[2 * v + 1], count);
      current.set(band.subarray(3 * r, 3 * r + 3), 3 * v);
    }
    bits = draw(keys, 1);
    const seeds = [];
    for (let v = 0; v < n; v++) if (modulo(bits[2 * v], bits[2 * v + 1], SEED_RATE) === 0) seeds.push(v);
    if (seeds.length) {
      const seeded = new Float32Array(seeds.length * k);
      seeds.forEach((v, i) => seeded.set(sample.subarray(v * k, (v + 1) * k), i * k));
      const found = this.nearest(seeded);
      seeds.forEach((v, i) => current.set(found.subarray(3 * i, 3 * i + 3), 3 * v));
    }
    const best = this.distance(sample, current);
    let changed = new Uint8Array(n).fill(1); // whose match changed last round: only their offers are new
    let slot = 2;
    for (let iteration = 0; iteration < ITERATIONS; iteration++) {
      const previous = current.slice();
      const searches = SEARCH.map(() => draw(keys, slot++)); // the random draws of this round, in slot order
      const anywhere = draw(keys, slot++);
      for (let v = 0; v < n; v++) { // the candidates in Python's order
        const x = blocks[3 * v], y = blocks[3 * v + 1], z = blocks[3 * v + 2];
        for (const length of PROPAGATION) { // each neighbour's previous match, shifted by the step between them
          for (const [a, b, c] of AXIS_STEPS) {
            const neighbour = lookup(x - a * length, y - b * length, z - c * length);
            if (neighbour < 0 || !changed[neighbour]) continue; // none, or the offer it made last round
            this.offer(sample, current, best, v, previous[3 * neighbour] + a * length, previous[3 * neighbour + 1] + b * length,
              previous[3 * neighbour + 2] + c * length, true);
          }
        }
        SEARCH.forEach((radius, s) => { // a block near the previous match: offsets from bits 0-15, 16-31, 32-47
          const hi = searches[s][2 * v], lo = searches[s][2 * v + 1], span = 2 * radius + 1;
          this.offer(sample, current, best, v, previous[3 * v] + ((lo & 0xffff) % span) - radius,
            previous[3 * v + 1] + ((lo >>> 16) % span) - radius, previous[3 * v + 2] + ((hi & 0xffff) % span) - radius, false);
        });
        const r = modulo(anywhere[2 * v], anywhere[2 * v + 1], count); // anywhere in the band
        this.offer(sample, current, best, v, band[3 * r], band[3 * r + 1], band[3 * r + 2], false);
      }
      changed = Uint8Array.from({ length: n }, (_, v) => (current[3 * v] !== previous[3 * v]
        || current[3 * v + 1] !== previous[3 * v + 1] || current[3 * v + 2] !== previous[3 * v + 2] ? 1 : 0));
    }
    return current;
  }

  /** Each block u (n, 3) of a sample starting from its `inherited` match (a match continued), in REFINE rounds
   * offered each neighbour's match continued, then its own moved by one block along each axis; one whose match is
   * off the band after them searches the whole example. (n, 3) Int32Array. */
  refine(sampleAt, blocks, inherited) {
    const n = blocks.length / 3, k = this.width;
    const sample = patches(sampleAt, blocks);
    const lookup = voxelLookup(blocks);
    const current = inherited.slice();
    const best = this.distance(sample, current).map((d) => d * COHERENT);
    for (let round = 0; round < REFINE; round++) {
      const previous = current.slice();
      for (let v = 0; v < n; v++) {
        const x = blocks[3 * v], y = blocks[3 * v + 1], z = blocks[3 * v + 2];
        for (const [a, b, c] of AXIS_STEPS) { // each neighbour's match continued
          const neighbour = lookup(x - a, y - b, z - c);
          if (neighbour >= 0) {
            this.offer(sample, current, best, v, previous[3 * neighbour] + a, previous[3 * neighbour + 1] + b,
              previous[3 * neighbour + 2] + c, true);
          }
        }
        for (const [a, b, c] of AXIS_STEPS) { // its own moved by one block
          this.offer(sample, current, best, v, previous[3 * v] + a, previous[3 * v + 1] + b, previous[3 * v + 2] + c, false);
        }
      }
    }
    const lost = []; // off the band still: the whole example searched
    for (let v = 0; v < n; v++) if (!Number.isFinite(best[v])) lost.push(v);
    if (lost.length) {
      const missing = new Float32Array(lost.length * k);
      lost.forEach((v, i) => missing.set(sample.subarray(v * k, (v + 1) * k), i * k));
      const found = this.nearest(missing);
      lost.forEach((v, i) => current.set(found.subarray(3 * i, 3 * i + 3), 3 * v));
    }
    return current;
  }
}

/** The example's side of matching at every level (Python's Matcher): level l's blocks are 2^l voxels a side,
 * its band the blocks that hold a voxel with tiles to read. */
export class Matcher {
  constructor(tiles, reference) {
    const band = tiles.band();
    this.levels = [];
    for (let level = 0; level <= LEVELS; level++) {
      const size = reference.size.map((n) => Math.ceil(n / (1 << level)));
      this.levels.push(new Level(level ? uniqueVoxels(blocksOf(band, level), size) : band, reference.at(level), size));
    }
  }

  /** The example voxel J(u) of each voxel u (n, 3) of a sample's grid (`sample` its Pyramid), coarse to fine:
   * (n, 3) Int32Array. */
  match(sample, voxels) {
    const n = voxels.length / 3, fine = this.levels[0];
    checkBytes(n * fine.width * 16 + (fine.band.length / 3) * 8 * 64, `matching ${n} voxels to the example`);
    if (!n) return new Int32Array(0);
    const grid = (level) => sample.size.map((m) => Math.ceil(m / (1 << level)));
    let blocks = uniqueVoxels(blocksOf(voxels, LEVELS), grid(LEVELS));
    let matched = this.levels[LEVELS].search(sample.at(LEVELS), blocks);
    for (let level = LEVELS - 1; level >= 0; level--) {
      const finer = level ? uniqueVoxels(blocksOf(voxels, level), grid(level)) : voxels;
      const lookup = voxelLookup(blocks), inherited = new Int32Array(finer.length);
      for (let v = 0; v < finer.length; v += 3) {
        const row = lookup(finer[v] >> 1, finer[v + 1] >> 1, finer[v + 2] >> 1);
        for (let a = 0; a < 3; a++) inherited[v + a] = 2 * matched[3 * row + a] + (finer[v + a] & 1);
      }
      matched = this.levels[level].refine(sample.at(level), finer, inherited);
      blocks = finer;
    }
    return matched;
  }
}

/** A function from voxel (x, y, z) to its row in `voxels` (n, 3), -1 where absent. */
export function voxelLookup(voxels) {
  const n = voxels.length / 3, low = [0, 0, 0], size = [1, 1, 1];
  if (n) {
    for (let a = 0; a < 3; a++) {
      let least = Infinity, most = -Infinity;
      for (let i = a; i < voxels.length; i += 3) { least = Math.min(least, voxels[i]); most = Math.max(most, voxels[i]); }
      low[a] = least;
      size[a] = most - least + 1;
    }
  }
  checkBytes(size[0] * size[1] * size[2] * 4, `a lookup of ${n} voxels`);
  const table = new Int32Array(size[0] * size[1] * size[2]).fill(-1);
  for (let i = 0; i < n; i++) {
    table[((voxels[3 * i] - low[0]) * size[1] + voxels[3 * i + 1] - low[1]) * size[2] + voxels[3 * i + 2] - low[2]] = i;
  }
  return (x, y, z) => {
    x -= low[0]; y -= low[1]; z -= low[2];
    return x < 0 || y < 0 || z < 0 || x >= size[0] || y >= size[1] || z >= size[2] ? -1 : table[(x * size[1] + y) * size[2] + z];
  };
}

/** The model's matcher, made once: the reconstruction's patches at every level of the example's band. */
export async function matcher(model) {
  if (!model.matcher) {
    model.matcher = (async () => {
      const recon = await sample(model, null);
      return new Matcher(model.tiles, pyramid(model, (await project(model, recon)).planes, recon.size));
    })();
    model.matcher.catch(() => { model.matcher = null; }); // a failure is not kept: the next sample tries again
  }
  return model.matcher;
}

/** J of one sample: its surface band matched to the example as a whole (`example`, matcher's), and the rest
 * of its grid, when asked for, from the band outwards. */
export class Correspondence {
  /** `kept`: a composed sample's parts, [{ low, high, planes (projected) }], whose band deep in each box takes
   * their own matches (a later part wins where boxes overlap), as Python's. */
  constructor(example, model, planes, size, kept = []) {
    this.size = size;
    this.band = surfaceBand(model, gridHidden(model, planes, size), size);
    this.matched = example.match(pyramid(model, planes, size), this.band);
    this.lookup = voxelLookup(this.band);
    this.field = null;
    for (const { low, high, planes: partPlanes } of kept) {
      const own = new Correspondence(example, model, partPlanes, size);
      for (let r = 0; r < this.band.length / 3; r++) {
        let deep = true; // deeper than the join inside the box (a box reaching the grid's edge has no join there)
        for (let a = 0; a < 3; a++) {
          const v = this.band[3 * r + a];
          if (!((v >= low[a] + KEPT_MARGIN || low[a] <= 0) && (v <= high[a] - KEPT_MARGIN || high[a] >= size[a] - 1))) deep = false;
        }
        const row = deep ? own.lookup(this.band[3 * r], this.band[3 * r + 1], this.band[3 * r + 2]) : -1;
        if (row >= 0) this.matched.set(own.matched.subarray(3 * row, 3 * row + 3), 3 * r);
      }
    }
  }

  /** The example voxel of each (n, 3) voxel of the sample's grid (Python's __call__). */
  call(voxels) {
    const [X, Y, Z] = this.size, out = new Int32Array(voxels.length);
    for (let i = 0; i < voxels.length; i += 3) {
      const x = Math.min(Math.max(voxels[i], 0), X - 1), y = Math.min(Math.max(voxels[i + 1], 0), Y - 1);
      const z = Math.min(Math.max(voxels[i + 2], 0), Z - 1);
      const row = this.lookup(x, y, z);
      if (row >= 0) out.set(this.matched.subarray(3 * row, 3 * row + 3), i);
      else {
        this.field ??= this.spread();
        out.set(this.field.subarray(3 * ((x * Y + y) * Z + z), 3 * ((x * Y + y) * Z + z) + 3), i);
      }
    }
    return out;
  }

  /** J on every voxel of the grid: (X, Y, Z, 3) Int32Array (the band's own, or carried from it one voxel a
   * round, from the first voxel beside it in STEPS' order known before the round; all zeros if the sample
   * has no surface). */
  spread() {
    const [X, Y, Z] = this.size, count = X * Y * Z, strides = [Y * Z, Z, 1];
    checkBytes(count * 8 * 8, `matching a ${this.size.join('x')} grid`);
    const field = new Int32Array(3 * count);
    const known = new Int32Array(count).fill(-1); // the round in which a voxel's match became known
    let frontier = [];
    for (let r = 0; r < this.band.length / 3; r++) {
      const v = (this.band[3 * r] * Y + this.band[3 * r + 1]) * Z + this.band[3 * r + 2];
      field.set(this.matched.subarray(3 * r, 3 * r + 3), 3 * v);
      known[v] = 0;
      frontier.push(v);
    }
    const at = (v) => [Math.floor(v / (Y * Z)), Math.floor(v / Z) % Y, v % Z];
    for (let round = 1; frontier.length; round++) {
      const next = []; // the unknown voxels beside the last round's: this round's
      for (const v of frontier) {
        const place = at(v);
        for (const step of STEPS) {
          const axis = step.findIndex((s) => s !== 0), to = place[axis] - step[axis];
          const w = v - step[axis] * strides[axis];
          if (to >= 0 && to < this.size[axis] && known[w] === -1) { known[w] = -2; next.push(w); }
        }
      }
      for (const v of next) {
        const place = at(v);
        for (const step of STEPS) { // take from the first voxel v + step known before this round
          const axis = step.findIndex((s) => s !== 0), from = place[axis] + step[axis];
          const w = v + step[axis] * strides[axis];
          if (from < 0 || from >= this.size[axis] || known[w] < 0 || known[w] >= round) continue;
          for (let a = 0; a < 3; a++) field[3 * v + a] = field[3 * w + a] - step[a];
          break;
        }
        known[v] = round;
      }
      frontier = next;
    }
    return field;
  }
}

/** The example's colours as a distant view shows them, as colour.example_palette: each tile's mean (its 1x1 mip),
 * once each, as 0xRRGGBB in increasing order (Int32Array). */
export function examplePalette(tiles) {
  const means = tiles.mips[tiles.mips.length - 1], packed = new Set();
  for (let i = 0; i < means.length; i += 3) packed.add((means[i] << 16) | (means[i + 1] << 8) | means[i + 2]);
  return Int32Array.from([...packed].sort((a, b) => a - b));
}

/** The palette's (examplePalette's) nearest colour to the bytes r, g, b, as colour.nearest_in_palette: the
 * squared distance over the bytes, the first of equals. Returns 0xRRGGBB. */
export function nearestInPalette(palette, r, g, b) {
  let best = Infinity, found = 0;
  for (const p of palette) {
    const d = (r - (p >> 16)) ** 2 + (g - ((p >> 8) & 255)) ** 2 + (b - (p & 255)) ** 2;
    if (d < best) [best, found] = [d, p];
  }
  return found;
}

/** Where points (n, 3) (Float64Array, sample model units) of a sample whose voxels `matched` maps to example
 * voxels stand in the example, as runtime/colour.py's example_points: calls at(i, q, smooth, normal, voxel) for
 * each point i with q (3), the signed distance grid's value there, the example's unit normal (3) and q's voxel
 * (3). A point beyond the grid's last voxel belongs to that voxel. */
function examplePoints(tiles, matched, points, grid, at) {
  const n = points.length / 3, u = new Int32Array(3 * n);
  for (let i = 0; i < 3 * n; i++) u[i] = Math.min(Math.max(Math.floor(points[i] + 0.5), 0), grid[i % 3] - 1); // halves up
  const example = matched(u);
  const q = [0, 0, 0], normal = [0, 0, 0], voxel = [0, 0, 0];
  for (let i = 0; i < n; i++) {
    for (let a = 0; a < 3; a++) q[a] = example[3 * i + a] + (points[3 * i + a] - u[3 * i + a]);
    const smooth = trilinear(tiles.distance, tiles.size, q, normal);
    const length = Math.max(Math.sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]), 1e-12);
    for (let a = 0; a < 3; a++) normal[a] /= length;
    for (let a = 0; a < 3; a++) voxel[a] = Math.min(Math.max(Math.floor(q[a] + 0.5), 0), tiles.size[a] - 1);
    at(i, q, smooth, normal, voxel);
  }
}

/** The tile of `direction` at `voxel` moved `reach` along its axis, and its surface under q as a plane of its
 * slope through its depth there, as runtime/colour.py's tile_under: null for none, else { tile, above: q's
 * distance outside it along its normal over lean, a, b: where q lies on the tile's plane, sa, sb: the slope, lean }. */
function tileUnder(tiles, q, voxel, direction, reach) {
  const axis = direction >> 1, [pa, pb] = ACROSS[axis];
  const at = [voxel[0], voxel[1], voxel[2]];
  at[axis] += reach;
  const own = tiles.ownTile(at[0], at[1], at[2], direction);
  if (own < 0) return null;
  const la = q[axis] - tiles.voxels[3 * own + axis];
  const a = q[pa] - tiles.voxels[3 * own + pa], b = q[pb] - tiles.voxels[3 * own + pb];
  const sa = tiles.slopes[2 * own], sb = tiles.slopes[2 * own + 1];
  const lean = 1 + (sa * sa + sb * sb);
  return { tile: own, above: (la - bilinearDepth(tiles.depth, tiles.side, own, a, b)) / lean, a, b, sa, sb, lean };
}

/** The example's surface under points (n, 3) (Float64Array, sample model units) of a sample whose voxels
 * `matched` maps to example voxels, as runtime/colour.py's surface_under: of the tiles of q's voxel and of those
 * beside it along each tile's axis, the one whose surface is nearest q, and where on its plane: { tile Int32Array
 * (n,), across Float64Array (n, 2) }. */
export function surfaceUnder(tiles, matched, points, grid) {
  const n = points.length / 3, tile = new Int32Array(n), across = new Float64Array(2 * n);
  examplePoints(tiles, matched, points, grid, (i, q, smooth, normal, voxel) => {
    let best = Infinity;
    for (let direction = 0; direction < 6; direction++) {
      for (const reach of REACH_ORDER) {
        const found = tileUnder(tiles, q, voxel, direction, reach);
        if (found === null) continue;
        const facing = normal[direction >> 1] * (direction & 1 ? 1 : -1);
        const score = Math.abs(found.above) * Math.sqrt(found.lean) + TURN * (1 - facing);
        if (score < best) {
          best = score;
          tile[i] = found.tile;
          across[2 * i] = found.a + found.above * found.sa;
          across[2 * i + 1] = found.b + found.above * found.sb;
        }
      }
    }
  });
  return { tile, across };
}

/** The colour at points (n, 3) (Float64Array, sample model units) of a sample whose voxels `matched` maps to
 * example voxels (a function of an Int32Array (n, 3)), read where surfaceUnder says: (n, 3) Float32Array sRGB,
 * as runtime/colour.py's read_colours. */
export function readColours(tiles, matched, points, grid, footprint = null) {
  const n = points.length / 3, side = tiles.side;
  const { tile, across } = surfaceUnder(tiles, matched, points, grid);
  acrossTiles(tiles, tile, across);
  let level = 0;
  if (footprint !== null && footprint > 0) {
    level = Math.min(Math.max(roundHalfEven(Math.log2(footprint * side)), 0), tiles.mips.length - 1);
  }
  const m = side >> level;
  const x = Float32Array.from({ length: n }, (_, i) => (across[2 * i] + 0.5) * m - 0.5);
  const y = Float32Array.from({ length: n }, (_, i) => (across[2 * i + 1] + 0.5) * m - 0.5);
  return bilinearTiles(tiles.mips[level], m, tile, x, y);
}

/** Points (n, 3) of a sample's surface moved by the example's relief under them, as runtime/colour.py's
 * relief: along the example's normal by how far its surface at full detail (the nearest of the tiles of the
 * direction nearest the normal, passing over one read where its depth is clipped) stands out of its smooth
 * surface, at most RELIEF voxels, fading out where that direction turns from the normal (FACING). Float64Array (n, 3). */
export function relief(tiles, matched, points, grid) {
  const out = Float64Array.from(points);
  examplePoints(tiles, matched, points, grid, (i, q, smooth, normal, voxel) => {
    let dominant = 0; // the direction nearest the normal, the first of equals (numpy's argmax)
    for (let direction = 1; direction < 6; direction++) {
      if (normal[direction >> 1] * (direction & 1 ? 1 : -1) > normal[dominant >> 1] * (dominant & 1 ? 1 : -1)) dominant = direction;
    }
    let nearest = Infinity, height = 0;
    for (const reach of REACH_ORDER) {
      const found = tileUnder(tiles, q, voxel, dominant, reach);
      if (found === null || depthClipped(tiles.depth, tiles.side, found.tile, found.a, found.b)) continue;
      if (!(Math.abs(found.above) * Math.sqrt(found.lean) < nearest)) continue;
      nearest = Math.abs(found.above) * Math.sqrt(found.lean);
      height = found.above * Math.sqrt(found.lean) * (dominant & 1 ? 1 : -1);
    }
    if (nearest === Infinity) return;
    const facing = normal[dominant >> 1] * (dominant & 1 ? 1 : -1);
    const lift = Math.min(Math.max(smooth - height, -RELIEF), RELIEF)
      * Math.min(Math.max((facing - FACING[0]) / (FACING[1] - FACING[0]), 0), 1);
    for (let a = 0; a < 3; a++) out[3 * i + a] = points[3 * i + a] + lift * normal[a];
  });
  return out;
}

/** A grid (X, Y, Z) at point q, trilinear with voxel centres at integers (past the outer centres, the outer cells
 * go on linearly up to a voxel out; farther, clamped), and its gradient into `gradient` (3): float64, as
 * runtime/colour.py's trilinear. Returns the value. */
export function trilinear(grid, size, q, gradient) {
  const low = [0, 0, 0], high = [0, 0, 0], f = [0, 0, 0];
  for (let a = 0; a < 3; a++) {
    const p = Math.min(Math.max(q[a], -1), size[a]);
    low[a] = Math.min(Math.max(Math.floor(p), 0), Math.max(size[a] - 2, 0));
    f[a] = p - low[a];
    high[a] = Math.min(low[a] + 1, size[a] - 1);
  }
  let value = 0;
  gradient[0] = 0; gradient[1] = 0; gradient[2] = 0;
  for (let corner = 0; corner < 8; corner++) {
    const c = [(corner >> 2) & 1, (corner >> 1) & 1, corner & 1];
    const index = c.map((bit, a) => (bit ? high[a] : low[a]));
    const v = grid[(index[0] * size[1] + index[1]) * size[2] + index[2]];
    const w = c.map((bit, a) => (bit ? f[a] : 1 - f[a]));
    value += v * w[0] * w[1] * w[2];
    for (let a = 0; a < 3; a++) {
      const dw = w.map((wb, b) => (b !== a ? wb : c[a] ? 1 : -1));
      gradient[a] += v * dw[0] * dw[1] * dw[2];
    }
  }
  return value;
}

/** Where a place on a tile's plane lies beyond the tile's own voxel, the tile of the same direction of the voxel
 * it lies in (its own, or one along the axis): a direction's tiles read as one surface. tile and across, in place. */
export function acrossTiles(tiles, tile, across) {
  for (let i = 0; i < tile.length; i++) {
    if (Math.abs(across[2 * i]) <= 0.5 && Math.abs(across[2 * i + 1]) <= 0.5) continue;
    const direction = tiles.directions[tile[i]], axis = direction >> 1, [pa, pb] = ACROSS[axis];
    const centre = [0, 1, 2].map((a) => tiles.voxels[3 * tile[i] + a]);
    const stepA = Math.floor(centre[pa] + across[2 * i] + 0.5) - centre[pa];
    const stepB = Math.floor(centre[pb] + across[2 * i + 1] + 0.5) - centre[pb];
    const neighbour = centre.slice();
    neighbour[pa] += stepA;
    neighbour[pb] += stepB;
    const found = tiles.read(Int32Array.from(neighbour))[direction];
    if (found < 0) continue;
    tile[i] = found;
    across[2 * i] -= stepA;
    across[2 * i + 1] -= stepB;
  }
}

/** Tiles' depth (N, T, T) at in-plane point (a, b) of [-0.5, 0.5]^2, in voxels: runtime/colour.py's
 * bilinear_depth (its bilinear blend, then float64). */
export function bilinearDepth(depth, side, tile, a, b) {
  const x = Float32Array.of(f32((a + 0.5) * side - 0.5)), y = Float32Array.of(f32((b + 0.5) * side - 0.5));
  return bilinearOne(depth, side, tile, x[0], y[0]) * (2 * DEPTH_RANGE) - DEPTH_RANGE;
}

/** Bilinear lookup in tiles (N, n, n, 3) at texel coordinates x (rows), y (columns), clamped; the blend in
 * float64 as numpy's, then float32. */
export function bilinearTiles(images, n, tile, x, y) {
  const out = new Float32Array(3 * tile.length), last = Math.max(n - 2, 0);
  for (let i = 0; i < tile.length; i++) {
    const xi = Math.min(Math.max(x[i], 0), n - 1), yi = Math.min(Math.max(y[i], 0), n - 1);
    const x0 = Math.min(Math.floor(xi), last), y0 = Math.min(Math.floor(yi), last);
    const x1 = Math.min(x0 + 1, n - 1), y1 = Math.min(y0 + 1, n - 1);
    const fx = xi - x0, fy = yi - y0;
    const at = (a, b, c) => images[((tile[i] * n + a) * n + b) * 3 + c];
    for (let c = 0; c < 3; c++) {
      const top = at(x0, y0, c) * (1 - fy) + at(x0, y1, c) * fy;
      const bottom = at(x1, y0, c) * (1 - fy) + at(x1, y1, c) * fy;
      out[3 * i + c] = (top * (1 - fx) + bottom * fx) / 255;
    }
  }
  return out;
}

/** One channel's bilinear lookup, as bilinearTiles of values (N, n, n, 1): float32. */
/** Whether any of the four texels bilinearDepth reads holds the end of the depth range (0 or 255): the tile's
 * surface left the voxel there, as runtime/colour.py's depth_clipped. */
export function depthClipped(depth, side, tile, a, b) {
  const x = Math.min(Math.max(f32((a + 0.5) * side - 0.5), 0), side - 1), y = Math.min(Math.max(f32((b + 0.5) * side - 0.5), 0), side - 1);
  const last = Math.max(side - 2, 0);
  const x0 = Math.min(Math.floor(x), last), y0 = Math.min(Math.floor(y), last);
  const x1 = Math.min(x0 + 1, side - 1), y1 = Math.min(y0 + 1, side - 1);
  return [[x0, y0], [x0, y1], [x1, y0], [x1, y1]].some(([r, c]) => {
    const value = depth[(tile * side + r) * side + c];
    return value === 0 || value === 255;
  });
}

function bilinearOne(values, n, tile, x, y) {
  const last = Math.max(n - 2, 0);
  const xi = Math.min(Math.max(x, 0), n - 1), yi = Math.min(Math.max(y, 0), n - 1);
  const x0 = Math.min(Math.floor(xi), last), y0 = Math.min(Math.floor(yi), last);
  const x1 = Math.min(x0 + 1, n - 1), y1 = Math.min(y0 + 1, n - 1);
  const fx = xi - x0, fy = yi - y0;
  const at = (a, b) => values[(tile * n + a) * n + b];
  const top = at(x0, y0) * (1 - fy) + at(x0, y1) * fy;
  const bottom = at(x1, y0) * (1 - fy) + at(x1, y1) * fy;
  return f32((top * (1 - fx) + bottom * fx) / 255);
}

/**
 * A coloured model's colour of one sample as a function of points: (n, 3) model coordinates (Float64Array)
 * -> (n, 3) Float32Array sRGB, with an optional footprint (the length in voxels a colour stands for). A
 * format-5 model matches the sample once; a format-4 model reads its colour head, as does any without `detail`.
 */
export async function colouring(model, tri, detail = true) {
  const proj = await project(model, tri);
  if (!model.tiles || !detail) {
    const head = (points) => projectedColours(model, proj, points);
    head.relief = (points) => Float64Array.from(points); // the colour head has no relief
    return head;
  }
  const kept = [];
  for (const part of tri.kept ?? []) kept.push({ low: part.low, high: part.high, planes: (await project(model, part.tri)).planes });
  return planesColouring(model, proj.planes, tri.size, kept);
}

/** `colouring` of a format-5 sample given as its projected planes (query.js's project) and its size: a world's
 * windows come so (world.js's windowColouring), as runtime/colour.py's planes_colouring. Its `relief` moves points
 * by the example's relief. */
export async function planesColouring(model, planes, size, kept = []) {
  const matched = new Correspondence(await matcher(model), model, planes, size, kept);
  const at = (voxels) => matched.call(voxels);
  const colour = (points, footprint = null) => readColours(model.tiles, at, points, size, footprint);
  colour.relief = (points) => relief(model.tiles, at, points, size);
  return colour;
}

/** A coloured model's sRGB colour at points of a sample (model coordinates): (n, 3) Float32Array in [0, 1]. */
export async function colours(model, tri, coords, footprint = null) {
  return (await colouring(model, tri))(coords, footprint);
}

/** The colours at a sample's mesh vertices (positions in the training input's frame, as surface gives them),
 * each standing for `footprint` voxels (a mesh `scale` times finer: 1 / scale). */
export async function vertexColours(model, tri, positions, footprint = null) {
  const { origin, spacing } = model.manifest;
  const coords = Float64Array.from(positions, (p, i) => (p - origin[i % 3]) / spacing[i % 3]);
  return colours(model, tri, coords, footprint);
}

/** A sample's mesh given its relief and colour, as runtime.mesh.paint: on a grid `scale` times finer than the
 * voxels, at least RELIEF_SCALE, a format-5 model's vertices (`positions`, the input's frame) move by its
 * example's relief; then a coloured model's each take the colour around it (1 / scale voxels). Without
 * `detail`, no relief, and colour from the colour head. { positions Float32Array, colours (null for a
 * geometry-only model) }. */
export async function paintMesh(model, tri, positions, scale, detail = true) {
  const { origin, spacing } = model.manifest;
  const relief = detail && model.tiles && scale >= RELIEF_SCALE;
  if (!relief && !model.manifest.colour) return { positions, colours: null };
  const surface = await colouring(model, tri, detail);
  let coords = Float64Array.from(positions, (p, i) => (p - origin[i % 3]) / spacing[i % 3]);
  if (relief) coords = surface.relief(coords);
  return { positions: Float32Array.from(coords, (c, i) => origin[i % 3] + c * spacing[i % 3]),
           colours: model.manifest.colour ? surface(coords, 1 / scale) : null };
}
