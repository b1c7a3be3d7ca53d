"""What every answer of `sinrun serve` gets, whatever its route: the Host
check, the isolation headers, gzip, and entity tags.

- A request whose Host header names none of the allowed names is answered
  400: a page elsewhere that points a name of its own at this address (DNS
  rebinding) is refused.
- Every answer carries the cross-origin isolation headers (COOP/COEP), so
  the page's in-browser sampling may run onnxruntime-web's WASM on several
  threads (SharedArrayBuffer needs them); the page loads nothing from elsewhere.
- Answers of 1 kB and more are gzip-compressed for clients that accept
  gzip. The page's static files (its scripts, onnxruntime-web's 14 MB of
  WASM, 3.7 MB sent) are compressed once, on their first request, and kept
  in memory (about 4 MB in all: StaticFiles); samples, JSON and model files
  are compressed as they go out (Starlette's GZipMiddleware). A compressed
  answer's ETag is weak (W/"..."): the bytes sent are gzip's, not the file's.
- A file made or loaded by the server gets its ETag from entity_tag and is
  answered by file_answer, which gives 304 where If-None-Match names it.
  Static files say Cache-Control: no-cache: their names are not versioned,
  so a browser keeps them and revalidates them (304, Starlette's ETag)
  rather than reuse them unasked.

- Every 4xx and 5xx answer is one line of JSON, {"detail": "..."}, whoever
  made it: the routes, Starlette's layers under them (a malformed Range, an
  unknown path, a method not allowed: JSONErrors) and uvicorn's parser
  under those (a request it cannot parse, a negative Content-Length:
  JSONH11Protocol).
- HEAD is answered wherever GET is, with GET's headers and no body, and
  `If-None-Match: *` by HTTP's rule: 304 for a GET or HEAD of a resource
  that exists, 412 for another method.

The isolation headers and the reading of Accept-Encoding are the exported
site's server's (site_server.py, which stands alone), imported from there.
"""

import asyncio
import hashlib
import json
from http import HTTPStatus
from pathlib import Path

from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles as StarletteStaticFiles
from starlette.datastructures import Headers, MutableHeaders
from starlette.middleware.gzip import GZipMiddleware

from sinshape.serve import compress
from sinshape.serve.site_server import ISOLATION_HEADERS, accepts_gzip

# Samples, JSON and model files: gzip level 6 (zlib's default) as they go out; level 9 takes twice
# as long for 1% less. The page's files are compressed once, at compress.LEVEL (StaticFiles).
GZIP_LEVEL, GZIP_MINIMUM = 6, 1024
LOOPBACK = ("127.0.0.1", "localhost", "::1")
ANY_ADDRESS = ("0.0.0.0", "::", "")


def entity_tag(body: bytes) -> str:
    """A strong ETag for these bytes: their sha256, quoted. A seed stands for
    the same shape everywhere, so a tag never goes stale."""
    return f'"{hashlib.sha256(body).hexdigest()[:40]}"'


def file_answer(request, body: bytes, tag: str, media_type: str, headers: dict) -> Response:
    """`body` with its ETag `tag`, Cache-Control: no-cache and `headers`; or
    304 with the same headers and no body where If-None-Match names the tag
    (weak or strong: a gzipped answer's tag is the same one made weak)."""
    headers = {"ETag": tag, "Cache-Control": "no-cache", **headers}
    known = [item.strip().removeprefix("W/") for item in request.headers.get("if-none-match", "").split(",")]
    if tag in known or "*" in known:
        return Response(status_code=304, headers=headers)
    return Response(body, media_type=media_type, headers=headers)


def host_name(header: str) -> str:
    """The name in a Host header, without its port: 'localhost:8000' ->
    'localhost', '[::1]:8000' -> '::1'."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:header.find("]")] if "]" in header else header
    return header.rsplit(":", 1)[0] if header.count(":") == 1 else header


def allowed_hosts(host: str, extra=()) -> tuple:
    """The loopback names, the address listened on (unless it is every
    address), and `extra`."""
    return tuple(dict.fromkeys([*LOOPBACK, *([] if host in ANY_ADDRESS else [host.strip("[]")]), *extra]))


class HostsAndIsolation:
    """ASGI middleware: a request whose Host header names none of `allowed`
    is answered 400; every answer gets the isolation headers, and a
    compressed answer's strong ETag is made weak. (Plain ASGI, not
    Starlette's BaseHTTPMiddleware, under which a route cannot see its
    client leave.)"""

    def __init__(self, app, allowed: set):
        self.app, self.allowed = app, allowed

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        host = host_name(Headers(scope=scope).get("host", ""))
        if host not in self.allowed:
            answer = JSONResponse({"detail": f"this server does not answer to the host {host!r}; it answers to "
                                             f"{', '.join(sorted(self.allowed))} (allowed_hosts)"}, status_code=400)
            return await answer(scope, receive, send)

        async def send_isolated(message):
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                headers.update(ISOLATION_HEADERS)
                etag = headers.get("etag", "")
                if "content-encoding" in headers and etag.startswith('"'):  # a strong tag names the exact bytes
                    headers["etag"] = f"W/{etag}"
            await send(message)

        await self.app(scope, receive, send_isolated)


class StaticFiles(StarletteStaticFiles):
    """The page's files, each with Cache-Control: no-cache, and gzipped for
    clients that accept it: each file worth it (compress.py) once, on its
    first such request, in a worker thread; kept in memory for the server's
    life (about 4 MB) and made again only if the file changes. Range
    requests, and clients that do not accept gzip, get the file itself."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.packed = {}  # Path -> ((mtime_ns, size), a future of gzip's bytes or None)

    async def get_response(self, path: str, scope) -> Response:
        response = await super().get_response(path, scope)
        response.headers["Cache-Control"] = "no-cache"
        if not (isinstance(response, FileResponse) and response.status_code == 200 and response.stat_result):
            return response  # 304, redirects, errors
        file, stat = Path(response.path), response.stat_result
        if not compress.worth_trying(file, stat.st_size):
            return response
        response.headers["Vary"] = "Accept-Encoding"
        request = Headers(scope=scope)
        if scope["method"] != "GET" or "range" in request or not accepts_gzip(request.get("accept-encoding", "")):
            return response
        body = await self.gzipped(file, (stat.st_mtime_ns, stat.st_size))
        if body is None:
            return response
        headers = {key: value for key, value in response.headers.items()
                   if key not in ("content-length", "accept-ranges")}
        return Response(body, headers={**headers, "Content-Encoding": "gzip"})

    async def gzipped(self, file: Path, key: tuple) -> bytes | None:
        """The file's gzip (None: not worth it); requests that ask at once share one compression."""
        known = self.packed.get(file)
        if known is not None and known[0] == key and known[1].done() and not known[1].exception():
            return known[1].result()
        if known is None or known[0] != key:
            future = asyncio.get_running_loop().run_in_executor(None, lambda: compress.packed(file.read_bytes()))
            known = self.packed[file] = (key, future)
        try:
            return await asyncio.shield(known[1])  # a client that leaves does not cancel it for the others
        except OSError:
            self.packed.pop(file, None)
            return None


