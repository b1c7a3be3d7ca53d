// Marching cubes at 0.5 on the padded grid: the classic algorithm with Paul
// Bourke's triangle table (the one three.js ships in MarchingCubes.js), one
// vertex per crossed grid edge, shared by the cubes around it. The Python
// runtime uses scikit-image's Lewiner variant, which resolves ambiguous cubes
// differently, so face counts may differ by a few per ten thousand.
//
// The grid is padded with one empty point on every side, so surfaces close at
// its border, as runtime/mesh.py does (a world's tile leaves its shared sides open).

// Triangles per cube configuration: edge numbers 0-11 as the letters 0-9, a, b,
// three per triangle; '-' for none. Bit v of a configuration is set when corner
// v is below the level (outside).
export const TABLE = '- 083 019 183981 12a 08312a 92a029 2832a8a98 3b2 0b28b0 19023b 1b219b98b 3a1ba3 0a108a8ba 3903b9ba9 98aa8b 478 430734 019847 419471731 12a847 34730412a 92a902847 2a9297273794 8473b2 b47b24204 90184723b 47b94b9b2921 3a13ba784 1ba14b1047b4 47890b9bab03 47b4b99ba 954 954083 054150 854835315 12a954 30812a495 52a542402 2a5325354348 95423b 0b208b495 05401523b 21525828b485 a3ba13954 4950818a18ba 54050b5bab03 54858aa8b 978579 930953573 078017157 153357 978957a12 a12950530573 802825857a52 2a5253357 7957893b2 95797292027b 23b018178157 b21b17715 958857a13a3b 5705097b010aba0 ba0b03a50807570 ba57b5 a65 0835a6 9015a6 1831985a6 165261 165126308 965906026 598582526328 23ba65 b08b20a65 01923b5a6 5a61929b298b 63b653513 08b0b50515b6 3b6036065059 65969bb98 5a6478 43047365a 1905a6847 a65197173794 612651478 125526304347 847905065026 739794329596269 3b2784a65 5a647242027b 01947823b5a6 9219b294b7b45a6 8473b53515b6 51b5b610b7b404b 059065036b63847 65969b4797b9 a4964a 4a649a083 a01a60640 83181686461a 149124264 308129249264 024426 832824426 a49a64b23 08228b49a4a6 3b201606461a 64161a48121b8b1 964936913b63 8b1810b61914641 3b6360064 648b68 7a678a89a 0730a709a67a a671a7178180 a67a71173 126168189867 269291679093739 780706602 732672 23ba68a89867 20727b09767a9a7 1801781a767a23b b21b17a61671 896867916b63136 091b67 7807063b0b60 7b6 76b 308b76 019b76 819831b76 a126b7 12a3086b7 2902a96b7 6b72a3a83a98 723627 708760620 276237019 162186198876 a76a17137 a7617a187108 03707a0a96a7 76a7a88a9 684b86 36b306046 86b846901 946963931b36 6846b82a1 12a30b06b046 4b846b0292a9 a93a32943b36463 823842462 042462 190234246438 194142246 8138618466a1 a10a06604 4634386a3039a93 a946a4 49576b 083495b76 50154076b b76834354315 954a1276b 6b712a083495 76b54a42a402 348354325a52b76 723762549 954086062687 362376150540 628687218485158 954a16176137 16a176107870954 40a4a503a6a737a 76a7a854a48a 6956b9b89 36b063056095 0b805b01556b 6b3635531 12a95b9b8b56 0b306b09656912a b85b56805a52025 6b36352a3a53 589528562382 956960062 158180568382628 156216 13616a386569896 a10a06950560 03856a a56 b5a75b b5ab75830 5b75ab190 a75ab7981831 b12b71751 08312717572b 9759279022b7 75272b592328982 25a235375 820852875a25 9015a35373a2 982921872a25752 135375 087071175 903935537 987597 5845a8ab8 5045b05abb30 01984a8aba45 ab4a45b34941314 2512852b8458 04b0b345b2b151b 0250592b5458b85 9452b3 25a352345384 5a2524420 3a235a385458019 5a2524192942 845853351 045105 845853905035 945 4b749b9ab 0834979b79ab 1ab1b414074b 3143481a474bab4 4b79b492b912 9749b791b2b1083 b74b42240 b74b42834324 29a279237749 9a7974a27870207 37a3a274a1a040a 1a2874 491417713 491417081871 403743 487 9a8ab8 30939bb9a 01a0a88ab 31ab3a 12b1b99b8 30939b1292b9 02b80b 32b 23828aa89 9a2092 23828a0181a8 1a2 138918 091 038 -'.split(' ').map((s) => (s === '-' ? [] : Array.from(s, (ch) => parseInt(ch, 16))));
// Corners (x, y, z) and edges (corner pairs) in Bourke's numbering.
export const CORNERS = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]];
export const EDGES = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]];

