"""The ASGI app: list models, describe one, sample one as a file, give a
sample's coarse layout (runtime.layout, for the page's layout editor), and the page.

Routes parse typed query values (a wrong type is a 422 with a one-line
message before any code runs), call the runtime, and answer. Everything a
request shares is made once, in the lifespan: the loaded models, a thread
pool and a semaphore sized to the cores (sampling never runs on the event
loop), and a bounded LRU cache of finished files keyed by the normalised
request. A seed stands for the same shape everywhere, so a file's ETag (the
sha256 of its bytes) is strong and the cache never goes stale.

Errors are JSON {"detail": "one line"}: 422 for a value of the wrong type
or range, 400 for a value the runtime refuses, 413 for work that would
exceed the runtime's memory limit (the message gives the figure), 404 for an
unknown model, 503 when no sampling slot frees up in time, 504 when
sampling takes longer than the time limit.

Every answer carries the cross-origin isolation headers (COOP/COEP), so the
page's in-browser sampling may run onnxruntime-web's WASM on several threads
(SharedArrayBuffer needs them); the page loads nothing from elsewhere.

Answers of 1 kB and more are gzip-compressed for clients that accept gzip.
The page's static files (its scripts, onnxruntime-web's 14 MB of WASM,
3.7 MB sent) are compressed once, on their first request, and kept in
memory (about 4 MB in all: StaticFiles); samples, JSON and model files are
compressed as they go out (Starlette's GZipMiddleware). A compressed
answer's ETag is weak (W/"..."): the bytes sent are gzip's, not the file's.
Static files say Cache-Control: no-cache: their names are not versioned, so
a browser keeps them and revalidates them (304) rather than reuse them unasked.
"""

import asyncio
import hashlib
import importlib.metadata
import io
import json
import logging
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles as StarletteStaticFiles
import numpy as np
import trimesh  # noqa: F401  a service makes whole meshes: imported at start-up, not in its first request
from pydantic import BaseModel
from starlette.datastructures import Headers, MutableHeaders
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect
from starlette.middleware.gzip import GZipMiddleware

from sinshape import models as shipped
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.runtime import generate, layout, load, mesh, write
from sinshape.runtime.request import Layout, SampleRequest, make, resolved
from sinshape.serve import compress

STATIC = Path(__file__).parent / "static"
Format = Literal["glb", "ply", "obj", "stl", "off", "npz"]
LayoutFormat = Literal["json", "vox", "npz"]
MEDIA_TYPES = {"glb": "model/gltf-binary", "obj": "model/obj", "stl": "model/stl",
               "json": "application/json"}  # others: octet-stream
MAX_SMOOTH = mesh.MAX_SMOOTH  # smoothing cannot be interrupted either; the runtime bounds it
# Cross-origin isolation: lets the page use SharedArrayBuffer (multi-threaded WASM).
ISOLATION_HEADERS = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp"}
# Samples, JSON and model files: gzip level 6 (zlib's default) as they go out; level 9 takes twice
# as long for 1% less. The page's files are compressed once, at compress.LEVEL (StaticFiles).
GZIP_LEVEL, GZIP_MINIMUM = 6, 1024
log = logging.getLogger("sinshape.serve")


class Detail(BaseModel):
    """Every error's body."""

    detail: str


def errors(*statuses) -> dict:
    """OpenAPI descriptions of a route's error answers (422 replaces FastAPI's list form)."""
    meaning = {400: "a value the runtime refuses", 404: "no such model", 413: "over the memory limit",
               422: "a value of the wrong type or range", 503: "no sampling slot free in time",
               504: "over the time limit"}
    return {status: {"model": Detail, "description": meaning[status]} for status in statuses}


FILE_ANSWERS = {
    200: {"description": "The file", "content": {t: {} for t in [*MEDIA_TYPES.values(), "application/octet-stream"]}},
    304: {"description": "Not modified: If-None-Match named its ETag"},
    **errors(400, 404, 413, 422, 503, 504),
}


