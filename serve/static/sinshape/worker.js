// The browser runtime in a module worker, so that the page stays responsive
// while a sample is made, and a sample is stopped by ending the worker:
//
//   const worker = new Worker(new URL('./sinshape/worker.js', import.meta.url), { type: 'module' });
//
// Messages in, each with an id the answers repeat:
//   { id, type: 'load', name, bytes, file }  load and check a model (bytes: Uint8Array)
//     -> { id, type: 'loaded', backend, threads, seconds, sizes, origin, spacing }  (the manifest's grids and frame)
//   { id, type: 'sample', name, seed, factors, scale, smooth, keep, grow, layout }  seed: digits; edits, at most one:
//       keep: { base, box }  the box (6 percentages of the sample, as strings: x0 y0 z0 x1 y1 z1) of the sample
//             of `seed`, the rest from the sample of seed `base`, as runtime.compose (edit.js)
//       grow: { by, anchor }  the sample of `seed` grown, as runtime.edit.grow (edit.js)
//       layout: { grid, shape }  the sample of `seed` made from this layout, as runtime.layout.from_layout (layout.js)
//     -> { id, type: 'progress', stage, fraction }  (fraction in [0, 1], or null)
//     -> { id, type: 'done', positions, faces, seconds }  (the buffers are transferred)
//   { id, type: 'layout', name, seed, factors }  the level-0 layout of the sample of `seed`, as runtime.layout.layout
//     -> { id, type: 'done', grid, shape }  (grid: Uint8Array in C order, 1 full)
//   any of them -> { id, type: 'error', message, input }  (input: an InputError, a message for the user)
import * as sinshape from './runtime.js';

const models = new Map(); // name -> a promise of the loaded model

async function load({ name, bytes, file }) {
  const started = performance.now();
  const loading = sinshape.loadModel(bytes, { name: file });
  models.set(name, loading);
  try {
    const model = await loading;
    const { sizes, origin, spacing } = model.manifest;
    return { backend: model.backend, threads: model.threads, seconds: (performance.now() - started) / 1000,
             sizes, origin, spacing };
  } catch (error) {
    models.delete(name); // a later try loads again
    throw error;
  }
}

/** A box given in percentages of a sample of finest size `size`, in its voxels: as runtime/edit.py's parse_part. */
function boxCorners(box, size) {
  const values = box.map((p) => Number(p));
  if (values.length !== 6 || !values.every(Number.isFinite)) throw new sinshape.InputError('a box is 6 percentages: x0,y0,z0,x1,y1,z1');
  const voxels = (i) => values[i] / 100 * (size[i % 3] - 1);
  return { low: [0, 1, 2].map(voxels), high: [3, 4, 5].map(voxels) };
}

async function loaded(name) {
  if (!models.has(name)) throw new Error(`the model '${name}' is not loaded in the worker`);
  return models.get(name);
}

async function sample({ name, seed, factors, scale, smooth, keep, grow, layout }, progress) {
  const model = await loaded(name);
  const started = performance.now();
  progress(keep ? 'composing' : grow ? 'growing' : layout ? 'fitting the layout' : 'sampling', null);
  let tri;
  if (keep) {
    const size = sinshape.scaledSizes(model.manifest.sizes, factors).at(-1);
    tri = await sinshape.compose(model, BigInt(keep.base), [{ seed: BigInt(seed), ...boxCorners(keep.box, size) }], factors);
  } else if (grow) {
    tri = await sinshape.grow(model, BigInt(seed), grow.by, grow.anchor, factors);
  } else if (layout) {
    tri = await sinshape.fromLayout(model, BigInt(seed), layout.grid, layout.shape, factors);
  } else {
    tri = await sinshape.sample(model, BigInt(seed), factors);
  }
  const grid = await sinshape.dense(model, tri, scale, (f) => progress('querying the grid', f));
  const mesh = sinshape.surface(grid, tri.size, model.manifest, (f) => progress('meshing', f));
  sinshape.smooth(mesh, smooth, 0.5, (f) => progress('smoothing', f));
  return { positions: mesh.positions, faces: mesh.faces, seconds: (performance.now() - started) / 1000 };
}

self.onmessage = async ({ data: job }) => {
  const { id } = job;
  let shown = '';
  const progress = (stage, fraction) => { // a message when the whole percent changes, not per slice
    const key = `${stage} ${fraction === null ? '' : Math.floor(fraction * 100)}`;
    if (key !== shown) self.postMessage({ id, type: 'progress', stage, fraction });
    shown = key;
  };
  try {
    if (job.type === 'load') {
      self.postMessage({ id, type: 'loaded', ...(await load(job)) });
    } else if (job.type === 'layout') {
      const { grid, shape } = await sinshape.layout(await loaded(job.name), BigInt(job.seed), 0, job.factors);
      self.postMessage({ id, type: 'done', grid, shape }, [grid.buffer]);
    } else if (job.type === 'sample') {
      const result = await sample(job, progress);
      self.postMessage({ id, type: 'done', ...result }, [result.positions.buffer, result.faces.buffer]);
    } else {
      throw new Error(`unknown job type '${job.type}'`);
    }
  } catch (error) {
    self.postMessage({ id, type: 'error', message: String(error?.message ?? error), input: error instanceof sinshape.InputError });
  }
};
