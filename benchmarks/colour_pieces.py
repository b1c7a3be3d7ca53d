"""Whether a coloured model's samples copy their example in coherent pieces
or as a patchwork: the correspondence made coarse to fine (the runtime's)
beside single voxels matched alone at the finest level (PatchMatch on
7-voxel patches, as the first coloured models did), on the same samples,
in one run (docs/BENCHMARKS.md, "Coherent pieces").

    python benchmarks/colour_pieces.py MODEL.onnx [--seeds 4]

Per seed and way:
- pieces: the share of the surface band's voxels in pieces (neighbours
  that copy neighbouring places of the example, colour.piece_sizes) of
  fewer than 27 voxels, and the median voxel's piece size;
- fit: the mean distance from each band voxel's patch to the patch of the
  example voxel it copies (square root of the integer squared distance, in
  steps of 1/256 of a hidden sum): what coherence costs in likeness;
- seconds to match the band.
"""

import argparse
import time

import numpy as np

from sinshape.runtime import colour, generate, load_model, query


def seven_voxel_level(model) -> colour.Level:
    """The example's finest level with 7-voxel patches (colour.PATCH): what
    the fit is measured in whatever the runtime compares, and what single
    voxels are matched alone with."""
    if not hasattr(model, "seven_voxel_level"):
        recon = generate.sample(model, None)
        reference = colour.pyramid(model, query.project(model, recon).planes, recon.size)
        model.seven_voxel_level = colour.Level(model.example_tiles.band(), reference.at(0), reference.size)
    return model.seven_voxel_level


def measure(model, seed: int) -> dict:
    triplane = generate.sample(model, seed)
    planes = query.project(model, triplane).planes
    band = colour.surface_band(model, colour.grid_hidden(model, planes, triplane.size), triplane.size)
    sample = colour.pyramid(model, planes, triplane.size)
    matcher = colour.matcher(model)
    finest = seven_voxel_level(model)
    ways = {"coarse to fine": lambda: matcher.match(sample, band),
            "voxels alone": lambda: finest.search(sample.at(0), band)}
    out = {}
    for name, match in ways.items():
        start = time.perf_counter()
        matched = match()
        seconds = time.perf_counter() - start
        sizes = colour.piece_sizes(band, matched)
        fit = np.sqrt(finest.distance(colour.patches(sample.at(0), band), matched))
        out[name] = (np.mean(sizes < 27), np.median(sizes), fit.mean(), seconds)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("--seeds", type=int, default=4)
    args = parser.parse_args()
    model = load_model(args.model, threads=1)
    colour.matcher(model)  # made once per model, not timed
    seven_voxel_level(model)
    print(f"{'seed':>4} {'way':<15} {'in pieces < 27':>14} {'median piece':>12} {'fit':>7} {'seconds':>7}")
    rows = {}
    for seed in range(1, args.seeds + 1):
        for name, (small, median, fit, seconds) in measure(model, seed).items():
            rows.setdefault(name, []).append((small, median, fit, seconds))
            print(f"{seed:>4} {name:<15} {small:>14.1%} {median:>12.0f} {fit:>7.0f} {seconds:>7.2f}")
    for name, values in rows.items():
        small, median, fit, seconds = np.mean(values, axis=0)
        print(f"mean {name:<15} {small:>14.1%} {median:>12.0f} {fit:>7.0f} {seconds:>7.2f}")


if __name__ == "__main__":
    main()