@dataclass(frozen=True)
class Job:
    """One file a route asks for, normalised (the runtime's request with its
    parts resolved), so that equal jobs give equal bytes: the cache's key.
    layout_of: not the sample but its layout at this level (format json, vox or npz)."""

    model: str
    request: SampleRequest
    format: str
    layout_of: int | None = None

    def filename(self) -> str:
        request = self.request
        tags = [f"seed{request.seed}"] + [f"keep{part.seed}" for part in request.keep]
        if self.layout_of is not None:
            tags.append(f"layout{self.layout_of}")
        if request.grow:
            tags.append("grow" + "x".join(f"{f:g}" for f in request.grow))
        if request.layout:
            tags.append("layout" + hashlib.sha256(request.layout.bits).hexdigest()[:8])
        if request.size != (1.0, 1.0, 1.0):
            tags.append("size" + "x".join(f"{f:g}" for f in request.size))
        if request.scale != 1:
            tags.append(f"scale{request.scale:g}")
        if request.smooth and self.format != "npz":
            tags.append(f"smooth{request.smooth}")
        return f"{self.model}_{'_'.join(tags)}.{self.format}"


@dataclass(frozen=True)
class Sample:
    """A finished file."""

    body: bytes
    etag: str  # strong: the sha256 of the body, quoted
    faces: int | None  # None for an occupancy grid
    seconds: float  # time it took to make


# The query parameters of a sample (the layout route takes seed and size too).
SeedQuery = Annotated[int, Query(ge=0, lt=2**63, description="The same seed gives the same shape.")]
SizeQuery = Annotated[str, Query(description="Factors of the training size: one, or sx,sy,sz.")]
ScaleQuery = Annotated[float, Query(gt=0, allow_inf_nan=False,
                                    description="Query a grid this many times finer per axis.")]
SmoothQuery = Annotated[int, Query(ge=0, le=MAX_SMOOTH, description="Laplacian smoothing steps.")]
FormatQuery = Annotated[Format, Query(description="glb ply obj stl off: a mesh; npz: the occupancy grid.")]


@dataclass
class SampleQuery:
    """What both sample routes take: the model's name (the path's) and the
    query parameters of a sample."""

    name: str
    seed: SeedQuery = 0
    size: SizeQuery = "1"
    scale: ScaleQuery = 1.0
    smooth: SmoothQuery = 0
    format: FormatQuery = "glb"


MAX_UPLOAD_BYTES = 4 << 20  # a layout of a coarse level is a few kB


def layout_suffix(data: bytes) -> str:
    """.vox or .npz, by the file's first bytes."""
    if data.startswith(b"VOX "):
        return ".vox"
    if data.startswith(b"PK"):
        return ".npz"
    raise InputError("the layout is neither a MagicaVoxel .vox nor an .npz file")


class Cancelled(Exception):
    """Raised inside a sampling thread whose request ran out of time, or whose clients all left."""


class ClientGone(Exception):
    """The client closed the connection before its sample was made."""


DISCONNECT_POLL = 0.25  # seconds between checks that a waiting client is still there


def layout_file(grid: np.ndarray, level: int, format: str) -> bytes:
    """A layout as `sinrun layout` writes it (.vox, .npz), or as JSON: {shape,
    level, occupancy}, occupancy a string of '0' and '1' per cell, x slowest, z fastest."""
    if format == "vox":
        if max(grid.shape) > layout.MAX_LAYOUT_SIDE:
            raise InputError(f"a {'x'.join(map(str, grid.shape))} layout; .vox holds at most "
                             f"{layout.MAX_LAYOUT_SIDE} voxels per axis (ask for npz)")
        return layout.vox_bytes(grid)
    if format == "npz":
        buffer = io.BytesIO()
        np.savez_compressed(buffer, layout=grid.astype(bool))
        return buffer.getvalue()
    cells = np.where(grid.ravel(), b"1", b"0").tobytes().decode()
    return json.dumps({"shape": list(grid.shape), "level": level, "occupancy": cells}).encode()


