"""Edits in the browser against the Python runtime, on the shipped models.

    python benchmarks/web_edit_speed.py [--models acropolis terrain towerruins] [--repeats 3]

What the page's editor does for one edit, start to finish, at scale 1: the
edited tri-plane, the grid, the mesh. In headless chromium (the tests'
harness, tests/browser.py) on a site written by `sinrun export-web`, WASM on
one thread, and in the Python runtime (one thread), the median of
`--repeats` after one warm-up. The edits are benchmarks/edit.py's: seed 0
plain; seed 0 with the box BOX kept from seed 1000; seed 0 grown 1.5x along
x; seed 0's level-0 layout edited four ways (removed, duplicated,
moved, added), generated from with seed 0; and the page's own unit of
editing, a click: one block on top of the layout, the one nearest its
centre, removed or with a block added on it; the nearest with room beside
it moved one cell along x; and the five nearest removed (five clicks: each regenerates from all of them).
"""

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, open_page, static_server  # noqa: E402
from edit import BOX, edited_layouts  # noqa: E402

from sinshape import models  # noqa: E402
from sinshape.runtime import layout as layouts  # noqa: E402
from sinshape.runtime import load, mesh  # noqa: E402
from sinshape.runtime.edit import compose, grow, parse_part  # noqa: E402
from sinshape.runtime.generate import sample  # noqa: E402
from sinshape.serve import site  # noqa: E402

BROWSER_JS = """async ([file, edits, repeats]) => {
  const s = await import('./static/sinshape/runtime.js');
  const model = await s.loadModel(new Uint8Array(await (await fetch(file)).arrayBuffer()), { name: file });
  const medians = {};
  for (const [label, how, args] of edits) {
    const times = [];
    for (let i = 0; i <= repeats; i++) {
      const started = performance.now();
      const tri = await s[how](model, ...args);
      s.surface(await s.dense(model, tri, 1), tri.size, model.manifest);
      if (i > 0) times.push(performance.now() - started);
    }
    medians[label] = times.sort((a, b) => a - b)[Math.floor(times.length / 2)];
  }
  return medians;
}"""


def block_edits(layout) -> dict:
    """What clicks on the page's blocks make: (X, Y, Z) bool layouts, by label."""
    centre = (np.array(layout.shape) - 1) / 2
    tops = [tuple(p) for p in np.argwhere(layout[:, :, :-1] & ~layout[:, :, 1:])]  # full, empty above
    tops.sort(key=lambda p: (np.abs(np.array(p) - centre).sum(), p))
    (i, j, k), out = tops[0], {}
    a, b, c = next(p for p in tops if p[0] + 1 < layout.shape[0] and not layout[p[0] + 1, p[1], p[2]])
    for label, cells in (("1 block removed", {(i, j, k): False}), ("1 block added", {(i, j, k + 1): True}),
                         ("1 block moved", {(a, b, c): False, (a + 1, b, c): True}),
                         ("5 blocks removed", dict.fromkeys(tops[:5], False))):
        out[label] = layout.copy()
        for cell, full in cells.items():
            out[label][cell] = full
    return out


def edits(model) -> list:
    """(label, runtime.js function, its arguments, the Python runtime's same edit) for each edit."""
    part = parse_part(f"1000:{BOX}", model.manifest, model.manifest.sizes[-1])
    box = {"seed": part.seed, "low": list(part.low), "high": list(part.high)}
    rows = [("plain sample", "sample", [0], lambda: sample(model, 0)),
            ("a box kept", "compose", [0, [box]], lambda: compose(model, 0, [part])),
            ("grown 1.5x", "grow", [0, [1.5, 1, 1], [0.5, 0, 0]], lambda: grow(model, 0, (1.5, 1, 1), (0.5, 0, 0)))]
    own = layouts.layout(model, 0)
    for edit, target in {**edited_layouts(own), **block_edits(own)}.items():
        rows.append((f"layout: {edit}", "fromLayout", [0, target.ravel().astype(int).tolist(), list(target.shape)],
                     lambda target=target: layouts.from_layout(model, 0, target)))
    return rows


def python_ms(make, repeats: int, model) -> float:
    times = []
    for i in range(repeats + 1):
        started = time.perf_counter()
        mesh.extract(model, make(), 1)
        if i:
            times.append((time.perf_counter() - started) * 1e3)
    return statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["acropolis", "terrain", "towerruins"])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    print(f"milliseconds per edit, start to mesh at scale 1, median of {args.repeats}\n")
    print("| model | edit | browser (WASM, 1 thread) | Python runtime (1 thread) |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp, chromium() as browser:
        folder = Path(tmp) / "site"
        site.export_site(args.models, folder)
        with static_server(folder) as base:
            for name in args.models:
                model = load.load_model(models.find(name), threads=1)
                rows = edits(model)
                page = open_page(browser, base)
                page.goto(f"{base}/README.txt")
                browser_ms = page.evaluate(BROWSER_JS, [f"models/{name}.onnx",
                                                        [row[:3] for row in rows], args.repeats])
                page.close()
                for label, _, _, make in rows:
                    print(f"| {name} | {label} | {browser_ms[label]:.0f} | {python_ms(make, args.repeats, model):.0f} |",
                          flush=True)


if __name__ == "__main__":
    main()
