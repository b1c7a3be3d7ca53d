"""The paper's scores (LP-IoU, LP-F, diversity) of a model's samples at a
finer grid than it was trained on, with the example's relief and without
it, against its example voxelised at that grid (docs/BENCHMARKS.md,
"Relief at twice the training resolution").

    python benchmarks/relief_lp.py towerruins ../shared/data/meshes/towerruins/towerruins.obj --samples 20 --scale 2

Three ways to a sample's occupancy at `--scale`, on the same seeds:
- "queried": the tri-planes queried on the fine grid (what `sinrun eval
  --scale` does; relief is a move of the mesh's vertices, so it is not
  there);
- "mesh without relief" and "mesh with relief": the sample's mesh at
  `--scale` (the relief's moves applied or left out), voxelised onto the
  fine grid by the same voxeliser that makes the reference from the
  example, so that the two are read alike.
Relief moves vertices only at scales of 2 and up; at scale 1 the two meshes
are the same.
"""

import argparse
import time

import numpy as np


def mesh_volume(vertices: np.ndarray, faces: np.ndarray, size, scale: float) -> np.ndarray:
    """A mesh in model coordinates (the finest level's voxels, centres at
    integers) voxelised on the grid `scale` times finer that spans the
    model's box."""
    import trimesh

    from sinshape.prep import voxelize
    from sinshape.runtime.query import grid_shape

    shape = grid_shape(size, scale)
    spacing = np.asarray(size, float) / np.asarray(shape)
    return voxelize.voxelize(trimesh.Trimesh(vertices, faces, process=False), -0.5 * np.ones(3), spacing, shape)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("example", help="the mesh the model was trained on")
    parser.add_argument("--samples", type=int, default=20)
    parser.add_argument("--scale", type=float, default=2)
    args = parser.parse_args()

    from sinshape import models
    from sinshape.prep.pyramid import reference_grid
    from sinshape.runtime import colour, evaluate, generate, load_model, mesh as meshing

    model = load_model(models.find(args.model))
    truth = reference_grid(args.example, model.manifest, args.scale)
    volumes = {"queried": [], "mesh without relief": [], "mesh with relief": []}
    seconds = dict.fromkeys(volumes, 0.0)
    for seed in range(args.samples):
        triplane = generate.sample(model, seed)
        started = time.perf_counter()
        volumes["queried"].append(evaluate.sample_volumes(model, [seed], args.scale)[0])
        seconds["queried"] += time.perf_counter() - started
        started = time.perf_counter()
        plain = meshing.band_mesh(model, triplane, args.scale)
        faces = np.asarray(plain.faces)
        seconds["mesh without relief"] += time.perf_counter() - started
        moved = colour.colouring(model, triplane).relief(plain.vertices) if args.scale >= colour.RELIEF_SCALE \
            else np.asarray(plain.vertices)
        seconds["mesh with relief"] += time.perf_counter() - started
        volumes["mesh without relief"].append(mesh_volume(np.asarray(plain.vertices), faces, triplane.size, args.scale))
        volumes["mesh with relief"].append(mesh_volume(moved, faces, triplane.size, args.scale))
    print(f"{args.model} (trained at res {model.manifest.raw.get('config', {}).get('res', '?')}), "
          f"{args.samples} samples at scale {args.scale:g} ({'x'.join(map(str, volumes['queried'][0].shape))}), "
          f"against {args.example} voxelised at {'x'.join(map(str, truth.shape))}")
    print("| occupancy | LP-IoU | LP-F | diversity | seconds a sample (to the occupancy's source) |")
    print("|---|---|---|---|---|")
    for name, grids in volumes.items():
        lp = evaluate.lp_metrics(grids, truth)
        print(f"| {name} | {lp['lp_iou']:.3f} | {lp['lp_f']:.3f} | {evaluate.diversity(grids):.3f} "
              f"| {seconds[name] / args.samples:.2f} |")


if __name__ == "__main__":
    main()
