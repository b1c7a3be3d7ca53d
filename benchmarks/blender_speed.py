"""The Blender extension against the runtime alone, side by side in one run.

    python benchmarks/blender_speed.py [--repeats 5] [--big-repeats 3] [--variations 20] [--big-variations 6]
                                       [--tables same speed variations responsiveness]

Needs bpy (pip install 'sinshape[blender]'); runs headless, in background
mode, where each operator finishes before it returns. Prints four tables:

1. The same shape as the command line: each object's mesh against the .ply
   `sinrun sample` writes for the same settings (write.write_request, what
   the command calls): vertex and face counts, the largest difference of a
   vertex in the model's frame. The shipped models at scale 1 and 4, a kept
   box and a layout edited by moving cubes.
2. Regenerating an object (settings -> request -> make -> extract -> the
   turn to Z up, its edges -> the bpy mesh) against the runtime's make +
   extract with the model loaded, alternated, the best of --repeats (the
   run least disturbed by other work), in wall and in CPU seconds (this
   process's threads: what the work costs, whatever else runs): towerruins
   at scale 1 and 8, and the budget 1.2 x runtime + 50 ms.
3. --variations seeds of towerruins at scale 1, and --big-variations at
   scale 4: the Variations operator (many's worker processes, objects made)
   against `runtime.many.sample_many` writing .ply files with a worker per
   core and with one, and against a thread per core in this process.
4. Responsiveness: while a scale-8 sample is made on the add-on's worker
   thread, the main thread runs a 10 ms timer loop that, as Blender's event
   loop runs bpy.app.timers, calls the add-on's timer function; the longest
   gap between ticks while the sample is computed, and the time the main
   thread spends putting the finished mesh into Blender (which only it may);
   beside it the same loop idle, and while the same sample is made in
   another process (the CPU's share without the GIL's). Background mode has
   no event loop of its own: this loop stands in for it.
"""

import argparse
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402

import blender  # noqa: E402
from blender import convert, live, work  # noqa: E402
from sinshape import models  # noqa: E402
from sinshape.runtime import load, many, mesh, write  # noqa: E402
from sinshape.runtime.load import default_threads  # noqa: E402
from sinshape.runtime.request import SampleRequest, make  # noqa: E402


def add(**options):
    bpy.ops.sinshape.add_sample(**options)
    return bpy.context.active_object


def difference(obj, model, request, folder: Path) -> tuple:
    """(same counts, largest vertex difference) of an object's mesh and the command line's .ply."""
    path = folder / "cli.ply"
    write.write_request(model, request, path)
    expected = convert.ply_arrays(path.read_bytes())
    vertices, faces = convert.mesh_arrays(obj.data)
    vertices = convert.to_model(vertices, model.manifest.up)
    same = vertices.shape == expected[0].shape and np.array_equal(faces, expected[1])
    return same, len(vertices), len(faces), float(np.abs(vertices - expected[0]).max()) if same else float("nan")


def equality_table(folder: Path) -> None:
    print("\n### The same shape as the command line\n")
    print("| object | vertices | faces | counts and faces equal | largest vertex difference |")
    print("|---|---|---|---|---|")
    rows = []
    for name in sorted(models.available()):
        for scale in (1, 4):
            obj = add(model=name, seed=3, scale=scale)
            rows.append((f"{name}, seed 3, scale {scale}", obj))
    obj = add(model="towerruins", seed=7)
    bpy.ops.sinshape.keep_box_add()
    rows.append((f"towerruins seed 7 keeping `{obj.sinshape.keep_part.split(':')[0]}:...` (a keep box)", obj))
    obj = add(model="towerruins", seed=3)
    bpy.ops.sinshape.layout_show()
    cubes = obj.sinshape.layout_object
    vertices = convert.mesh_vertices(cubes.data)
    moved = vertices[:, 0] > np.median(vertices[:, 0])  # cubes past the middle along x, moved a cell along y
    vertices[moved, 1] += np.ptp(vertices[:8, 1])
    cubes.data.vertices.foreach_set("co", vertices.ravel())
    bpy.context.view_layer.objects.active = obj
    bpy.ops.sinshape.layout_apply()
    rows.append(("towerruins seed 3, half its layout's cubes moved a cell", obj))
    for label, obj in rows:
        model = live.load_model(obj.sinshape)
        same, n, f, largest = difference(obj, model, live.request_of(obj, model), folder)
        print(f"| {label} | {n} | {f} | {'yes' if same else 'NO'} | {largest:.1e} |", flush=True)


def timed(function) -> float:
    started = time.perf_counter()
    function()
    return time.perf_counter() - started