def make_sample(model, job: Job, cancel: threading.Event) -> Sample:
    """The file one job asks for, made by the runtime (runs in a worker thread)."""

    def check_cancel(*_):
        if cancel.is_set():
            raise Cancelled

    started = time.perf_counter()
    if job.layout_of is not None:  # a layout, not a sample
        grid = layout.layout(model, job.request.sample_seed, job.layout_of, job.request.size)
        body, faces = layout_file(grid, job.layout_of, job.format), None
    else:
        triplane = make(model, job.request)
        check_cancel()
        body, result = write.sample_bytes(model, triplane, job.filename(), mesh_progress=check_cancel,
                                          **job.request.mesh_options())
        faces = None if result is None else len(result.faces)
    return Sample(body, f'"{hashlib.sha256(body).hexdigest()[:40]}"', faces, time.perf_counter() - started)


class Sampler:
    """Bounded sampling: at most `slots` samples at once, each within `timeout`
    seconds, finished files kept in an LRU cache of at most `cache_bytes`.

    Identical requests in flight share one computation. Lives on the event
    loop's thread; only make_sample runs in the pool.
    """

    def __init__(self, slots: int, timeout: float, cache_bytes: int, cache_entries: int = 256):
        self.slots = asyncio.Semaphore(slots)
        self.pool = ThreadPoolExecutor(max_workers=slots, thread_name_prefix="sample")
        self.timeout = timeout
        self.cache = OrderedDict()  # Job -> Sample, least recently used first
        self.cache_bytes, self.cache_entries, self.cached_bytes = cache_bytes, cache_entries, 0
        self.pending = {}  # Job -> asyncio.Task
        self.running = self.most_running = 0  # samples being made now, and at most so far
        self.cancels = set()  # one Event per sample being made
        self.waiting = {}  # Job -> clients waiting for it

    async def get(self, model, request: Job, gone=None) -> tuple:
        """(Sample, True if it came from the cache). `gone`, an async
        function, says whether the client has left: when every client
        waiting for a sample has left, it is stopped (ClientGone)."""
        if request in self.cache:
            self.cache.move_to_end(request)
            return self.cache[request], True
        task = self.pending.get(request)
        if task is None:
            task = asyncio.ensure_future(self.compute(model, request))
            self.pending[request] = task
            self.waiting[request] = 0
            task.add_done_callback(lambda _: (self.pending.pop(request, None), self.waiting.pop(request, None)))
        self.waiting[request] += 1
        try:
            while True:
                done, _ = await asyncio.wait({task}, timeout=DISCONNECT_POLL)
                if done:
                    return task.result(), False
                if gone is not None and await gone():
                    raise ClientGone
        except ClientGone:
            if request in self.waiting:
                self.waiting[request] -= 1
                if self.waiting[request] == 0:  # nobody wants it any more: free the slot
                    task.cancel()
            raise

    async def compute(self, model, request: Job) -> Sample:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout
        try:
            await asyncio.wait_for(self.slots.acquire(), self.timeout)
        except asyncio.TimeoutError:
            raise HTTPException(503, f"busy: no sampling slot came free within {self.timeout:g} s; "
                                     "try again later") from None
        cancel = threading.Event()
        self.cancels.add(cancel)
        self.running += 1
        self.most_running = max(self.most_running, self.running)
        future = loop.run_in_executor(self.pool, make_sample, model, request, cancel)
        future.add_done_callback(lambda f: self.finished(f, cancel))
        try:
            result = await asyncio.wait_for(asyncio.shield(future), max(0.0, deadline - loop.time()))
        except asyncio.CancelledError:  # every client has gone
            cancel.set()
            raise
        except asyncio.TimeoutError:
            cancel.set()
            raise HTTPException(504, f"sampling took longer than the {self.timeout:g} s limit; "
                                     "ask for a smaller size or scale") from None
        self.store(request, result)
        return result

    def finished(self, future, cancel: threading.Event) -> None:
        """The slot is freed when the thread ends, not when the request gives up on it."""
        self.cancels.discard(cancel)
        self.running -= 1
        self.slots.release()
        if not future.cancelled():
            future.exception()  # retrieved, so a cut-off request's Cancelled is not logged as lost

    def store(self, request: Job, result: Sample) -> None:
        if len(result.body) > self.cache_bytes // 4:
            return  # a few huge files would flush everything else
        self.cache[request] = result
        self.cached_bytes += len(result.body)
        while self.cached_bytes > self.cache_bytes or len(self.cache) > self.cache_entries:
            _, dropped = self.cache.popitem(last=False)
            self.cached_bytes -= len(dropped.body)

    def close(self) -> None:
        """Stop: samples being made stop at their next slab, queued ones never start."""
        for cancel in self.cancels:
            cancel.set()
        self.pool.shutdown(wait=False, cancel_futures=True)


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
        if scope["method"] != "GET" or "range" in request or not compress.accepts_gzip(request.get("accept-encoding", "")):
            return response
        body = await self.gzipped(file, (stat.st_mtime_ns, stat.st_size))
        if body is None:
            return response
        headers = {key: value for key, value in response.headers.items() if key not in ("content-length", "accept-ranges")}
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


