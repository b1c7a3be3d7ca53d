// The maps the user opens for the world mode. A height map, read as
// world_maps.parse_height_map reads it: a greyscale .png (black 0, white RELIEF
// times the model's height; columns along the first horizontal axis, rows
// from the bottom up along the second) or a .npy array of heights in voxels
// ([i, j]: tile i, j's); a greyscale .png is decoded here, 16 bits included, as
// Pillow reads it, a colour one by the browser. A model map, read as
// world_maps.parse_model_map reads it: a palette .png's indices or a greyscale
// one's values (decoded here, as Pillow reads them, 16 bits included), laid
// out as a height map's pixels, or a .npy array of models' indices.
//
//   const heights = await readHeightMap(file, info);   // world.js's HeightMap
//   const placed = await readModelMap(file);           // world.js's ModelMap
import { InputError } from '../sinshape/errors.js';
import { HeightMap, MAX_MAP_SIDE, ModelMap, worldTiling } from '../sinshape/world.js';

export const RELIEF = 4; // world_maps.RELIEF: an image's white, in the model's heights
export const MAX_MAP_BYTES = 64 << 20; // world_maps.MAX_MAP_BYTES: a map file

/** A map file's bytes; one of more than MAX_MAP_BYTES is refused, unread, as world_maps.parse_height_map and parse_model_map refuse it. */
async function mapBytes(file, what, field) {
  if (file.size > MAX_MAP_BYTES) throw new InputError(`${file.name}: ${Math.floor(file.size / 2 ** 20)} MB is too large for ${what}`, field);
  return new Uint8Array(await file.arrayBuffer());
}

/** The .npy array's values, [i][j] in C order, and its shape: little-endian floats and integers only. */
function readNpy(bytes) {
  const text = new TextDecoder().decode(bytes.subarray(0, Math.min(bytes.length, 4096)));
  if (!text.startsWith('\u0093NUMPY') && !(bytes[0] === 0x93 && text.slice(1, 6) === 'NUMPY')) throw new Error('not a .npy file');
  const headerLength = bytes[6] === 1 ? bytes[8] | (bytes[9] << 8) : new DataView(bytes.buffer, bytes.byteOffset).getUint32(8, true);
  const start = bytes[6] === 1 ? 10 : 12, header = text.slice(start, start + headerLength);
  const descr = /'descr':\s*'([<|]?)([fiu])(\d)'/.exec(header), shape = /'shape':\s*\((\d+),\s*(\d+)\)/.exec(header);
  if (!descr || !shape || /'fortran_order':\s*True/.test(header)) throw new Error('a 2-D numeric array in C order, as numpy.save writes it');
  const kind = { f4: Float32Array, f8: Float64Array, i1: Int8Array, i2: Int16Array, i4: Int32Array, i8: BigInt64Array, u1: Uint8Array,
    u2: Uint16Array, u4: Uint32Array, u8: BigUint64Array }[descr[2] + descr[3]];
  if (!kind) throw new Error(`its numbers (${descr[2]}${descr[3]}) are not ones this page reads`);
  const dims = [Number(shape[1]), Number(shape[2])], data = bytes.slice(start + headerLength);
  return { values: Array.from(new kind(data.buffer, 0, dims[0] * dims[1]), Number), shape: dims };
}

/**
 * A height map from a file (.png or .npy), as world_maps.parse_height_map: a one-line Error where it is not one.
 * A greyscale .png (8 or 16 bits, or fewer) is decoded here, so its heights are Pillow's to the bit; a colour
 * one through the browser's image decoder, its pixels' luminance taken as Pillow's convert('L') takes it.
 */
