"""Far tiles beside near ones: how true a tile at lod n is to its lod-0 self,
and whether the border between tiles of two levels is closed
(docs/WORLDS.md, "Far tiles true to near ones").

    python benchmarks/world_lod.py --models terrain terrain_colour --block 4 --seed 3

For every tile of a block and every coarser level n:
- heights: the tile's height field seen from above (world_tiles.tile_heights),
  the coarse one interpolated onto the fine tile's columns; their
  correlation within each tile (each tile's mean taken out: its own hills,
  not the world's), the median and the least of the block, and over the
  whole block (the heights as they are);
- holes: the share of the fine tile's columns holding ground where the
  coarse tile holds none, and the coarse mesh's open edges off its four
  sides;
- colour: the mean sRGB colour of the tile's surface (weighed by area, the
  skirt left out), the largest difference of a channel, lod n against lod 0;
- borders: each side two tiles of the block share, one at lod n - 1 and the
  other at lod n (a view's rings: each ring one level coarser than the one
  inside it), the finer tile asked with `skirt` as a streamed view asks a
  full tile. Between the two borders' heights, points up the gap: open
  where no face lying in the side plane covers one, seen from that side
  (the coarser tile's skirt faces the finer side, the finer tile's the
  coarser). The share of the side's length open from each side.
"""

import argparse

import numpy as np

from sinshape import models
from sinshape.runtime import load_model, world, world_tiles

TOLERANCE = 1e-4  # voxels: a border this close is closed


def on_columns(coarse: tuple, fine: tuple) -> np.ndarray:
    """A coarse height field (positions, positions, heights) interpolated
    linearly onto a finer one's columns, as its mesh lies between them."""
    a, b, heights = coarse
    along_b = np.stack([np.interp(fine[1], b, row) for row in heights])
    return np.stack([np.interp(fine[0], a, column) for column in along_b.T]).T


def open_edges_inside(surface, tiling) -> int:
    """Edges of one face only that do not lie on one of the tile's four sides."""
    faces = surface.faces
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    lone = unique[counts == 1]
    on_side = np.zeros(len(lone), bool)
    for axis in tiling.horizontal:
        for at in (0, tiling.stride[axis]):
            on_side |= (surface.vertices[lone, axis] == at).all(axis=1)
    return int((~on_side).sum())


def mean_colour(surface, faces: int) -> np.ndarray:
    """The area-weighed mean colour of a surface's first `faces` faces (its
    own, without the skirt), each face the mean of its vertices'."""
    triangles = surface.vertices[surface.faces[:faces]]
    area = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    rgb = surface.colours[surface.faces[:faces], :3].astype(np.float64).mean(axis=1)
    return (rgb * area[:, None]).sum(axis=0) / area.sum()


def in_plane_faces(surface, axis: int, at: float, toward: int, along: int, up: int) -> np.ndarray:
    """The surface's faces lying in its side plane (model axis `axis` = `at`)
    whose front faces the side `toward` (+1 or -1 along `axis`), as (F, 3, 2)
    corners (along the side, up): what a viewer on that side sees there."""
    corners = surface.vertices[surface.faces]
    corners = corners[(corners[:, :, axis] == at).all(axis=1)]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])[:, axis]
    return corners[normal * toward > 0][:, :, [along, up]]


