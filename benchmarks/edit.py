"""Edited samples against plain ones, on the shipped models.

    python benchmarks/edit.py [--samples 50] [--models acropolis terrain towerruins]

Kept parts: for each model, sample i (i < --samples) is seed i with the box
BOX (in percent of the sample) taken from seed 1000 + i (`runtime.compose`).
It prints, per model:
- kept: the largest occupancy difference between a composed sample and its
  part's source, inside the box less the join margin (exact: 0);
- base: the same against seed i, over the voxels away from the box and its
  shadow (exact: 0);
- LP-IoU, LP-F and diversity of the composed samples and of plain seeds
  0 .. n-1, against the training example (docs/EVALUATION.md);
- seconds for one sample at scale 1 made into a mesh (sample or compose,
  then extract), the median of 5, side by side, and their ratio.

Layouts: seed i's level-0 layout, edited four ways (a slab above the floor
removed, a stretch along x copied further along, everything above the floor
moved along x, a block added at a corner), generated from with seed i. Per
edit: the IoU of the result (area-averaged to the layout's grid) with the
edited layout, the share of the edited cells it follows (mean and worst),
LP-IoU, LP-F and diversity against the example, seconds per mesh as above,
and the time to write and read the layout as .vox.
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from sinshape import models
from sinshape.prep import shapes
from sinshape.prep.pyramid import reference_grid
from sinshape.runtime import dense, extract, load_model, sample
from sinshape.runtime import layout as layouts, layout_files
from sinshape.runtime.edit import MARGIN, compose, parse_part
from sinshape.runtime.evaluate import diversity, lp_metrics

BOX = "20%,0%,0%:70%,60%,100%"
REPO = Path(__file__).resolve().parent.parent


def training_example(name: str, folder: Path) -> Path:
    """The mesh a shipped model was trained on: a procedural shape, or the test data's towerruins."""
    if name == "towerruins":
        return REPO / "tests" / "data" / "towerruins" / "towerruins.obj"
    path = folder / f"{name}.obj"
    shapes.make_shape(name).export(path)
    return path


def regions(part, size) -> tuple:
    """(kept, far) boolean grids: inside the box less the margin; away from it and its shadow."""
    axes = np.meshgrid(*[np.arange(n) for n in size], indexing="ij")
    inside, outside = [], []
    for v, lo, hi, n in zip(axes, part.low, part.high, size):
        inside.append((v >= (lo + MARGIN if lo > 0 else 0)) & (v <= (hi - MARGIN if hi < n - 1 else n)))
        outside.append((v <= lo - MARGIN) | (v >= hi + MARGIN))
    x, y, z = outside
    return inside[0] & inside[1] & inside[2], (x | y) & (x | z) & (y | z)


def seconds(make) -> float:
    times = []
    for _ in range(5):
        started = time.perf_counter()
        make()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def measure(name: str, count: int, folder: Path) -> dict:
    model = load_model(models.find(name))
    size = model.manifest.sizes[-1]
    parts = [parse_part(f"{1000 + i}:{BOX}", model.manifest, size) for i in range(count)]
    kept, far = regions(parts[0], size)
    composed, plain, kept_diff, base_diff = [], [], 0.0, 0.0
    for i, part in enumerate(parts):
        grid = dense(model, compose(model, i, [part]))
        base = dense(model, sample(model, i))
        kept_diff = max(kept_diff, float(np.abs(grid[kept] - dense(model, sample(model, part.seed))[kept]).max()))
        base_diff = max(base_diff, float(np.abs(grid[far] - base[far]).max())) if far.any() else float("nan")
        composed.append(grid > 0.5)
        plain.append(base > 0.5)
    truth = reference_grid(training_example(name, folder), model.manifest, 1.0)
    scores = {label: {**{k: lp_metrics(v, truth)[k] for k in ("lp_iou", "lp_f")}, "diversity": diversity(v)}
              for label, v in (("plain", plain), ("composed", composed))}
    plain_s = seconds(lambda: extract(model, sample(model, 0)))
    compose_s = seconds(lambda: extract(model, compose(model, 0, [parts[0]])))
    return {"model": name, "size": size, "kept": kept_diff, "kept_voxels": int(kept.sum()),
            "base": base_diff, "far_voxels": int(far.sum()), **scores,
            "plain_s": plain_s, "compose_s": compose_s}