class Growable {
  constructor(Type) { this.Type = Type; this.data = new Type(1 << 12); this.length = 0; }

  push3(a, b, c) {
    if (this.length + 3 > this.data.length) {
      const bigger = new this.Type(this.data.length * 2);
      bigger.set(this.data);
      this.data = bigger;
    }
    this.data[this.length++] = a; this.data[this.length++] = b; this.data[this.length++] = c;
  }

  done() { return this.data.slice(0, this.length); }
}

/**
 * The 0.5 surface of an occupancy grid { data: (Mx, My, Mz) Float32Array, shape }.
 * Returns { positions: Float32Array (V, 3) in padded grid units (point p of the
 * grid is at p + 1), faces: Uint32Array (F, 3) }, faces wound so normals point out.
 * pad: empty points added per axis, [low, high] (a world's tile, 0 on the
 * sides it shares with its neighbours, is open there; point p is at p + low).
 */
export function marchingCubes(grid, level = 0.5, progress = null, pad = [[1, 1], [1, 1], [1, 1]]) {
  const [mx, my, mz] = grid.shape, src = grid.data;
  const [[lx, hx], [ly, hy], [lz, hz]] = pad;
  const px = mx + lx + hx, py = my + ly + hy, pz = mz + lz + hz; // padded
  const value = (x, y, z) => (x < lx || y < ly || z < lz || x >= lx + mx || y >= ly + my || z >= lz + mz ? 0
    : src[((x - lx) * my + (y - ly)) * mz + (z - lz)]);
  const positions = new Growable(Float32Array), faces = new Growable(Uint32Array);
  let vertices = 0;
  // Vertex index of each crossed edge, -1 if none yet: x-edges of the current
  // slab, y- and z-edges of its two x-layers.
  const layer = py * pz;
  const xEdges = new Int32Array(layer);
  let yEdges = [new Int32Array(layer).fill(-1), new Int32Array(layer).fill(-1)];
  let zEdges = [new Int32Array(layer).fill(-1), new Int32Array(layer).fill(-1)];
  const corner = new Float64Array(8);
  const edgeVertex = new Int32Array(12);

  // The vertex on edge e of cube (x, y, z), made once.
  const vertexOn = (e, x, y, z) => {
    const [a, b] = EDGES[e];
    const ca = CORNERS[a], cb = CORNERS[b];
    const axis = ca[0] !== cb[0] ? 0 : ca[1] !== cb[1] ? 1 : 2;
    const lo = ca[axis] < cb[axis] ? ca : cb; // the edge's lower end, relative to the cube
    const gx = x + lo[0], gy = y + lo[1], gz = z + lo[2];
    const slot = gy * pz + gz;
    const store = axis === 0 ? xEdges : axis === 1 ? yEdges[lo[0]] : zEdges[lo[0]];
    if (store[slot] >= 0) return store[slot];
    const va = corner[ca[axis] < cb[axis] ? a : b], vb = corner[ca[axis] < cb[axis] ? b : a];
    const t = (level - va) / (vb - va);
    positions.push3(gx + (axis === 0 ? t : 0), gy + (axis === 1 ? t : 0), gz + (axis === 2 ? t : 0));
    store[slot] = vertices;
    return vertices++;
  };

  for (let x = 0; x < px - 1; x++) {
    xEdges.fill(-1);
    for (let y = 0; y < py - 1; y++) {
      for (let z = 0; z < pz - 1; z++) {
        let config = 0;
        for (let v = 0; v < 8; v++) {
          const c = CORNERS[v];
          corner[v] = value(x + c[0], y + c[1], z + c[2]);
          if (corner[v] < level) config |= 1 << v;
        }
        const triangles = TABLE[config];
        if (triangles.length === 0) continue;
        edgeVertex.fill(-1);
        for (let i = 0; i < triangles.length; i += 3) {
          for (let k = 0; k < 3; k++) {
            const e = triangles[i + k];
            if (edgeVertex[e] < 0) edgeVertex[e] = vertexOn(e, x, y, z);
          }
          faces.push3(edgeVertex[triangles[i]], edgeVertex[triangles[i + 1]], edgeVertex[triangles[i + 2]]);
        }
      }
    }
    // Layer x + 1 becomes the next slab's layer 0.
    [yEdges, zEdges] = [[yEdges[1], yEdges[0].fill(-1)], [zEdges[1], zEdges[0].fill(-1)]];
    progress?.((x + 1) / (px - 1));
  }
  return { positions: positions.done(), faces: faces.done() };
}

