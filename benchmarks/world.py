"""Endless worlds, measured: seams, cost at any distance, and quality.

    python benchmarks/world.py [--models terrain acropolis towerruins] [--block 4] [--windows 100]
                               [--sections seams cost quality repetition map models] [--blend 1.0]

Seams: a block of tiles at scale 1 and 2: the largest occupancy difference
on shared faces, border vertices matched, and whether the block's union is
closed everywhere but its outer sides. Cost: seconds and peak traced memory
per tile at 0, 10^3, 10^6 and 10^9 tiles from the origin (each measured
alternately, best of 3, no window kept between tiles), and tiles per second
of a `sinrun world` job on all cores. Quality: LP-IoU, LP-F and diversity
(runtime/evaluate.py) of windows the size of an ordinary sample cut at
random places of the worlds of 10 seeds (most straddle tile borders),
beside ordinary samples. Repetition: the autocorrelation of the height
field (evaluate.height_autocorrelation) along each horizontal axis of long
strips of tiles at S/2 and at the tile period S and its multiples, beside
ordinary samples as long; and the relief (the spread of column heights) at
tile corners, at tile centres and over ordinary samples.
Models: a scattered world of the model and the next one of --models (the
first's after the last), placed by a checkerboard model map of 4 x 4
tiles a square: a tile's seconds near the origin and 10^15 tiles out
beside the model's world alone (alternately, best of 3, nothing kept).
--blend sets world.BLEND (the share of a stride over which one window gives
way to the next) for a comparison.
"""

import argparse
import dataclasses
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from sinshape import models
from sinshape.prep import shapes
from sinshape.prep.pyramid import reference_grid
from sinshape.runtime import evaluate, load_model, world, world_maps, world_points, world_tiles
from sinshape.runtime.generate import sample
from sinshape.runtime.query import dense

ROOT = Path(__file__).resolve().parent.parent
LARGE = (2.5, 2.5, 1.0)  # horizontal factors of the ordinary samples windows are also cut from
STRIP = 24  # tiles along the axis whose autocorrelation is measured
TRAINING_INPUTS = {"terrain": "shape", "acropolis": "shape", "towerruins": ROOT / "tests/data/towerruins/towerruins.obj"}


def world_grid(model, seed: int, rows: range, columns: range, scale: float = 1.0,
               options: world.WorldOptions = world.PLAIN) -> np.ndarray:
    """Occupancy of a block of tiles as one grid (each shared face once)."""
    h0, h1 = world.world_tiling(model).horizontal
    strips = []
    for i in rows:
        row = [world_tiles.tile_occupancy(model, seed, (i, j), scale, options=options) for j in columns]
        row = [np.take(t, range(0 if k == 0 else 1, t.shape[h1]), axis=h1) for k, t in enumerate(row)]
        strips.append(np.concatenate(row, axis=h1))
    strips = [np.take(s, range(0 if k == 0 else 1, s.shape[h0]), axis=h0) for k, s in enumerate(strips)]
    return np.concatenate(strips, axis=h0)


