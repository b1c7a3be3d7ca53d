"""Colour by correspondence (format 5) in the browser against the Python
runtime, on the same machine, and how often the two agree.

    python benchmarks/colour_web_speed.py [MODEL.onnx] [--scale 2] [--seeds 1 2 3 4 5]
    python benchmarks/colour_web_speed.py [MODEL.onnx] --tiles 0,0 1,0 1000000000,-1000000000 [--seeds 3] [--scale 1] \
        [--arrange scatter]

Exports MODEL (default: tests/data/tiny_colour.onnx) with `sinrun
export-web` into a temporary folder, serves it on loopback and, in headless
chromium (the tests' harness, tests/browser.py; WASM on 1 thread), makes
each seed's sample and its mesh at `--scale`, then times its colours at the
mesh's vertices (footprint 1 / scale, as the page and `sinrun sample` ask
them): the planes projected, the sample's surface band matched to the
example (PatchMatch) and the tiles read at every vertex. The example's
side of matching (the reconstruction's patches), made once per model, is
timed apart; one seed is coloured first to warm the page's JIT. The Python
runtime (1 thread) does the same at its own mesh's vertices. Then the share
of the browser's vertices whose colour bytes are Python's at those vertices.

With --tiles, the same for tiles of the world of each seed (the model's own
arrangement unless --arrange, full detail): each tile's mesh at `--scale`, then its colours
at the mesh's vertices (tileColours / world.tile_colours, footprint 1 /
scale) timed with no window kept (its windows made, and each of those it
reads matched to the example), against Python's at the browser's vertices.
"""

import argparse
import base64
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, open_page, static_server  # noqa: E402

from sinshape.runtime import colour, generate, load, mesh, query, world  # noqa: E402
from sinshape.serve import site  # noqa: E402

DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "tests" / "data" / "tiny_colour.onnx"

# The start of the page scripts below, given `file`: the runtime `s`, `C` (colour.js), the model, and
# `b64`, a typed array's bytes as base64.
IN_PAGE = """
  const s = await import('./static/sinshape/runtime.js');
  const C = await import('./static/sinshape/colour.js');
  const model = await s.loadModel(new Uint8Array(await (await fetch(file)).arrayBuffer()), { name: file });
  const b64 = (array) => {
    const bytes = new Uint8Array(array.buffer, array.byteOffset, array.byteLength);
    let text = '';
    for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
    return btoa(text);
  };
"""

BROWSER_JS = """async ([file, seeds, scale]) => {""" + IN_PAGE + """
  let t = performance.now();
  await C.matcher(model);
  const matcher = (performance.now() - t) / 1000;
  const runs = [];
  for (const [i, seed] of [seeds[0], ...seeds].entries()) {
    const tri = await s.sample(model, seed, [1, 1, 1]);
    const m = s.surface(await s.dense(model, tri, scale), tri.size, model.manifest);
    t = performance.now();
    const colours = await s.vertexColours(model, tri, m.positions, 1 / scale);
    const seconds = (performance.now() - t) / 1000;
    if (i > 0) runs.push({ seed, seconds, positions: b64(m.positions), colours: b64(colours) });
  }
  return { matcher, runs };
}"""


TILES_JS = """async ([file, seed, tiles, scale, arrange]) => {""" + IN_PAGE + """
  const W = await import('./static/sinshape/world.js');
  await C.matcher(model);
  const options = W.worldOptions({ arrange }), runs = [];
  for (const [i, tile] of [tiles[0], ...tiles].entries()) {
    W.dropWindows();
    const at = tile.map(BigInt), m = await W.tileMesh(model, BigInt(seed), at, scale, options);
    const t = performance.now();
    const colours = await W.tileColours(model, BigInt(seed), at, m.positions, options, 1 / scale);
    const seconds = (performance.now() - t) / 1000;
    if (i > 0) runs.push({ tile, seconds, positions: b64(m.positions), colours: b64(colours) });
  }
  return runs;
}"""


def floats(text: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), np.float32).reshape(-1, 3)


def browser_runs(path: Path, script: str, *arguments):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "site"
        name = site.export_site([str(path)], folder)["models"][0]
        with chromium() as browser, static_server(folder) as base:
            page = open_page(browser, base)
            page.goto(f"{base}/README.txt")
            result = page.evaluate(script, [f"models/{name}.onnx", *arguments])
            page.close()
    return result