/**
 * A grid's mesh in the model's frame (finest training voxels), or the training
 * input's frame when a manifest is given: { positions, faces }.
 * size: the tri-plane's (X, Y, Z); the grid spans it with its own point counts.
 * progress(fraction), if given, is called after each slab.
 */
export function surface(grid, size, manifest = null, progress = null) {
  const { positions, faces } = marchingCubes(grid, 0.5, progress);
  const steps = size.map((n, i) => (n - 1) / (grid.shape[i] - 1));
  const origin = manifest ? manifest.origin : [0, 0, 0], spacing = manifest ? manifest.spacing : [1, 1, 1];
  for (let i = 0; i < positions.length; i++) {
    const a = i % 3;
    positions[i] = origin[a] + (positions[i] - 1) * steps[a] * spacing[a];
  }
  return { positions, faces };
}

/** Volume and centre of mass of a closed mesh (trimesh's mass_properties, unit density). */
export function massProperties({ positions: p, faces: f }) {
  let volume = 0;
  const moment = [0, 0, 0];
  for (let i = 0; i < f.length; i += 3) {
    const a = 3 * f[i], b = 3 * f[i + 1], c = 3 * f[i + 2];
    const u = [p[b] - p[a], p[b + 1] - p[a + 1], p[b + 2] - p[a + 2]];
    const v = [p[c] - p[a], p[c + 1] - p[a + 1], p[c + 2] - p[a + 2]];
    const cross = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    for (let k = 0; k < 3; k++) {
      const x0 = p[a + k], x1 = p[b + k], x2 = p[c + k], f1 = x0 + x1 + x2;
      if (k === 0) volume += cross[0] * f1;
      moment[k] += cross[k] * (x0 * x0 + x1 * x1 + x0 * x1 + x2 * f1);
    }
  }
  volume /= 6;
  return { volume, center: moment.map((m) => m / 24 / volume) };
}

/**
 * Laplacian smoothing as trimesh's filter_laplacian (the Python runtime's
 * --smooth): each step moves every vertex by lamb towards the mean of its
 * neighbours, then rescales about the centre of mass to the initial volume.
 * Changes mesh.positions in place and returns the mesh. progress(fraction),
 * if given, is called after each step.
 */
export function smooth(mesh, iterations, lamb = 0.5, progress = null) {
  const { positions, faces } = mesh;
  const n = positions.length / 3;
  if (!iterations || faces.length === 0) return mesh;
  // Unique neighbours of every vertex, in compressed rows.
  const pairs = new Set();
  const degree = new Int32Array(n);
  for (let i = 0; i < faces.length; i += 3) {
    for (let k = 0; k < 3; k++) {
      const a = faces[i + k], b = faces[i + (k + 1) % 3];
      const key = a < b ? a * n + b : b * n + a;
      if (!pairs.has(key)) { pairs.add(key); degree[a]++; degree[b]++; }
    }
  }
  const start = new Int32Array(n + 1);
  for (let v = 0; v < n; v++) start[v + 1] = start[v] + degree[v];
  const fill = start.slice(0, n), neighbours = new Int32Array(start[n]);
  for (const key of pairs) {
    const a = Math.floor(key / n), b = key - a * n;
    neighbours[fill[a]++] = b;
    neighbours[fill[b]++] = a;
  }
  const initial = massProperties(mesh);
  const current = Float64Array.from(positions), next = new Float64Array(current.length);
  const view = { positions: current, faces };
  for (let step = 0; step < iterations; step++) {
    for (let v = 0; v < n; v++) {
      const count = start[v + 1] - start[v];
      for (let k = 0; k < 3; k++) {
        let sum = 0;
        for (let j = start[v]; j < start[v + 1]; j++) sum += current[3 * neighbours[j] + k];
        next[3 * v + k] = count ? current[3 * v + k] + lamb * (sum / count - current[3 * v + k]) : current[3 * v + k];
      }
    }
    current.set(next);
    const scale = Math.cbrt(initial.volume / massProperties(view).volume);
    for (let i = 0; i < current.length; i++) {
      const c = initial.center[i % 3];
      current[i] = (current[i] - c) * scale + c;
    }
    progress?.((step + 1) / iterations);
  }
  positions.set(current);
  return mesh;
}