export async function readHeightMap(file, info) {
  const bytes = await mapBytes(file, 'a height map', 'heights');
  try {
    if (/\.npy$/i.test(file.name)) {
      const { values, shape } = readNpy(bytes);
      return HeightMap.of(values, shape);
    }
    const header = pngHeader(bytes), [w, h] = [header.width, header.height];
    if (Math.max(w, h) > MAX_MAP_SIDE) throw new Error(`${w}x${h} pixels; a height map has at most ${MAX_MAP_SIDE} a side`);
    const full = { 'I;16': 65535, '1': 1 }[header.mode] ?? 255; // white: Pillow's 16-bit, 1-bit and 8-bit grey
    const grey = ['L', 'I;16', '1'].includes(header.mode) ? await pngPixels(header) : await luminance(bytes);
    const tiling = worldTiling(info), relief = RELIEF * tiling.stride[tiling.up];
    const values = new Array(w * h);
    for (let i = 0; i < w; i++) {
      for (let j = 0; j < h; j++) values[i * h + j] = (grey[(h - 1 - j) * w + i] / full) * relief; // the bottom row is j = 0
    }
    return HeightMap.of(values, [w, h]);
  } catch (error) {
    throw new Error(`${file.name}: not a height map (${error.message})`);
  }
}

/** A colour image's pixels' luminance, rows from the top, as Pillow's convert('L'): (19595 R + 38470 G + 7471 B + 2^15) >> 16. */
async function luminance(bytes) {
  const image = await createImageBitmap(new Blob([bytes]), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
  const canvas = new OffscreenCanvas(image.width, image.height), context = canvas.getContext('2d');
  context.drawImage(image, 0, 0);
  const rgba = context.getImageData(0, 0, image.width, image.height).data, out = new Array(image.width * image.height);
  for (let k = 0; k < out.length; k++) out[k] = (rgba[4 * k] * 19595 + rgba[4 * k + 1] * 38470 + rgba[4 * k + 2] * 7471 + 0x8000) >> 16;
  return out;
}

/** A .png's header and its image data, unread: { width, height, depth, colour (its colour type), interlace, mode (Pillow's
 * name for its kind of pixel), data: the IDAT chunks' bytes }. */
function pngHeader(bytes) {
  if (![137, 80, 78, 71, 13, 10, 26, 10].every((b, k) => bytes[k] === b)) throw new Error('not a .png image');
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength), parts = [];
  let header = null;
  for (let at = 8, length = 0; at + 8 <= bytes.length; at += 12 + length) { // chunks: length, type, data, CRC
    length = view.getUint32(at);
    const type = String.fromCharCode(...bytes.subarray(at + 4, at + 8)), data = bytes.subarray(at + 8, at + 8 + length);
    if (type === 'IEND') break;
    if (type === 'IHDR') header = { width: view.getUint32(at + 8), height: view.getUint32(at + 12), depth: data[8], colour: data[9], interlace: data[12] };
    if (type === 'IDAT') parts.push(data);
  }
  if (!header || !parts.length) throw new Error('a .png without its header or image data');
  const { depth, colour } = header;
  const mode = { 0: depth === 1 ? '1' : depth === 16 ? 'I;16' : 'L', 2: 'RGB', 3: 'P', 4: 'LA', 6: 'RGBA' }[colour];
  return { ...header, mode, data: new Blob(parts) };
}

/** Paeth's predictor (the PNG specification's filter 4). */
function paeth(left, up, corner) {
  const p = left + up - corner, pa = Math.abs(p - left), pb = Math.abs(p - up), pc = Math.abs(p - corner);
  return pa <= pb && pa <= pc ? left : pb <= pc ? up : corner;
}

/**
 * A one-channel .png's pixels (pngHeader's), as Pillow reads a greyscale or
 * palette image: rows from the top, each sample as it is (a palette's index;
 * 1-bit grey 0 or 1, 16-bit its value) but 2- and 4-bit grey, widened to 8
 * bits. Adam7-interlaced images too.
 */
