"""Colour's cost and quality: a coloured model beside a geometry-only one
trained on the same example with the same budget (docs/BENCHMARKS.md, "Colour").

    python benchmarks/colour.py cost painted_terrain.ply
    python benchmarks/colour.py quality painted_terrain.ply colour.onnx geometry.onnx

cost: per level of the default preset's pyramid, seconds per training
iteration and the peak memory one iteration adds, each level measured with
and without colour in fresh processes, one after the other, then the ratio.
quality: LP-IoU, LP-F and diversity of both models (docs/EVALUATION.md);
the time to sample and mesh a .ply of each (the coloured one with its
colours), seeds interleaved; the reconstruction's colour against the
example's (PSNR of its vertex colours against the colour of the example's
surface nearest each vertex); the samples' colours against the example's
(the per-channel Wasserstein distance of their vertex colours to the
example surface's, in 8-bit steps) and against each other (the same
distance between two seeds' samples, the colour's diversity).
"""

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def measure(path: str, level: int, colour: bool, rounds: int = 3) -> dict:
    """Seconds per iteration and bytes one iteration adds, at `level` (run in a child)."""
    from sinshape.prep.pyramid import load_pyramid
    from sinshape.trainer import device, train
    from sinshape.trainer.config import make_config

    config = make_config(None, precision="fp32")
    pyramid = load_pyramid(Path(path), config.res, colour=colour)
    trainer = train.Trainer(config, pyramid, device.choose("cpu", "fp32"))
    for _ in range(level):  # untrained levels cost what trained ones do
        trainer.begin_level()
        trainer.finish_level()
    trainer.begin_level()
    with open("/proc/self/statm") as f:
        before = int(f.read().split()[1]) * resource.getpagesize()
    recon = trainer.recon_inputs()
    trainer.iterate(recon)  # the first allocates and picks kernels
    started = time.perf_counter()
    for _ in range(rounds):
        trainer.iterate(recon)
    return {"seconds": (time.perf_counter() - started) / rounds, "size": list(pyramid.sizes[level]),
            "bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before,
            "levels": len(pyramid.sizes)}


def cost(path: str) -> None:
    def child(level, colour):
        command = [sys.executable, __file__, "child", path, str(level), str(int(colour))]
        return json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout)

    print("| level | size | s/iteration geometry | s/iteration colour | ratio | peak MiB geometry | peak MiB colour | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    level, levels = 0, 1
    while level < levels:
        plain, coloured = child(level, False), child(level, True)
        levels = plain["levels"]
        print(f"| {level} | {'x'.join(map(str, plain['size']))} | {plain['seconds']:.3f} | {coloured['seconds']:.3f} | "
              f"{coloured['seconds'] / plain['seconds']:.2f} | {plain['bytes'] / 2**20:.0f} | "
              f"{coloured['bytes'] / 2**20:.0f} | {coloured['bytes'] / plain['bytes']:.2f} |")
        level += 1


def wasserstein(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over channels of the 1-D Wasserstein distance of two colour sets, in 8-bit steps."""
    quantiles = np.linspace(0, 1, 201)
    return float(np.mean([np.abs(np.quantile(a[:, c], quantiles) - np.quantile(b[:, c], quantiles)).mean()
                          for c in range(3)]) * 255)


def quality(path: str, coloured_path: str, plain_path: str, samples: int, seeds: int) -> None:
    from scipy.spatial import cKDTree

    from sinshape.prep import colour, voxelize
    from sinshape.runtime import evaluate, generate, load_model, mesh, write

    coloured, plain = load_model(coloured_path), load_model(plain_path)
    print("| model | LP-IoU | LP-F | diversity |")
    print("|---|---|---|---|")
    for name, model in (("geometry only", plain), ("coloured", coloured)):
        scores = evaluate.evaluate_model(model, Path(path), samples=samples)
        print(f"| {name} | {scores['lp_iou']:.3f} | {scores['lp_f']:.3f} | {scores['diversity']:.3f} |")

    times = {"geometry only": [], "coloured": []}
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(seeds):
            for name, model in (("geometry only", plain), ("coloured", coloured)):
                started = time.perf_counter()
                write.write_sample(model, generate.sample(model, seed), Path(folder) / "s.ply")
                times[name].append(time.perf_counter() - started)
    plain_s, coloured_s = (np.median(times[k]) for k in ("geometry only", "coloured"))
    print(f"\nsampling a .ply (median of {seeds} seeds): geometry only {plain_s:.3f} s, coloured {coloured_s:.3f} s, "
          f"ratio {coloured_s / plain_s:.2f}")

    scene, data = voxelize.read_scene(Path(path))
    surface = colour.surface_colour(scene, Path(path), data, voxel=float(np.min(coloured.manifest.spacing)))
    tree = cKDTree(surface.points)
    recon = mesh.extract(coloured, generate.sample(coloured, None))
    truth = surface.rgb[tree.query(recon.vertices)[1]]
    error = np.mean((recon.visual.vertex_colors[:, :3] / 255 - truth) ** 2)
    print(f"reconstruction's vertex colours against the example's nearest surface: PSNR {10 * np.log10(1 / error):.1f} dB")
    sample_colours = [mesh.extract(coloured, generate.sample(coloured, seed)).visual.vertex_colors[:, :3] / 255
                      for seed in range(seeds)]
    to_example = np.mean([wasserstein(c, surface.rgb) for c in sample_colours])
    between = np.mean([wasserstein(a, b) for i, a in enumerate(sample_colours) for b in sample_colours[i + 1:]])
    recon_to_example = wasserstein(recon.visual.vertex_colors[:, :3] / 255, surface.rgb)
    print(f"colour distance to the example (Wasserstein, 8-bit steps): samples {to_example:.2f}, "
          f"reconstruction {recon_to_example:.2f}; between samples (diversity) {between:.2f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["cost", "quality", "child"])
    parser.add_argument("example")
    parser.add_argument("more", nargs="*")
    parser.add_argument("--samples", type=int, default=100, help="samples scored for LP-IoU, LP-F, diversity")
    parser.add_argument("--seeds", type=int, default=8, help="seeds sampled for times and colour statistics")
    args = parser.parse_args()
    if args.what == "child":
        print(json.dumps(measure(args.example, int(args.more[0]), bool(int(args.more[1])))))
    elif args.what == "cost":
        cost(args.example)
    else:
        quality(args.example, *args.more, samples=args.samples, seeds=args.seeds)


if __name__ == "__main__":
    main()
