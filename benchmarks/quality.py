"""Quality and cost, SSG (tri-planes) against the SinGAN-3D baseline (voxels).

    python benchmarks/quality.py INPUT... [--res 64] [--max-res 72] [--iters 300] [--samples 100]
                                 [--generators triplane voxel] [--work DIR] [--json OUT]

For every input (a mesh, or an SSG .h5 pyramid cut to the levels whose
longest side is at most --max-res) and generator, in fresh processes:
train with `sinrun train` (wall time, per-level time, peak memory), then
sample --samples shapes and score them as the paper does (LP-IoU, LP-F,
diversity; runtime/evaluate.py), with the sampling time and peak memory.
The tri-plane model samples through the torch-free runtime; the voxel
baseline has no .onnx form and samples with torch. Prints a markdown table.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

SINRUN = str(Path(sys.executable).with_name("sinrun"))

SAMPLE_VOXEL = """
import json, sys, time
import torch
from sinshape.core import noise
from sinshape.runtime import evaluate
from sinshape.prep import pyramid
from sinshape.trainer.checkpoint import load_generator
checkpoint, reference, samples = sys.argv[1], sys.argv[2], int(sys.argv[3])
torch.set_num_threads(2)
generator, sizes, amps = load_generator(checkpoint)
truth = pyramid.load_pyramid(reference, res=max(sizes[-1]), levels=1).levels[-1]
started = time.perf_counter()
volumes = []
with torch.no_grad():
    for seed in range(samples):
        rng = torch.Generator().manual_seed(seed)
        z0 = torch.from_numpy(noise.z0_noise(seed, sizes[0]))[None, None]
        noises = [None] + [[amps[i] * torch.randn((1, 1, *sizes[i]), generator=rng)] for i in range(1, len(sizes))]
        volumes.append(generator(z0, noises, sizes)[0].numpy() > 0.5)
sampled = time.perf_counter()
lp = evaluate.lp_metrics(volumes, truth)
print(json.dumps({"lp_iou": lp["lp_iou"], "lp_f": lp["lp_f"], "diversity": evaluate.diversity(volumes),
                  "seconds_sampling": sampled - started,
                  "level_seconds": torch.load(checkpoint, weights_only=True)["seconds"], "sizes": sizes}))
"""


# Scored in a fresh process, like training, so that its peak memory is its own.
SAMPLE_TRIPLANE = """
import json, sys
from sinshape.runtime import evaluate, load
model, reference, samples = load.load_model(sys.argv[1]), sys.argv[2], int(sys.argv[3])
scores = evaluate.evaluate_model(model, reference, samples)
print(json.dumps({**scores, "level_seconds": model.manifest.raw["training"]["level_seconds"],
                  "sizes": [list(s) for s in model.manifest.sizes]}))
"""

# Runs a command in a fresh wrapper process, whose children are only that
# command, so RUSAGE_CHILDREN's max RSS is the command's own peak.
WRAPPER = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
           "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, file=sys.stderr); sys.exit(r.returncode)")


def run_measured(command: list) -> tuple:
    """Run a command; its output, wall seconds and peak RSS in MB."""
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", WRAPPER, *command], capture_output=True, text=True)
    wall = time.perf_counter() - started
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command[:3])} failed:\n{result.stderr[-2000:]}")
    return result.stdout, wall, float(result.stderr.strip().splitlines()[-1])


def cut_pyramid(path: Path, max_res: int, folder: Path) -> Path:
    """An SSG pyramid keeping only the levels whose longest side is <= max_res."""
    out = folder / f"{path.stem}_max{max_res}.h5"
    with h5py.File(path) as source, h5py.File(out, "w") as target:
        grids = [source[f"scale{i}"][()] for i in range(int(source.attrs["n_scales"]))]
        kept = [g for g in grids if max(g.shape) <= max_res]
        target.attrs["n_scales"] = len(kept)
        for i, grid in enumerate(kept):
            target.create_dataset(f"scale{i}", data=grid)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", type=Path)
    parser.add_argument("--res", type=int, default=64, help="finest resolution for mesh inputs")
    parser.add_argument("--max-res", type=int, default=72, help="finest level kept of .h5 inputs")
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--generators", nargs="+", default=["triplane", "voxel"])
    parser.add_argument("--work", type=Path, default=None, help="where models are kept (default: a temp folder)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    work = args.work or Path(tempfile.mkdtemp(prefix="sinshape-quality-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    print("| shape | generator | grid | train min | s/iter per level | train peak MB | LP-IoU | LP-F | diversity "
          "| sample s/shape | sample peak MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for source in args.inputs:
        data = cut_pyramid(source, args.max_res, work) if source.suffix == ".h5" else source
        for generator in args.generators:
            model = work / f"{data.stem}_{generator}{'.onnx' if generator == 'triplane' else '.pt'}"
            _, train_wall, train_mb = run_measured([
                SINRUN, "train", str(data), "-o", str(model), "--res", str(args.res), "--iters", str(args.iters),
                "--generator", generator, "--quiet"])
            script = SAMPLE_TRIPLANE if generator == "triplane" else SAMPLE_VOXEL
            output, _, sample_mb = run_measured([sys.executable, "-c", script, str(model), str(data), str(args.samples)])
            scores = json.loads(output.strip().splitlines()[-1])
            level_seconds, sizes = scores["level_seconds"], scores["sizes"]
            row = {
                "shape": source.name, "generator": generator, "grid": "x".join(map(str, sizes[-1])),
                "levels": len(sizes), "iters": args.iters, "train_minutes": train_wall / 60,
                "seconds_per_iteration": [s / args.iters for s in level_seconds], "train_peak_mb": train_mb,
                "lp_iou": scores["lp_iou"], "lp_f": scores["lp_f"], "diversity": scores["diversity"],
                "sample_seconds": scores["seconds_sampling"] / args.samples, "sample_peak_mb": sample_mb,
            }
            rows.append(row)
            per_level = " / ".join(f"{s:.2f}" for s in row["seconds_per_iteration"])
            print(f"| {row['shape']} | {generator} | {row['grid']} | {row['train_minutes']:.1f} | {per_level} | "
                  f"{row['train_peak_mb']:.0f} | {row['lp_iou']:.3f} | {row['lp_f']:.3f} | {row['diversity']:.3f} | "
                  f"{row['sample_seconds']:.3f} | {row['sample_peak_mb']:.0f} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
