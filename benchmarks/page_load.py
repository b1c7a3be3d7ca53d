"""The page's first load: bytes on the wire and time to the first shape, for
`sinrun serve` and for the `sinrun export-web` site, this checkout against
another install (a release).

    python benchmarks/page_load.py --before RELEASE/bin/sinrun [--now NOW/bin/sinrun] [--model terrain]

Each case is a fresh headless chromium (empty cache) opening the page: the
served page samples on the server (its default), the exported site in the
browser (WASM, one thread: Python's file server sends no isolation headers),
served by `python -m http.server`, which compresses nothing. Bytes are the
response bodies as sent (compressed where the server compressed them); time
runs from navigation to the status line's face count.
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

from browser import chromium, http_server_process, open_page  # noqa: E402


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def first_load(base: str, path: str = "/") -> tuple:
    """(MB sent, seconds to the first shape) of one page load in a fresh browser."""
    with chromium() as browser:
        page = open_page(browser, base)
        sent = []
        page.on("requestfinished", lambda request: sent.append(request.sizes()["responseBodySize"]))
        started = time.perf_counter()
        page.goto(base + path)
        page.wait_for_function("/faces/.test(document.querySelector('#status')?.textContent || '')", timeout=120000)
        seconds = time.perf_counter() - started
        page.wait_for_timeout(500)  # late requests (the WASM's worker files) finish
        return sum(sent) / 2**20, seconds


def served(sinrun: str, model: str) -> tuple:
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
        return first_load(base, f"/?model={model}")
    finally:
        process.terminate()
        process.wait(timeout=20)


def exported(sinrun: str, model: str) -> tuple:
    with tempfile.TemporaryDirectory() as folder:
        site = Path(folder) / "site"
        subprocess.run([sinrun, "export-web", model, "-o", str(site)], check=True, capture_output=True)
        with http_server_process(site) as base:
            return first_load(base)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", required=True, help="the other install's sinrun executable")
    parser.add_argument("--now", default=str(Path(sys.executable).with_name("sinrun")))
    parser.add_argument("--model", default="terrain")
    args = parser.parse_args()
    print("| page | install | MB sent | seconds to the first shape |")
    print("|---|---|---|---|")
    for page, measure in (("`sinrun serve` (server sampling)", served), ("`export-web` site (browser sampling)", exported)):
        for name, sinrun in (("before", args.before), ("now", args.now)):
            megabytes, seconds = measure(sinrun, args.model)
            print(f"| {page} | {name} | {megabytes:.2f} | {seconds:.2f} |", flush=True)


if __name__ == "__main__":
    main()