def load_models(names, threads: int | None = None) -> dict:
    """Shipped model names or .onnx paths -> {name: loaded model}; none: every shipped model."""
    paths = {}
    for item in names or sorted(shipped.available()):
        path = shipped.find(item)
        name = item if item in shipped.available() and not Path(item).is_file() else path.stem
        if name in paths:
            raise InputError(f"two models are called {name!r}; rename one file")
        paths[name] = path
    if not paths:
        raise InputError("no model given and no shipped model is installed; name a .onnx file")
    return {name: load.load_model(path, threads=threads) for name, path in paths.items()}


def summary(name: str, model) -> dict:
    """What a client needs to know about a model: its levels, sizes, training input and config."""
    m = model.manifest.raw
    training = m.get("training", {})
    return {
        "name": name,
        "file": model.path.name,
        "levels": len(m["levels"]),
        "size": list(model.manifest.sizes[-1]),
        "sizes": [list(s) for s in model.manifest.sizes],
        "noise_amps": model.manifest.noise_amps,
        "training_input": m.get("source", {}),
        "training": {key: training[key] for key in ("seconds", "iterations_per_level") if key in training},
        "config": m.get("config", {}),
        "frame": m["frame"],
        "up": model.manifest.up,
        "format_version": m["format_version"],
    }


def one_line(error: RequestValidationError) -> str:
    """Pydantic's list of errors -> 'seed: Input should be a valid integer (got 'x')'."""
    parts = []
    for e in error.errors():
        where = ".".join(str(p) for p in e.get("loc", ()) if p not in ("query", "path"))
        got = f" (got {e['input']!r})" if "input" in e and e["input"] is not None else ""
        parts.append(f"{where}: {e.get('msg', 'invalid')}{got}")
    return "; ".join(parts)


LOOPBACK = ("127.0.0.1", "localhost", "::1")
ANY_ADDRESS = ("0.0.0.0", "::", "")


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


