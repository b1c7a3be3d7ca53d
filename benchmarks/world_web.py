"""Endless worlds in the browser: tiles made in the page's worker at each
level of detail, the page's first view filled, and its frame times while
tiles stream, in headless chromium (WebGL drawn by its software renderer,
SwiftShader: no GPU), from the page's worker and from `sinrun serve`, with
the Python runtime beside them.

    python benchmarks/world_web.py [MODEL] [--arrange blend|scatter] [--reach 3] [--seconds 10] [--repeats 5]
                                   [--seed 3] [--shots PNG]

Exports MODEL (default: the shipped terrain) with `sinrun export-web`, serves
it with the site's own serve.py (cross-origin isolated: WASM on threads) and
opens it in headless chromium (the tests' harness, tests/browser.py):

- The worker: a worker of its own (static/sinshape/worker.js, as the page
  starts it) makes tiles with no window kept at every level of detail (far
  apart: four new windows each; at lod 0 near the origin and 10^9 tiles
  away, in turn), along a row at full detail (two new windows
  each) and again (none new: the decoding, the mesh and its normals only),
  and, to compare, samples of the training size; the median of `--repeats`
  each, after a warm-up.
- The page, in browser mode and then from `sinrun serve MODEL`: world mode
  at `--reach` tiles around the camera's (each a level coarser per tile past
  the first ring), from choosing it (the model already loaded) until every
  tile is made, with the frame intervals (requestAnimationFrame) meanwhile:
  the worst, the 95th percentile and the median.
- Flying (browser mode): the frame intervals for `--seconds` while the camera
  flies forward at its speed (tiles made meanwhile, and dropped behind),
  then, every tile made, while it turns in place.
- The Python runtime makes the same ring at the same levels, in the same
  order, on one thread.

With --shots PNG, the page in world mode at 1100x700 and, beside it, at a
phone's 390x844 is saved as one picture (docs/world-page.png).
"""

import argparse
import io
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, open_page, server_process, site_server_process, wait_world  # noqa: E402

from sinshape import models  # noqa: E402
from sinshape.runtime import load, world  # noqa: E402
from sinshape.serve import site  # noqa: E402

WORKER_JS = """async ([file, seed, repeats, arrange, levels]) => {
  const { sampleRequest } = await import('./static/sinshape/request.js');
  const worker = new Worker('static/sinshape/worker.js', { type: 'module' });
  let ids = 0;
  const call = (message) => new Promise((resolve, reject) => {
    const id = ++ids;
    const listen = ({ data }) => {
      if (data.id !== id || data.type === 'progress') return;
      worker.removeEventListener('message', listen);
      if (data.type === 'error') reject(new Error(data.message));
      else resolve(data);
    };
    worker.addEventListener('message', listen);
    worker.postMessage({ id, ...message });
  });
  const bytes = new Uint8Array(await (await fetch(file)).arrayBuffer());
  const loaded = await call({ type: 'load', name: 'model', bytes, file });
  const tile = async (i, j, lod = 0) => {
    const started = performance.now();
    await call({ type: 'sample', name: 'model', request: sampleRequest({ seed: BigInt(seed), tile: [BigInt(i), BigInt(j)], frame: 'tile', arrange, lod }) });
    return performance.now() - started;
  };
  await tile(-7777, 0);  // the warm-up: the JIT, onnxruntime's first runs
  const cold = Array.from({ length: levels }, () => []), far = [], row = [], warm = [], sample = [];
  for (let k = 1; k <= repeats; k++) {
    const started = performance.now();
    await call({ type: 'sample', name: 'model', request: sampleRequest({ seed: BigInt(seed + k) }) });
    sample.push(performance.now() - started);
  }
  for (let k = 1; k <= repeats; k++) {  // near and far in turn
    for (let lod = 0; lod < levels; lod++) cold[lod].push(await tile(1000 * k + 100 * lod, 0, lod));
    far.push(await tile(1e9 + 1000 * k, -1e9));
  }
  await tile(50000, 0);
  for (let k = 1; k <= repeats; k++) row.push(await tile(50000 + k, 0));
  for (let k = 1; k <= repeats; k++) warm.push(await tile(50000 + repeats, 0));
  worker.terminate();
  return { cold, far, row, warm, sample, threads: loaded.threads };
}"""

