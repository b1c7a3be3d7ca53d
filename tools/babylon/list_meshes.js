// What Babylon.js makes of a .glb: its own glTF loader in a NullEngine (node, no GPU), the file
// given as bytes. Prints one line, RESULT {"extensions": [...], "meshes": [...]}: the glTF
// extensions its loader applied, and each mesh with vertices, its name, vertex and triangle
// counts, its bounds (Babylon's left-handed world: x flipped) and whether its material has a
// normal map. tests/test_asset.py runs it (NODE_PATH: where .ci/run installs Babylon.js).
//   node tools/babylon/list_meshes.js asset.glb
const fs = require('fs');
const BABYLON = require('babylonjs');
globalThis.BABYLON = BABYLON; // babylonjs-loaders registers itself on the global
require('babylonjs-loaders');

async function main(path) {
  BABYLON.Logger.LogLevels = BABYLON.Logger.ErrorLogLevel;
  const scene = new BABYLON.Scene(new BABYLON.NullEngine());
  const extensions = [];
  let complete = null;
  BABYLON.SceneLoader.OnPluginActivatedObservable.add((loader) => {
    loader.onExtensionLoadedObservable.add((extension) => extensions.push(extension.name));
    complete = new Promise((resolve) => loader.onCompleteObservable.add(resolve)); // every level loaded (MSFT_lod)
  });
  await BABYLON.SceneLoader.ImportMeshAsync('', '', new Uint8Array(fs.readFileSync(path)), scene, null, '.glb');
  await complete;
  const meshes = scene.meshes.filter((mesh) => mesh.getTotalVertices() > 0).map((mesh) => {
    mesh.computeWorldMatrix(true);
    mesh.refreshBoundingInfo();
    const box = mesh.getBoundingInfo().boundingBox;
    return { name: mesh.name, vertices: mesh.getTotalVertices(), triangles: mesh.getTotalIndices() / 3,
             min: box.minimumWorld.asArray(), max: box.maximumWorld.asArray(), normalMap: Boolean(mesh.material?.bumpTexture) };
  });
  console.log(`RESULT ${JSON.stringify({ extensions, meshes })}`);
}

main(process.argv[2]).catch((error) => { console.error(error.message); process.exit(1); });
