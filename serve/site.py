"""`sinrun export-web`: a static folder that samples models in the browser.

The folder holds the page (index.html, the viewer in browser-only mode), the
JavaScript runtime (static/sinshape/), onnxruntime-web and three.js (static/
vendor/), and the models (models/NAME.onnx, listed in models.json). Any
static file server serves it, offline; nothing runs on the server.

onnxruntime-web runs WASM on several threads only in a cross-origin isolated
page, which needs two response headers (COOP/COEP). Without them the page
runs single-threaded and says so. The folder says how to send them: its
serve.py (Python's file server plus the headers), a `_headers` file (the
format of Netlify and Cloudflare Pages) and README.txt.

Beside every file that gzip shrinks by a fifth or more (the .wasm, the
scripts) lies FILE.gz, made once (compress.py), which serve.py sends to
clients that accept gzip, as nginx's gzip_static does. Every answer says
Cache-Control: no-cache (names are not versioned: a browser keeps files and
revalidates them, 304).

Needs no FastAPI: only the runtime (to check the models) and the files.
"""

import inspect
import json
import shutil
from pathlib import Path

from sinshape import models as shipped
from sinshape.core import files
from sinshape.core.errors import InputError
from sinshape.runtime import load
from sinshape.serve import compress

STATIC = Path(__file__).parent / "static"
MARKER = ".sinshape-site"  # marks a folder this command wrote, so a new export may replace it
# Every answer, from serve.py and (through _headers) from Netlify or Cloudflare Pages.
HEADERS = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp",
           "Cache-Control": "no-cache"}

SERVE_PY = '''"""Serve this folder:  python serve.py [PORT]   (Python 3.8 or newer, nothing else)

Sends what `python -m http.server` does not: the cross-origin isolation
headers that let onnxruntime-web run WASM on several threads; FILE.gz in
place of FILE to a client that accepts gzip (Content-Encoding: gzip, the
type of FILE); and Cache-Control: no-cache with an ETag and Last-Modified,
so a browser keeps what it fetched and checks it with a short request (304)
on each visit: the files' names are not versioned, so nothing may be reused
without asking.
"""

import email.utils
import functools
import http.server
import os
import sys

TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript", ".mjs": "text/javascript",
         ".wasm": "application/wasm", ".json": "application/json", ".css": "text/css",
         ".onnx": "application/octet-stream", ".gz": "application/gzip"}


ACCEPTS_GZIP


class Handler(http.server.SimpleHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive: a visit's requests share connections
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, **TYPES}

    def end_headers(self):
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        super().end_headers()

    def send_head(self):
        path = self.translate_path(self.path)
        if self.path.split("?", 1)[0].split("#", 1)[0].endswith("/"):
            path = os.path.join(path, "index.html")
        if not os.path.isfile(path):
            return super().send_head()  # folders, missing files: as http.server answers them
        packed = path + ".gz"
        has_packed = os.path.isfile(packed)
        chosen = packed if has_packed and accepts_gzip(self.headers.get("Accept-Encoding", "")) else path
        try:
            file = open(chosen, "rb")
        except OSError:
            self.send_error(404, "File not found")
            return None
        stat = os.fstat(file.fileno())
        etag = '"%x-%x%s"' % (stat.st_size, stat.st_mtime_ns, "-gzip" if chosen == packed else "")
        if self.unchanged(etag, int(stat.st_mtime)):
            file.close()
            self.send_response(304)
            self.send_validators(etag, stat, has_packed)
            self.end_headers()
            return None
        self.send_response(200)
        self.send_header("Content-Type", self.guess_type(path))
        if chosen == packed:
            self.send_header("Content-Encoding", "gzip")
        self.send_header("Content-Length", str(stat.st_size))
        self.send_validators(etag, stat, has_packed)
        self.end_headers()
        return file

    def unchanged(self, etag, modified):
        """If-None-Match names this tag, or (without it) If-Modified-Since is not before the file's time."""
        tags = self.headers.get("If-None-Match")
        if tags is not None:
            return any(tag.strip() in (etag, "W/" + etag, "*") for tag in tags.split(","))
        since = self.headers.get("If-Modified-Since")
        try:
            return since is not None and modified <= email.utils.parsedate_to_datetime(since).timestamp()
        except (TypeError, ValueError, IndexError, OverflowError):
            return False

    def send_validators(self, etag, stat, has_packed):
        self.send_header("Cache-Control", "no-cache")
        self.send_header("ETag", etag)
        self.send_header("Last-Modified", self.date_time_string(stat.st_mtime))
        if has_packed:  # on both answers, so that no cache gives gzip to a client that did not ask
            self.send_header("Vary", "Accept-Encoding")


port = int(sys.argv[1]) if len(sys.argv) > 1 else 8000
folder = os.path.dirname(os.path.abspath(__file__))
server = http.server.ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Handler, directory=folder))
print(f"serving on http://127.0.0.1:{port}/ (Ctrl-C stops)")
try:
    server.serve_forever()
except KeyboardInterrupt:
    pass
'''.replace("ACCEPTS_GZIP\n", inspect.getsource(compress.accepts_gzip))  # the script stands alone: a copy, made here

