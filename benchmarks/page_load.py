"""The page's first load: bytes on the wire and time to the first shape, for
`sinrun serve` and for the `sinrun export-web` site, this checkout against
another install (a release).

    python benchmarks/page_load.py --before RELEASE/bin/sinrun [--now NOW/bin/sinrun] [--model terrain]

Each case is a fresh headless chromium (empty cache) opening the page: the
served page samples on the server (its default) or in the browser
(`where=browser`: onnxruntime-web's files come from `sinrun serve`); the
exported site samples in the browser, served two ways: by `python -m
http.server`, which compresses nothing and sends no isolation headers (WASM
on one thread), and by the site's own `serve.py` (isolation headers, so
WASM on threads; the .gz copies where the export wrote them). Bytes are the response bodies as sent
(compressed where the server compressed them); time runs from navigation to
the status line's face count. "again" is a second load of the same page in
the same browser: what its cache saves (revalidations answered 304 carry no
body). Loopback only: over a network the bytes cost time too.
"""

import argparse
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import chromium, http_server_process, site_server_process  # noqa: E402


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def first_load(base: str, path: str = "/") -> list:
    """[(MB sent, seconds to the first shape)] of a page's first load in a
    fresh browser, and of a second load in the same browser."""
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 900, "height": 600})  # no page.route: it turns the cache off
        sent = []
        # -1 or less: answered from the browser's cache, nothing sent
        page.on("requestfinished", lambda request: sent.append(max(0, request.sizes()["responseBodySize"])))
        loads = []
        for _ in range(2):
            sent.clear()
            started = time.perf_counter()
            page.goto(base + path)
            page.wait_for_function("/faces/.test(document.querySelector('#status')?.textContent || '')",
                                   timeout=120000)
            seconds = time.perf_counter() - started
            page.wait_for_timeout(500)  # late requests (the WASM's worker files) finish
            loads.append((sum(sent) / 1e6, seconds))  # MB of 10^6 bytes, as the docs give file sizes
        return loads


def served(sinrun: str, model: str, where: str = "server") -> tuple:
    port = free_port()
    process = subprocess.Popen([sinrun, "serve", model, "--port", str(port)], stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            try:
                urllib.request.urlopen(f"{base}/health", timeout=2).close()
                break
            except OSError:
                time.sleep(0.1)
        return first_load(base, f"/?model={model}&where={where}")
    finally:
        process.terminate()
        process.wait(timeout=20)


def served_browser(sinrun: str, model: str) -> tuple:
    return served(sinrun, model, "browser")


def exported(sinrun: str, model: str, server=http_server_process) -> tuple:
    with tempfile.TemporaryDirectory() as folder:
        site = Path(folder) / "site"
        subprocess.run([sinrun, "export-web", model, "-o", str(site)], check=True, capture_output=True)
        with server(site) as base:
            return first_load(base)


def exported_serve_py(sinrun: str, model: str) -> tuple:
    return exported(sinrun, model, site_server_process)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", required=True, help="the other install's sinrun executable")
    parser.add_argument("--now", default=str(Path(sys.executable).with_name("sinrun")))
    parser.add_argument("--model", default="terrain")
    args = parser.parse_args()
    print("| page | install | MB sent | seconds to the first shape | again: MB sent | again: seconds |")
    print("|---|---|---|---|---|---|")
    cases = (("`sinrun serve` (server sampling)", served),
             ("`sinrun serve` (browser sampling, threads)", served_browser),
             ("`export-web` site, `python -m http.server` (browser, 1 thread)", exported),
             ("`export-web` site, its `serve.py` (browser, threads)", exported_serve_py))
    for page, measure in cases:
        for name, sinrun in (("before", args.before), ("now", args.now)):
            (megabytes, seconds), (again_megabytes, again_seconds) = measure(sinrun, args.model)
            print(f"| {page} | {name} | {megabytes:.2f} | {seconds:.2f} | {again_megabytes:.2f} | {again_seconds:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
