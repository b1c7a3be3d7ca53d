"""Sampling in the browser against the Python runtime, on the same machine.

    python benchmarks/web_speed.py [MODEL] [--scales 1 2] [--seed 3] [--repeats 5]

Exports MODEL (default: the shipped terrain) with `sinrun export-web` into a
temporary folder, serves it on loopback twice, without and with the
cross-origin isolation headers (COOP/COEP), and samples in headless chromium
(the tests' harness, tests/browser.py): WASM on 1 thread, then on as many
threads as the browser reports cores. Each figure is the median of
`--repeats` samples after one warm-up: sample (the level chain on
onnxruntime-web, with the noise), grid (the decoder on every grid point),
mesh (marching cubes), and for a coloured model the colour at the mesh's
vertices (a grey model's is 0; a format-5 model's matcher, made once per
model, in the warm-up). The Python runtime does the same work (sample, then
extract, which meshes only the band around the surface) with 1 and with
all threads. Ends with the static folder's size.
"""

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, open_page, static_server  # noqa: E402

from sinshape import models  # noqa: E402
from sinshape.runtime import generate, load, mesh  # noqa: E402
from sinshape.serve import site  # noqa: E402

BROWSER_JS = """async ([file, seed, scale, repeats]) => {
  const s = await import('./static/sinshape/runtime.js');
  const bytes = new Uint8Array(await (await fetch(file)).arrayBuffer());
  let t = performance.now();
  const model = await s.loadModel(bytes, { name: file });
  const load = performance.now() - t;
  const runs = [];
  for (let i = 0; i <= repeats; i++) {
    const t0 = performance.now();
    const tri = await s.sample(model, seed, [1, 1, 1]);
    const t1 = performance.now();
    const grid = await s.dense(model, tri, scale);
    const t2 = performance.now();
    const m = s.surface(grid, tri.size);
    const t3 = performance.now();
    if (model.manifest.colour) await s.colours(model, tri, m.positions, 1 / scale); // at the mesh's vertices (voxels), as the page
    const t4 = performance.now();
    if (i > 0) runs.push({ sample: t1 - t0, grid: t2 - t1, mesh: t3 - t2, colour: t4 - t3, total: t4 - t0, faces: m.faces.length / 3 });
  }
  return { load, runs, backend: model.backend, threads: model.threads, isolated: crossOriginIsolated };
}"""


def median(runs, key):
    return statistics.median(r[key] for r in runs)


def browser_rows(folder: Path, name: str, seed: int, scales, repeats: int, isolated: bool, browser) -> list:
    rows = []
    with static_server(folder, isolated=isolated) as base:
        for scale in scales:
            page = open_page(browser, base)  # a fresh page: onnxruntime's threads are fixed per page
            page.goto(f"{base}/README.txt")
            result = page.evaluate(BROWSER_JS, [f"models/{name}.onnx", seed, scale, repeats])
            page.close()
            runs = result["runs"]
            label = f"browser, {result['backend'].upper()} {result['threads']} thread{'s' * (result['threads'] > 1)}"
            rows.append((label, scale, median(runs, "sample"), median(runs, "grid") + median(runs, "mesh"),
                         median(runs, "total"), runs[0]["faces"], result["load"], median(runs, "colour")))
    return rows


def python_rows(path: Path, seed: int, scales, repeats: int, threads: int) -> list:
    model = load.load_model(path, threads=threads)
    rows = []
    for scale in scales:
        runs = []
        for i in range(repeats + 1):
            t0 = time.perf_counter()
            triplane = generate.sample(model, seed)
            t1 = time.perf_counter()
            result = mesh.extract(model, triplane, scale, frame="model")
            t2 = time.perf_counter()
            if i:
                runs.append({"sample": (t1 - t0) * 1e3, "rest": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3})
        rows.append((f"Python runtime, {threads} thread{'s' * (threads > 1)}", scale, median(runs, "sample"),
                     median(runs, "rest"), median(runs, "total"), len(result.faces), None, None))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", default="terrain")
    parser.add_argument("--scales", type=float, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    path = models.find(args.model)  # a shipped name or a .onnx file
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "site"
        written = site.export_site([args.model], folder)
        name = written["models"][0]
        rows = []
        with chromium() as browser:
            for isolated in (False, True):
                rows += browser_rows(folder, name, args.seed, args.scales, args.repeats, isolated, browser)
        for threads in sorted({1, load.default_threads()}):
            rows += python_rows(path, args.seed, args.scales, args.repeats, threads)

    print(f"{args.model}, seed {args.seed}: milliseconds per sample, median of {args.repeats}\n")
    print("| runtime | scale | sample (level chain) | grid + mesh | colour at the vertices | total | faces |")
    print("|---|---|---|---|---|---|---|")
    for label, scale, sample_ms, rest_ms, total_ms, faces, _, colour_ms in sorted(rows, key=lambda r: (r[1], r[0])):
        colour = "-" if colour_ms is None else f"{colour_ms:.0f}"  # Python's extract colours the mesh in its own time
        print(f"| {label} | {scale:g} | {sample_ms:.0f} | {rest_ms:.0f} | {colour} | {total_ms:.0f} | {faces:,} |")
    loads = [r[6] for r in rows if r[6] is not None]
    print(f"\nbrowser: loading and checking the model (stage sessions, probes) {min(loads):.0f}-{max(loads):.0f} ms")
    print(f"static folder: {written['files']} files, {written['bytes'] / 2**20:.1f} MB")


if __name__ == "__main__":
    main()
