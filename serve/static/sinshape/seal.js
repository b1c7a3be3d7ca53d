// A model file's seal (docs/FORMAT.md, "Seal"), checked as core/manifest.py's
// `unseal` checks it: from format 3 a file ends with one more ONNX metadata
// entry {key: SEAL_KEY, value: the SHA-256 of every byte before it, as hex}.

export const SEAL_KEY = 'sinshape.sha256';
const ASCII = new TextEncoder();

/** The seal's bytes before its 64 hex digits: protobuf's encoding of a
 * ModelProto metadata_props (field 14) entry of key SEAL_KEY. */
export const SEAL_PREFIX = (() => {
  const key = ASCII.encode(SEAL_KEY);
  return Uint8Array.from([14 << 3 | 2, 2 + key.length + 2 + 64, 1 << 3 | 2, key.length, ...key, 2 << 3 | 2, 64]);
})();
export const SEAL_BYTES = SEAL_PREFIX.length + 64;

/** { body, sealed, intact }: sealed when `bytes` ends with a seal, intact when
 * its digest is the body's. An unsealed file is all body. */
export function unseal(bytes) {
  const tail = bytes.subarray(bytes.length - SEAL_BYTES);
  const sealed = bytes.length > SEAL_BYTES && SEAL_PREFIX.every((b, i) => tail[i] === b);
  if (!sealed) return { body: bytes, sealed: false, intact: false };
  const body = bytes.subarray(0, bytes.length - SEAL_BYTES);
  const digest = new TextDecoder().decode(tail.subarray(SEAL_PREFIX.length));
  return { body, sealed: true, intact: sha256Hex([body]) === digest };
}

const K = Uint32Array.from([
  0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
  0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
  0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
  0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
  0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
  0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
  0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
  0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2,
]);

/** SHA-256 of the concatenated byte arrays, as hex. In plain JS: crypto.subtle
 * exists only on https and localhost pages, and is asynchronous. */
function sha256Hex(parts) {
  const length = parts.reduce((n, p) => n + p.length, 0);
  const padded = new Uint8Array(Math.ceil((length + 9) / 64) * 64);
  let at = 0;
  for (const p of parts) { padded.set(p, at); at += p.length; }
  padded[length] = 0x80;
  const view = new DataView(padded.buffer);
  view.setUint32(padded.length - 8, Math.floor(length / 2 ** 29));  // the length in bits, big-endian
  view.setUint32(padded.length - 4, (length * 8) >>> 0);
  const h = Uint32Array.from([0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19]);
  const w = new Uint32Array(64);
  const rotr = (x, n) => (x >>> n) | (x << (32 - n));
  for (let block = 0; block < padded.length; block += 64) {
    for (let i = 0; i < 16; i++) w[i] = view.getUint32(block + 4 * i);
    for (let i = 16; i < 64; i++) {
      const s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >>> 3);
      const s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >>> 10);
      w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    let a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], k = h[7];
    for (let i = 0; i < 64; i++) {
      const t1 = k + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + w[i];
      const t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
      k = g; g = f; f = e; e = (d + t1) | 0; d = c; c = b; b = a; a = (t1 + t2) | 0;
    }
    h[0] += a; h[1] += b; h[2] += c; h[3] += d; h[4] += e; h[5] += f; h[6] += g; h[7] += k;
  }
  return Array.from(h, (v) => v.toString(16).padStart(8, '0')).join('');
}