# Frame times (requestAnimationFrame) while `recording` is set.
RECORD_JS = """() => {
  const times = window.frameTimes = [];  // a recording of its own: an earlier loop stops at its next frame
  window.recording = true;
  const tick = (t) => { times.push(t); if (window.recording && window.frameTimes === times) requestAnimationFrame(tick); };
  requestAnimationFrame(tick);
}"""


def intervals(times: list) -> dict:
    """Frame times (ms) -> the intervals' worst, 95th percentile and median (ms), and frames per second."""
    gaps = sorted(b - a for a, b in zip(times, times[1:]))
    return {"worst": gaps[-1], "p95": gaps[int(0.95 * (len(gaps) - 1))], "median": statistics.median(gaps),
            "fps": (len(times) - 1) / ((times[-1] - times[0]) / 1000)}


def frames_while(page, key: str, seconds: float) -> dict:
    """Hold `key` for `seconds`: the frame intervals (intervals)."""
    page.evaluate(RECORD_JS)
    page.keyboard.down(key)
    page.wait_for_timeout(seconds * 1000)
    page.keyboard.up(key)
    return intervals(page.evaluate("window.recording = false, window.frameTimes"))


def first_view(page, base: str, seed: int, reach: int, arrange: str) -> dict:
    """World mode chosen on a page showing a sample (its model loaded): seconds until every tile
    of the view is shown (at the coarsest level first) and until each is at its own level, its
    tiles, and the frame intervals meanwhile."""
    page.goto(f"{base}/?seed={seed}&reach={reach}")
    page.wait_for_function("document.body.dataset.state === 'ready'", timeout=120_000)
    page.evaluate(RECORD_JS)
    started = page.evaluate(f"""() => {{ const t = performance.now(); document.getElementById('arrange').value = '{arrange}';
      const edit = document.getElementById('edit'); edit.value = 'world'; edit.dispatchEvent(new Event('change')); return t; }}""")
    page.wait_for_function(f"window.sinshapeView.world.status()?.shown === {(2 * reach + 1) ** 2}", polling=20,
                           timeout=600_000)
    filled = (page.evaluate("performance.now()") - started) / 1000
    status = wait_world(page, timeout=600_000)
    seconds = (page.evaluate("performance.now()") - started) / 1000
    frames = intervals(page.evaluate("window.recording = false, window.frameTimes"))
    return {"filled": filled, "seconds": seconds, "tiles": status["tiles"], "frames": frames}


def ring(reach: int, size) -> list:
    """The tiles within `reach` of tile (0, 0), nearest first from the camera over its middle, and the
    level of detail the page asks each at (viewer/world.js's FINE: a level coarser per tile past the first)."""
    tiles = [(i, j) for i in range(-reach, reach + 1) for j in range(-reach, reach + 1)]
    return [(t, max(0, max(abs(t[0]), abs(t[1])) - 1))
            for t in sorted(tiles, key=lambda t: math.hypot(t[0] * size[0], t[1] * size[1]))]


def python_ring(path: Path, seed: int, reach: int, arrange: str) -> float:
    """Seconds for the Python runtime, one thread, to make the ring's tiles at their levels in the page's order."""
    model = load.load_model(path, threads=1)
    layout = world.world_layout(model)
    size = [layout.stride[a] * model.manifest.spacing[a] for a in layout.horizontal]
    world.tile_surface(model, seed, (-7777, 0))  # the warm-up
    world._windows.clear()
    coarsest = len(model.manifest.sizes) - 1
    started = time.perf_counter()
    for tile, lod in ring(reach, size):
        world.tile_surface(model, seed, tile, options=world.WorldOptions(arrange, lod=min(lod, coarsest)))
    return time.perf_counter() - started