def costs(function) -> tuple:
    """(wall seconds, CPU seconds of this process's threads): the CPU time
    is what the work costs, whatever else the machine runs."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def speed_table(repeats: int, big_repeats: int) -> None:
    print("\n### Regenerating an object, towerruins (seconds, the best of the runs)\n")
    print("| scale | | runtime: make + extract | the add-on: regenerate | ratio | budget 1.2 x + 50 ms | within |")
    print("|---|---|---|---|---|---|---|")
    model = load.load_model(models.find("towerruins"))
    for scale, runs in ((1, repeats), (8, big_repeats)):
        obj = add(model="towerruins", seed=3, scale=scale)
        request = live.request_of(obj, model)
        alone, addon = [], []
        for _ in range(runs):  # alternated, so that a busy moment falls on both
            alone.append(costs(lambda: mesh.extract(model, make(model, request), **request.mesh_options())))
            addon.append(costs(lambda: live.regenerate(obj, force=True)))
        for k, kind in enumerate(("wall", "CPU")):
            a, b = min(t[k] for t in alone), min(t[k] for t in addon)
            budget = 1.2 * a + 0.05
            print(f"| {scale} | {kind} | {a:.3f} | {b:.3f} | {b / a:.2f} | {budget:.3f} | "
                  f"{'yes' if b <= budget else 'NO'} |", flush=True)


def many_of_this_script(*args, **options):
    """sample_many, its workers not importing this script (and bpy) again: live.plain_main."""
    with live.plain_main():
        return many.sample_many(*args, **options)


def variations_table(count: int, scale: float, folder: Path) -> None:
    cores = default_threads()
    print(f"\n### {count} variations of towerruins at scale {scale:g} ({cores} cores; seconds, start-up included)\n")
    print("| how | seconds | seeds/s |")
    print("|---|---|---|")
    path = models.find("towerruins")
    obj = add(model="towerruins", seed=0, scale=scale)
    model = live.load_model(obj.sinshape)
    request = SampleRequest(scale=scale)
    seeds = range(1, count + 1)
    runs = [
        ("the add-on's Variations (many's worker processes, objects made)",
         lambda: bpy.ops.sinshape.variations(count=count, first_seed=1, arrange="GRID")),
        ("runtime alone: many.sample_many to .ply files, one worker per core",
         lambda: many_of_this_script(path, seeds, folder / f"many{scale}" / "{seed}.ply", request=request)),
        ("runtime alone: sample_many, one worker",
         lambda: many.sample_many(path, seeds, folder / f"one{scale}" / "{seed}.ply", workers=1, request=request)),
        (f"{cores} threads of this process, make + extract each",
         lambda: list(ThreadPoolExecutor(cores).map(
             lambda seed: live.make_mesh(model, request.with_seed(seed)), seeds))),
    ]
    for label, run in runs:
        (folder / f"many{scale}").mkdir(exist_ok=True)
        (folder / f"one{scale}").mkdir(exist_ok=True)
        seconds = timed(run)
        print(f"| {label} | {seconds:.2f} | {count / seconds:.2f} |", flush=True)


ELSEWHERE = """
import sys
sys.path.insert(0, {root!r})
from blender import live
from sinshape import models
from sinshape.runtime.load import load_model
from sinshape.runtime.request import SampleRequest
live.make_mesh(load_model(models.find("towerruins")), SampleRequest(3, scale={scale}))
"""


def responsiveness_table(scale: float) -> None:
    print(f"\n### The main thread while towerruins at scale {scale:g} is made (milliseconds)\n")
    print("| while | ticks | longest gap between 10 ms ticks | 99th percentile | putting the mesh into Blender |")
    print("|---|---|---|---|---|")
    obj = add(model="towerruins", seed=3)
    with live.suspended():
        obj.sinshape.scale = scale
    model = live.load_model(obj.sinshape)
    request = live.request_of(obj, model)
    worker = work.Worker(synchronous=False)
    applying = []

    def apply(arrays):
        applying.append(timed(lambda: live.set_mesh(obj, arrays, request)))

    def ticks(until) -> list:
        gaps, last = [], time.perf_counter()
        while not until():
            time.sleep(0.01)
            gaps.append(time.perf_counter() - last)
            worker.poll()
            last = time.perf_counter()  # the timer function's own time (putting the mesh in) counts apart
        return gaps

    started = time.perf_counter()
    idle = ticks(lambda: time.perf_counter() - started > 2)
    job = work.Job(obj.name, "scale 8", lambda j: j.deliver(live.make_mesh(model, request, j.progress)), apply,
                   print)
    worker.submit(job)
    busy = ticks(lambda: not worker.busy())
    # The same work in another process: what the CPU alone costs the main thread, without the GIL.
    other = subprocess.Popen([sys.executable, "-c", ELSEWHERE.format(root=str(ROOT), scale=scale)])
    elsewhere = ticks(lambda: other.poll() is not None)
    rows = (("idle", idle, None), ("making the sample on the add-on's worker thread", busy, applying[0]),
            ("the same sample made in another process", elsewhere, None))
    for label, gaps, put in rows:
        gaps = np.array(gaps) * 1000
        print(f"| {label} | {len(gaps)} | {gaps.max():.0f} | {np.percentile(gaps, 99):.0f} | "
              f"{'-' if put is None else f'{put * 1000:.0f} ({len(obj.data.vertices)} vertices)'} |", flush=True)


TABLES = ["same", "speed", "variations", "responsiveness"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--big-repeats", type=int, default=3)
    parser.add_argument("--variations", type=int, default=20)
    parser.add_argument("--big-variations", type=int, default=6, help="variations at scale 4")
    parser.add_argument("--tables", nargs="+", choices=TABLES, default=TABLES, help="which tables (default: all)")
    args = parser.parse_args()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender.register()
    print(f"bpy {bpy.app.version_string} (background), {default_threads()} cores, numpy {np.__version__}")
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        if "same" in args.tables:
            equality_table(folder)
        if "speed" in args.tables:
            speed_table(args.repeats, args.big_repeats)
        if "variations" in args.tables:
            variations_table(args.variations, 1, folder)
            variations_table(args.big_variations, 4, folder)
        if "responsiveness" in args.tables:
            responsiveness_table(8)


if __name__ == "__main__":
    main()