README = """sinshape in the browser: {names}

Open index.html through any static file server; samples are made in the
browser (onnxruntime-web), nothing runs on the server, nothing is fetched
from elsewhere. For example, in this folder:

    python serve.py                   then open http://127.0.0.1:8000/
    python -m http.server             (or this: single-threaded, uncompressed)

WASM runs on several threads only when the page is cross-origin isolated,
which needs these two headers on every file:

    Cross-Origin-Opener-Policy: same-origin
    Cross-Origin-Embedder-Policy: require-corp

`python serve.py` sends them; `_headers` gives them to Netlify and
Cloudflare Pages; for nginx: add_header for both. Without them the page
works single-threaded and says so. Opening index.html as a file:// URL does
not work (browsers do not load modules from files).

FILE.gz beside a file is that file gzipped (level 9): serve.py sends it,
with Content-Encoding: gzip, to browsers that accept gzip, so the 14 MB
.wasm travels as 3.7 MB; nginx does the same with `gzip_static on;`.
Netlify and Cloudflare Pages compress on their own. Files are sent with
Cache-Control: no-cache: browsers keep them and revalidate (304), since
their names do not change when their contents do. The sinshape
documentation, docs/WEB.md, has a whole nginx configuration.

Made by `sinrun export-web` (sinshape {version}).
"""


def resolve(names) -> dict:
    """Shipped model names or .onnx paths -> {name: loaded model}, each checked
    by the Python loader (the same refusals as `sinrun sample`)."""
    models = {}
    for item in names:
        path = shipped.find(item)
        name = item if item in shipped.available() and not Path(item).is_file() else path.stem
        if name in models:
            raise InputError(f"two models are called {name!r}; rename one file")
        models[name] = load.load_model(path, threads=1)
    if not models:
        raise InputError("name at least one model (a shipped name or a .onnx file)")
    return models


def page_html() -> str:
    """The viewer's page, switched to browser-only sampling."""
    html = (STATIC / "index.html").read_text()
    changes = {
        '<body data-state="starting">': '<body data-state="starting" data-site="static">',
        'The API is described at <a href="openapi.json">openapi.json</a>.':
            'Samples are made in this browser: nothing runs on the server.',
    }
    for old, new in changes.items():
        if old not in html:
            raise RuntimeError(f"serve/static/index.html no longer contains {old!r}")
        html = html.replace(old, new)
    return html


def write_site(folder: Path, models: dict, version: str) -> None:
    """Every file of the site, into an empty `folder`; models as sealed
    format-3 files (older ones rewritten), which is what the browser reads."""
    shutil.copytree(STATIC, folder / "static", ignore=shutil.ignore_patterns("index.html", "__pycache__"))
    (folder / "index.html").write_text(page_html())
    (folder / "models").mkdir()
    listing = []
    for name, model in models.items():
        (folder / "models" / f"{name}.onnx").write_bytes(load.format3_bytes(model))
        sizes = model.manifest.sizes
        listing.append({"name": name, "size": list(sizes[-1]), "levels": len(sizes), "up": model.manifest.up,
                        "file": f"models/{name}.onnx"})
    (folder / "models.json").write_text(json.dumps(listing, indent=1) + "\n")
    (folder / "serve.py").write_text(SERVE_PY)
    (folder / "_headers").write_text("/*\n" + "".join(f"  {k}: {v}\n" for k, v in HEADERS.items()))
    (folder / "README.txt").write_text(README.format(names=", ".join(models), version=version))
    compress.write_beside(folder)
    (folder / MARKER).write_text(json.dumps({"sinshape": version, "models": list(models)}) + "\n")


def folder_bytes(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())


def export_site(names, out, version: str = "") -> dict:
    """Write a static site sampling `names` (shipped names or .onnx paths) to `out`.

    `out` must not exist, be empty, or be a site this function wrote before
    (it is then replaced). Written next to `out` and renamed into place, so
    a failure leaves nothing behind. Returns {"path", "models", "bytes", "files"}.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).is_file():
        raise InputError(f"{out}: a folder with other files in it; name a new or empty folder "
                         "(a folder that export-web wrote is replaced)")
    models = resolve(names)
    for model in models.values():  # replacing the folder would delete them
        if out.resolve() in model.path.resolve().parents:
            raise InputError(f"{model.path}: a model inside the folder {out} that is replaced; copy it elsewhere first")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise InputError(f"{parent}: no such folder")
    # Unique names of bounded length: two exports to one folder never share them.
    temporary, old = files.temporary_path(parent / out.name, "partial"), files.temporary_path(parent / out.name, "old")
    try:
        temporary.mkdir()
        write_site(temporary, models, version)
        if out.exists():
            out.rename(old)
        temporary.rename(out)
    except OSError as error:
        raise InputError(f"{out}: cannot write the site ({error.strerror or error})") from None
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
    written = [f for f in out.rglob("*") if f.is_file()]
    return {"path": out, "models": list(models), "bytes": sum(f.stat().st_size for f in written), "files": len(written)}