def shots(browser, base: str, seed: int, path: Path) -> None:
    """The page in world mode on a wide screen and, beside it, a phone's: one picture."""
    from PIL import Image

    pictures = []
    for viewport in ({"width": 1100, "height": 700}, {"width": 390, "height": 844}):
        context = browser.new_context(viewport=viewport, has_touch=viewport["width"] < 600)
        page = context.new_page()
        page.goto(f"{base}/?seed={seed}&edit=world&reach=3")
        wait_world(page, timeout=600_000)
        page.wait_for_timeout(500)
        pictures.append(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
        context.close()
    wide, phone = pictures
    phone = phone.resize((round(phone.width * wide.height / phone.height), wide.height), Image.LANCZOS)
    both = Image.new("RGB", (wide.width + 16 + phone.width, wide.height), "white")
    both.paste(wide, (0, 0))
    both.paste(phone, (wide.width + 16, 0))
    both.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", nargs="?", default="terrain")
    parser.add_argument("--arrange", choices=world.ARRANGEMENTS, default=None, help="default: the model's own")
    parser.add_argument("--reach", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--shots", type=Path)
    args = parser.parse_args()

    path = models.find(args.model)
    manifest = load.load_model(path, threads=1).manifest
    arrange, levels = args.arrange or manifest.arrange, len(manifest.sizes)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "site"
        site.export_site([args.model], folder)
        with site_server_process(folder) as base, chromium() as browser:
            page = open_page(browser, base)
            page.goto(f"{base}/README.txt")
            worker = page.evaluate(WORKER_JS, [f"models/{args.model}.onnx", args.seed, args.repeats, arrange, levels])
            in_browser = first_view(page, base, args.seed, args.reach, arrange)
            before = page.evaluate("window.sinshapeView.world.status()")
            flying = frames_while(page, "w", args.seconds)
            after = page.evaluate("window.sinshapeView.world.status()")
            memory = page.evaluate("window.sinshapeView.memory()")
            wait_world(page, timeout=600_000)
            still = frames_while(page, "ArrowLeft", args.seconds)
            assert not page.errors, page.errors
            if args.shots:
                shots(browser, base, args.seed, args.shots)
        sinrun = Path(sys.executable).with_name("sinrun")
        with server_process([str(sinrun), "serve", args.model, "--port"], Path(tmp), "sinrun serve") as base, \
                chromium() as browser:
            page = open_page(browser, base)
            from_server = first_view(page, base, args.seed, args.reach, arrange)
            assert not page.errors, page.errors
    python = python_ring(path, args.seed, args.reach, arrange)

    ms = lambda values: f"{statistics.median(values):.0f} ms"  # noqa: E731
    frames = lambda f: (f"worst {f['worst']:.0f} ms, 95th percentile {f['p95']:.0f} ms, median {f['median']:.0f} ms, "  # noqa: E731
                        f"{f['fps']:.1f} frames/s")
    print(f"{args.model} ({arrange}), seed {args.seed}: headless chromium, WebGL on SwiftShader (software), "
          f"WASM on {worker['threads']} threads; load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after\n")
    print("| the browser's worker, a tile (mesh and normals) | median |")
    print("|---|---|")
    for lod, values in enumerate(worker["cold"]):
        print(f"| no window kept (4 made), lod {lod} | {ms(values)} ({statistics.median(values) / statistics.median(worker['cold'][0]):.2f}x) |")
    print(f"| ... 10^9 tiles away, lod 0 | {ms(worker['far'])} ({statistics.median(worker['far']) / statistics.median(worker['cold'][0]):.2f}x) |")
    print(f"| along a row (2 made), lod 0 | {ms(worker['row'])} |")
    print(f"| every window kept (the decoding, the mesh and its normals) | {ms(worker['warm'])} |")
    print(f"| a sample at the training size, for comparison | {ms(worker['sample'])} |")
    for label, view in (("in the browser", in_browser), ("from sinrun serve", from_server)):
        lods = sorted({t[4] for t in view["tiles"]})
        count = len(view["tiles"])
        print(f"\nthe page's first view {label}, reach {args.reach}: {count} tiles shown in {view['filled']:.1f} s, "
              f"each at its level of detail ({lods}) in {view['seconds']:.1f} s; "
              f"frames meanwhile: {frames(view['frames'])}")
    print(f"(the Python runtime, 1 thread, the same tiles at the same levels: {python:.1f} s, {count / python:.1f} tiles/s)")
    print(f"\nflying {args.seconds:g} s (browser): {frames(flying)}; {after['made'] - before['made']} tiles made, "
          f"{after['dropped'] - before['dropped']} dropped, tile {', '.join(before['at'])} to {', '.join(after['at'])}; "
          f"GPU geometries after: {memory['geometries']}")
    print(f"turning in place {args.seconds:g} s, no tile made: {frames(still)}")


if __name__ == "__main__":
    main()
