"""`sinrun export-web`: a static folder that samples models in the browser.

The folder holds the page (index.html, the viewer in browser-only mode), the
JavaScript runtime (static/sinshape/), onnxruntime-web and three.js (static/
vendor/), and the models (models/NAME.onnx, listed in models.json). Any
static file server serves it, offline; nothing runs on the server.

onnxruntime-web runs WASM on several threads only in a cross-origin isolated
page, which needs two response headers (COOP/COEP). Without them the page
runs single-threaded and says so. The folder says how to send them: its
serve.py (Python's file server plus the headers: site_server.py, copied as
it is), a `_headers` file (the format of Netlify and Cloudflare Pages) and
README.txt.

Beside every file that gzip shrinks by a fifth or more (the .wasm, the
scripts) lies FILE.gz, made once (compress.py), which serve.py sends to
clients that accept gzip, as nginx's gzip_static does. Every answer says
Cache-Control: no-cache (names are not versioned: a browser keeps files and
revalidates them, 304).

Needs no FastAPI: only the runtime (to check the models) and the files.
Every file is written through core.files.atomic_write.

Nothing the user put in the folder is deleted: the folder's `.sinshape-site`
lists every file the command wrote, with its SHA-256, and a new export
replaces only those (a listed file the user changed is theirs now). A
folder holding anything else is refused, naming what is in the way, unless
`force`, which keeps those files and replaces the command's own.
"""

import hashlib
import json
import os
import shutil
from pathlib import Path

from sinshape.core import files
from sinshape.core.errors import InputError
from sinshape.runtime import load
from sinshape.serve import catalog, compress, site_server

