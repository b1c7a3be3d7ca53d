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

Needs no FastAPI: only the runtime (to check the models) and the files.
"""

import json
import shutil
from pathlib import Path

from sinshape import models as shipped
from sinshape.core import files
from sinshape.core.errors import InputError
from sinshape.runtime import load

STATIC = Path(__file__).parent / "static"
MARKER = ".sinshape-site"  # marks a folder this command wrote, so a new export may replace it
HEADERS = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp"}

SERVE_PY = '''"""Serve this folder with the cross-origin isolation headers that let
onnxruntime-web run WASM on several threads:  python serve.py [PORT]
(`python -m http.server` works too, single-threaded.)"""

import functools
import http.server
import sys
from pathlib import Path


class Handler(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map,
                      ".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm"}

    def end_headers(self):
        self.send_header("Cross-Origin-Opener-Policy", "same-origin")
        self.send_header("Cross-Origin-Embedder-Policy", "require-corp")
        super().end_headers()


port = int(sys.argv[1]) if len(sys.argv) > 1 else 8000
server = http.server.ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Handler, directory=Path(__file__).parent))
print(f"serving on http://127.0.0.1:{port}/ (Ctrl-C stops)")
try:
    server.serve_forever()
except KeyboardInterrupt:
    pass
'''

README = """sinshape in the browser: {names}

Open index.html through any static file server; samples are made in the
browser (onnxruntime-web), nothing runs on the server, nothing is fetched
from elsewhere. For example:

    python -m http.server -d .        then open http://localhost:8000/

WASM runs on several threads only when the page is cross-origin isolated,
which needs these two headers on every file:

    Cross-Origin-Opener-Policy: same-origin
    Cross-Origin-Embedder-Policy: require-corp

`python serve.py` sends them; `_headers` gives them to Netlify and
Cloudflare Pages; for nginx: add_header for both. Without them the page
works single-threaded and says so. Opening index.html as a file:// URL does
not work (browsers do not load modules from files).

The files are sent as they are unless the server compresses them; the
.wasm is 28 MB, 6.7 MB gzipped. Over a network, let the server gzip
application/wasm and JavaScript (nginx: gzip on; gzip_comp_level 6;
gzip_types text/javascript application/javascript application/wasm;
and map .mjs to text/javascript). The sinshape documentation, docs/WEB.md,
has a whole nginx configuration.

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
