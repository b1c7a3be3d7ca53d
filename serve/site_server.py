"""Serve this folder:  python serve.py [PORT]   (Python 3.8 or newer, nothing else)

Sends what `python -m http.server` does not: the cross-origin isolation
headers that let onnxruntime-web run WASM on several threads; errors as a
line of JSON, as `sinrun serve` answers them; FILE.gz in
place of FILE to a client that accepts gzip (Content-Encoding: gzip, the
type of FILE); and Cache-Control: no-cache with an ETag and Last-Modified,
so a browser keeps what it fetched and checks it with a short request (304)
on each visit: the files' names are not versioned, so nothing may be reused
without asking.

(sinshape's serve/site_server.py, copied as it is into every folder `sinrun
export-web` writes: the standard library only, since a site is served where
sinshape is not installed. `sinrun serve` takes its isolation headers and
its reading of Accept-Encoding from here.)
"""

import email.utils
import functools
import http.server
import json
import os
import sys

# Cross-origin isolation: lets the page use SharedArrayBuffer (multi-threaded WASM).
ISOLATION_HEADERS = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp"}
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript", ".mjs": "text/javascript",
         ".wasm": "application/wasm", ".json": "application/json", ".css": "text/css",
         ".onnx": "application/octet-stream", ".gz": "application/gzip"}


def accepts_gzip(header: str) -> bool:
    """Whether an Accept-Encoding header accepts gzip: 'gzip, br' yes,
    'gzip;q=0' and 'identity' no, '*' yes."""
    for item in header.split(","):
        name, _, parameters = item.partition(";")
        if name.strip().lower() not in ("gzip", "x-gzip", "*"):
            continue
        quality = parameters.strip().lower().replace(" ", "")
        try:
            return not (quality.startswith("q=") and float(quality[2:]) == 0)
        except ValueError:
            return False
    return False


class Handler(http.server.SimpleHTTPRequestHandler):
    """Python's file server, plus the isolation headers, FILE.gz and the validators."""

    protocol_version = "HTTP/1.1"  # keep-alive: a visit's requests share connections
    # http.server's table of types, extended; read only
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, **TYPES}  # noqa: RUF012

    def end_headers(self):
        for name, value in ISOLATION_HEADERS.items():
            self.send_header(name, value)
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
            file = open(chosen, "rb")  # noqa: SIM115  http.server sends and closes what send_head returns
        except OSError:
            self.send_error(404, "File not found")
            return None
        stat = os.fstat(file.fileno())
        encoding = "-gzip" if chosen == packed else ""
        etag = f'"{stat.st_size:x}-{stat.st_mtime_ns:x}{encoding}"'
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

    def send_error(self, code, message=None, explain=None):
        """An error as `sinrun serve` answers one: a line of JSON, {"detail": ...}."""
        short = self.responses.get(code, ("Error", ""))[0]
        detail = " ".join(str(message or short).split())
        body = json.dumps({"detail": detail}).encode()
        self.log_error("code %d, message %s", code, detail)
        self.send_response(code, detail.encode("latin-1", "replace").decode("latin-1"))
        self.send_header("Connection", "close")
        if code >= 200 and code not in (204, 205, 304):
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        if self.command != "HEAD" and code >= 200 and code not in (204, 205, 304):
            self.wfile.write(body)

    def send_validators(self, etag, stat, has_packed):
        self.send_header("Cache-Control", "no-cache")
        self.send_header("ETag", etag)
        self.send_header("Last-Modified", self.date_time_string(stat.st_mtime))
        if has_packed:  # on both answers, so that no cache gives gzip to a client that did not ask
            self.send_header("Vary", "Accept-Encoding")


def make_server(folder: str, port: int) -> http.server.ThreadingHTTPServer:
    """A server of `folder` on 127.0.0.1:`port` (0: a free port), not yet serving."""
    return http.server.ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Handler, directory=folder))


def main(argv) -> None:
    """`python serve.py [PORT]`: serve the folder this file lies in until
    Ctrl-C. A port that is not one, or cannot be listened on, is one line
    on stderr and exit status 1."""
    if len(argv) > 1 or argv and not (argv[0].isdigit() and 0 <= int(argv[0]) <= 65535):
        sys.exit(f"Error: give one port, a whole number from 0 to 65535 (python serve.py [PORT]); got {' '.join(argv)!r}")
    port = int(argv[0]) if argv else 8000
    try:
        server = make_server(os.path.dirname(os.path.abspath(__file__)), port)
    except OSError as error:
        sys.exit(f"Error: cannot listen on 127.0.0.1:{port} ({error.strerror or error})")
    print(f"serving on http://127.0.0.1:{port}/ (Ctrl-C stops)")
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main(sys.argv[1:])
