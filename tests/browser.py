"""A headless chromium on a static folder, for the browser runtime's tests and
benchmarks/web_speed.py: a loopback file server in a thread (with or without
the cross-origin isolation headers that multi-threaded WASM needs) and a page.
"""

import contextlib
import functools
import http.server
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
# WebGL without a GPU: chromium's software renderer (as tests/test_serve_page.py).
ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
ISOLATION = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp"}


class Handler(http.server.SimpleHTTPRequestHandler):
    """Python's file server (the types of `python -m http.server`), plus optional headers."""

    headers_to_send = {}

    def end_headers(self):
        for key, value in self.headers_to_send.items():
            self.send_header(key, value)
        super().end_headers()

    def log_message(self, *args):
        pass


# The most a test waits for a thing to happen (a server to answer, a page to
# report): a hang guard only, far above what it takes on a machine busy with
# other work (a server answers in about a second); no test times it.
GUARD_SECONDS = 120


@contextlib.contextmanager
def server_process(command, folder: Path, what: str):
    """`command` (its last argument the port) run in `folder`, a child process
    on a free loopback port: yields the base URL once it answers."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen([*command, str(port)], cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + GUARD_SECONDS
        while True:
            with contextlib.suppress(OSError):
                urllib.request.urlopen(f"{base}/", timeout=5).close()
                break
            assert process.poll() is None, f"{what} stopped"
            assert time.monotonic() < deadline, f"{what} did not answer within {GUARD_SECONDS} s"
            time.sleep(0.1)
        yield base
    finally:
        process.terminate()
        process.wait(timeout=10)


def http_server_process(folder: Path):
    """`python -m http.server` in FOLDER itself, as a user would run it: yields the base URL."""
    return server_process([sys.executable, "-m", "http.server", "--bind", "127.0.0.1"], folder, "python -m http.server")


def site_server_process(folder: Path):
    """`python serve.py` of a folder `sinrun export-web` wrote, as its README says: yields the base URL."""
    return server_process([sys.executable, "-I", "-S", "serve.py"], folder, "the site's serve.py")  # the standard library only


@contextlib.contextmanager
def static_server(folder: Path, isolated: bool = False):
    """Serve `folder` on a free loopback port in a thread: yields the base URL."""
    handler = type("Handler", (Handler,), {"headers_to_send": ISOLATION if isolated else {}})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=str(folder)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def launch(playwright, extra_args=()):
    """Headless chromium from a running sync_playwright(), with the software renderer."""
    return playwright.chromium.launch(executable_path=CHROMIUM, args=[*ARGS, *extra_args])


@contextlib.contextmanager
def chromium(extra_args=()):
    """Headless chromium (Playwright's sync API runs one instance at a time): yields the browser."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = launch(playwright, extra_args)
        try:
            yield browser
        finally:
            browser.close()


def open_page(browser, base: str):
    """A page that may reach only `base` (page.errors: uncaught errors, page.outside:
    requests elsewhere, which are aborted)."""
    page = browser.new_page(viewport={"width": 900, "height": 600})
    page.errors, page.outside = [], []
    page.on("pageerror", lambda error: page.errors.append(str(error)))
    page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(base)
               else (page.outside.append(route.request.url), route.abort()))
    return page


@contextlib.contextmanager
def exported_site_page(browser, models: list, folder: Path):
    """`sinrun export-web MODELS -o folder`, served as its README says, open in a page of `browser` (page.base)."""
    from sinshape.serve import site

    site.export_site(models, folder)
    with site_server_process(folder) as base:
        page = open_page(browser, base)
        page.base = base
        page.goto(f"{base}/README.txt")
        yield page
        page.close()


# ---- the page's layout editor (tests/test_serve_page.py on the server, tests/test_web.py in the browser)
# The first full cell whose face `normal` a click in the view picks (that cell and that face), with
# `room` empty cells beyond the face inside the layout, in none of the columns `skip` ([[i, j], ...]):
# { cell, x, y } in client coordinates, or null.
CLICKABLE_JS = """([normal, room, skip = []]) => {
  const view = window.sinshapeView, layout = view.layout(), [X, Y, Z] = layout.shape;
  const full = (c) => c.every((v, a) => v >= 0 && v < layout.shape[a]) && layout.grid[(c[0] * Y + c[1]) * Z + c[2]] === 1;
  const inside = (c) => c.every((v, a) => v >= 0 && v < layout.shape[a]);
  const rect = document.querySelector('#view canvas').getBoundingClientRect();
  for (let i = 0; i < X; i++) for (let j = 0; j < Y; j++) for (let k = 0; k < Z; k++) {
    const cell = [i, j, k];
    if (!full(cell) || skip.some(([a, b]) => a === i && b === j)) continue;
    let ok = true;
    for (let r = 1; r <= room; r++) {
      const beyond = cell.map((v, a) => v + r * normal[a]);
      if (!inside(beyond) || full(beyond)) ok = false;
    }
    if (!ok) continue;
    const point = view.facePoint(cell, normal);
    if (point.x < rect.left + 20 || point.x > rect.right - 20 || point.y < rect.top + 20 || point.y > rect.bottom - 20) continue;
    const hit = view.pick(point.x, point.y);
    if (hit && hit.cell.join() === cell.join() && hit.normal.join() === normal.join()) return { cell, ...point };
  }
  return null;
}"""


def layout_in_page(page) -> np.ndarray:
    got = page.evaluate("window.sinshapeView.layout()")
    return np.array(got["grid"], bool).reshape(got["shape"])


def edits_text(grid: np.ndarray, base: np.ndarray) -> str:
    """The page's text of a layout edit (serve/static/viewer/layout-cells.js: encodeEdits)."""
    return ",".join(f"{'a' if grid[c] else 'r'}{c[0]}.{c[1]}.{c[2]}" for c in map(tuple, np.argwhere(grid != base)))


def wait_cells(page, text: str) -> None:
    page.wait_for_function("([text]) => ['ready', 'error'].includes(document.body.dataset.state) && "
                           "(new URLSearchParams(location.search).get('cells') ?? '') === text", arg=[text],
                           timeout=60_000)
    assert page.evaluate("document.body.dataset.state") == "ready", page.text_content("#error")


# ---- the page's world mode (tests/test_world_web.py in the browser, tests/test_serve_page.py on the server)
def wait_world(page, timeout=120_000) -> dict:
    """Until every tile within reach of the camera is made and the page is ready: the world's status."""
    page.wait_for_function("(() => { const s = window.sinshapeView.world.status(); return s && "
                           "!/to make/.test(document.getElementById('status').textContent) && "
                           "document.body.dataset.state === 'ready'; })()", timeout=timeout)
    return page.evaluate("window.sinshapeView.world.status()")
