// The browser runtime in a module worker, so that the page stays responsive
// while a sample is made, and a sample is stopped by ending the worker:
//
//   const worker = new Worker(new URL('./sinshape/worker.js', import.meta.url), { type: 'module' });
//
// Messages in, each with an id the answers repeat:
//   { id, type: 'load', name, bytes, file }  load and check a model (bytes: Uint8Array)
//     -> { id, type: 'loaded', backend, threads, seconds }
//   { id, type: 'sample', name, seed, factors, scale, smooth }  seed: digits
//     -> { id, type: 'progress', stage, fraction }  (fraction in [0, 1], or null)
//     -> { id, type: 'done', positions, faces, seconds }  (the buffers are transferred)
//   any of them -> { id, type: 'error', message, input }  (input: an InputError, a message for the user)
import * as sinshape from './runtime.js';

const models = new Map(); // name -> a promise of the loaded model

async function load({ name, bytes, file }) {
  const started = performance.now();
  const loading = sinshape.loadModel(bytes, { name: file });
  models.set(name, loading);
  try {
    const model = await loading;
    return { backend: model.backend, threads: model.threads, seconds: (performance.now() - started) / 1000 };
  } catch (error) {
    models.delete(name); // a later try loads again
    throw error;
  }
}

async function sample({ name, seed, factors, scale, smooth }, progress) {
  if (!models.has(name)) throw new Error(`the model '${name}' is not loaded in the worker`);
  const model = await models.get(name);
  const started = performance.now();
  progress('sampling', null);
  const tri = await sinshape.sample(model, BigInt(seed), factors);
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