def create_app(loaded: dict, slots: int | None = None, timeout: float = 60.0,
               cache_bytes: int = 256 << 20, allowed_hosts=LOOPBACK) -> FastAPI:
    """The web app serving `loaded` ({name: runtime Model}).

    slots: samples made at once (default: the cores); timeout: seconds a
    request may take; cache_bytes: memory for finished files; allowed_hosts:
    the names a request's Host header may give (a page elsewhere that points
    a name of its own at this address, DNS rebinding, is refused).
    """
    if not (isinstance(timeout, (int, float)) and 0 < timeout < float("inf")):
        raise InputError(f"timeout must be a positive number of seconds, got {timeout}", "timeout")
    slots = slots or load.default_threads()
    allowed = {name.lower().strip("[]") for name in allowed_hosts}
    sealed = {name: load.format3_bytes(model) for name, model in loaded.items()}  # never re-read from disk
    sealed_tags = {name: f'"{hashlib.sha256(data).hexdigest()[:40]}"' for name, data in sealed.items()}

    @asynccontextmanager
    async def lifespan(app):
        app.state.sampler = Sampler(slots, timeout, cache_bytes)
        yield
        app.state.sampler.close()

    app = FastAPI(title="sinshape", version=importlib.metadata.version("sinshape"), lifespan=lifespan,
                  description="Sample new 3D shapes from sinshape models. No authentication.",
                  docs_url=None, redoc_url=None)  # their pages load scripts from a CDN; /openapi.json stays

    # Outermost last: HostsAndIsolation sees the compressed answer's headers.
    app.add_middleware(AnswerGZip, minimum_size=GZIP_MINIMUM, compresslevel=GZIP_LEVEL)
    app.add_middleware(HostsAndIsolation, allowed=allowed)

    @app.exception_handler(RequestValidationError)
    async def invalid(request, error):
        return JSONResponse({"detail": one_line(error)}, status_code=422)

    @app.exception_handler(InputError)
    async def refused(request, error):
        return JSONResponse({"detail": str(error)}, status_code=413 if isinstance(error, MemoryLimitError) else 400)

    @app.exception_handler(Exception)
    async def failed(request, error):
        log.exception("failed: %s", request.url)
        return JSONResponse({"detail": f"internal error ({type(error).__name__}); see the server's log"},
                            status_code=500)

    async def answer(request: Request, model, wanted: Job) -> Response:
        """The file a sample request asks for, from the cache or made, with its headers."""
        try:
            made, hit = await request.app.state.sampler.get(model, wanted, request.is_disconnected)
        except ClientGone:
            return Response(status_code=499)  # nginx's "client closed request": nobody reads it
        headers = {"ETag": made.etag, "Cache-Control": "no-cache", "X-Cache": "hit" if hit else "miss",
                   "X-Sample-Seconds": f"{made.seconds:.3f}",
                   "Content-Disposition": f'attachment; filename="{wanted.filename()}"'}
        if made.faces is not None:
            headers["X-Faces"] = str(made.faces)
        known = [tag.strip().removeprefix("W/") for tag in request.headers.get("if-none-match", "").split(",")]
        if made.etag in known:
            return Response(status_code=304, headers=headers)
        return Response(made.body, media_type=MEDIA_TYPES.get(wanted.format, "application/octet-stream"),
                        headers=headers)

    def find(name: str):
        if name not in loaded:
            raise HTTPException(404, f"unknown model {name!r}; this server has {', '.join(loaded)}")
        return loaded[name]

    @app.get("/health", summary="Liveness: the server answers and how busy it is")
    async def health(request: Request):
        sampler = request.app.state.sampler
        return {"status": "ok", "models": len(loaded), "slots": slots, "sampling": sampler.running,
                "most_sampling": sampler.most_running, "in_flight": len(sampler.pending),
                "cached_files": len(sampler.cache), "cached_bytes": sampler.cached_bytes}

    @app.get("/api/models", summary="The models this server samples")
    async def list_models():
        return [{"name": name, "size": list(m.manifest.sizes[-1]), "levels": len(m.manifest.sizes),
                 "up": m.manifest.up, "training_input": m.manifest.raw.get("source", {}).get("name")}
                for name, m in loaded.items()]

    @app.get("/api/models/{name}", summary="One model's manifest: levels, sizes, training input, config",
             responses=errors(404))
    async def describe(name: str):
        return summary(name, find(name))

    @app.get("/api/models/{name}/onnx", summary="The model file, as loaded and checked at start-up, sealed "
             "as format 3 (what the browser reads)", response_class=Response,
             responses={200: {"content": {"application/octet-stream": {}}},
                        304: {"description": "Not modified: If-None-Match named its ETag"}, **errors(404)})
    async def model_file(request: Request, name: str):
        find(name)
        headers = {"ETag": sealed_tags[name], "Cache-Control": "no-cache",
                   "Content-Disposition": f'attachment; filename="{name}.onnx"'}
        known = [tag.strip().removeprefix("W/") for tag in request.headers.get("if-none-match", "").split(",")]
        if sealed_tags[name] in known:  # the browser has it: a page's second visit fetches no model again
            return Response(status_code=304, headers=headers)
        return Response(sealed[name], media_type="application/octet-stream", headers=headers)

    @app.get("/api/models/{name}/sample", summary="One sample as a file",
             response_class=Response, responses=FILE_ANSWERS)
    async def sample(
        request: Request,
        q: Annotated[SampleQuery, Depends()],
        keep: Annotated[list[str], Query(max_length=16, description="Parts to keep from other samples, "
                                         "SEED:X0,Y0,Z0:X1,Y1,Z1 (the model's frame, or percentages like 50%); "
                                         "repeat for more. The rest comes from `seed`.")] = [],
        grow: Annotated[str | None, Query(description="Grow the sample by these factors (one, or sx,sy,sz, "
                                          "each at least 1), keeping what it had.")] = None,
        anchor: Annotated[str, Query(description="With grow: where the old sample sits, per axis from 0 "
                                     "(low side) to 1 (high side).")] = "0",
    ):
        model = find(q.name)
        where = generate.parse_triple(anchor, lambda v: 0 <= v <= 1, "three fractions in [0, 1]", "anchor")
        wanted = SampleRequest(q.seed, size=generate.parse_size(q.size), scale=q.scale, smooth=q.smooth,
                               keep=tuple(keep), grow=generate.parse_size(grow) if grow else None,
                               anchor=where if grow else None)  # the anchor's default is not a choice
        return await answer(request, model, Job(q.name, resolved(model, wanted), q.format))

    @app.post("/api/models/{name}/sample", summary="One sample with the structure of an uploaded layout",
              response_class=Response, responses=FILE_ANSWERS)
    async def sample_from_layout(
        request: Request,
        q: Annotated[SampleQuery, Depends()],
        resample_layout: Annotated[bool, Query(description="Fit a layout of another grid size to level 0's.")] = False,
    ):
        """The body is the layout file (.vox or .npz, as `sinrun layout` writes it, edited), at most 4 MB."""
        try:
            body = await request.body()
        except ClientDisconnect:  # gone before its layout arrived: nobody reads an answer
            return Response(status_code=499)
        if not body or len(body) > MAX_UPLOAD_BYTES:
            raise InputError(f"send the layout file as the request body (1 byte to {MAX_UPLOAD_BYTES >> 20} MB)")
        model = find(q.name)
        grid = await run_in_threadpool(layout.parse_layout, body, layout_suffix(body), "the layout")
        wanted = SampleRequest(q.seed, size=generate.parse_size(q.size), scale=q.scale, smooth=q.smooth,
                               layout=Layout.of(grid, resample_layout))
        return await answer(request, model, Job(q.name, wanted, q.format))

    @app.get("/api/models/{name}/layout", summary="A sample's coarse layout, as `sinrun layout` writes it",
             response_class=Response, responses=FILE_ANSWERS)
    async def sample_layout(
        request: Request,
        name: str,
        seed: SeedQuery = 0,
        size: SizeQuery = "1",
        level: Annotated[int, Query(ge=0, description="The level whose grid the layout is; 0, the coarsest, "
                                    "by default.")] = 0,
        format: Annotated[LayoutFormat, Query(description="json: {shape, level, occupancy: '0'/'1' per cell, x "
                                              "slowest, z fastest}; vox (MagicaVoxel) or npz, as `sinrun layout`.")] = "json",
    ):
        """The sample's occupancy averaged over one level's grid, full where more than half is: what
        POST sample takes back, edited."""
        model = find(name)
        wanted = Job(name, SampleRequest(seed, size=generate.parse_size(size)), format, layout.check_level(model, level))
        return await answer(request, model, wanted)

    static = StaticFiles(directory=STATIC)

    @app.get("/", include_in_schema=False)
    async def page(request: Request):
        return await static.get_response("index.html", request.scope)

    app.mount("/static", static, name="static")
    return app


def bind(host: str, port: int):
    """A listening socket, bound here so that a taken port is one line, not a server's traceback."""
    import socket

    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
    except (OSError, OverflowError) as error:
        raise InputError(f"cannot listen on {host}:{port} ({getattr(error, 'strerror', None) or error})") from None
    return sock


def run(loaded: dict, host: str = "127.0.0.1", port: int = 8000, timeout: float = 60.0, extra_hosts=(),
        ready=None) -> None:
    """Serve `loaded` until interrupted. `ready(url, allowed hosts)` is
    called once the socket listens (with the port it got, for port 0)."""
    import uvicorn

    allowed = allowed_hosts(host, extra_hosts)
    application = create_app(loaded, timeout=timeout, allowed_hosts=allowed)
    sock = bind(host, port)
    shown = f"[{host}]" if ":" in host else host
    if ready:
        ready(f"http://{shown}:{sock.getsockname()[1]}/", allowed)
    server = uvicorn.Server(uvicorn.Config(application, log_level="warning", timeout_graceful_shutdown=5))
    server.run(sockets=[sock])