async function pngPixels({ width, height, depth, colour, interlace, data }) {
  const raw = new Uint8Array(await new Response(data.stream().pipeThrough(new DecompressionStream('deflate'))).arrayBuffer());
  const widen = colour === 0 && (depth === 2 || depth === 4) ? 255 / ((1 << depth) - 1) : 1;
  const passes = interlace ? [[0, 0, 8, 8], [4, 0, 8, 8], [0, 4, 4, 8], [2, 0, 4, 4], [0, 2, 2, 4], [1, 0, 2, 2], [0, 1, 1, 2]] : [[0, 0, 1, 1]];
  const pixels = new Array(width * height), step = Math.max(1, depth / 8); // bytes from a pixel to the one before it
  let at = 0;
  for (const [x0, y0, dx, dy] of passes) { // (x0, y0, dx, dy): the pixels of a pass, as Adam7 spaces them
    const w = Math.ceil((width - x0) / dx), h = Math.ceil((height - y0) / dy), length = Math.ceil((w * depth) / 8);
    let above = new Uint8Array(length);
    for (let y = 0; w > 0 && y < h; y++) {
      const filter = raw[at], line = raw.slice(at + 1, at + 1 + length);
      if (filter > 4 || line.length < length) throw new Error('its image data is damaged');
      at += 1 + length;
      for (let k = 0; k < length; k++) {
        const left = k >= step ? line[k - step] : 0, up = above[k], corner = k >= step ? above[k - step] : 0;
        line[k] += filter === 1 ? left : filter === 2 ? up : filter === 3 ? (left + up) >> 1 : filter === 4 ? paeth(left, up, corner) : 0;
      }
      for (let x = 0; x < w; x++) {
        const bit = x * depth, sample = depth === 16 ? (line[2 * x] << 8) | line[2 * x + 1]
          : (line[bit >> 3] >> (8 - depth - (bit & 7))) & ((1 << depth) - 1);
        pixels[(y0 + y * dy) * width + x0 + x * dx] = sample * widen;
      }
      above = line;
    }
  }
  return pixels;
}

/** A model map from a file (.png or .npy), as world_maps.parse_model_map: an InputError (one line) where it is not one. */
export async function readModelMap(file) {
  const bytes = await mapBytes(file, 'a model map', 'models_map'), { name } = file, suffix = /\.[^.]*$/.exec(name)?.[0].toLowerCase() ?? '';
  if (suffix === '.npy') {
    let read;
    try {
      read = readNpy(bytes);
    } catch (error) {
      throw new InputError(`${name}: not a 2-D numeric .npy array of at most ${MAX_MAP_SIDE} a side (${error.message})`, 'models_map');
    }
    return ModelMap.of(read.values, read.shape);
  }
  if (suffix !== '.png') {
    throw new InputError(`${name}: a model map is a .png image or a .npy array, got ${suffix ? `'${suffix}'` : 'no extension'}`, 'models_map');
  }
  let image;
  try {
    image = pngHeader(bytes);
  } catch (error) {
    throw new InputError(`${name}: not a readable image (${error.message})`, 'models_map');
  }
  const { width: w, height: h, mode } = image;
  if (Math.max(w, h) > MAX_MAP_SIDE) throw new InputError(`${name}: ${w}x${h} pixels; a model map has at most ${MAX_MAP_SIDE} a side`, 'models_map');
  if (!['P', 'L', 'I;16', '1'].includes(mode)) {
    throw new InputError(`${name}: a model map is a palette or greyscale image (a model's index per pixel), got mode ${mode}`, 'models_map');
  }
  let pixels;
  try {
    pixels = await pngPixels(image);
  } catch (error) {
    throw new InputError(`${name}: not a readable image (${error.message})`, 'models_map');
  }
  const values = new Array(w * h);
  for (let i = 0; i < w; i++) for (let j = 0; j < h; j++) values[i * h + j] = pixels[(h - 1 - j) * w + i]; // the bottom row is j = 0
  return ModelMap.of(values, [w, h]);
}
