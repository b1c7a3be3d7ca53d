// Occupancy on a grid from a tri-plane, as runtime/query.py's dense: the
// decoder's first layer is applied to each plane once (stage decoder_planes),
// bilinear interpolation commutes with it, so a grid point costs three vector
// adds, a ReLU and a dot product.
import { InputError } from './errors.js';
import { resizeWeights, roundHalfEven } from './generate.js';

export const PLANE_AXES = [[0, 1], [0, 2], [1, 2]]; // the grid axes each plane keeps, in PLANES order

export const MAX_GRID_SIDE = 1 << 16;
export const TAB_BYTES = 2 * 2 ** 30; // what one piece of work may take in a browser tab: well under its memory

/** The final tri-plane times the decoder's first layer: { planes: 3 x (H, W, D), size }. */
export async function project(model, tri) {
  const outputs = await model.decoderPlanes.run(tri.planes.map((p) => ({ data: p.data, dims: [1, ...p.dims] })));
  return { planes: outputs.map((o) => ({ data: o.data, dims: Array.from(o.dims).slice(1) })), size: tri.size };
}

/** Points per axis of a grid `scale` times finer than `size`. */
export function gridShape(size, scale) {
  if (!Number.isFinite(scale) || scale <= 0) throw new InputError(`--scale must be a positive number, got ${scale}`);
  const shape = size.map((n) => Math.max(2, roundHalfEven(n * scale)));
  if (Math.max(...shape) > MAX_GRID_SIDE) {
    throw new InputError(`--scale ${scale} asks for a ${shape.join('x')} grid; at most ${MAX_GRID_SIDE} points per axis are supported`);
  }
  return shape;
}

/** A (H, W, D) plane interpolated to (ma, mb) points: (ma, mb, D) Float32Array. */
function finePlane(plane, ma, mb) {
  const [h, w, d] = plane.dims, src = plane.data;
  const ra = resizeWeights(h, ma), rb = resizeWeights(w, mb);
  const rows = new Float32Array(ma * w * d); // along the first axis: (ma, W, D)
  for (let i = 0; i < ma; i++) {
    const a0 = ra.low[i] * w * d, a1 = ra.high[i] * w * d, p = ra.wLow[i], q = ra.wHigh[i];
    for (let t = 0; t < w * d; t++) rows[i * w * d + t] = p * src[a0 + t] + q * src[a1 + t];
  }
  const out = new Float32Array(ma * mb * d);
  for (let i = 0; i < ma; i++) {
    for (let j = 0; j < mb; j++) {
      const b0 = (i * w + rb.low[j]) * d, b1 = (i * w + rb.high[j]) * d, p = rb.wLow[j], q = rb.wHigh[j];
      const at = (i * mb + j) * d;
      for (let c = 0; c < d; c++) out[at + c] = p * rows[b0 + c] + q * rows[b1 + c];
    }
  }
  return out;
}

/**
 * Occupancy on every point of a grid `scale` times finer than the tri-plane:
 * { data: Float32Array (Mx, My, Mz) in C order, shape }. progress(fraction),
 * if given, is called after each x slice.
 */
export function projectedDense(model, proj, scale = 1, progress = null) {
  const [mx, my, mz] = gridShape(proj.size, scale);
  if (mx * my * mz * 4 > TAB_BYTES) throw new InputError(`a dense ${mx}x${my}x${mz} occupancy grid needs more memory than a page should take`);
  const d = model.manifest.hidden;
  const xy = finePlane(proj.planes[0], mx, my);
  const xz = finePlane(proj.planes[1], mx, mz);
  const yz = finePlane(proj.planes[2], my, mz);
  const { bias1, weight2, bias2 } = model.head;
  const out = new Float32Array(mx * my * mz);
  const sum = new Float32Array(d);
  for (let x = 0; x < mx; x++) {
    for (let y = 0; y < my; y++) {
      const a = (x * my + y) * d;
      for (let c = 0; c < d; c++) sum[c] = xy[a + c] + bias1[c];
      for (let z = 0; z < mz; z++) {
        const b = (x * mz + z) * d, e = (y * mz + z) * d;
        let s = bias2;
        for (let c = 0; c < d; c++) {
          const h = sum[c] + xz[b + c] + yz[e + c];
          if (h > 0) s += h * weight2[c];
        }
        out[(x * my + y) * mz + z] = 1 / (1 + Math.exp(-s));
      }
    }
    progress?.((x + 1) / mx);
  }
  return { data: out, shape: [mx, my, mz] };
}


/** Occupancy on a grid `scale` times finer than the tri-plane, as runtime/query.py's dense
 * (progress(fraction), if given, after each x slice). */
export async function dense(model, tri, scale = 1, progress = null) {
  return projectedDense(model, await project(model, tri), scale, progress);
}
