"""How close a model's reconstruction comes to its example's surface at
finer than a voxel, with the example's relief and without it (the same
mesh, the relief left out), in one run (docs/BENCHMARKS.md, "Relief of a
geometry-only model").

    python benchmarks/relief_fidelity.py towerruins ../shared/data/meshes/towerruins/towerruins.obj --scale 4

Both surfaces, in the model's voxels, carry points drawn 16 per square
voxel (sharpness.surface_points); from each point to the other surface's
nearest point: the Chamfer distance (the mean of both directions' means)
and the F-score at a tenth and a quarter of a voxel (the harmonic mean of
the share of each surface's points within that of the other).
"""

import argparse

import numpy as np

from sharpness import surface_points


def distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """From each point of a to its nearest point of b."""
    from scipy.spatial import cKDTree

    return cKDTree(b).query(a, workers=-1)[0]


def scores(made: np.ndarray, example: np.ndarray) -> tuple:
    """(Chamfer, F at 0.1, F at 0.25) between two point sets, in voxels."""
    there, back = distances(made, example), distances(example, made)
    f = []
    for tau in (0.1, 0.25):
        precision, recall = np.mean(there < tau), np.mean(back < tau)
        f.append(2 * precision * recall / max(precision + recall, 1e-12))
    return (there.mean() + back.mean()) / 2, *f


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("example")
    parser.add_argument("--scale", type=float, default=4)
    args = parser.parse_args()

    import trimesh

    from sinshape import models
    from sinshape.runtime import colour, generate, load_model, mesh as meshing

    model = load_model(models.find(args.model))
    origin, spacing = np.asarray(model.manifest.origin), np.asarray(model.manifest.spacing)
    example = trimesh.load(args.example, force="mesh", process=False)
    truth = surface_points((np.asarray(example.vertices) - origin) / spacing, np.asarray(example.faces))
    triplane = generate.sample(model, None)
    plain = meshing.band_mesh(model, triplane, args.scale)
    faces = np.asarray(plain.faces)
    print(f"{args.model} reconstruction at scale {args.scale:g} against {args.example} ({len(truth)} points)")
    print("| mesh | Chamfer (voxels) | F-score at 0.1 voxel | F-score at 0.25 voxel |")
    print("|---|---|---|---|")
    for name, vertices in (("without relief", np.asarray(plain.vertices)),
                           ("with relief", colour.colouring(model, triplane).relief(plain.vertices))):
        chamfer, f10, f25 = scores(surface_points(vertices, faces), truth)
        print(f"| {name} | {chamfer:.4f} | {f10:.3f} | {f25:.3f} |")


if __name__ == "__main__":
    main()
