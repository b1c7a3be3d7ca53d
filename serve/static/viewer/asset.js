// A game asset shown as an engine shows it (docs/ASSETS.md, "Levels of detail"): its levels of detail
// (the .glb's MSFT_lod) in a three.js LOD, each coarser level shown once the asset covers less of the
// view's height than the file's MSFT_screencoverage gives for the level before it, so that zooming out
// draws the coarser levels, as a game does with distance.
//
//   assetLevels(data, fov)  the .glb's bytes -> a THREE.LOD of its levels, for a camera of that vertical field of view
//   levelTriangles(lod)     each level's triangles, finest first
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

/**
 * The asset's levels, finest first, as a THREE.LOD: level k > 0 is drawn from the distance at
 * which the finest level's bounding sphere spans the file's coverage[k - 1] of the height of a
 * view `fov` degrees high. A file without MSFT_lod gives its one level.
 */
export async function assetLevels(data, fov) {
  const asset = await new GLTFLoader().parseAsync(data, '');
  const finest = asset.parser.json.nodes[0];
  const ids = finest.extensions?.MSFT_lod?.ids ?? [];
  const coverage = finest.extras?.MSFT_screencoverage ?? [];
  const levels = await Promise.all([0, ...ids].map((id) => asset.parser.getDependency('node', id)));
  const lod = new THREE.LOD();
  const radius = new THREE.Box3().setFromObject(levels[0]).getBoundingSphere(new THREE.Sphere()).radius;
  const tangent = Math.tan(THREE.MathUtils.degToRad(fov / 2));
  levels.forEach((level, k) => lod.addLevel(level, k ? radius / ((coverage[k - 1] ?? 0.5 ** k) * tangent) : 0));
  return lod;
}

/** Each of a LOD's levels' triangles, finest first. */
export function levelTriangles(lod) {
  return lod.levels.map(({ object }) => {
    let count = 0;
    object.traverse((node) => { if (node.isMesh) count += node.geometry.index.count / 3; });
    return count;
  });
}
