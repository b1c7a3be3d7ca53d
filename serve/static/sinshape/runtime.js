// The sinshape runtime for the browser: sample shapes from a sinshape .onnx
// file with onnxruntime-web, with no server. The same seed gives the same
// shape as the Python runtime (docs/FORMAT.md is the contract; docs/WEB.md
// says what differs). It makes geometry: colour, relief and worlds are the
// Python runtime's alone (docs/WEB.md, "One runtime").
//
//   import * as sinshape from './sinshape/runtime.js';
//   const model = await sinshape.loadModel(bytes, { name: 'terrain.onnx' });
//   const tri = await sinshape.sample(model, 3, [1, 1, 1]);
//   const grid = await sinshape.dense(model, tri, 2);    // { data: Float32Array (X, Y, Z), shape }
//   const mesh = sinshape.surface(grid, tri.size, model.manifest);   // { positions, faces }
//   sinshape.smooth(mesh, 3);                            // Laplacian steps, as --smooth
//   const edited = await sinshape.compose(model, 7, [{ seed: 3, low: [0, 0, 0], high: [30, 36, 31] }]);  // as runtime.compose
//   const laid = await sinshape.layout(model, 3);                        // { grid, shape }: level 0's layout, as runtime.layout.layout
//   const fitted = await sinshape.fromLayout(model, 3, laid.grid, laid.shape);  // as runtime.layout.from_layout
//   const tri2 = await sinshape.make(model, sinshape.sampleRequest({ seed: 3n, grow: [2, 1, 1] }));  // as runtime.request.make
export { ConflictError, InputError } from './errors.js';
export { loadModel, configure, parseManifest } from './model.js';
export { parseSize, parseTriple, sample, scaledSizes } from './generate.js';
export { compose, grow, parsePart } from './edit.js';
export { Layout, make, sampleRequest } from './request.js';
export { HeightMap, ModelMap, worldTiling } from './world.js';
export { normal, streamKey } from './noise.js';
export { dense, gridShape, project, projectedDense } from './query.js';
export { fromLayout, layout } from './layout.js';
export { marchingCubes, massProperties, smooth, surface } from './mesh.js';
