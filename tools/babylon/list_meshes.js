// What Babylon.js makes of a .glb: its own glTF loader in a NullEngine (node, no GPU), the file
// given as bytes. Prints one line, RESULT {"extensions": [...], "meshes": [...]}: the glTF
// extensions its loader applied, and each mesh with vertices, its name, vertex and triangle
// counts, its bounds (Babylon's left-handed world: x flipped) and whether its material has a
// normal map. tests/test_asset.py runs it (NODE_PATH: where .ci/run installs Babylon.js).
//   node tools/babylon/list_meshes.js asset.glb
// EXT_meshopt_compression: Babylon's loader decodes it with meshoptimizer's decoder, which it loads
// as a script from its CDN; under node, with no CDN and no Web Workers, it is given the same decoder
// from the page's copy of three.js's addons (the one the page reads such files with), decoding in place.
const fs = require('fs');
const path = require('path');
const { pathToFileURL } = require('url');
const BABYLON = require('babylonjs');
globalThis.BABYLON = BABYLON; // babylonjs-loaders registers itself on the global
require('babylonjs-loaders');

const DECODER = path.join(__dirname, '..', '..', 'serve', 'static', 'vendor', 'three', 'addons', 'libs', 'meshopt_decoder.module.js');

async function main(file) {
  const { MeshoptDecoder } = await import(pathToFileURL(DECODER).href);
  globalThis.MeshoptDecoder = { ...MeshoptDecoder, useWorkers() {} }; // what Babylon's script would have set
  BABYLON.Tools.LoadBabylonScriptAsync = async () => {}; // the decoder is here already
  BABYLON.Logger.LogLevels = BABYLON.Logger.ErrorLogLevel;
  const scene = new BABYLON.Scene(new BABYLON.NullEngine());
  const extensions = [];
  let complete = null;
  BABYLON.SceneLoader.OnPluginActivatedObservable.add((loader) => {
    loader.onExtensionLoadedObservable.add((extension) => extensions.push(extension.name));
    complete = new Promise((resolve) => loader.onCompleteObservable.add(resolve)); // every level loaded (MSFT_lod)
  });
  await BABYLON.SceneLoader.ImportMeshAsync('', '', new Uint8Array(fs.readFileSync(file)), scene, null, '.glb');
  await complete;
  const meshes = scene.meshes.filter((mesh) => mesh.getTotalVertices() > 0).map((mesh) => {
    mesh.computeWorldMatrix(true);
    mesh.refreshBoundingInfo();
    const box = mesh.getBoundingInfo().boundingBox;
    return { name: mesh.name, vertices: mesh.getTotalVertices(), triangles: mesh.getTotalIndices() / 3,
             min: box.minimumWorld.asArray(), max: box.maximumWorld.asArray(), normalMap: Boolean(mesh.material?.bumpTexture) };
  });
  console.log(`RESULT ${JSON.stringify({ extensions, meshes })}`);
  process.exit(0); // Babylon's loader leaves a timer for the decoder's workers
}

main(process.argv[2]).catch((error) => { console.error(error.message); process.exit(1); });
