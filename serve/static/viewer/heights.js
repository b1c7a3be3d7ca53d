// A height map the user opens for the world mode, read as world.parse_height_map
// reads it: a greyscale .png (black 0, white RELIEF times the model's height;
// columns along the first horizontal axis, rows from the bottom up along the
// second) or a .npy array of heights in voxels ([i, j]: tile i, j's). The
// browser decodes an image to 8 bits a channel, so a 16-bit .png reads coarser
// here than with sinrun.
//
//   const heights = await readHeightMap(file, info);   // world.js's HeightMap
import { HeightMap, worldLayout } from '../sinshape/world.js';

export const RELIEF = 4; // world.RELIEF: an image's white, in the model's heights

/** The .npy array's values, [i][j] in C order, and its shape: little-endian floats and integers only. */
function readNpy(bytes) {
  const text = new TextDecoder().decode(bytes.subarray(0, Math.min(bytes.length, 4096)));
  if (!text.startsWith('\u0093NUMPY') && !(bytes[0] === 0x93 && text.slice(1, 6) === 'NUMPY')) throw new Error('not a .npy file');
  const headerLength = bytes[6] === 1 ? bytes[8] | (bytes[9] << 8) : new DataView(bytes.buffer, bytes.byteOffset).getUint32(8, true);
  const start = bytes[6] === 1 ? 10 : 12, header = text.slice(start, start + headerLength);
  const descr = /'descr':\s*'([<|]?)([fiu])(\d)'/.exec(header), shape = /'shape':\s*\((\d+),\s*(\d+)\)/.exec(header);
  if (!descr || !shape || /'fortran_order':\s*True/.test(header)) throw new Error('a 2-D numeric array in C order, as numpy.save writes it');
  const kind = { f4: Float32Array, f8: Float64Array, i1: Int8Array, i2: Int16Array, i4: Int32Array, u1: Uint8Array, u2: Uint16Array, u4: Uint32Array }[descr[2] + descr[3]];
  if (!kind) throw new Error(`its numbers (${descr[2]}${descr[3]}) are not ones this page reads`);
  const dims = [Number(shape[1]), Number(shape[2])], data = bytes.slice(start + headerLength);
  return { values: Array.from(new kind(data.buffer, 0, dims[0] * dims[1])), shape: dims };
}

/** A height map from a file (.png or .npy), as world.parse_height_map: a one-line Error where it is not one. */
export async function readHeightMap(file, info) {
  const bytes = new Uint8Array(await file.arrayBuffer());
  try {
    if (/\.npy$/i.test(file.name)) {
      const { values, shape } = readNpy(bytes);
      return HeightMap.of(values, shape);
    }
    const image = await createImageBitmap(new Blob([bytes]));
    const canvas = new OffscreenCanvas(image.width, image.height), context = canvas.getContext('2d');
    context.drawImage(image, 0, 0);
    const pixels = context.getImageData(0, 0, image.width, image.height).data;
    const layout = worldLayout(info), relief = RELIEF * layout.stride[layout.up];
    const [w, h] = [image.width, image.height], values = new Array(w * h);
    for (let i = 0; i < w; i++) {
      for (let j = 0; j < h; j++) {
        const at = 4 * ((h - 1 - j) * w + i); // the bottom row is j = 0
        values[i * h + j] = ((pixels[at] * 299 + pixels[at + 1] * 587 + pixels[at + 2] * 114) / 1000 / 255) * relief;
      }
    }
    return HeightMap.of(values, [w, h]);
  } catch (error) {
    throw new Error(`${file.name}: not a height map (${error.message})`);
  }
}