def covered(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which (n, 2) points lie in any of (F, 3, 2) triangles (edges included)."""
    def side(p, q):
        return (q[0] - p[0]) * (points[:, 1] - p[1]) - (q[1] - p[1]) * (points[:, 0] - p[0])

    hit = np.zeros(len(points), bool)
    for a, b, c in triangles:
        d = np.stack([side(a, b), side(b, c), side(c, a)])
        hit |= (d >= -1e-9).all(axis=0) | (d <= 1e-9).all(axis=0)
    return hit


def border_heights(surface, faces: int, axis: int, at: float, along: int, up: int, ts: np.ndarray) -> np.ndarray:
    """The top of a tile's own border on its side plane (model axis `axis` =
    `at`) at points `ts` along the side: the highest of the edges of its
    first `faces` faces (its own, not the skirt's) lying in that plane and
    belonging to one face only."""
    own = surface.faces[:faces]
    edges = np.sort(np.concatenate([own[:, [0, 1]], own[:, [1, 2]], own[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    lone = unique[counts == 1]
    ends = surface.vertices[lone]
    ends = ends[(ends[:, :, axis] == at).all(axis=1)]
    top = np.full(len(ts), -np.inf)
    for (t0, y0), (t1, y1) in ends[:, :, [along, up]]:
        if t1 == t0:
            top[ts == t0] = np.maximum(top[ts == t0], max(y0, y1))
            continue
        inside = (ts >= min(t0, t1)) & (ts <= max(t0, t1))
        top[inside] = np.maximum(top[inside], y0 + (ts[inside] - t0) * (y1 - y0) / (t1 - t0))
    return top


def border_openness(model, fine: tuple, coarse: tuple, axis: int) -> tuple:
    """The shares of a shared side open from the finer tile's side and from
    the coarser's. fine, coarse: (surface, its own faces' count) of two
    neighbours, the side being the fine tile's high end along horizontal
    axis number `axis` (0 or 1) and the coarse tile's low end. Between the
    two borders, at 4 points per voxel along the side, eight points up the
    gap: open where one is covered by no face seen from there (the coarser
    tile's skirt from the finer side where the coarser border is the
    higher, the finer tile's from the coarser side where the finer is)."""
    tiling = world.world_tiling(model)
    h, along, up = tiling.horizontal[axis], tiling.horizontal[1 - axis], tiling.up
    ts = np.linspace(0, tiling.stride[along], 4 * tiling.stride[along] + 1)
    hf = border_heights(*fine, h, tiling.stride[h], along, up, ts)
    hc = border_heights(*coarse, h, 0, along, up, ts)
    low, high = np.minimum(hf, hc), np.maximum(hf, hc)
    gap = np.linspace(0.05, 0.95, 8)
    points = np.stack([np.repeat(ts, len(gap)), (low[:, None] + gap * (high - low)[:, None]).ravel()], axis=1)
    shares = []
    # From the finer side a gap shows where the coarser border is the higher
    # (the finer tile's own ground hides the rest), and the coarser tile's
    # skirt must cover it; from the coarser side the other way about.
    for (surface, _), at, toward, higher in ((coarse, 0, -1, hc - hf), (fine, tiling.stride[h], +1, hf - hc)):
        real = np.repeat(higher > TOLERANCE, len(gap))
        seen = covered(in_plane_faces(surface, h, at, toward, along, up), points)
        shares.append(float((real & ~seen).reshape(len(ts), len(gap)).any(axis=1).mean()))
    return tuple(shares)


def measure(name: str, block: int, seed: int) -> list:
    model = load_model(models.find(name), threads=1)
    tiling = world.world_tiling(model)
    levels = len(model.manifest.sizes)
    tiles = [(i, j) for i in range(block) for j in range(block)]
    heights, surfaces, own_faces = {}, {}, {}
    for lod in range(levels):
        options = world.WorldOptions(lod=lod, skirt=True)  # a full tile beside a coarser one has its skirt too
        for tile in tiles:
            heights[lod, tile] = world_tiles.tile_heights(model, seed, tile, options=options)
            surfaces[lod, tile] = world_tiles.tile_surface(model, seed, tile, options=options)
            own_faces[lod, tile] = len(world_tiles.tile_mesh(model, seed, tile, options=options)[1])
    rows = []
    for lod in range(1, levels):
        within, fine_all, coarse_all, holes, colour = [], [], [], [], []
        inside_edges = sum(open_edges_inside(surfaces[lod, tile], tiling) for tile in tiles)
        for tile in tiles:
            fine = heights[0, tile]
            coarse = on_columns(heights[lod, tile], fine)
            ground = ~np.isnan(fine[2])
            holes.append(np.isnan(coarse[ground]).mean())
            kept = ground & ~np.isnan(coarse)
            f, c = fine[2][kept], coarse[kept]
            within.append(np.corrcoef(f - f.mean(), c - c.mean())[0, 1])
            fine_all.append(f)
            coarse_all.append(c)
            if model.manifest.colour:
                colour.append(np.abs(mean_colour(surfaces[lod, tile], own_faces[lod, tile])
                                     - mean_colour(surfaces[0, tile], own_faces[0, tile])).max())
        from_fine, from_coarse = [], []
        for i, j in tiles:
            for axis, neighbour in enumerate(((i + 1, j), (i, j + 1))):
                if neighbour in tiles:
                    shares = border_openness(model, (surfaces[lod - 1, (i, j)], own_faces[lod - 1, (i, j)]),
                                             (surfaces[lod, neighbour], own_faces[lod, neighbour]), axis)
                    from_fine.append(shares[0])
                    from_coarse.append(shares[1])
        rows.append({
            "model": name, "lod": lod,
            "within": (float(np.median(within)), float(np.min(within))),
            "block": float(np.corrcoef(np.concatenate(fine_all), np.concatenate(coarse_all))[0, 1]),
            "holes": (float(np.max(holes)), inside_edges),
            "colour": (float(np.median(colour)), float(np.max(colour))) if colour else None,
            "borders": (float(np.mean(from_fine)), float(np.mean(from_coarse))),
        })
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["terrain", "terrain_colour"])
    parser.add_argument("--block", type=int, default=4, help="tiles along each side of the block measured")
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    print(f"{args.block} x {args.block} tiles of seed {args.seed}, scale 1; each lod n against lod 0 "
          "(borders: lod n - 1 beside lod n)")
    print("| model | lod | height correlation within a tile, median / least | over the block "
          "| columns without ground (most in a tile) / open edges inside | mean colour difference, median / most "
          "| border open from the finer side / the coarser |")
    print("|---|---|---|---|---|---|---|")
    for name in args.models:
        for row in measure(name, args.block, args.seed):
            colour = "-" if row["colour"] is None else "{:.1f} / {:.1f}".format(*row["colour"])
            print("| {} | {} | {:.3f} / {:.3f} | {:.3f} | {:.1%} / {} | {} | {:.1%} / {:.1%} |".format(
                name, row["lod"], *row["within"], row["block"], *row["holes"], colour, *row["borders"]))


if __name__ == "__main__":
    main()
