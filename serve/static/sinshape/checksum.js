// The format-2 checksum of a model, computed as runtime/manifest.py's
// `checksum` computes it (docs/FORMAT.md, "Checksum"): sha256 over the
// manifest less its checksum as canonical JSON (Python's json.dumps with
// sorted keys, no spaces, ASCII), then every initializer in order of name: its
// name, a zero byte, its float32 values little-endian.
//
// The canonical JSON must be Python's to the byte, so it is printed from the
// manifest's text, not from JSON.parse's values: JSON.parse cannot tell 1.0
// from 1, which Python prints differently, and loses integers beyond 2^53.

const UTF8 = new TextEncoder();

/** Compare strings by code point, as Python sorts them (JS's sort uses UTF-16 units). */
function byCodePoint(a, b) {
  const x = Array.from(a, (c) => c.codePointAt(0)), y = Array.from(b, (c) => c.codePointAt(0));
  for (let i = 0; i < Math.min(x.length, y.length); i++) if (x[i] !== y[i]) return x[i] - y[i];
  return x.length - y.length;
}

/** JSON text -> a tree that keeps each number's digits: {object: [[key, v]]}, {array}, {string}, {number}, {literal}. */
function readJson(text) {
  let at = 0;
  const fail = () => { throw new SyntaxError(`bad JSON at ${at}`); };
  const space = () => { while (at < text.length && ' \t\n\r'.includes(text[at])) at++; };
  const token = (pattern) => {
    pattern.lastIndex = at;
    const match = pattern.exec(text);
    if (!match) fail();
    at = pattern.lastIndex;
    return match[0];
  };
  const STRING = /"(?:[^"\\\u0000-\u001f]|\\(?:["\\/bfnrt]|u[0-9a-fA-F]{4}))*"/y;
  const NUMBER = /-?(?:0|[1-9]\d*)(?:\.\d+)?(?:[eE][+-]?\d+)?/y;
  const LITERAL = /true|false|null|NaN|Infinity|-Infinity/y;  // Python's json reads the last three too
  const value = () => {
    space();
    const c = text[at];
    if (c === '{' || c === '[') {
      at++;
      const items = [];
      space();
      if (text[at] !== (c === '{' ? '}' : ']')) {
        for (;;) {
          space();
          if (c === '{') {
            const key = JSON.parse(token(STRING));
            space();
            if (text[at++] !== ':') fail();
            items.push([key, value()]);
          } else items.push(value());
          space();
          if (text[at] !== ',') break;
          at++;
        }
      }
      if (text[at++] !== (c === '{' ? '}' : ']')) fail();
      return c === '{' ? { object: items } : { array: items };
    }
    if (c === '"') return { string: JSON.parse(token(STRING)) };
    LITERAL.lastIndex = at;
    if (LITERAL.test(text)) {
      LITERAL.lastIndex = at;
      return { literal: token(LITERAL) };
    }
    return { number: token(NUMBER) };
  };
  const tree = value();
  space();
  if (at !== text.length) fail();
  return tree;
}

/** A string as Python's json.dumps prints it with ensure_ascii. */
function pythonString(s) {
  const escapes = { '"': '\\"', '\\': '\\\\', '\n': '\\n', '\r': '\\r', '\t': '\\t', '\b': '\\b', '\f': '\\f' };
  let out = '"';
  for (let i = 0; i < s.length; i++) {
    const code = s.charCodeAt(i);  // UTF-16 units: astral characters come out as surrogate pairs, as in Python
    if (escapes[s[i]]) out += escapes[s[i]];
    else if (code < 0x20 || code > 0x7e) out += `\\u${code.toString(16).padStart(4, '0')}`;
    else out += s[i];
  }
  return `${out}"`;
}

/** A float as Python's repr prints it: the shortest digits that read back
 * (as JS's), fixed notation for exponents -5 < e < 16 (with '.0' if whole),
 * else d.ddde+XX with at least two exponent digits. */
export function pythonFloat(x) {
  if (Number.isNaN(x)) return 'NaN';
  if (!Number.isFinite(x)) return x > 0 ? 'Infinity' : '-Infinity';
  if (x === 0) return Object.is(x, -0) ? '-0.0' : '0.0';
  const [mantissa, exponentText] = Math.abs(x).toExponential().split('e');  // shortest round-trip digits
  const digits = mantissa.replace('.', '');
  const exponent = Number(exponentText);
  const sign = x < 0 ? '-' : '';
  if (exponent < -4 || exponent >= 16) {
    const e = `${exponent < 0 ? '-' : '+'}${String(Math.abs(exponent)).padStart(2, '0')}`;
    return `${sign}${digits[0]}${digits.length > 1 ? `.${digits.slice(1)}` : ''}e${e}`;
  }
  if (exponent < 0) return `${sign}0.${'0'.repeat(-exponent - 1)}${digits}`;
  const whole = digits.slice(0, exponent + 1).padEnd(exponent + 1, '0');
  return `${sign}${whole}.${digits.slice(exponent + 1) || '0'}`;
}

function pythonJson(node) {
  if (node.object) {
    const entries = new Map(node.object);  // a repeated key: the last one wins, as in Python
    const keys = [...entries.keys()].sort(byCodePoint);
    return `{${keys.map((k) => `${pythonString(k)}:${pythonJson(entries.get(k))}`).join(',')}}`;
  }
  if (node.array) return `[${node.array.map(pythonJson).join(',')}]`;
  if ('string' in node) return pythonString(node.string);
  if (node.literal) return node.literal;
  const t = node.number;
  return /^-?\d+$/.test(t) ? BigInt(t).toString() : pythonFloat(Number(t));
}

/** The canonical JSON the checksum covers: the manifest's text without its `checksum`. */
export function canonicalManifest(text) {
  const tree = readJson(text);
  tree.object = tree.object.filter(([key]) => key !== 'checksum');
  return pythonJson(tree);
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
export function sha256Hex(parts) {
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

/** 'sha256:...' of a manifest's text and the model's weights: [[name, their
 * float32 values as little-endian bytes]]. */
export function modelChecksum(manifestText, weights) {
  const parts = [UTF8.encode(canonicalManifest(manifestText))];
  for (const [name, bytes] of [...weights].sort((a, b) => byCodePoint(a[0], b[0]))) {
    parts.push(UTF8.encode(name), new Uint8Array(1), bytes);
  }
  return `sha256:${sha256Hex(parts)}`;
}
