// Occupancy on a grid from a tri-plane, as runtime/query.py's dense (and a
// format-4 model's colour head at points, as its colouring): the
// decoder's first layer is applied to each plane once (stage decoder_planes),
// bilinear interpolation commutes with it, so a grid point costs three vector
// adds, a ReLU and a dot product.
import { InputError } from './errors.js';
import { resizeWeights, roundHalfEven } from './generate.js';

export const PLANE_AXES = [[0, 1], [0, 2], [1, 2]]; // the grid axes each plane keeps, in PLANES order

/** A coloured model's colour head (runtime/query.py: head_colour): sigmoid(relu(h + b1) @ w_colour + b_colour)
 * of one pre-activation vector, its sRGB into out[outAt..outAt + 2]. */
export function headColour(head, hidden, at = 0, out = new Float32Array(3), outAt = 0) {
  const { bias1, weightColour: w, biasColour: b } = head;
  let r = b[0], g = b[1], bl = b[2];
  for (let c = 0; c < bias1.length; c++) {
    const h = hidden[at + c] + bias1[c];
    if (h > 0) { r += h * w[3 * c]; g += h * w[3 * c + 1]; bl += h * w[3 * c + 2]; }
  }
  out[outAt] = 1 / (1 + Math.exp(-r));
  out[outAt + 1] = 1 / (1 + Math.exp(-g));
  out[outAt + 2] = 1 / (1 + Math.exp(-bl));
  return out;
}

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

/** A (H, W, D) plane at a real cell position (u, v), bilinear as runtime/query.py's bilinear, added into out (D). */
export function addBilinear(plane, u, v, out) {
  const [h, w, d] = plane.dims, src = plane.data;
  const u0 = Math.min(Math.max(Math.floor(u), 0), Math.max(h - 2, 0)), v0 = Math.min(Math.max(Math.floor(v), 0), Math.max(w - 2, 0));
  const u1 = Math.min(u0 + 1, h - 1), v1 = Math.min(v0 + 1, w - 1);
  const fu = u - u0, fv = v - v0;
  const a = (u0 * w + v0) * d, b = (u0 * w + v1) * d, c = (u1 * w + v0) * d, e = (u1 * w + v1) * d;
  for (let k = 0; k < d; k++) {
    out[k] += (src[a + k] * (1 - fv) + src[b + k] * fv) * (1 - fu) + (src[c + k] * (1 - fv) + src[e + k] * fv) * fu;
  }
}

/**
 * A format-4 model's sRGB colour at points, as runtime/query.py's colouring:
 * coords (n, 3) in finest voxels (grid point (i, j, k) of the sample at
 * scale 1 at (i, j, k)); a point outside the tri-plane takes the colour of
 * the nearest point inside. Returns Float32Array (n, 3) in [0, 1].
 */
export function projectedColours(model, proj, coords) {
  const n = coords.length / 3, d = model.manifest.hidden, size = proj.size;
  const out = new Float32Array(3 * n), hidden = new Float64Array(d), at = [0, 0, 0];
  for (let i = 0; i < n; i++) {
    for (let a = 0; a < 3; a++) at[a] = Math.min(Math.max(coords[3 * i + a], 0), size[a] - 1);
    hidden.fill(0);
    PLANE_AXES.forEach(([a, b], k) => addBilinear(proj.planes[k], at[a], at[b], hidden));
    headColour(model.head, hidden, 0, out, 3 * i);
  }
  return out;
}
