"""Colour's cost and quality: a coloured model beside a geometry-only one
trained on the same example with the same budget (docs/BENCHMARKS.md, "Colour").

    python benchmarks/colour.py cost painted_terrain.ply
    python benchmarks/colour.py sampling colour.onnx
    python benchmarks/colour.py quality painted_terrain.ply colour.onnx geometry.onnx

cost: per level of the default preset's pyramid (res 64), seconds per
training iteration with and without colour, iterations interleaved in one
process, and the peak memory one iteration adds, each in a fresh process;
then the ratios.
sampling: the time to sample and write a .ply without colour, with the
colour head's and with colour read by correspondence (a format-5 model),
from one coloured model, seeds interleaved, and each coloured way's peak
memory. quality: LP-IoU, LP-F and diversity of both models
(docs/EVALUATION.md); sampling; the reconstruction's colour against the
example's (PSNR of its vertex colours against the colour of the example's
surface nearest each vertex); the samples' colours against the example's
(the per-channel Wasserstein distance of their vertex colours to the
example surface's, in 8-bit steps) and against each other (the same
distance between two seeds' samples, the colour's diversity).
"""

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def trainer_at(pyramid, level: int):
    """A trainer of the default preset (float32, CPU) ready at `level`, with
    its reconstruction's input; untrained levels cost what trained ones do."""
    from sinshape.trainer import device, train
    from sinshape.trainer.config import make_config

    trainer = train.Trainer(make_config(None, precision="fp32"), pyramid, device.choose("cpu", "fp32"))
    for _ in range(level):
        trainer.begin_level()
        trainer.finish_level()
    trainer.begin_level()
    return trainer, trainer.recon_inputs()


def peak(path: str, level: int, colour: bool) -> int:
    """Bytes one iteration at `level` adds to this process (run in a child)."""
    from sinshape.prep.pyramid import load_pyramid

    trainer, recon = trainer_at(load_pyramid(Path(path), 64, colour=colour), level)
    with open("/proc/self/statm") as f:
        before = int(f.read().split()[1]) * resource.getpagesize()
    for _ in range(2):  # the first allocates
        trainer.iterate(recon)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before