def seams(model, block: int, options) -> dict:
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    out = {}
    for scale in (1.0, 2.0):
        grids = {(i, j): world_tiles.tile_occupancy(model, 3, (i, j), scale, options=options) for i in range(block) for j in range(block)}
        worst = 0.0
        for (i, j), grid in grids.items():
            for di, dj, axis in ((1, 0, h0), (0, 1, h1)):
                if (i + di, j + dj) in grids:
                    other = grids[i + di, j + dj]
                    worst = max(worst, float(np.abs(np.take(grid, -1, axis) - np.take(other, 0, axis)).max()))
        out[f"face difference, scale {scale:g}"] = worst
    matched = total = 0
    for i in range(block - 1):
        a, b = (world_tiles.tile_mesh(model, 3, (i, 0), options=options)[0],
                world_tiles.tile_mesh(model, 3, (i + 1, 0), options=options)[0])
        on_a = {tuple(v) for v in a[a[:, h0] == tiling.stride[h0]] - np.eye(3)[h0] * tiling.stride[h0]}
        on_b = {tuple(v) for v in b[b[:, h0] == 0]}
        matched, total = matched + len(on_a & on_b), total + len(on_a | on_b)
    out["border vertices matched"] = f"{matched} of {total}"
    same = total_normals = 0
    for i in range(block - 1):
        a, b = (world_tiles.tile_surface(model, 3, (i, 0), options=options), world_tiles.tile_surface(model, 3, (i + 1, 0), options=options))
        on_a = {tuple(v - np.eye(3)[h0] * tiling.stride[h0]): tuple(n) for v, n in zip(a.vertices, a.normals)
                if v[h0] == tiling.stride[h0]}
        on_b = {tuple(v): tuple(n) for v, n in zip(b.vertices, b.normals) if v[h0] == 0}
        same += sum(on_a[v] == on_b.get(v) for v in on_a)
        total_normals += len(on_a)
    out["border normals equal to the bit"] = f"{same} of {total_normals}"
    vertices, faces = [], []
    count = 0
    for i in range(block):
        for j in range(block):
            v, f = world_tiles.tile_mesh(model, 3, (i, j), options=options)
            vertices.append(v + np.array(world_tiles.tile_corner(model, (i, j))))
            faces.append(f + count)
            count += len(v)
    unique, index = np.unique(np.concatenate(vertices), axis=0, return_inverse=True)
    faces = index.reshape(-1)[np.concatenate(faces)]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    edge, counts = np.unique(edges, axis=0, return_counts=True)
    ends = unique[edge[counts == 1]]
    outer = np.zeros(len(ends), bool)
    for axis in (h0, h1):
        for at in (0, block * tiling.stride[axis]):
            outer |= (ends[:, :, axis] == at).all(axis=1)
    out[f"{block}x{block} union"] = ("closed but for its outer sides" if outer.all() and counts.max() == 2
                                     else f"{int((~outer).sum())} open edges inside, {int((counts > 2).sum())} non-manifold")
    return out


BLOCK = 5  # tiles a side of the block whose tiles share their windows
RUN = 6  # tiles in a row measured at each distance: a scattered world's tiles hold 0 to 4 objects


def forget_windows() -> None:
    """Drop the windows' planes and colourings kept for the next tiles: a tile made after it makes its own."""
    world._windows.clear()
    world_points._colourings.clear()


def cost(model, name: str, options) -> dict:
    """Seconds and traced memory of a tile (mesh, normals and all) with no
    window kept, the mean over a row of RUN tiles at each of four distances
    and at each coarser level of detail, measured alternately, best of 3;
    and a `sinrun world` job on one and two workers."""
    out = {}
    distances = [0, 10**3, 10**6, 10**9]
    levels = range(1, len(model.manifest.sizes))
    kinds = [("distance", d) for d in distances] + [("lod", lod) for lod in levels]
    best = {kind: (np.inf, 0) for kind in kinds}
    for _ in range(3):
        for kind in kinds:
            d, chosen = (kind[1], options) if kind[0] == "distance" else (0, dataclasses.replace(options, lod=kind[1]))
            seconds = peak = 0
            for k in range(RUN):
                forget_windows()
                started = time.perf_counter()
                world_tiles.tile_surface(model, 3, (d + k, -d), options=chosen)
                seconds += (time.perf_counter() - started) / RUN
                # The memory in a run of its own: tracing slows Python's own work (a coarser tile's most) 2 to 3 times.
                forget_windows()
                tracemalloc.start()
                world_tiles.tile_surface(model, 3, (d + k, -d), options=chosen)
                peak = max(peak, tracemalloc.get_traced_memory()[1])
                tracemalloc.stop()
            best[kind] = (min(best[kind][0], seconds), max(best[kind][1], peak))
    full = best[("distance", 0)][0]
    for kind, (seconds, peak) in best.items():
        label = f"a tile at {kind[1]:g} (mean of {RUN})" if kind[0] == "distance" else f"a tile at lod {kind[1]} (x full)"
        ratio = f" ({seconds / full:.2f}x)" if kind[0] == "lod" else ""
        out[f"{label}: s / MB"] = f"{seconds:.3f}{ratio} / {peak / 2**20:.1f}"
    # A block made row by row, its windows kept (as the page and Blender make a view): a tile shares
    # its windows with its neighbours, and a coarser one each window's first levels only.
    block = {lod: np.inf for lod in (0, levels[-1])}
    for _ in range(3):
        for lod in block:
            forget_windows()
            started = time.perf_counter()
            for i in range(BLOCK):
                for j in range(BLOCK):
                    world_tiles.tile_surface(model, 3, (i, j), options=dataclasses.replace(options, lod=lod))
            block[lod] = min(block[lod], (time.perf_counter() - started) / BLOCK**2)
    out[f"a tile of a {BLOCK} x {BLOCK} block, windows kept, lod 0 / lod {levels[-1]}: s"] = (
        f"{block[0]:.3f} / {block[levels[-1]]:.3f} ({block[levels[-1]] / block[0]:.2f}x)")
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as folder:
            started = time.perf_counter()
            subprocess.run([str(Path(sys.executable).with_name("sinrun")), "world", name, "--tiles", "0:5,0:5", "-o",
                            folder, "--workers", str(workers), "--arrange", options.arrange], check=True,
                           capture_output=True)
            out[f"tiles/s, sinrun world (36 tiles, {workers} workers)"] = f"{36 / (time.perf_counter() - started):.2f}"
    return out


