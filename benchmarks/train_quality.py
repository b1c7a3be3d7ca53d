"""Training quality per budget: train, sample 100, score.

    python benchmarks/train_quality.py --minutes 10 20 40                  # the default trainer
    python benchmarks/train_quality.py --minutes 10 20 40 --preset paper   # the paper's exact method
    python benchmarks/train_quality.py --minutes 10 --seeds 0 1 --pyramid NaturalArch_r128s7.h5
    python benchmarks/train_quality.py --iters 150 --seeds 0 1 --label box32 -- --box 32
    python benchmarks/train_quality.py --minutes 40 --sinrun OTHER/.venv/bin/sinrun --label before
    python benchmarks/train_quality.py --minutes 10 --mesh towerruins.obj --res 128

The example is an SSG .h5 pyramid (--pyramid), by default the procedural
acropolis voxelised at the six level sizes of one of the paper's res-128
pyramids (31x15x15 .. 128x36x60), or a mesh voxelised as `sinrun train`
does (--mesh, --res), written once so that any sinshape version (--sinrun)
trains on exactly the same grids. Each run trains in a fresh
process (`sinrun train PYRAMID --preset P --minutes M` or `--iters N`),
then `sinrun eval` scores 100 samples against the pyramid's finest level
(LP-IoU, LP-F, diversity). Arguments after `--` go to `sinrun train`. One
JSON line per run goes to --results. Runs are one after another: a run
beside other work gets fewer iterations for its minutes.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError

# The level sizes of one of the paper's res-128 pyramids.
PAPER_SIZES = [(31, 15, 15), (41, 15, 19), (54, 16, 26), (72, 20, 34), (96, 28, 44), (128, 36, 60)]


def write_pyramid(path: Path, levels: list) -> Path:
    """Grids (coarsest first) as an SSG .h5 pyramid, through a temporary file."""
    import h5py

    tmp = path.with_name(path.name + ".part")
    with h5py.File(tmp, "w") as f:
        f.attrs["n_scales"] = len(levels)
        for i, level in enumerate(levels):
            f[f"scale{i}"] = level
    tmp.rename(path)
    return path


def acropolis_pyramid(path: Path) -> Path:
    """The acropolis voxelised at each of PAPER_SIZES (its box fills every grid)."""
    from sinshape.prep import shapes, voxelize

    if path.exists():
        return path
    mesh = shapes.make_shape("acropolis")
    low, high = mesh.bounds
    return write_pyramid(path, [voxelize.voxelize(mesh, low, (high - low) / np.array(size), size)
                                for size in PAPER_SIZES])


def mesh_pyramid(mesh: Path, res: int, path: Path) -> Path:
    """A mesh voxelised as `sinrun train MESH --res RES` does, written once so
    that every run trains on exactly the same grids."""
    from sinshape.prep.pyramid import pyramid_from_mesh

    if path.exists():
        return path
    return write_pyramid(path, pyramid_from_mesh(mesh, res).levels)


def model_training(sinrun: str, model: Path) -> tuple:
    """Iterations and learning rate per level as trained (rates None from
    versions that did not record them), from the model's manifest (read with
    the sinrun that wrote it, whose Python has onnx)."""
    script = ("import json, sys, onnx; m = json.loads({p.key: p.value for p in "
              "onnx.load(sys.argv[1]).metadata_props}['sinshape.manifest']); "
              "t = m['training']; n = t['iterations_per_level']; "
              "print(json.dumps([n if isinstance(n, list) else [n] * len(m['levels']), t.get('learning_rates')]))")
    python = Path(sinrun).with_name("python")
    return json.loads(subprocess.run([str(python), "-c", script, str(model)], check=True, capture_output=True,
                                     text=True).stdout)


def rate_range(rates) -> str:
    """The levels' learning rates as one figure or a range ("?" for models that predate them)."""
    if not rates:
        return "?"
    low, high = f"{min(rates):.1e}", f"{max(rates):.1e}"
    return low if low == high else f"{low} to {high}"


def run(command: list) -> float:
    """Seconds the command took; if it fails, its own one-line error (on
    stderr) is the last word and this script exits with its status."""
    started = time.perf_counter()
    code = subprocess.run(command, stdout=subprocess.DEVNULL).returncode
    if code:
        sys.exit(code)
    return time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iters", type=int, nargs="*", default=[], help="iterations per level, one run each")
    parser.add_argument("--minutes", type=float, nargs="*", default=[], help="time budgets, one run each")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--preset", default="default", help="the sinrun train preset (default, paper)")
    parser.add_argument("--pyramid", type=Path, default=None, help="an SSG .h5 pyramid (default: the acropolis "
                        "at the paper's level sizes)")
    parser.add_argument("--mesh", type=Path, default=None, help="a mesh instead: voxelised at --res as sinrun "
                        "train does, into WORK/NAME_rRES.h5")
    parser.add_argument("--res", type=int, default=128, help="with --mesh: the finest level's longest side")
    parser.add_argument("--sinrun", default=str(Path(sys.executable).with_name("sinrun")))
    parser.add_argument("--label", default=None, help="default: the preset's name")
    parser.add_argument("--work", type=Path, default=Path("train_quality"))
    parser.add_argument("--results", type=Path, default=None, help="default: WORK/results.jsonl")
    parser.add_argument("train_args", nargs="*", help="passed to sinrun train (after --)")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    results = args.results or args.work / "results.jsonl"
    if args.mesh:
        try:
            pyramid = mesh_pyramid(args.mesh, args.res, args.work / f"{args.mesh.stem}_r{args.res}.h5")
        except InputError as error:
            sys.exit(f"Error: {error}")
    else:
        pyramid = args.pyramid or acropolis_pyramid(args.work / "acropolis_paper_sizes.h5")
    label = args.label or args.preset

    budgets = [("--iters", str(n)) for n in args.iters] + [("--minutes", str(m)) for m in args.minutes]
    print("| run | shape | seed | budget | training wall | iterations per level | learning rate "
          "| LP-IoU | LP-F | diversity |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for flag, value in budgets:
        for seed in args.seeds:
            name = f"{label}_{pyramid.stem}_{flag.strip('-')}{value}_seed{seed}"
            model, scores = args.work / f"{name}.onnx", args.work / f"{name}.json"
            wall = run([args.sinrun, "train", str(pyramid), "-o", str(model), "--preset", args.preset, flag, value,
                        "--seed", str(seed), "--quiet", *args.train_args])
            run([args.sinrun, "eval", str(model), "--reference", str(pyramid), "-n", "100",
                 "--json", str(scores)])
            summary = json.loads(scores.read_text())
            iterations, rates = model_training(args.sinrun, model)
            row = {"label": label, "shape": pyramid.stem, "seed": seed, "iterations_per_level": iterations,
                   "learning_rates": rates, flag.strip("-"): float(value), "train_args": args.train_args,
                   "wall_seconds": round(wall, 1), **{k: summary[k] for k in ("lp_iou", "lp_f", "diversity")}}
            with open(results, "a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"| {label} | {pyramid.stem} | {seed} | {flag} {value} | {wall / 60:.1f} min | "
                  f"{', '.join(map(str, iterations))} | {rate_range(rates)} | {row['lp_iou']:.3f} "
                  f"| {row['lp_f']:.3f} | {row['diversity']:.3f} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
