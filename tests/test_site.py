"""The folder `sinrun export-web` writes, served by its own serve.py: the
.gz copies beside its files, byte-identical exports, and what serve.py
sends (gzip or plain, types, cache headers, 304). No browser needed: the
page itself is tested in test_web.py."""

import ast
import gzip
import http.client
import sys
from pathlib import Path

import pytest

from browser import site_server_process
from sinshape.serve import site, site_server

TINY = Path(__file__).parent / "data" / "tiny.onnx"  # float weights alone, which gzip shrinks by about a tenth

WASM = "static/vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm"


def site_files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_sites_gz_copies_are_its_files_and_two_exports_are_byte_identical(tmp_path):
    site.export_site([str(TINY)], tmp_path / "one")
    site.export_site([str(TINY)], tmp_path / "two")
    files = site_files(tmp_path / "one")
    assert site_files(tmp_path / "two") == files
    packed = {name for name in files if name.endswith(".gz")}
    assert {f"{WASM}.gz", "static/vendor/onnxruntime-web/ort.wasm.min.mjs.gz", "static/sinshape/model.js.gz",
            "static/vendor/onnxruntime-web/ort-wasm-simd-threaded.mjs.gz", "static/vendor/three/three.core.js.gz",
            "index.html.gz"} <= packed
    for name in packed:
        data = files[name]
        assert gzip.decompress(data) == files[name.removesuffix(".gz")], name
        assert data[3] & 0x08 == 0 and data[4:8] == bytes(4), f"{name}: a file name or a time in its header"
        assert data[8] == 2, f"{name}: not gzip's level 9"  # XFL: maximum compression
    assert len(files[f"{WASM}.gz"]) < len(files[WASM]) / 3
    # A model's float weights shrink by about a tenth: no second copy; nor for small files.
    assert "models/tiny.onnx.gz" not in files and "models.json.gz" not in files


def fetch(base: str, path: str, **headers) -> tuple:
    """(status, headers, body) of a GET through http.client: nothing decompressed, 304 not an error."""
    connection = http.client.HTTPConnection(base.removeprefix("http://"), timeout=30)
    try:
        connection.request("GET", "/" + path, headers={k.replace("_", "-"): v for k, v in headers.items()})
        answer = connection.getresponse()
        return answer.status, answer.headers, answer.read()
    finally:
        connection.close()


def test_the_sites_serve_py_sends_gzip_types_and_cache_headers(tmp_path):
    out = tmp_path / "site"
    site.export_site([str(TINY)], out)
    rules = (out / "_headers").read_text().splitlines()
    assert rules[0] == "/*" and {"  Cache-Control: no-cache", "  Cross-Origin-Opener-Policy: same-origin",
                                 "  Cross-Origin-Embedder-Policy: require-corp"} == set(rules[1:])
    with site_server_process(out) as base:  # the standard library only (python -I -S)
        for path, kind in ((WASM, "application/wasm"), ("static/vendor/onnxruntime-web/ort.wasm.min.mjs", "text/javascript"),
                           ("static/sinshape/runtime.js", "text/javascript"), ("", "text/html; charset=utf-8")):
            file = out / (path or "index.html")
            status, plain, body = fetch(base, path)
            assert status == 200 and body == file.read_bytes() and "Content-Encoding" not in plain, path
            status, packed, body = fetch(base, path, Accept_Encoding="gzip, deflate, br")
            assert status == 200 and packed["Content-Encoding"] == "gzip" and gzip.decompress(body) == file.read_bytes()
            assert int(packed["Content-Length"]) == len(body) == (file.parent / f"{file.name}.gz").stat().st_size
            for answer in (plain, packed):  # the same type, cache headers and isolation both ways
                assert answer["Content-Type"] == kind and answer["Vary"] == "Accept-Encoding", path
                assert answer["Cache-Control"] == "no-cache" and answer["ETag"] and answer["Last-Modified"]
                assert answer["Cross-Origin-Opener-Policy"] == "same-origin"
                assert answer["Cross-Origin-Embedder-Policy"] == "require-corp"
            assert plain["ETag"] != packed["ETag"]  # two representations, two tags
            # Revalidation: the tag the browser holds (or the date) gives 304 and no body; another tag, the file.
            status, again, body = fetch(base, path, Accept_Encoding="gzip", If_None_Match=packed["ETag"])
            assert (status, body, again["ETag"], again["Cache-Control"]) == (304, b"", packed["ETag"], "no-cache")
            assert fetch(base, path, If_None_Match=plain["ETag"])[0] == 304
            assert fetch(base, path, If_Modified_Since=plain["Last-Modified"])[0] == 304
            assert fetch(base, path, Accept_Encoding="gzip", If_None_Match=plain["ETag"])[0] == 200
        assert "Content-Encoding" not in fetch(base, WASM, Accept_Encoding="gzip;q=0, identity")[1]
        status, answer, body = fetch(base, "models/tiny.onnx", Accept_Encoding="gzip")  # no .gz: as it is
        assert status == 200 and body == TINY.read_bytes() and "Content-Encoding" not in answer
        assert answer["Content-Type"] == "application/octet-stream" and answer["Cache-Control"] == "no-cache"
        assert fetch(base, "static")[0] == 301 and fetch(base, "nope.js")[0] == 404


def test_the_sites_serve_py_is_site_server_standing_alone(tmp_path):
    """serve.py is serve/site_server.py as it is: Python 3.8's grammar and
    the standard library only, since a site is served where sinshape is not
    installed (test_the_sites_serve_py_sends_... runs it with python -I -S)."""
    site.export_site(["terrain"], tmp_path / "site")
    source = Path(site_server.__file__).read_bytes()
    assert (tmp_path / "site" / "serve.py").read_bytes() == source
    tree = ast.parse(source, feature_version=(3, 8))
    imported = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert imported and imported <= sys.stdlib_module_names, imported - sys.stdlib_module_names
    newer = {"removeprefix", "removesuffix"}  # str methods of 3.9
    assert not {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)} & newer


@pytest.mark.parametrize("header, gzip_please", [
    ("gzip, deflate, br", True), ("GZIP", True), ("x-gzip", True), ("*", True), ("br, gzip;q=0.5", True),
    ("gzip;q=0", False), ("gzip; q=0.0", False), ("identity", False), ("", False), ("gzip;q=nope", False),
])
def test_accept_encoding_is_read_as_the_service_reads_it(header, gzip_please):
    """One reading of Accept-Encoding for serve.py and `sinrun serve`'s static files."""
    from sinshape.serve import http

    assert site_server.accepts_gzip(header) is gzip_please
    assert http.accepts_gzip is site_server.accepts_gzip
