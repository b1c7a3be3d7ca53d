"""Training quality per budget on real shapes: train, sample 100, score.

    python benchmarks/train_quality.py                     # the real set, 10 and 30 min, seeds 0 and 1
    python benchmarks/train_quality.py --shapes NaturalArch towerruins --minutes 10 --seeds 0
    python benchmarks/train_quality.py --minutes 10 20 40 --preset paper   # the paper's exact method
    python benchmarks/train_quality.py --iters 150 --seeds 0 1 --label box32 -- --box 32
    python benchmarks/train_quality.py --minutes 40 --sinrun OTHER/.venv/bin/sinrun --label before

By default every run of the real set: the SSG pyramids Canyon, NaturalArch
and SmallTown (DATA/pyramids), the tower ruin mesh voxelised at res 128 as
`sinrun train` does (DATA/meshes/towerruins), and, as one row among them,
the procedural acropolis voxelised at the six level sizes of one of the
paper's res-128 pyramids (31x15x15 .. 128x36x60). Meshes are written once as
.h5 pyramids under WORK, so that any sinshape version (--sinrun) trains on
exactly the same grids; --pyramid or --mesh (with --res) adds a shape of
your own. Each run trains in a fresh process (`sinrun train PYRAMID --preset
P --minutes M` or `--iters N`), then `sinrun eval` scores 100 samples
against the pyramid's finest level (LP-IoU, LP-F, diversity), and the table
shows the iterations each level got. Arguments after `--` go to `sinrun
train`. One JSON line per run goes to --results. Runs are one after another
(a run beside other work gets fewer iterations for its minutes); --jobs N
runs N at once, for --iters runs on a GPU (`-- --device cuda`). The whole
default set is 5 shapes x 2 budgets x 2 seeds: about 7 hours.
"""

import argparse
import itertools
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
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
    """A mesh voxelised as `sinrun train MESH --res RES --no-colour` does,
    written once so that every run trains on exactly the same grids."""
    from sinshape.prep.pyramid import pyramid_from_mesh

    if path.exists():
        return path
    return write_pyramid(path, pyramid_from_mesh(mesh, res, colour=False).levels)  # geometry is measured


REAL_PYRAMIDS = {"Canyon": "Canyon_r128s6.h5", "NaturalArch": "NaturalArch_r128s7.h5",
                 "SmallTown": "SmallTown_r128s6.h5"}
REAL_MESHES = {"towerruins": "towerruins/towerruins.obj"}
SHAPES = [*REAL_PYRAMIDS, *REAL_MESHES, "acropolis"]


def shape_pyramid(name: str, data: Path, work: Path, res: int) -> Path:
    """The .h5 pyramid a shape of the default set trains on."""
    if name in REAL_PYRAMIDS:
        return data / "pyramids" / REAL_PYRAMIDS[name]
    if name in REAL_MESHES:
        return mesh_pyramid(data / "meshes" / REAL_MESHES[name], res, work / f"{name}_r{res}.h5")
    return acropolis_pyramid(work / "acropolis_paper_sizes.h5")


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


class RunFailed(Exception):
    """A sinrun command failed; its own one-line error went to stderr."""


def run(command: list) -> float:
    """Seconds the command took."""
    started = time.perf_counter()
    code = subprocess.run(command, stdout=subprocess.DEVNULL).returncode
    if code:
        raise RunFailed(code)
    return time.perf_counter() - started