def reference_of(name: str, model, folder: Path) -> np.ndarray:
    source = TRAINING_INPUTS[name]
    if source == "shape":
        source = folder / f"{name}.obj"
        shapes.write_shape(name, source)
    return reference_grid(source, model.manifest)


def quality(model, name: str, windows: int, options) -> dict:
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    finest = model.manifest.sizes[-1]
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as folder:
        reference = reference_of(name, model, Path(folder))
    cut = []
    per_world = max(1, windows // 10)
    for seed in range(10):
        grid = world_grid(model, seed, range(4), range(4), options=options) > 0.5
        for _ in range(per_world):
            start = [0, 0, 0]
            for axis in (h0, h1):
                start[axis] = int(rng.integers(0, grid.shape[axis] - finest[axis] + 1))
            cut.append(grid[tuple(slice(s, s + n) for s, n in zip(start, finest))])
    samples = [dense(model, sample(model, seed)) > 0.5 for seed in range(len(cut))]
    crops = []  # the same cut from large ordinary samples: what a window of any large sample scores
    for seed in range(10):
        large = [1.0, 1.0, 1.0]
        for axis in (h0, h1):
            large[axis] = LARGE[0]
        grid = dense(model, sample(model, seed, tuple(large))) > 0.5
        for _ in range(per_world):
            start = [int(rng.integers(0, grid.shape[a] - finest[a] + 1)) for a in range(3)]
            crops.append(grid[tuple(slice(s, s + n) for s, n in zip(start, finest))])
    out = {}
    for label, volumes in (("world windows: LP-IoU / LP-F / diversity", cut),
                           ("ordinary samples", samples),
                           (f"windows of ordinary samples {LARGE[0]:g} times as large along each horizontal axis", crops)):
        lp = evaluate.lp_metrics(volumes, reference)
        out[label] = f"{lp['lp_iou']:.3f} / {lp['lp_f']:.3f} / {evaluate.diversity(volumes):.3f}"
    return out


def strips(model, seeds, options) -> dict:
    """Per horizontal axis, long strips of the world (STRIP tiles along it,
    3 across) and ordinary samples as large, one of each per seed."""
    tiling = world.world_tiling(model)
    h0, h1 = tiling.horizontal
    finest = model.manifest.sizes[-1]
    out = {}
    for axis, other in ((h0, h1), (h1, h0)):
        block = {axis: range(STRIP), other: range(3)}
        worlds = [world_grid(model, seed, block[h0], block[h1], options=options) for seed in seeds]
        factors = [1.0, 1.0, 1.0]
        for a in (h0, h1):
            factors[a] = worlds[0].shape[a] / finest[a]
        out[axis] = (worlds, [dense(model, sample(model, seed, tuple(factors))) for seed in seeds])
    return out


def zones(grid: np.ndarray, tiling, width: float = 0.1) -> dict:
    """Height-field columns of a world grid (a block from tile (0, 0)) near the
    tiles' corners (within `width` of a stride from a border along both
    horizontal axes) and near their centres (within `width` of the middle
    along both): (n,) heights each."""
    h0, h1 = tiling.horizontal
    height = evaluate.height_field(grid, tiling.up)  # (h0, h1)
    fraction = [(np.arange(height.shape[k]) % tiling.stride[a]) / tiling.stride[a] for k, a in enumerate((h0, h1))]
    corner = [np.minimum(f, 1 - f) <= width for f in fraction]
    centre = [np.abs(f - 0.5) <= width for f in fraction]
    return {"corners": height[np.ix_(*corner)].ravel(), "centres": height[np.ix_(*centre)].ravel()}


def repetition(model, options, seeds=(7, 8)) -> dict:
    """The height field's autocorrelation at the tile period S and its
    multiples along each horizontal axis, world against ordinary samples as
    long (mean over `seeds`); and the relief (std of heights) at tile
    corners, centres and over ordinary samples."""
    tiling = world.world_tiling(model)
    out = {}
    relief = {"corners": [], "centres": [], "ordinary": []}
    for axis, (worlds, ordinary) in strips(model, seeds, options).items():
        period = tiling.stride[axis]
        lags = [period // 2, period, 2 * period, 3 * period]
        for label, grids in (("world", worlds), ("an ordinary sample as long", ordinary)):
            values = np.mean([evaluate.height_autocorrelation(g, tiling.up, axis, lags) for g in grids], axis=0)
            out[f"height autocorrelation along {'xyz'[axis]} at S/2, S, 2S, 3S ({lags}), {label}"] = \
                " ".join(f"{v:+.3f}" for v in values)
        for grid in worlds:
            for key, heights in zones(grid, tiling).items():
                relief[key].append(heights)
        relief["ordinary"] += [evaluate.height_field(g, tiling.up).ravel() for g in ordinary]
    if options.arrange != "blend":  # tiles neither blend at their centres nor hold one window at their corners
        relief.pop("corners"), relief.pop("centres")
        out["relief (std of heights, voxels): ordinary samples"] = f"{np.std(np.concatenate(relief['ordinary'])):.2f}"
        return out
    spread = {key: float(np.std(np.concatenate(v))) for key, v in relief.items()}
    out["relief (std of heights, voxels): tile corners / tile centres / ordinary samples"] = \
        f"{spread['corners']:.2f} / {spread['centres']:.2f} / {spread['ordinary']:.2f}" + \
        (f" (centres {spread['centres'] / spread['corners'] - 1:+.0%} against corners)" if spread["corners"] else "")
    return out


def painted_map(tiles: int, relief: float) -> np.ndarray:
    """A designer's map over tiles x tiles: two hills and a valley between,
    heights 0 to `relief` voxels (what a brush would paint)."""
    r = (np.arange(tiles) + 0.5) / tiles
    u, v = r[:, None], r[None, :]
    hills = np.exp(-((u - 0.3) ** 2 + (v - 0.3) ** 2) / 0.02) + 0.8 * np.exp(-((u - 0.7) ** 2 + (v - 0.65) ** 2) / 0.03)
    valley = 0.5 * np.exp(-((u - v) ** 2) / 0.01)
    heights = np.clip(hills - valley + 0.3, 0, None)
    return relief * heights / heights.max()


def world_heights(model, seed: int, tiles: int, options) -> np.ndarray:
    """The height field (occupied voxels per column) of tiles x tiles from
    (0, 0), each tile's shared faces once: (tiles S0 + 1, tiles S1 + 1)."""
    tiling = world.world_tiling(model)
    rows = []
    for i in range(tiles):
        row = [evaluate.height_field(world_tiles.tile_occupancy(model, seed, (i, j), options=options), tiling.up)
               for j in range(tiles)]
        row = [t[:, (0 if k == 0 else 1):] for k, t in enumerate(row)]
        rows.append(np.concatenate(row, axis=1))
    return np.concatenate([r[(0 if k == 0 else 1):] for k, r in enumerate(rows)], axis=0)


def large_shape(model, options, tiles: int = 32, relief_factor: float = 4.0) -> dict:
    """A world of tiles x tiles painted with painted_map (relief_factor
    times the model's height): its large-scale relief (the std of each
    tile's mean height) against the model's own height band (the std of an
    ordinary sample's heights) and the plain world's, and how it follows
    the map (correlation of each tile's mean height with its pixel)."""
    tiling = world.world_tiling(model)
    relief = relief_factor * tiling.stride[tiling.up]
    heights = painted_map(tiles, relief)
    painted = dataclasses.replace(options, heights=world_maps.HeightMap.of(heights))
    out = {}
    band = float(np.std(evaluate.height_field(dense(model, sample(model, 7)), tiling.up)))
    for label, chosen in (("plain", options), (f"painted, relief {relief:g} voxels", painted)):
        field = world_heights(model, 7, tiles, chosen)
        s0, s1 = tiling.stride[tiling.horizontal[0]], tiling.stride[tiling.horizontal[1]]
        means = field[:tiles * s0, :tiles * s1].reshape(tiles, s0, tiles, s1).mean(axis=(1, 3))
        out[f"{tiles}x{tiles} tiles, {label}: large-scale relief (std of tile means) / model's band"] = \
            f"{means.std():.2f} / {band:.2f} voxels ({means.std() / band:.1f}x)"
        if chosen is painted:
            out["... correlation of tile means with the painted heights"] = \
                f"{np.corrcoef(means.ravel(), heights.ravel())[0, 1]:.3f}"
    return out


def several_models(model, other, name: str, other_name: str) -> dict:
    """Seconds of a tile (mesh, normals and all, nothing kept), the mean
    over 48 tiles near the origin and 10^15 tiles out, of a scattered world
    of `model` alone and of `model` and `other` on a checkerboard, measured
    alternately, best of 3."""
    checkers = (np.indices((16, 16)).sum(axis=0) // 4) % 2
    worlds = {f"{name} alone": world.WorldOptions("scatter"),
              f"{name} + {other_name}": world.WorldOptions("scatter", models=(other,),
                                                            models_map=world_maps.ModelMap.of(checkers))}
    places = {"near the origin": (0, 0), "10^15 tiles out": (10**15, -10**15)}
    best = {}
    for _ in range(3):
        for label, options in worlds.items():
            for where, (i0, j0) in places.items():
                seconds = 0
                tiles = [(i0 + i, j0 + j) for i in range(8) for j in range(6)]
                for tile in tiles:
                    forget_windows()
                    started = time.perf_counter()
                    world_tiles.tile_surface(model, 3, tile, options=options)
                    seconds += (time.perf_counter() - started) / len(tiles)
                best[label, where] = min(best.get((label, where), np.inf), seconds)
    return {f"a tile of {label}, {where} (mean of 48): s": f"{seconds:.3f}" for (label, where), seconds in best.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["terrain", "acropolis", "towerruins"])
    parser.add_argument("--block", type=int, default=4)
    parser.add_argument("--windows", type=int, default=100)
    parser.add_argument("--sections", nargs="+", default=["seams", "cost", "quality", "repetition", "map"])
    parser.add_argument("--blend", type=float, default=None)
    parser.add_argument("--contrast", type=float, default=None,
                        help="every model's blend contrast exponent, for a comparison (default: each model's own)")
    parser.add_argument("--spacing", type=float, default=None, help="a scattered world's spacing, for a comparison")
    parser.add_argument("--density", type=float, default=None, help="a scattered world's density, for a comparison")
    parser.add_argument("--arrange", choices=world.ARRANGEMENTS, default=None,
                        help="every model's arrangement (default: each model's own, as its manifest records)")
    args = parser.parse_args()
    if args.blend is not None:
        world.BLEND = args.blend
    scattered = {name: getattr(args, name) for name in ("spacing", "density") if getattr(args, name) is not None}
    print(f"world.BLEND = {world.BLEND}, scattered worlds' {scattered or 'defaults'}")
    for number, name in enumerate(args.models):
        model = load_model(models.find(name))
        if args.contrast is not None:
            model.manifest = dataclasses.replace(model.manifest, contrast=args.contrast)
        other_name = args.models[(number + 1) % len(args.models)]
        arrange = args.arrange or model.manifest.arrange
        options = world.WorldOptions(arrange=arrange, **(scattered if arrange == "scatter" else {}))
        tiling = world.world_tiling(model)
        print(f"\n## {name}: up {model.manifest.up}, tiles of {tiling.stride[tiling.horizontal[0]]} x "
              f"{tiling.stride[tiling.horizontal[1]]} voxels, windows {'x'.join(map(str, model.manifest.sizes[-1]))}, "
              f"{options.arrange}, blend contrast {model.manifest.contrast:g}\n")
        print("| measure | value |\n|---|---|")
        for section in args.sections:
            figures = {"seams": lambda: seams(model, args.block, options), "cost": lambda: cost(model, name, options),
                       "quality": lambda: quality(model, name, args.windows, options),
                       "repetition": lambda: repetition(model, options),
                       "map": lambda: large_shape(model, options),
                       "models": lambda: several_models(model, load_model(models.find(other_name)), name,
                                                        other_name)}[section]()
            for key, value in figures.items():
                print(f"| {key} | {value} |", flush=True)


if __name__ == "__main__":
    main()
