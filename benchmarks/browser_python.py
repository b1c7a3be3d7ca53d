"""What running the Python runtime itself in the page would cost at load,
against the page's own JavaScript runtime: one figure of the choice between
the hand-written mirror and Pyodide (docs/WEB.md, "One runtime or two").

In one fresh headless chromium each (empty cache), served from loopback:
  - the exported site (`sinrun export-web terrain`): bytes sent and seconds
    from navigation to its first sample's face count;
  - Pyodide's core (the npm package, fetched by `npm pack` into a temporary
    folder), opened in a blank page: bytes and seconds to `loadPyodide()`
    and a first line of Python run. numpy, which the runtime needs and which
    Pyodide ships apart, is not included (its wheel comes from Pyodide's
    CDN, out of this machine's reach), so the figure is a floor.

    python benchmarks/browser_python.py [--pyodide 0.27.7] [--rounds 3]

Needs chromium, Playwright and npm (the registry).
"""

import argparse
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, static_server  # noqa: E402

PYODIDE_PAGE = """<!doctype html><meta charset="utf-8"><title>pyodide</title>
<script type="module">
import { loadPyodide } from "./pyodide.mjs";
const started = performance.now();
const pyodide = await loadPyodide({ indexURL: "./" });
const answer = pyodide.runPython("import sys; sys.version.split()[0]");
document.title = `ready ${answer} ${((performance.now() - started) / 1000).toFixed(3)}`;
</script>"""


def load(base: str, path: str, ready: str) -> tuple:
    """(MB sent, seconds) of a first load in a fresh browser, until `ready` (a JS condition) holds."""
    with chromium() as browser:
        page = browser.new_page()
        sent = []
        page.on("requestfinished", lambda request: sent.append(max(0, request.sizes()["responseBodySize"])))
        started = time.perf_counter()
        page.goto(base + path)
        page.wait_for_function(ready, timeout=180000)
        seconds = time.perf_counter() - started
        page.wait_for_timeout(300)
        return sum(sent) / 1e6, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pyodide", default="0.27.7", help="Pyodide's npm version.")
    parser.add_argument("--rounds", type=int, default=3)
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as root:
        root = Path(root)
        subprocess.run([sys.executable, "-c", "from sinshape.cli.main import main; main()", "export-web", "terrain",
                        "-o", str(root / "site")], check=True, capture_output=True)
        subprocess.run(["npm", "pack", f"pyodide@{options.pyodide}", "--silent"], cwd=root, check=True,
                       capture_output=True)
        with tarfile.open(next(root.glob("pyodide-*.tgz"))) as packed:
            packed.extractall(root, filter="data")
        (root / "package" / "index.html").write_text(PYODIDE_PAGE)
        core = sum(f.stat().st_size for f in (root / "package").iterdir()
                   if f.suffix in (".wasm", ".zip", ".js", ".mjs", ".json")) / 1e6
        rows = {"the page's JavaScript runtime, to its first sample": [], "Pyodide's core, to its first line": []}
        for _ in range(options.rounds):  # alternated, so that both see the same machine
            with static_server(root / "site") as base:
                rows["the page's JavaScript runtime, to its first sample"].append(
                    load(base, "/", "/faces/.test(document.querySelector('#status')?.textContent || '')"))
            with static_server(root / "package") as base:
                rows["Pyodide's core, to its first line"].append(load(base, "/index.html",
                                                                       "document.title.startsWith('ready')"))
    print(f"Pyodide {options.pyodide}: its core's files {core:.1f} MB (numpy not included)\n")
    print("| first load | MB sent | seconds (each round) |\n|---|---|---|")
    for name, loads in rows.items():
        print(f"| {name} | {loads[0][0]:.1f} | {' / '.join(f'{s:.2f}' for _, s in loads)} |")


if __name__ == "__main__":
    main()
