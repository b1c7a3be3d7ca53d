"""Endless worlds in the browser: tiles per second made in the page's worker,
and the frame rate while flying, in headless chromium (WebGL drawn by its
software renderer, SwiftShader: no GPU), with the Python runtime beside it.

    python benchmarks/world_web.py [MODEL] [--reach 3] [--seconds 10] [--repeats 5] [--seed 3] [--shots PNG]

Exports MODEL (default: the shipped terrain) with `sinrun export-web`, serves
it with the site's own serve.py (cross-origin isolated: WASM on threads) and
opens it in headless chromium (the tests' harness, tests/browser.py):

- The worker: a worker of its own (static/sinshape/worker.js, as the page
  starts it) makes tiles with no window kept (far apart: four new windows
  each), along a row (two new windows each, the two it shares kept) and
  again (none new: the decoding and the mesh only), and, to compare,
  samples of the training size; the median of `--repeats` each, after a
  warm-up.
- The page: world mode at `--reach` tiles around the camera's, from choosing
  it (the model already loaded) until every tile of the ring is made.
- Flying: the frame intervals (requestAnimationFrame) for `--seconds` while
  the camera flies forward at its speed (tiles made in the worker meanwhile,
  and dropped behind), then, every tile made, while it turns in place.
- The Python runtime makes the same ring, in the same order, on one thread.

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

from browser import chromium, open_page, site_server_process, wait_world  # noqa: E402

from sinshape import models  # noqa: E402
from sinshape.runtime import load, world  # noqa: E402
from sinshape.serve import site  # noqa: E402

WORKER_JS = """async ([file, seed, repeats]) => {
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
  const tile = async (i, j) => {
    const started = performance.now();
    await call({ type: 'sample', name: 'model', request: sampleRequest({ seed: BigInt(seed), tile: [BigInt(i), BigInt(j)], frame: 'tile' }) });
    return performance.now() - started;
  };
  await tile(-7777, 0);  // the warm-up: the JIT, onnxruntime's first runs
  const cold = [], row = [], warm = [], sample = [];
  for (let k = 1; k <= repeats; k++) {
    const started = performance.now();
    await call({ type: 'sample', name: 'model', request: sampleRequest({ seed: BigInt(seed + k) }) });
    sample.push(performance.now() - started);
  }
  for (let k = 1; k <= repeats; k++) cold.push(await tile(1000 * k, 0));
  await tile(50000, 0);
  for (let k = 1; k <= repeats; k++) row.push(await tile(50000 + k, 0));
  for (let k = 1; k <= repeats; k++) warm.push(await tile(50000 + repeats, 0));
  worker.terminate();
  return { cold, row, warm, sample, threads: loaded.threads };
}"""

# Frame times (requestAnimationFrame) while `recording` is set.
RECORD_JS = """() => {
  window.frameTimes = [];
  window.recording = true;
  const tick = (t) => { window.frameTimes.push(t); if (window.recording) requestAnimationFrame(tick); };
  requestAnimationFrame(tick);
}"""


def frames_while(page, key: str, seconds: float) -> dict:
    """Hold `key` for `seconds`: the frame intervals' median and 95th percentile (ms), frames per second."""
    page.evaluate(RECORD_JS)
    page.keyboard.down(key)
    page.wait_for_timeout(seconds * 1000)
    page.keyboard.up(key)
    times = page.evaluate("window.recording = false, window.frameTimes")
    gaps = sorted(b - a for a, b in zip(times, times[1:]))
    return {"median": statistics.median(gaps), "p95": gaps[int(0.95 * (len(gaps) - 1))],
            "fps": (len(times) - 1) / ((times[-1] - times[0]) / 1000)}


def ring(reach: int, size) -> list:
    """The tiles within `reach` of tile (0, 0), nearest first from the camera over its middle, as the page orders them."""
    tiles = [(i, j) for i in range(-reach, reach + 1) for j in range(-reach, reach + 1)]
    return sorted(tiles, key=lambda t: math.hypot(t[0] * size[0], t[1] * size[1]))