def train_and_score(args, label: str, pyramid: Path, flag: str, value: str, seed: int) -> dict:
    """Train one model, score 100 samples; the results' row."""
    name = f"{label}_{pyramid.stem}_{flag.strip('-')}{value}_seed{seed}"
    model, scores = args.work / f"{name}.onnx", args.work / f"{name}.json"
    wall = run([args.sinrun, "train", str(pyramid), "-o", str(model), "--preset", args.preset, flag, value,
                "--seed", str(seed), "--quiet", *args.train_args])
    run([args.sinrun, "eval", str(model), "--reference", str(pyramid), "-n", "100", "--json", str(scores)])
    summary = json.loads(scores.read_text())
    iterations, rates = model_training(args.sinrun, model)
    return {"label": label, "shape": pyramid.stem, "seed": seed, "iterations_per_level": iterations,
            "learning_rates": rates, flag.strip("-"): float(value), "train_args": args.train_args,
            "wall_seconds": round(wall, 1), **{k: summary[k] for k in ("lp_iou", "lp_f", "diversity")}}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iters", type=int, nargs="*", default=[], help="iterations per level, one run each")
    parser.add_argument("--minutes", type=float, nargs="*", default=None,
                        help="time budgets, one run each (default: 10 30, unless --iters is given)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--shapes", nargs="*", choices=SHAPES, default=None,
                        help="shapes of the default set (default: all, unless --pyramid or --mesh is given)")
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data",
                        help="where the real shapes are: DATA/pyramids/*.h5, DATA/meshes/towerruins")
    parser.add_argument("--preset", default="default", help="the sinrun train preset (default, paper)")
    parser.add_argument("--pyramid", type=Path, default=None, help="an SSG .h5 pyramid of your own")
    parser.add_argument("--mesh", type=Path, default=None, help="a mesh of your own: voxelised at --res as "
                        "sinrun train does, into WORK/NAME_rRES.h5")
    parser.add_argument("--res", type=int, default=128, help="meshes' finest level's longest side")
    parser.add_argument("--sinrun", default=str(Path(sys.executable).with_name("sinrun")))
    parser.add_argument("--label", default=None, help="default: the preset's name")
    parser.add_argument("--work", type=Path, default=Path("train_quality"))
    parser.add_argument("--results", type=Path, default=None, help="default: WORK/results.jsonl")
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs at once (default 1: a run beside others gets fewer iterations for its "
                             "minutes; more suits a GPU with --iters)")
    parser.add_argument("train_args", nargs="*", help="passed to sinrun train (after --)")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    results = args.results or args.work / "results.jsonl"
    own = args.pyramid or args.mesh
    shapes = args.shapes if args.shapes is not None else ([] if own else SHAPES)
    try:
        pyramids = [shape_pyramid(name, args.data, args.work, args.res) for name in shapes]
        if args.mesh:
            pyramids.append(mesh_pyramid(args.mesh, args.res, args.work / f"{args.mesh.stem}_r{args.res}.h5"))
    except InputError as error:
        sys.exit(f"Error: {error}")
    pyramids += [args.pyramid] if args.pyramid else []
    missing = [str(p) for p in pyramids if not p.is_file()]
    if missing:
        sys.exit(f"Error: no such file: {', '.join(missing)} (give --data, or choose --shapes)")
    label = args.label or args.preset
    minutes = args.minutes if args.minutes is not None else ([] if args.iters else [10, 30])

    budgets = [("--iters", str(n)) for n in args.iters] + [("--minutes", f"{m:g}") for m in minutes]
    print("| run | shape | seed | budget | training wall | iterations per level | learning rate "
          "| LP-IoU | LP-F | diversity |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    runs = itertools.product(pyramids, budgets, args.seeds)
    with ThreadPoolExecutor(args.jobs) as pool:
        pending = [pool.submit(train_and_score, args, label, pyramid, flag, value, seed)
                   for pyramid, (flag, value), seed in runs]
        try:
            for done in as_completed(pending):
                row = done.result()
                with open(results, "a") as f:
                    f.write(json.dumps(row) + "\n")
                budget = next(f"--{key} {row[key]:g}" for key in ("iters", "minutes") if key in row)
                print(f"| {label} | {row['shape']} | {row['seed']} | {budget} | {row['wall_seconds'] / 60:.1f} min | "
                      f"{', '.join(map(str, row['iterations_per_level']))} | {rate_range(row['learning_rates'])} "
                      f"| {row['lp_iou']:.3f} | {row['lp_f']:.3f} | {row['diversity']:.3f} |", flush=True)
        except RunFailed as failed:  # its error is the last word; runs not started are dropped
            for future in pending:
                future.cancel()
            return failed.args[0]


if __name__ == "__main__":
    sys.exit(main())
