"""The memory a sample is refused by against what it takes, side by side.

    python benchmarks/memory_estimate.py [--cases NAME ...] [--blender]

Each case runs in a fresh process: the model is loaded, then the sample is
written as `sinrun sample` writes it (write.write_request), while a thread
reads the process's resident memory every 2 ms. Printed per case: what
request.check_memory estimates (the figure a refusal gives), the peak
memory above the loaded model's, their ratio (at least 1 is the aim: a
refusal that comes too late is the failure), the faces estimated
(mesh.estimate_faces, where the output holds a whole mesh) and made, and
the seconds. With --blender (needs bpy), a case also runs as the Blender
extension makes an object (live.make_mesh, then the bpy mesh).
"""

import argparse
import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# name: (model, request fields, output file)
CASES = {
    "towerruins scale 4, .glb": ("towerruins", dict(seed=3, scale=4.0), "s.glb"),
    "towerruins size 4, .ply streamed": ("towerruins", dict(seed=3, size=(4.0, 4.0, 4.0)), "s.ply"),
    "towerruins size 4, .obj": ("towerruins", dict(seed=3, size=(4.0, 4.0, 4.0)), "s.obj"),
    "towerruins size 3, smoothed twice": ("towerruins", dict(seed=3, size=(3.0, 3.0, 3.0), smooth=2), "s.ply"),
    "terrain size 6x6x1 at scale 2, .glb": ("terrain", dict(seed=3, size=(6.0, 6.0, 1.0), scale=2.0), "s.glb"),
    "terrain grown 4x4x1, .glb": ("terrain", dict(seed=3, grow=(4.0, 4.0, 1.0)), "s.glb"),
    "towerruins, a layout at size 2": ("towerruins", dict(seed=3, size=(2.0, 2.0, 2.0), layout="own"), "s.ply"),
}

CHILD = textwrap.dedent("""
    import json, sys, tempfile, threading, time
    from pathlib import Path
    import numpy as np
    sys.path.insert(0, {root!r})
    blender = {blender!r}
    if blender:
        import bpy
        from blender import live
    from sinshape import models
    from sinshape.core import budget
    from sinshape.core.errors import MemoryLimitError
    from sinshape.runtime import layout, load, mesh, request as requests, write

    def request_size(model, request):
        from sinshape.runtime.generate import scaled_sizes
        factors = request.size if request.grow is None else tuple(f * g for f, g in zip(request.size, request.grow))
        return scaled_sizes(model.manifest.sizes, factors)[-1]

    def rss():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096

    name, fields, out = json.loads(sys.argv[1])
    model = load.load_model(models.find(name))
    if fields.get("layout") == "own":
        grid = layout.layout(model, fields["seed"], 0, tuple(fields["size"]))
        grid[: grid.shape[0] // 2] = False
        fields["layout"] = requests.Layout.of(grid)
    request = requests.SampleRequest(**fields)
    # The figure a refusal gives: the check under a limit of 1 byte, which
    # always goes on to estimate the faces (where the output holds a mesh).
    estimated = []
    check = budget.check_memory
    budget.check_memory = lambda needed, what, limit=None: (estimated.append(needed), check(needed, what, limit))[1]
    if blender:
        per_face = max(live.BYTES_PER_FACE, mesh.held_per_face(request.smooth, largest=request.largest))
        made_for = dict(output="mesh", per_face=per_face)
    else:
        made_for = write.made_for(out, request)
    try:
        requests.check_memory(model, request, memory_limit=1, **made_for)
    except MemoryLimitError:
        pass
    budget.check_memory = check
    needed = estimated[-1]
    faces_estimated = mesh.estimate_faces(model, request_size(model, request), request.scale) \
        if made_for["output"] == "mesh" else None
    base = rss()
    peak = [0]
    done = threading.Event()
    def watch():
        while not done.is_set():
            peak[0] = max(peak[0], rss() - base)
            time.sleep(0.002)
    threading.Thread(target=watch, daemon=True).start()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        if blender:
            arrays = live.make_mesh(model, request)
            live.put_mesh(bpy.data.meshes.new("sample"), arrays, True)
            faces = len(arrays[1])
        else:
            path = Path(folder) / out
            write.write_request(model, request, path)
        seconds = time.perf_counter() - started
        time.sleep(0.01)
        done.set()
        if not blender:
            import trimesh
            faces = len(trimesh.load(path, force="mesh", process=False).faces)
    print("RESULT" + json.dumps(dict(needed=needed, peak=peak[0], faces=faces, estimated=faces_estimated,
                                     seconds=seconds)))
""")


def run(name: str, blender: bool) -> dict:
    model, fields, out = CASES[name]
    script = CHILD.format(root=str(ROOT), blender=blender)
    done = subprocess.run([sys.executable, "-c", script, json.dumps([model, fields, out])], capture_output=True,
                          text=True)
    if done.returncode:
        raise SystemExit(f"{name}: {done.stderr[-2000:]}")
    return json.loads(done.stdout.split("RESULT", 1)[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--blender", action="store_true", help="also as the Blender extension makes an object")
    args = parser.parse_args()
    print("| case | made by | estimate (GiB) | peak above the model (GiB) | estimate / peak | faces estimated | "
          "faces made | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.cases:
        for blender in (False, True) if args.blender else (False,):
            r = run(name, blender)
            faces = f"{r['estimated']:,}" if r["estimated"] else "-"
            print(f"| {name} | {'Blender' if blender else 'sinrun sample'} | {r['needed'] / 2**30:.2f} | "
                  f"{r['peak'] / 2**30:.2f} | {r['needed'] / max(r['peak'], 1):.2f} | {faces} | {r['faces']:,} | "
                  f"{r['seconds']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