def python_ring(path: Path, seed: int, reach: int) -> float:
    """Seconds for the Python runtime, one thread, to make the ring's tiles in the page's order."""
    model = load.load_model(path, threads=1)
    layout = world.world_layout(model)
    size = [layout.stride[a] * model.manifest.spacing[a] for a in layout.horizontal]
    world.tile_mesh(model, seed, (-7777, 0))  # the warm-up
    world._windows.clear()
    started = time.perf_counter()
    for tile in ring(reach, size):
        world.tile_mesh(model, seed, tile)
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
    parser.add_argument("--reach", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--shots", type=Path)
    args = parser.parse_args()

    path = models.find(args.model)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "site"
        site.export_site([args.model], folder)
        with site_server_process(folder) as base, chromium() as browser:
            page = open_page(browser, base)
            page.goto(f"{base}/README.txt")
            worker = page.evaluate(WORKER_JS, [f"models/{args.model}.onnx", args.seed, args.repeats])
            page.goto(f"{base}/?seed={args.seed}&reach={args.reach}")  # a sample first: the worker holds the model
            page.wait_for_function("document.body.dataset.state === 'ready'", timeout=120_000)
            started = page.evaluate("() => { const t = performance.now(); const edit = document.getElementById('edit');"
                                    " edit.value = 'world'; edit.dispatchEvent(new Event('change')); return t; }")
            status = wait_world(page, timeout=600_000)
            filled = (page.evaluate("performance.now()") - started) / 1000
            tiles = len(status["tiles"])
            before = page.evaluate("window.sinshapeView.world.status()")
            flying = frames_while(page, "w", args.seconds)
            after = page.evaluate("window.sinshapeView.world.status()")
            memory = page.evaluate("window.sinshapeView.memory()")
            wait_world(page, timeout=600_000)
            still = frames_while(page, "ArrowLeft", args.seconds)
            assert not page.errors, page.errors
            if args.shots:
                shots(browser, base, args.seed, args.shots)
    python = python_ring(path, args.seed, args.reach)

    row = lambda ms: f"{statistics.median(ms):.0f} ms, {1000 / statistics.median(ms):.1f} tiles/s"  # noqa: E731
    print(f"{args.model}, seed {args.seed}: headless chromium, WebGL on SwiftShader (software), "
          f"WASM on {worker['threads']} threads; load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after\n")
    print("| the browser's worker, a tile | median | ")
    print("|---|---|")
    print(f"| no window kept (4 made) | {row(worker['cold'])} |")
    print(f"| along a row (2 made) | {row(worker['row'])} |")
    print(f"| every window kept (the decoding and the mesh) | {row(worker['warm'])} |")
    print(f"| a sample at the training size, for comparison | {statistics.median(worker['sample']):.0f} ms |")
    print(f"\nthe page's world mode, reach {args.reach}: {tiles} tiles in {filled:.1f} s, {tiles / filled:.1f} tiles/s "
          f"(the Python runtime, 1 thread, the same ring: {python:.1f} s, {tiles / python:.1f} tiles/s)")
    print(f"flying {args.seconds:g} s: {flying['fps']:.1f} frames/s, interval median {flying['median']:.0f} ms, "
          f"95th percentile {flying['p95']:.0f} ms; {after['made'] - before['made']} tiles made, "
          f"{after['dropped'] - before['dropped']} dropped, tile {', '.join(before['at'])} to {', '.join(after['at'])}; "
          f"GPU geometries after: {memory['geometries']}")
    print(f"turning in place {args.seconds:g} s, no tile made: {still['fps']:.1f} frames/s, interval median "
          f"{still['median']:.0f} ms, 95th percentile {still['p95']:.0f} ms")


if __name__ == "__main__":
    main()