STATIC = Path(__file__).parent / "static"
MARKER = ".sinshape-site"  # the files this command wrote in a folder, with their SHA-256: what a new export may replace
MAX_MARKER_BYTES = 1 << 20
SHOWN = 5  # files in the way named in a refusal
# Every answer, from serve.py and (through _headers) from Netlify or Cloudflare Pages.
HEADERS = {**site_server.ISOLATION_HEADERS, "Cache-Control": "no-cache"}
SERVER = Path(site_server.__file__)  # the site's serve.py

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
    by the Python loader (the same refusals as `sinrun sample`) and named as
    `sinrun serve` names it."""
    if not names:
        raise InputError("name at least one model (a shipped name or a .onnx file)")
    return catalog.load_models(names, threads=1)


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


def put(path: Path, data) -> None:
    """One file of the site, text or bytes, through atomic_write."""
    data = data.encode() if isinstance(data, str) else data
    path.parent.mkdir(parents=True, exist_ok=True)
    files.atomic_write(path, lambda f: f.write(data))


def write_site(folder: Path, models: dict, version: str) -> None:
    """Every file of the site, into an empty `folder`; models as sealed
    format-3 files (older ones rewritten), which is what the browser reads."""
    for source in sorted(STATIC.rglob("*")):
        if source.is_file() and source.name != "index.html" and "__pycache__" not in source.parts:
            put(folder / "static" / source.relative_to(STATIC), source.read_bytes())
    put(folder / "index.html", page_html())
    listing = []
    for name, model in models.items():
        put(folder / "models" / f"{name}.onnx", load.format3_bytes(model))
        listing.append({**catalog.entry(name, model), "file": f"models/{name}.onnx"})
    put(folder / "models.json", json.dumps(listing, indent=1) + "\n")
    put(folder / "serve.py", SERVER.read_bytes())
    put(folder / "_headers", "/*\n" + "".join(f"  {k}: {v}\n" for k, v in HEADERS.items()))
    put(folder / "README.txt", README.format(names=", ".join(models), version=version))
    compress.write_beside(folder)
    listing = {rel: [digest(folder / rel)] for rel in entries(folder)[0]}
    put(folder / MARKER, json.dumps({"sinshape": version, "models": list(models), "files": listing}) + "\n")


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def entries(folder: Path) -> tuple:
    """(regular files, everything else: links, pipes, ...) under `folder`, as
    relative POSIX paths, the marker left out; links are not followed."""
    regular, other = [], []
    for root, dirs, names in os.walk(folder):
        for name in [*names, *(d for d in dirs if os.path.islink(os.path.join(root, d)))]:
            path = Path(root, name)
            rel = path.relative_to(folder).as_posix()
            if rel != MARKER:
                (regular if path.is_file() and not path.is_symlink() else other).append(rel)
    return sorted(regular), sorted(other)


def written_before(folder: Path) -> dict:
    """{relative path: [SHA-256, ...]} of the files an export wrote in
    `folder`, from its marker, checked field by field ({} for none, or one
    that is not a marker)."""
    marker = folder / MARKER
    try:
        if not marker.is_file() or marker.is_symlink() or marker.stat().st_size > MAX_MARKER_BYTES:
            return {}
        listing = json.loads(marker.read_bytes()).get("files")
    except (OSError, ValueError, AttributeError, RecursionError):
        return {}
    if not isinstance(listing, dict):
        return {}
    return {rel: hashes for rel, hashes in listing.items()
            if isinstance(hashes, list) and all(isinstance(h, str) for h in hashes)}


def in_the_way(folder: Path) -> list:
    """What in `folder` an export did not write, or that changed since it
    did: files the user made, which an export never deletes."""
    if not folder.is_dir():
        return []
    ours = written_before(folder)
    regular, other = entries(folder)
    return sorted(other + [rel for rel in regular if rel not in ours or digest(folder / rel) not in ours[rel]])


def merge(made: Path, out: Path) -> None:
    """Move the site in `made` into `out`, file by file (each a rename),
    and remove the files the last export wrote that this one does not;
    anything else in `out` stays. The marker first lists old and new
    hashes, so that a crash halfway leaves every file accounted for."""
    old, new = written_before(out), written_before(made)
    both = {rel: old.get(rel, []) + new.get(rel, []) for rel in {*old, *new}}
    put(out / MARKER, json.dumps({"files": both}) + "\n")
    for rel in new:
        target = files.written_path(out / rel)
        target.parent.mkdir(parents=True, exist_ok=True)
        files.check_replaceable(target)
        os.replace(made / rel, target)
    for rel in sorted(set(old) - set(new)):
        path = out / rel
        if path.is_file() and not path.is_symlink() and digest(path) in old[rel]:
            path.unlink()
            for parent in path.relative_to(out).parents:
                if str(parent) != "." and not any((out / parent).iterdir()):
                    (out / parent).rmdir()
    os.replace(made / MARKER, out / MARKER)


def export_site(names, out, version: str = "", force: bool = False) -> dict:
    """Write a static site sampling `names` (shipped names or .onnx paths) to `out`.

    `out` is new, empty, or holds only what an export wrote there (which is
    replaced); anything else in it is refused by name, unless `force`, which
    keeps it and replaces the export's own files. A symbolic link is written
    through. The site is made beside `out` first, so a failure leaves `out`
    as it was. Returns {"path", "models", "bytes", "files"}.
    """
    out = files.written_path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    foreign = in_the_way(out)
    if foreign and not force:
        shown = ", ".join(foreign[:SHOWN]) + (f" and {len(foreign) - SHOWN} more" if len(foreign) > SHOWN else "")
        raise InputError(f"{out}: holds files export-web did not write ({shown}); move them away, or `force` to "
                         "keep them and replace the rest", "force")
    models = resolve(names)
    for model in models.values():  # replacing the folder would delete them
        if out.resolve() in model.path.resolve().parents:
            raise InputError(f"{model.path}: a model inside the folder {out} that is replaced; copy it elsewhere first")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise InputError(f"{parent}: no such folder")
    # A unique name of bounded length: two exports to one folder never share it.
    temporary = files.temporary_path(parent / out.name, "partial")
    try:
        temporary.mkdir()
        write_site(temporary, models, version)
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        if out.exists():
            merge(temporary, out)
        else:
            temporary.rename(out)
    except OSError as error:
        raise InputError(f"{out}: cannot write the site ({error.strerror or error})") from None
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
    written = written_before(out)
    return {"path": out, "models": list(models), "bytes": sum((out / rel).stat().st_size for rel in written),
            "files": len(written)}
