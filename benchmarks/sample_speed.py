"""Sampling speed and memory: the runtime against the straightforward way.

    python benchmarks/sample_speed.py MODEL.onnx [--scales 1 4 8] [--seed 3]

MODEL.onnx needs its training checkpoint MODEL.ckpt.pt beside it: the
straightforward way samples with the trainer's torch model, as the authors'
code does: tri-planes from torch, then grid_sample of every point of the fine
grid in chunks of 128^3 through the whole MLP, a dense occupancy volume, and
marching cubes on all of it. The runtime generates with onnxruntime and
meshes only the blocks its exact band search keeps. Each measurement runs in
a fresh process, so peak memory (max RSS) is its own. The same noise feeds
both, and the script checks that their meshes agree.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RUNTIME = """
import json, resource, sys, time
import numpy as np
from sinshape import runtime
model_path, seed, scale, threads = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
model = runtime.load_model(model_path, threads=threads)
runtime.extract(model, runtime.sample(model, seed), 1.0)  # warm-up: sessions allocate on first use
started = time.perf_counter()
triplane = runtime.sample(model, seed)
generated = time.perf_counter()
mesh = runtime.extract(model, triplane, scale, frame="model")
done = time.perf_counter()
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before the checks below, which are big
print(json.dumps({"generate": generated - started, "mesh": done - generated, "faces": len(mesh.faces),
                  "area": float(mesh.area), "peak_mb": peak_mb}))
"""

STRAIGHTFORWARD = """
import json, resource, sys, time
import numpy as np, torch, trimesh
from skimage import measure
from sinshape.runtime import generate, load
from sinshape.trainer import checkpoint
model_path, seed, scale, threads = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
torch.set_num_threads(threads)
generator, sizes, amps = checkpoint.load_generator(checkpoint.default_checkpoint_path(__import__("pathlib").Path(model_path)))
sample = generate.draw_noise(seed, sizes, generator.channels)
z0 = torch.from_numpy(sample.z0)[None, None]
noises = [None] + [[amps[i] * torch.from_numpy(p)[None] for p in planes] for i, planes in enumerate(sample.planes) if i]
started = time.perf_counter()
with torch.no_grad():
    planes = generator.planes(z0, noises, sizes)
    generated = time.perf_counter()
    shape = [max(2, round(n * scale)) for n in sizes[-1]]
    axes = [torch.linspace(-1, 1, n) for n in shape]
    volume = np.empty(shape, np.float32)
    chunk = 128 ** 3  # as the authors' code
    flat = volume.reshape(-1)
    total = flat.size
    for start in range(0, total, chunk):
        index = torch.arange(start, min(start + chunk, total))
        i, rest = index // (shape[1] * shape[2]), index % (shape[1] * shape[2])
        coords = torch.stack([axes[0][i], axes[1][rest // shape[2]], axes[2][rest % shape[2]]], dim=1)
        flat[start:start + len(index)] = generator.decoder.points(planes, coords).numpy()
queried = time.perf_counter()
v, f, _, _ = measure.marching_cubes(np.pad(volume, 1), 0.5)
steps = np.array([(n - 1) / (m - 1) for n, m in zip(sizes[-1], shape)])
mesh = trimesh.Trimesh((v - 1) * steps, f)  # model coordinates, as the runtime's
done = time.perf_counter()
peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"generate": generated - started, "query": queried - generated, "mesh": done - queried,
                  "faces": len(mesh.faces), "area": float(mesh.area), "peak_mb": peak_mb}))
"""

GFLOPS = """
import json, sys, time
import numpy as np, onnxruntime as ort
from onnx import TensorProto, helper
from sinshape import runtime
from sinshape.runtime import generate
model_path, seed, threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
model = runtime.load_model(model_path, threads=threads)
m = model.manifest
runtime.sample(model, seed)
runs = 5
started = time.perf_counter()
for _ in range(runs):
    runtime.sample(model, seed)