def cost(path: str, rounds: int) -> None:
    """Per level: seconds per iteration of both, their iterations interleaved
    in this process (a busy machine slows both alike; the median of
    `rounds`), and the peak memory of each in a child of its own."""
    from sinshape.prep.pyramid import load_pyramid

    pyramids = {colour: load_pyramid(Path(path), 64, colour=colour) for colour in (False, True)}

    def child(level, colour):
        command = [sys.executable, __file__, "child", path, str(level), str(int(colour))]
        return int(subprocess.run(command, check=True, capture_output=True, text=True).stdout)

    print("| level | size | s/iteration geometry | s/iteration colour | ratio | peak MiB geometry | peak MiB colour | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for level, size in enumerate(pyramids[False].sizes):
        trainers = {colour: trainer_at(pyramids[colour], level) for colour in (False, True)}
        times = {False: [], True: []}
        for _ in range(rounds + 1):  # the first of each allocates and picks kernels
            for colour, (trainer, recon) in trainers.items():
                started = time.perf_counter()
                trainer.iterate(recon)
                times[colour].append(time.perf_counter() - started)
        plain, coloured = (float(np.median(times[c][1:])) for c in (False, True))
        plain_bytes, coloured_bytes = child(level, False), child(level, True)
        print(f"| {level} | {'x'.join(map(str, size))} | {plain:.3f} | {coloured:.3f} | {coloured / plain:.2f} | "
              f"{plain_bytes / 2**20:.0f} | {coloured_bytes / 2**20:.0f} | {coloured_bytes / plain_bytes:.2f} |",
              flush=True)


def sampling(path: str, seeds: int, scales=(1, 4)) -> None:
    """The time to sample and write a .ply: geometry alone, colour from the
    decoder's colour head, and (a format-5 model) colour read from the
    example by correspondence: the same model and tri-planes, seeds
    interleaved; median over seeds. Then the peak memory of one coloured
    sample at scale 1, both ways, each in a fresh process."""
    import dataclasses

    from sinshape.runtime import generate, load_model, write

    coloured = load_model(path)
    # Geometry alone: no colour and no tiles (which would give its mesh the example's relief at scale 2 and up).
    ways = {"geometry": dataclasses.replace(coloured, manifest=dataclasses.replace(coloured.manifest, colour=False),
                                            example_tiles=None),
            "colour head": dataclasses.replace(coloured, example_tiles=None)}
    if coloured.example_tiles is not None:
        ways["correspondence"] = coloured
    with tempfile.TemporaryDirectory() as folder:
        for scale in scales:
            times = {name: [] for name in ways}
            for seed in range(seeds + 1):  # the first warms up (and makes the matcher)
                for name, model in ways.items():
                    started = time.perf_counter()
                    write.write_sample(model, generate.sample(model, seed), Path(folder) / "s.ply", scale=scale)
                    times[name].append(time.perf_counter() - started)
            medians = {name: float(np.median(t[1:])) for name, t in times.items()}
            print(f"sampling a .ply at scale {scale} (median of {seeds} seeds): "
                  + ", ".join(f"{name} {m:.3f} s" for name, m in medians.items())
                  + "; ratios to geometry: " + ", ".join(f"{name} {m / medians['geometry']:.2f}"
                                                          for name, m in medians.items() if name != "geometry"),
                  flush=True)
    for name in [n for n in ways if n != "geometry"]:
        command = [sys.executable, __file__, "peak", path, name]
        print(f"peak memory of one coloured sample ({name}): "
              f"{int(subprocess.run(command, check=True, capture_output=True, text=True).stdout) / 2**20:.0f} MiB")


def sampling_peak(path: str, way: str) -> int:
    """Peak resident bytes of loading `path` and writing one coloured sample (this process)."""
    import dataclasses

    from sinshape.runtime import generate, load_model, write

    model = load_model(path)
    if way == "colour head":
        model = dataclasses.replace(model, example_tiles=None)
    with tempfile.TemporaryDirectory() as folder:
        write.write_sample(model, generate.sample(model, 1), Path(folder) / "s.ply")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def wasserstein(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over channels of the 1-D Wasserstein distance of two colour sets, in 8-bit steps."""
    quantiles = np.linspace(0, 1, 201)
    return float(np.mean([np.abs(np.quantile(a[:, c], quantiles) - np.quantile(b[:, c], quantiles)).mean()
                          for c in range(3)]) * 255)


def quality(path: str, coloured_path: str, plain_path: str, samples: int, seeds: int) -> None:
    from scipy.spatial import cKDTree

    from sinshape.prep import colour, voxelize
    from sinshape.runtime import evaluate, generate, load_model, mesh

    coloured, plain = load_model(coloured_path), load_model(plain_path)
    print("| model | LP-IoU | LP-F | diversity |")
    print("|---|---|---|---|")
    for name, model in (("geometry only", plain), ("coloured", coloured)):
        scores = evaluate.evaluate_model(model, Path(path), samples=samples)
        print(f"| {name} | {scores['lp_iou']:.3f} | {scores['lp_f']:.3f} | {scores['diversity']:.3f} |")

    print()
    sampling(coloured_path, seeds)
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
    parser.add_argument("what", choices=["cost", "sampling", "quality", "child", "peak"])
    parser.add_argument("example")
    parser.add_argument("more", nargs="*")
    parser.add_argument("--samples", type=int, default=100, help="samples scored for LP-IoU, LP-F, diversity")
    parser.add_argument("--seeds", type=int, default=8, help="seeds sampled for times and colour statistics")
    parser.add_argument("--rounds", type=int, default=5, help="timed iterations per level and model")
    args = parser.parse_args()
    if args.what == "child":
        print(peak(args.example, int(args.more[0]), bool(int(args.more[1]))))
    elif args.what == "peak":
        print(sampling_peak(args.example, " ".join(args.more)))
    elif args.what == "sampling":
        sampling(args.example, args.seeds)
    elif args.what == "cost":
        cost(args.example, args.rounds)
    else:
        quality(args.example, *args.more, samples=args.samples, seeds=args.seeds)


if __name__ == "__main__":
    main()