def edited_layouts(layout) -> dict:
    """The four edits, on any layout: (X, Y, Z) bool at level 0."""
    x, y, z = layout.shape
    floor = max(1, z // 4)
    removed, duplicated, moved, added = (layout.copy() for _ in range(4))
    removed[x // 3:x // 2, :, floor:] = False
    duplicated[x // 2:x // 2 + x // 3] = layout[x // 6:x // 6 + x // 3]
    moved[:, :, floor:] = np.roll(layout[:, :, floor:], x // 5, axis=0)
    added[x // 10:x // 10 + max(2, x // 7), y // 10:y // 10 + max(2, y // 4), :] = True
    return {"removed": removed, "duplicated": duplicated, "moved": moved, "added": added}


def measure_layouts(name: str, count: int, folder: Path) -> list:
    model = load_model(models.find(name))
    truth = reference_grid(training_example(name, folder), model.manifest, 1.0)
    rows = {edit: {"iou": [], "edited": [], "grids": []} for edit in edited_layouts(layouts.layout(model, 0))}
    for i in range(count):
        own = layouts.layout(model, i)
        for edit, target in edited_layouts(own).items():
            grid = dense(model, layouts.from_layout(model, i, target))
            pooled = layouts.pool(grid, target.shape) > 0.5
            changed = target != own
            rows[edit]["iou"].append((pooled & target).sum() / (pooled | target).sum())
            rows[edit]["edited"].append(np.mean(pooled[changed] == target[changed]) if changed.any() else 1.0)
            rows[edit]["grids"].append(grid > 0.5)
    out = []
    for edit, r in rows.items():
        target = edited_layouts(layouts.layout(model, 0))[edit]
        lp = lp_metrics(r["grids"], truth)
        out.append({"edit": edit, "iou": float(np.mean(r["iou"])), "edited": float(np.mean(r["edited"])),
                     "worst": float(np.min(r["edited"])), "lp_iou": lp["lp_iou"], "lp_f": lp["lp_f"],
                     "diversity": diversity(r["grids"]),
                     "seconds": seconds(lambda: extract(model, layouts.from_layout(model, 0, target)))})
    path = folder / "layout.vox"
    io_seconds = seconds(lambda: (layout_files.write_layout(target, path), layout_files.read_layout(path)))
    return out, seconds(lambda: extract(model, sample(model, 0))), io_seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=50)
    parser.add_argument("--models", nargs="+", default=sorted(models.available()))
    args = parser.parse_args()
    print(f"box {BOX} of seed 1000 + i in seed i, {args.samples} samples per model\n")
    print("| model | kept: max difference (voxels compared) | away: max difference (voxels compared) | plain LP-IoU / LP-F / div "
          "| composed LP-IoU / LP-F / div | s per mesh, plain | composed | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name in args.models:
            r = measure(name, args.samples, Path(folder))
            p, c = r["plain"], r["composed"]
            print(f"| {name} {'x'.join(map(str, r['size']))} | {r['kept']:.1e} ({r['kept_voxels']}) "
                  f"| {r['base']:.1e} ({r['far_voxels']}) "
                  f"| {p['lp_iou']:.3f} / {p['lp_f']:.3f} / {p['diversity']:.3f} "
                  f"| {c['lp_iou']:.3f} / {c['lp_f']:.3f} / {c['diversity']:.3f} "
                  f"| {r['plain_s']:.3f} | {r['compose_s']:.3f} | {r['compose_s'] / r['plain_s']:.2f}x |", flush=True)
        print("\nLayouts: level 0 of seed i, edited, generated from with seed i\n")
        print("| model | edit | IoU with the layout | edited cells followed (worst) | LP-IoU / LP-F / div "
              "| s per mesh (plain) | ratio | layout .vox write + read |")
        print("|---|---|---|---|---|---|---|---|")
        for name in args.models:
            rows, plain_s, io_s = measure_layouts(name, args.samples, Path(folder))
            for r in rows:
                print(f"| {name} | {r['edit']} | {r['iou']:.3f} | {r['edited']:.3f} ({r['worst']:.3f}) "
                      f"| {r['lp_iou']:.3f} / {r['lp_f']:.3f} / {r['diversity']:.3f} "
                      f"| {r['seconds']:.3f} ({plain_s:.3f}) | {r['seconds'] / plain_s:.1f}x | {io_s * 1000:.1f} ms |",
                      flush=True)


if __name__ == "__main__":
    main()