def python_runs(model, seeds, scale: float) -> dict:
    t = time.perf_counter()
    colour.matcher(model)
    matcher = time.perf_counter() - t
    runs = []
    for i, seed in enumerate([seeds[0], *seeds]):
        triplane = generate.sample(model, seed)
        vertices = mesh.band_mesh(model, triplane, scale).vertices
        t = time.perf_counter()
        colour.colours(model, triplane, vertices, 1 / scale)
        if i:
            runs.append({"seed": seed, "seconds": time.perf_counter() - t, "vertices": len(vertices)})
    return {"matcher": matcher, "runs": runs}


def band_size(model, seed: int) -> int:
    triplane = generate.sample(model, seed)
    hidden = colour.grid_hidden(model, query.project(model, triplane).planes, triplane.size)
    return len(colour.surface_band(model, hidden, triplane.size))


def tiles_table(model, path: Path, seeds, tiles, scale: float, arrange: str) -> None:
    """The --tiles table: a world tile's colours in each runtime, no window kept, and their agreement."""
    options = world.WorldOptions(arrange=arrange)
    print(f"{path.name}, its world ({arrange}), scale {scale:g}: seconds to colour a tile's vertices, no window kept\n")
    print("| seed | tile | vertices | browser | Python | browser / Python | colour bytes equal |")
    print("|---|---|---|---|---|---|---|")
    for seed in seeds:
        runs = browser_runs(path, TILES_JS, seed, [list(t) for t in tiles], scale, arrange)
        for run in runs:
            tile, positions = tuple(run["tile"]), floats(run["positions"]).astype(np.float64)
            seconds = []
            for _ in range(2):  # the first warms the model's matcher and the runtime
                world._windows.clear()
                world._colourings.clear()
                t = time.perf_counter()
                expected = world.tile_colours(model, seed, tile, positions, options, 1 / scale)
                seconds.append(time.perf_counter() - t)
            share = (mesh.colour_bytes(floats(run["colours"])) == expected).all(axis=1).mean()
            print(f"| {seed} | {tile[0]}, {tile[1]} | {len(positions):,} | {run['seconds']:.3f} | {seconds[-1]:.3f} | "
                  f"{run['seconds'] / seconds[-1]:.2f} | {share:.4%} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--scale", type=float, default=None, help="the mesh's scale (default: 2, tiles 1)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--tiles", type=lambda text: tuple(int(v) for v in text.split(",")), nargs="+",
                        help="tiles I,J of each seed's world instead of samples")
    parser.add_argument("--arrange", choices=("blend", "scatter"), help="the world's (default: the model's own)")
    args = parser.parse_args()

    model = load.load_model(args.model, threads=1)
    if model.tiles is None:
        sys.exit(f"{args.model}: not a format-5 model (no colour tiles)")
    if args.tiles:
        return tiles_table(model, args.model, args.seeds, args.tiles, args.scale or 1.0,
                           args.arrange or model.manifest.arrange)
    args.scale = args.scale or 2.0
    browser = browser_runs(args.model, BROWSER_JS, list(args.seeds), args.scale)
    python = python_runs(model, args.seeds, args.scale)

    print(f"{args.model.name}, scale {args.scale:g}: seconds to colour a sample's vertices, "
          f"{model.manifest.tiles[0]:,} tiles of {model.manifest.tiles[1]}x{model.manifest.tiles[1]}\n")
    print("| seed | band voxels | vertices (browser, Python) | browser | Python | browser / Python | colour bytes equal |")
    print("|---|---|---|---|---|---|---|")
    origin, spacing = np.asarray(model.manifest.origin), np.asarray(model.manifest.spacing)
    shares = []
    for ours, theirs in zip(browser["runs"], python["runs"]):
        positions, colours = floats(ours["positions"]), floats(ours["colours"])
        expected = colour.colours(model, generate.sample(model, ours["seed"]), (positions - origin) / spacing,
                                  1 / args.scale)
        share = (mesh.colour_bytes(colours) == mesh.colour_bytes(expected)).all(axis=1).mean()
        shares.append(share)
        print(f"| {ours['seed']} | {band_size(model, ours['seed']):,} | {len(positions):,}, {theirs['vertices']:,} | "
              f"{ours['seconds']:.3f} | {theirs['seconds']:.3f} | {ours['seconds'] / theirs['seconds']:.2f} | "
              f"{share:.4%} |")
    median = lambda runs: statistics.median(r["seconds"] for r in runs)  # noqa: E731
    print(f"\nmedian: browser {median(browser['runs']):.3f} s, Python {median(python['runs']):.3f} s "
          f"({median(browser['runs']) / median(python['runs']):.2f}x); colour bytes equal at "
          f"{min(shares):.4%} to {max(shares):.4%} of the vertices")
    print(f"the example's side, once per model: browser {browser['matcher']:.3f} s, Python {python['matcher']:.3f} s")


if __name__ == "__main__":
    main()
