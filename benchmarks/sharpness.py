"""How sharp a model's samples are beside its example: the surface's
deviation from its own smoothing at one voxel, for the example mesh, the
reconstruction and samples at `--scale`, with the example's relief and
without it (the same meshes, the relief left out), in one run
(docs/BENCHMARKS.md, "Relief of a geometry-only model").

    python benchmarks/sharpness.py towerruins ../shared/data/meshes/towerruins/towerruins.obj --seeds 4 --scale 4

Points are drawn on each surface, 16 per square voxel of area; at each of
4,000 of them, a plane is fitted to the points within one voxel (least
squares), and the point's distance from it is its deviation. The figure is
the root mean square, in voxels: 0 for a surface flat at that size, larger
where it has detail a voxel across or finer (steps, ridges, courses of
stone). Also: the time of relief (matching and moving the vertices)
against the mesh's own, per mesh.
"""

import argparse
import time

import numpy as np

PER_AREA, PROBES, RADIUS = 16.0, 4000, 1.0


def surface_points(vertices: np.ndarray, faces: np.ndarray, per_area: float = PER_AREA,
                   rng: np.random.Generator | None = None) -> np.ndarray:
    """Points drawn uniformly on a mesh's surface, `per_area` per square unit."""
    triangles = vertices[faces]
    areas = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    rng = rng or np.random.default_rng(0)
    count = int(areas.sum() * per_area)
    face = rng.choice(len(faces), count, p=areas / areas.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    return triangles[face, 0] + u[:, None] * (triangles[face, 1] - triangles[face, 0]) \
        + v[:, None] * (triangles[face, 2] - triangles[face, 0])


def deviation(vertices: np.ndarray, faces: np.ndarray, seed: int = 0) -> float:
    """RMS distance, in the vertices' units, of surface points from the plane fitted to the points within RADIUS."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    points = surface_points(vertices, faces, PER_AREA, rng)
    count = len(points)
    tree = cKDTree(points)
    probes = points[rng.choice(count, min(PROBES, count), replace=False)]
    out = []
    for probe, near in zip(probes, tree.query_ball_point(probes, RADIUS)):
        if len(near) < 8:
            continue
        local = points[near] - points[near].mean(axis=0)
        normal = np.linalg.svd(local, full_matrices=False)[2][-1]
        out.append(float((probe - points[near].mean(axis=0)) @ normal))
    return float(np.sqrt(np.mean(np.square(out))))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("example")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--scale", type=float, default=4)
    args = parser.parse_args()

    import trimesh

    from sinshape import models
    from sinshape.runtime import colour, generate, load_model, mesh as meshing

    model = load_model(models.find(args.model))
    if model.example_tiles is None:
        raise SystemExit(f"{args.model} has no tiles: nothing to compare (give a format-5 model)")
    origin, spacing = np.asarray(model.manifest.origin), np.asarray(model.manifest.spacing)
    example = trimesh.load(args.example, force="mesh", process=False)
    in_voxels = (np.asarray(example.vertices) - origin) / spacing
    print(f"example {args.example}: deviation {deviation(in_voxels, np.asarray(example.faces)):.4f} voxels")
    print("| shape | without relief | with relief | mesh s | relief s |")
    print("|---|---|---|---|---|")
    for seed in [None, *range(1, args.seeds + 1)]:
        triplane = generate.sample(model, seed)
        started = time.perf_counter()
        plain = meshing.band_mesh(model, triplane, args.scale)
        meshed = time.perf_counter()
        moved = colour.colouring(model, triplane).relief(plain.vertices)
        relieved = time.perf_counter()
        faces = np.asarray(plain.faces)
        name = "reconstruction" if seed is None else f"seed {seed}"
        print(f"| {name} | {deviation(np.asarray(plain.vertices), faces):.4f} | {deviation(moved, faces):.4f} "
              f"| {meshed - started:.2f} | {relieved - meshed:.2f} |")


if __name__ == "__main__":
    main()