class AnswerGZip(GZipMiddleware):
    """Starlette's GZipMiddleware for every answer but the page's files
    ("/" and /static/), which StaticFiles compresses once."""

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and (scope["path"] == "/" or scope["path"].startswith("/static/")):
            return await self.app(scope, receive, send)
        await super().__call__(scope, receive, send)


def error_body(status: int, text: bytes) -> bytes:
    """{"detail": one line} of an error answer: its text, else the status's phrase."""
    detail = " ".join(text.decode("utf-8", "replace").split())[:500]
    if not detail:
        try:
            detail = HTTPStatus(status).phrase
        except ValueError:
            detail = f"status {status}"
    return json.dumps({"detail": detail}).encode()


class JSONErrors:
    """ASGI middleware, innermost: an error answer that is not JSON (Starlette's
    plain-text ones) is rewritten as {"detail": its text}; HEAD is routed as
    GET and answered without the body; `If-None-Match: *` answers 304 (GET,
    HEAD) or 412 (others) where the answer would have been a success."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        head = scope["method"] == "HEAD"
        if head:
            scope = {**scope, "method": "GET"}
        any_tag = "*" in [t.strip() for t in Headers(scope=scope).get("if-none-match", "").split(",")]
        state = {"start": None, "body": [], "mode": "pass"}

        async def send_checked(message):
            if message["type"] == "http.response.start":
                status = message["status"]
                headers = Headers(raw=message.get("headers", []))
                if status >= 400 and not headers.get("content-type", "").startswith("application/json"):
                    state["start"], state["mode"] = message, "error"
                    return
                if any_tag and 200 <= status < 300:
                    state["mode"] = "drop"
                    if scope["method"] == "GET":
                        kept = [(k, v) for k, v in message.get("headers", []) if k.lower() not in
                                (b"content-length", b"content-type", b"content-encoding")]
                        return await send({**message, "status": 304, "headers": kept})
                    state["start"], state["mode"] = {**message, "status": 412, "headers": []}, "error"
                    state["body"] = [b"the resource exists, and If-None-Match: * asks that it does not"]
                    return
                if head:
                    state["mode"] = "head"
                return await send(message)
            if state["mode"] == "error":
                if state["start"]["status"] != 412:
                    state["body"].append(message.get("body", b""))
                if message.get("more_body"):
                    return
                body = error_body(state["start"]["status"], b"".join(state["body"]))
                headers = MutableHeaders(raw=[(k, v) for k, v in state["start"].get("headers", []) if k.lower() not in
                                              (b"content-length", b"content-type", b"content-encoding")])
                headers["content-type"], headers["content-length"] = "application/json", str(len(body))
                await send({**state["start"], "headers": headers.raw})
                return await send({"type": "http.response.body", "body": b"" if head else body})
            if state["mode"] in ("drop", "head"):  # a 304, or HEAD: no body
                if not message.get("more_body"):
                    await send({"type": "http.response.body", "body": b""})
                return
            await send(message)

        await self.app(scope, receive, send_checked)


def json_400_protocol():
    """uvicorn's HTTP/1.1 protocol (h11) whose own 400, for a request it
    cannot parse, is JSON like every other error (uvicorn's is plain text)."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class JSONH11Protocol(H11Protocol):
        def send_400_response(self, msg: str) -> None:
            import h11

            body = error_body(400, msg.encode())
            headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                       (b"connection", b"close")]
            for event in (h11.Response(status_code=400, headers=headers, reason=b"Bad Request"), h11.Data(data=body),
                          h11.EndOfMessage()):
                self.transport.write(self.conn.send(event))
            self.transport.close()

    return JSONH11Protocol


def add_middleware(app, allowed: set) -> None:
    """The Host check, the isolation headers, gzip and JSON errors, on every answer of `app`."""
    # Outermost last: HostsAndIsolation sees the compressed answer's headers.
    app.add_middleware(JSONErrors)
    app.add_middleware(AnswerGZip, minimum_size=GZIP_MINIMUM, compresslevel=GZIP_LEVEL)
    app.add_middleware(HostsAndIsolation, allowed=allowed)
