"""Endless worlds on the page: its first view filled and its frame times
while tiles stream, in headless chromium (WebGL drawn by its software
renderer, SwiftShader: no GPU), every tile from `sinrun serve MODEL`'s tile
route (the Python runtime makes worlds), with the Python runtime beside it.

    python benchmarks/world_web.py [MODEL] [--arrange blend|scatter] [--reach 3] [--seconds 10] [--seed 3] [--settle 0]
                                  [--shots PNG]

- The page: world mode at `--reach` tiles around the camera's (each a level
  coarser per tile past the first ring), from choosing it (the model
  already loaded; chosen `--settle` seconds after the page is ready, at
  once by default) until every tile is made, with the frame intervals
  (requestAnimationFrame) meanwhile: the worst, the 95th percentile and
  the median.
- Flying: the frame intervals for `--seconds` while the camera flies
  forward at its speed (tiles made meanwhile, and dropped behind), then,
  every tile made, while it turns in place.
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

from browser import chromium, open_page, server_process, wait_world  # noqa: E402

from sinshape import models  # noqa: E402
from sinshape.runtime import load, world, world_tiles  # noqa: E402

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


def first_view(page, base: str, seed: int, reach: int, arrange: str, settle: float) -> dict:
    """World mode chosen on a page showing a sample (its model loaded), `settle` seconds after it is ready: seconds until every tile
    of the view is shown (at the coarsest level first) and until each is at its own level, its
    tiles, and the frame intervals meanwhile."""
    page.goto(f"{base}/?seed={seed}&reach={reach}")
    page.wait_for_function("document.body.dataset.state === 'ready'", timeout=120_000)
    page.wait_for_timeout(settle * 1000)
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
    tiling = world.world_tiling(model)
    size = [tiling.stride[a] * model.manifest.spacing[a] for a in tiling.horizontal]
    world_tiles.tile_surface(model, seed, (-7777, 0))  # the warm-up
    world._windows.clear()
    coarsest = len(model.manifest.sizes) - 1
    started = time.perf_counter()
    for tile, lod in ring(reach, size):
        world_tiles.tile_surface(model, seed, tile, options=world.WorldOptions(arrange, lod=min(lod, coarsest)))
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
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--settle", type=float, default=0, help="seconds between the page ready and the world chosen")
    parser.add_argument("--shots", type=Path)
    args = parser.parse_args()

    path = models.find(args.model)
    manifest = load.load_model(path, threads=1).manifest
    arrange = args.arrange or manifest.arrange
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        sinrun = Path(sys.executable).with_name("sinrun")
        with server_process([str(sinrun), "serve", args.model, "--port"], Path(tmp), "sinrun serve") as base, \
                chromium() as browser:
            page = open_page(browser, base)
            view = first_view(page, base, args.seed, args.reach, arrange, args.settle)
            before = page.evaluate("window.sinshapeView.world.status()")
            flying = frames_while(page, "w", args.seconds)
            after = page.evaluate("window.sinshapeView.world.status()")
            memory = page.evaluate("window.sinshapeView.memory()")
            wait_world(page, timeout=600_000)
            still = frames_while(page, "ArrowLeft", args.seconds)
            assert not page.errors, page.errors
            if args.shots:
                shots(browser, base, args.seed, args.shots)
    python = python_ring(path, args.seed, args.reach, arrange)

    frames = lambda f: (f"worst {f['worst']:.0f} ms, 95th percentile {f['p95']:.0f} ms, median {f['median']:.0f} ms, "  # noqa: E731
                        f"{f['fps']:.1f} frames/s")
    print(f"{args.model} ({arrange}), seed {args.seed}: headless chromium, WebGL on SwiftShader (software), tiles from "
          f"sinrun serve; load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after\n")
    lods = sorted({t[4] for t in view["tiles"]})
    count = len(view["tiles"])
    print(f"the page's first view, reach {args.reach}, chosen {args.settle:g} s after the page was ready: {count} tiles shown in {view['filled']:.1f} s, "
          f"each at its level of detail ({lods}) in {view['seconds']:.1f} s; frames meanwhile: {frames(view['frames'])}")
    print(f"(the Python runtime, 1 thread, the same tiles at the same levels: {python:.1f} s, {count / python:.1f} tiles/s)")
    print(f"\nflying {args.seconds:g} s: {frames(flying)}; {after['made'] - before['made']} tiles made, "
          f"{after['dropped'] - before['dropped']} dropped, tile {', '.join(before['at'])} to {', '.join(after['at'])}; "
          f"GPU geometries after: {memory['geometries']}")
    print(f"turning in place {args.seconds:g} s, no tile made: {frames(still)}")


if __name__ == "__main__":
    main()
