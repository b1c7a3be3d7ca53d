// The browser runtime in a module worker, so that the page stays responsive
// while a sample is made, and a sample is stopped by ending the worker:
//
//   const worker = new Worker(new URL('./sinshape/worker.js', import.meta.url), { type: 'module' });
//
// Messages in, each with an id the answers repeat:
//   { id, type: 'load', name, bytes, file }  load and check a model (bytes: Uint8Array)
//     -> { id, type: 'loaded', backend, threads, seconds, sizes, origin, spacing, up, arrange }  (the manifest's grids, frame and world)
//   { id, type: 'sample', name, request }  request: a sample request (request.js: sampleRequest, or a
//       structured clone of one), made as runtime.request.make makes it (request.js: make)
//     -> { id, type: 'progress', stage, fraction }  (fraction in [0, 1], or null)
//     -> { id, type: 'done', positions, faces, seconds, without }  (the buffers are transferred;
//        without: what the model has and the browser leaves to the Python runtime, of
//        'colour' and 'relief', where the request asked for its detail)
//   { id, type: 'layout', name, seed, factors }  the level-0 layout of the sample of `seed`, as runtime.layout.layout
//     -> { id, type: 'done', grid, shape }  (grid: Uint8Array in C order, 1 full)
//   any of them -> { id, type: 'error', message, input }  (input: an InputError, a message for the user)
import * as sinshape from './runtime.js';
import { make, sampleRequest } from './request.js';

const models = new Map(); // name -> a promise of the loaded model

async function load({ name, bytes, file }) {
  const started = performance.now();
  const loading = sinshape.loadModel(bytes, { name: file });
  models.set(name, loading);
  try {
    const model = await loading;
    const { sizes, origin, spacing, up, arrange } = model.manifest;
    return { backend: model.backend, threads: model.threads, seconds: (performance.now() - started) / 1000,
             sizes, origin, spacing, up, arrange };
  } catch (error) {
    models.delete(name); // a later try loads again
    throw error;
  }
}

async function loaded(name) {
  if (!models.has(name)) throw new Error(`the model '${name}' is not loaded in the worker`);
  return models.get(name);
}

async function sample({ name, request }, progress) {
  // A clone has lost its freezing: checked again, as cheap as it is, and first. A field it does not
  // know, or one make does not make (request.js: MAKES), is refused, never dropped.
  const wanted = sampleRequest(request);
  const model = await loaded(name);
  const started = performance.now();
  const tri = await make(model, wanted, progress);
  const grid = await sinshape.dense(model, tri, wanted.scale, (f) => progress('querying the grid', f));
  const mesh = sinshape.surface(grid, tri.size, model.manifest, (f) => progress('meshing', f));
  sinshape.smooth(mesh, wanted.smooth, 0.5, (f) => progress('smoothing', f));
  const { colour, tiles } = model.manifest;
  const without = wanted.detail ? [colour && 'colour', tiles && 'relief'].filter(Boolean) : [];
  return { positions: mesh.positions, faces: mesh.faces, seconds: (performance.now() - started) / 1000, without };
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
      const buffers = [result.positions, result.faces].map((array) => array.buffer);
      self.postMessage({ id, type: 'done', ...result }, buffers);
    } else {
      throw new Error(`unknown job type '${job.type}'`);
    }
  } catch (error) {
    self.postMessage({ id, type: 'error', message: String(error?.message ?? error), input: error instanceof sinshape.InputError });
  }
};
