"""Many shapes and huge shapes: seeds per second, threads, world-size terrain.

    python benchmarks/many_speed.py [--big-model MODEL --big-scale 8] [--sizes 1 2 4 8]

Prints three tables, every figure measured in this run, each cell a fresh
`sinrun sample` process (wall time from start to exit, start-up included;
peak memory is the process's max RSS, Ray's own processes not counted):

1. `--seeds 0-39 --scale 1` of the shipped terrain: 1 worker, one worker
   per core, and Ray on this machine with as many CPUs (its overhead:
   starting Ray, its actors, moving bytes through it).
2. One large sample (`--big-model`, `--big-scale`) with `--threads 1` and
   with all cores, written as a streamed .ply; then meshing at
   `--alternated-scale` with 1 thread and all, alternated in one process.
3. The terrain at `--size NxN,1` for each N of --sizes at `--scale 2`:
   seconds, peak memory, faces, file size (a streamed .ply).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Runs one command and reports its wall time and its peak memory (the
# maximum RSS of the processes it waited for: the command alone).
MEASURE = """
import json, resource, subprocess, sys, time
started = time.perf_counter()
code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode
print(json.dumps({"seconds": time.perf_counter() - started, "code": code,
                  "peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
"""


def measure(*args) -> dict:
    sinrun = str(Path(sys.executable).with_name("sinrun"))
    out = subprocess.run([sys.executable, "-c", MEASURE, sinrun, *map(str, args)], capture_output=True, text=True)
    result = json.loads(out.stdout)
    if result["code"] != 0:
        raise SystemExit(f"sinrun {' '.join(map(str, args))} failed: {out.stderr.strip()}")
    return result


def seeds_table(folder: Path, cores: int, seeds: int) -> None:
    print(f"\n### {seeds} seeds at scale 1, shipped terrain ({cores} cores)\n")
    print("| engine | workers | seconds | seeds/s |")
    print("|---|---|---|---|")
    runs = [("local", 1, []), ("local", cores, []), ("ray (local)", cores, ["--engine", "ray"])]
    for k, (name, workers, extra) in enumerate(runs):
        (folder / f"seeds{k}").mkdir()
        r = measure("sample", "terrain", "--seeds", f"0-{seeds - 1}", "-o", folder / f"seeds{k}" / "{seed}.ply",
                    "--workers", workers, *extra)
        print(f"| {name} | {workers} | {r['seconds']:.1f} | {seeds / r['seconds']:.2f} |", flush=True)


def big_table(folder: Path, model: str, scale: float, cores: int) -> None:
    print(f"\n### {model} at --scale {scale:g}, seed 3, streamed .ply\n")
    print("| threads | seconds | peak memory | faces |")
    print("|---|---|---|---|")
    for threads in sorted({1, cores}):
        out = folder / f"big{threads}.ply"
        r = measure("sample", model, "--seed", 3, "--scale", scale, "--threads", threads, "-o", out)
        print(f"| {threads} | {r['seconds']:.1f} | {r['peak_mb']:.0f} MB | {ply_faces(out):,} |", flush=True)
        out.unlink()


# Meshing with 1 thread and with all, alternated in one process: a ratio that
# other jobs on a shared machine disturb less than fresh processes' seconds.
ALTERNATED = """
import json, sys, time
from sinshape import models, runtime
from sinshape.runtime import mesh
model = runtime.load_model(models.find(sys.argv[1]))
triplane = runtime.sample(model, 3)
for threads in [1, int(sys.argv[3])] * 2:
    started = time.perf_counter()
    mesh.band_mesh(model, triplane, float(sys.argv[2]), threads=threads)
    print(json.dumps([threads, time.perf_counter() - started]), flush=True)
"""


def alternated_table(model: str, scale: float, cores: int) -> None:
    print(f"\n### meshing {model} at --scale {scale:g} in one process, threads alternated\n")
    print("| round | 1 thread | " + f"{cores} threads | speed-up |")
    print("|---|---|---|---|")
    out = subprocess.run([sys.executable, "-c", ALTERNATED, model, str(scale), str(cores)],
                         capture_output=True, text=True, check=True)
    seconds = [json.loads(line)[1] for line in out.stdout.splitlines()]
    for k in range(0, len(seconds), 2):
        print(f"| {k // 2 + 1} | {seconds[k]:.1f} s | {seconds[k + 1]:.1f} s | {seconds[k] / seconds[k + 1]:.2f}x |")


def terrain_table(folder: Path, sizes: list) -> None:
    print("\n### terrain at --size N,N,1 --scale 2, seed 3, streamed .ply\n")
    print("| size | area factor | seconds | peak memory | faces | file |")
    print("|---|---|---|---|---|---|")
    for n in sizes:
        out = folder / f"terrain{n}.ply"
        r = measure("sample", "terrain", "--seed", 3, "--size", f"{n},{n},1", "--scale", 2, "-o", out)
        print(f"| {n}x{n} | {n * n} | {r['seconds']:.1f} | {r['peak_mb']:.0f} MB | {ply_faces(out):,} | "
              f"{out.stat().st_size / 2**20:.0f} MB |", flush=True)
        out.unlink()


def ply_faces(path: Path) -> int:
    """The face count in a PLY header."""
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(b"element face"):
                return int(line.split()[-1])
            if line.startswith(b"end_header"):
                return 0


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=40, help="seeds in the first table")
    parser.add_argument("--big-model", default="towerruins", help="model of the second table")
    parser.add_argument("--big-scale", type=float, default=16.0, help="its --scale")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8], help="terrain sizes N (N,N,1)")
    parser.add_argument("--alternated-scale", type=float, default=8.0,
                        help="scale of --big-model for the alternated-threads table")
    parser.add_argument("--skip", nargs="*", default=[], choices=["seeds", "big", "alternated", "terrain"])
    args = parser.parse_args()
    cores = len(os.sched_getaffinity(0))
    print(f"{cores} cores, {time.strftime('%Y-%m-%d %H:%M')}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if "seeds" not in args.skip:
            seeds_table(folder, cores, args.seeds)
        if "big" not in args.skip:
            big_table(folder, args.big_model, args.big_scale, cores)
        if "alternated" not in args.skip:
            alternated_table(args.big_model, args.alternated_scale, cores)
        if "terrain" not in args.skip:
            terrain_table(folder, args.sizes)


if __name__ == "__main__":
    main()
