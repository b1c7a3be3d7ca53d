"""Whether a brick wall's samples keep their example's mortar and relief:
on the wall's broad faces (faces looking along y, within 25 degrees), the
share of the surface that is mortar-coloured, and how deep the mortar lies
behind the bricks, for the example itself and for the model's
reconstruction and samples at `--scale`, with relief and without, in one
run (docs/BENCHMARKS.md, "Relief").

    sinrun shape relief_wall -o wall.ply
    sinrun train wall.ply -o wall.onnx --res 48 --iters 300 --up z
    python benchmarks/relief.py wall.onnx wall.ply [--seeds 4] [--scale 4]

mortar: within 0.12 (sRGB, Euclidean) of the example's mortar colour, the
share of the broad faces' area. depth: per 0.4-unit strip along x, the
median distance of the mortar faces behind the bricks' faces (along the
face's normal, in the example's units), averaged over the strips that have
both; the example's bricks stand 0.012 out of their mortar. Run under the
previous runtime (PYTHONPATH), a model without relief gives "without" only.
"""

import argparse

import numpy as np

MORTAR = np.array((0.74, 0.71, 0.65))
NEAR = 0.12
STRIP = 0.4


def broad_face_figures(vertices: np.ndarray, faces: np.ndarray, rgb: np.ndarray) -> tuple:
    """(mortar share of the broad faces' area, mortar depth behind the bricks) of a mesh in
    the example's units with vertex colours rgb (n, 3) in [0, 1]."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    normal, area = mesh.face_normals, mesh.area_faces
    centre = mesh.triangles_center
    colour = rgb[faces].mean(axis=1)
    mortar = np.linalg.norm(colour - MORTAR, axis=1) < NEAR
    broad = np.abs(normal[:, 1]) > np.cos(np.radians(25))
    share = float(area[broad & mortar].sum() / area[broad].sum())
    depths = []
    for side in (-1, 1):  # the front (looking -y) and the back
        facing = broad & (np.sign(normal[:, 1]) == side)
        strip = np.floor(centre[:, 0] / STRIP)
        for s in np.unique(strip[facing]):
            here = facing & (strip == s)
            if (here & mortar).sum() > 3 and (here & ~mortar).sum() > 3:
                depths.append(side * (np.median(centre[here & ~mortar, 1]) - np.median(centre[here & mortar, 1])))
    return share, float(np.mean(depths)) if depths else float("nan")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("example")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--scale", type=float, default=4)
    args = parser.parse_args()

    import trimesh

    from sinshape.runtime import colour, generate, load_model, mesh

    model = load_model(args.model, threads=1)
    example = trimesh.load(args.example, process=False)
    share, depth = broad_face_figures(np.asarray(example.vertices), np.asarray(example.faces),
                                      np.asarray(example.visual.vertex_colors)[:, :3] / 255)
    print(f"{'shape':<16} {'relief':<8} {'mortar share':>12} {'mortar depth':>12}")
    print(f"{'example':<16} {'':<8} {share:>12.1%} {depth:>12.4f}")
    for seed in [None, *range(1, args.seeds + 1)]:
        triplane = generate.sample(model, seed)
        plain = mesh.band_mesh(model, triplane, args.scale)
        surface = colour.colouring(model, triplane)
        ways = {"without": np.asarray(plain.vertices)}
        if hasattr(surface, "relief"):
            ways["with"] = surface.relief(plain.vertices)
        for name, vertices in ways.items():
            rgb = surface(vertices, 1 / args.scale)
            share, depth = broad_face_figures(mesh.in_frame(vertices, model.manifest), np.asarray(plain.faces), rgb)
            label = "reconstruction" if seed is None else f"seed {seed}"
            print(f"{label:<16} {name:<8} {share:>12.1%} {depth:>12.4f}")


if __name__ == "__main__":
    main()
