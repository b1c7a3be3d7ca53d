"""A seed's shape with other numpy versions and BLAS kernels, side by side.

    python benchmarks/same_everywhere.py [--python OTHER_PYTHON ...] [--kernels Prescott Haswell ...]

numpy brings its own OpenBLAS (1.26: 0.3.23, 2.x: 0.3.27 and newer), which
picks its kernels by the CPU it finds and sums a matrix product in an order
of its own; OPENBLAS_CORETYPE picks them by name. Each environment (this
Python, and each --python, say a venv with Blender's numpy 1.26) runs under
each kernel family in a fresh process and makes, for each shipped model,
seed 3's tri-plane as it is, at size 1.5,1,0.8, grown 1.5,1,1, with a kept
box and from its layout with half its cells removed, and its mesh at scale
2. Printed against the first run: whether each tri-plane is the same bytes,
whether the meshes have the same faces, and the largest difference of a
vertex, in voxels.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from sinshape import models
    from sinshape.runtime import extract, layout, load_model, request
    out = {}
    for name in sys.argv[2:]:
        model = load_model(models.find(name))
        asked = {"plain": request.SampleRequest(seed=3), "sized": request.SampleRequest(seed=3, size=(1.5, 1, 0.8)),
                 "grown": request.SampleRequest(seed=3, grow=(1.5, 1, 1)),
                 "kept": request.SampleRequest(seed=3, keep="5:0%,0%,0%:50%,100%,100%")}
        for what, made in asked.items():
            out[f"{name}/{what}"] = np.concatenate([p.ravel() for p in request.make(model, made).planes])
        grid = layout.layout(model, 3)
        grid[: grid.shape[0] // 2] = False
        out[f"{name}/laid out"] = np.concatenate([p.ravel() for p in layout.from_layout(model, 3, grid).planes])
        mesh = extract(model, request.make(model, asked["plain"]), 2, frame="model")  # in voxels
        out[f"{name}/mesh vertices"], out[f"{name}/mesh faces"] = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    out["numpy"] = np.array(np.__version__)
    np.savez(sys.argv[1], **out)
""")


def run(python: str, kernels: str | None, names: list, folder: Path) -> dict:
    out = folder / f"{len(list(folder.iterdir()))}.npz"
    env = {**os.environ, **({"OPENBLAS_CORETYPE": kernels} if kernels else {})}
    done = subprocess.run([python, "-c", CHILD, str(out), *names], capture_output=True, text=True, env=env,
                          cwd=ROOT)
    if done.returncode:
        raise SystemExit(done.stderr[-2000:])
    return dict(np.load(out))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python", nargs="*", default=[], help="other interpreters (another numpy)")
    parser.add_argument("--kernels", nargs="*", default=["", "Prescott", "Haswell"],
                        help="OPENBLAS_CORETYPE values ('' for the CPU's own)")
    parser.add_argument("--models", nargs="+", default=["towerruins", "terrain", "acropolis"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        runs = [(python, kernels, run(python, kernels or None, args.models, Path(folder)))
                for python in [sys.executable, *args.python] for kernels in args.kernels]
    (_, _, first), label = runs[0], lambda python, kernels, made: f"numpy {made['numpy']}, {kernels or 'own'} kernels"
    planes = sorted({key.split("/")[1] for key in first if "/" in key and "mesh" not in key})
    print(f"Against {label(*runs[0])}:\n")
    print(f"| run | {' | '.join(f'{p} planes' for p in planes)} | mesh faces | largest vertex difference (voxels) |")
    print("|---|" + "---|" * (len(planes) + 2))
    for python, kernels, made in runs[1:]:
        same = [all(np.array_equal(first[f"{m}/{p}"], made[f"{m}/{p}"]) for m in args.models) for p in planes]
        faces = all(np.array_equal(first[f"{m}/mesh faces"], made[f"{m}/mesh faces"]) for m in args.models)
        worst = max(np.abs(first[f"{m}/mesh vertices"] - made[f"{m}/mesh vertices"]).max() if faces else np.inf
                    for m in args.models)
        print(f"| {label(python, kernels, made)} | {' | '.join('same bytes' if s else 'differ' for s in same)} | "
              f"{'same' if faces else 'differ'} | {worst:.2g} |")


if __name__ == "__main__":
    main()