seconds = (time.perf_counter() - started) / runs
# FLOPs of the level convolutions: per plane 4 convs of 2 * C * C * 9 per cell.
cells = sum(h * w for size in m.sizes for h, w in generate.plane_sizes(size))
flops = cells * 4 * 2 * m.channels * m.channels * 9
# A plain float32 matrix product in onnxruntime, same threads: the machine's practical limit.
n = 1024
graph = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["c"])], "mm",
                          [helper.make_tensor_value_info(x, TensorProto.FLOAT, [n, n]) for x in "ab"],
                          [helper.make_tensor_value_info("c", TensorProto.FLOAT, [n, n])])
options = ort.SessionOptions(); options.intra_op_num_threads = threads
session = ort.InferenceSession(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)],
                               ir_version=8).SerializeToString(), options, providers=["CPUExecutionProvider"])
a = np.random.default_rng(0).random((n, n), dtype=np.float32)
session.run(None, {"a": a, "b": a})
started = time.perf_counter()
for _ in range(10):
    session.run(None, {"a": a, "b": a})
matmul = 2 * n ** 3 * 10 / (time.perf_counter() - started) / 1e9
print(json.dumps({"generate_s": seconds, "generate_gflops": flops / seconds / 1e9, "matmul_gflops": matmul}))
"""


def run(code: str, *args) -> dict:
    result = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"measurement failed:\n{result.stderr}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("--scales", type=float, nargs="+", default=[1, 4, 8])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--skip-straightforward-above", type=float, default=4,
                        help="the dense way at scale 8 of a res-128 model needs a 4 GB volume; skip it above this")
    args = parser.parse_args()

    print("| scale | runtime: generate + mesh (s) | peak MB | straightforward (s) | peak MB | speed-up | faces (runtime / straightforward) |")
    print("|---|---|---|---|---|---|---|")
    for scale in args.scales:
        ours = run(RUNTIME, args.model, args.seed, scale, args.threads)
        ours_s = ours["generate"] + ours["mesh"]
        if scale <= args.skip_straightforward_above:
            base = run(STRAIGHTFORWARD, args.model, args.seed, scale, args.threads)
            base_s = base["generate"] + base["query"] + base["mesh"]
            cells = (f"{base_s:.2f} | {base['peak_mb']:.0f} | {base_s / ours_s:.1f}x | "
                     f"{ours['faces']} / {base['faces']}")
            assert abs(ours["area"] - base["area"]) < 0.01 * base["area"], "the two meshes differ"
        else:
            cells = f"not run | (dense grid alone: {4 * np.prod([round(n * scale) for n in sizes(args.model)]) / 2**30:.1f} GiB) | | {ours['faces']}"
        print(f"| {scale:g} | {ours['generate']:.2f} + {ours['mesh']:.2f} = {ours_s:.2f} | {ours['peak_mb']:.0f} | {cells} |",
              flush=True)

    sinrun = str(Path(sys.executable).with_name("sinrun"))
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        subprocess.run([sinrun, "sample", args.model, "--seed", str(args.seed), "-o", str(Path(folder) / "s.ply")],
                       check=True, capture_output=True)
    print(f"\n`sinrun sample MODEL --seed {args.seed}` (scale 1) wall time, start-up included: "
          f"{time.perf_counter() - started:.2f} s")
    flops = run(GFLOPS, args.model, args.seed, args.threads)
    print(f"generator: {flops['generate_s']:.3f} s per sample, {flops['generate_gflops']:.1f} GFLOP/s in its "
          f"convolutions; a plain {1024}^2 matmul in onnxruntime: {flops['matmul_gflops']:.1f} GFLOP/s")


def sizes(model_path: str) -> list:
    from sinshape.runtime import load

    return load.load_model(model_path, threads=1).manifest.sizes[-1]


if __name__ == "__main__":
    main()
