"""The ASGI app: list models, describe one, sample one as a file, give a
sample's coarse layout (runtime.layout, for the page's layout editor), and the page.

Routes parse typed query values (a wrong type is a 422 with a one-line
message before any code runs), build the runtime's request, call one
function, and answer. Everything a request shares is made once, by
create_app and its lifespan: the loaded models (catalog.py), their sealed
files, and the sampler (sampler.py: a thread pool and slots sized to the
cores, so that sampling never runs on the event loop, and a bounded LRU
cache of finished files keyed by the normalised job, jobs.py). What every
answer gets, whatever its route (the Host check, the isolation headers,
gzip, ETags and 304), is http.py's.

Errors are JSON {"detail": "one line"}: 422 for a value of the wrong type
or range or a query parameter the route does not take (refused, never
ignored), 400 for a value the runtime refuses, 413 for work that would
exceed the runtime's memory limit (the message gives the figure), 404 for an
unknown model, 503 when no sampling slot frees up in time, 504 when
sampling takes longer than the time limit.
"""

import importlib.metadata
import logging
import socket
from contextlib import asynccontextmanager
import dataclasses
from functools import partial
from pathlib import Path
from typing import Annotated, Literal

import trimesh  # noqa: F401  a service makes whole meshes: imported at start-up, not in its first request
from fastapi import APIRouter, Depends, FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from sinshape.core import files
from sinshape.core.errors import InputError, MemoryLimitError
from sinshape.runtime import asset, generate, layout, layout_files, load, world, world_maps, world_tiles
from sinshape.runtime.options import ASSET_OPTIONS, OPTION, OPTIONS
from sinshape.runtime.request import Layout, SampleRequest, resolved
from sinshape.serve import catalog, http
from sinshape.serve.catalog import load_models  # noqa: F401  the API: app.load_models, app.create_app, app.run
from sinshape.serve.http import LOOPBACK
from sinshape.serve.jobs import Job, make_sample
from sinshape.serve.sampler import ClientGone, NoSlot, OutOfTime, Sampler

STATIC = Path(__file__).parent / "static"
Format = Literal[files.OUTPUT_FORMATS]
LayoutFormat = Literal["json", "vox", "npz"]
MEDIA_TYPES = {"glb": "model/gltf-binary", "obj": "model/obj", "stl": "model/stl",
               "json": "application/json"}  # others: octet-stream
# What the library raises -> the status it is answered with, {"detail": its message}; the closest class counts.
class BodyTooLarge(InputError):
    """An upload larger than the route takes (its declared length, or what arrived)."""


STATUSES = {InputError: 400, MemoryLimitError: 413, BodyTooLarge: 413, NoSlot: 503, OutOfTime: 504}
log = logging.getLogger("sinshape.serve")


class Detail(BaseModel):
    """Every error's body."""

    detail: str


def errors(*statuses) -> dict:
    """OpenAPI descriptions of a route's error answers (422 replaces FastAPI's list form)."""
    meaning = {400: "a value the runtime refuses", 404: "no such model", 413: "over the memory limit, or a body too large",
               422: "a value of the wrong type or range", 503: "no sampling slot free in time",
               504: "over the time limit"}
    return {status: {"model": Detail, "description": meaning[status]} for status in statuses}


FILE_ANSWERS = {
    200: {"description": "The file", "content": {t: {} for t in [*MEDIA_TYPES.values(), "application/octet-stream"]}},
    304: {"description": "Not modified: If-None-Match named its ETag"},
    **errors(400, 404, 413, 422, 503, 504),
}


# The options of a sample request (runtime/options.py) the routes take other than
# as a query parameter of their name: {option: where it goes}. The others are
# `option_query`s; tests/test_options.py holds the routes to the table.
SPELLED = {"layout": "the body of POST .../sample", "tile": "i and j", "heights": "the body of POST .../tile"}


def option_query(name: str, optional: bool = False, **settings):
    """The query parameter of the sample request's option `name`: its type,
    range, choices and description from the table (runtime.options.OPTION),
    `settings` taking precedence; it may be left out (None) where its
    default is None or `optional` says. Factors are text ('2' or '2,1,1'),
    read by the runtime as the command line reads them."""
    return table_query(OPTION[name], optional, **settings)


def table_query(option, optional: bool = False, limits: bool = True, **settings):
    """The query parameter of a record of the options table, as option_query
    (without `limits`, its range is left to the runtime's one-line messages)."""
    kind = {"seed": int, "bool": bool, "int": int, "number": float, "factors": str, "parts": list[str],
            "models": list[str], "models_map": str, "counts": str,
            "choice": Literal[option.choices] if option.choices else None}[option.type]
    if optional or option.default is None:
        kind = kind | None
    bounds = {}
    if limits and option.low is not None and option.type in ("seed", "int", "number"):
        bounds["gt" if option.bounds[0] == "(" else "ge"] = option.low
    if limits and option.high is not None and option.type in ("seed", "int", "number"):
        bounds["lt" if option.bounds[1] == ")" else "le"] = option.high
    if option.type == "number":
        bounds["allow_inf_nan"] = False
    return Annotated[kind, Query(**{"description": option.help, **bounds, **settings})]


# The query parameters of a sample (the layout route takes seed and size too).
SeedQuery = option_query("seed", description="The same seed gives the same shape.")
SizeQuery = option_query("size")
ScaleQuery = option_query("scale")
FormatQuery = Annotated[Format, Query(description=f"{' '.join(files.MESH_FORMATS.values())}: a mesh; "
                                                 f"{' '.join(files.GRID_FORMATS.values())}: the occupancy grid.")]


def asset_query(name: str, kind: str) -> type:
    """The query parameters that make a `kind` of request's file a game
    asset (runtime.options.ASSET_OPTIONS, each from its record; None: not
    given), as a dataclass FastAPI reads with Depends(); its
    options(format) is the runtime's AssetOptions (None: a plain file; an
    asset is a .glb). A new asset option reaches the routes without a line here."""
    offered = [option for option in ASSET_OPTIONS if kind in option.goes_with]
    fields = [(option.name, table_query(option, True, False, description=(
        option.help if option.name == "lods" else f"With lods: {option.help[0].lower()}{option.help[1:]}")),
        dataclasses.field(default=None)) for option in offered]

    def options(self, format: str):
        made = asset.options_of(**{option.name: getattr(self, option.name) for option in offered})
        if made is not None and format != "glb":
            raise InputError(f"an asset is written as glb (glTF's binary), not {format}")
        return made

    made = dataclasses.make_dataclass(name, fields, namespace={"options": options})
    made.__doc__ = f"What makes a {kind} a game asset."
    return made


AssetQuery = asset_query("AssetQuery", "tile")  # a tile keeps its world's frame and is open at its sides
SampleAssetQuery = asset_query("SampleAssetQuery", "sample")


def query_model(name: str, kind: str, first: list, special: dict, doc: str, namespace: dict | None = None):
    """The query parameters of a route that makes `kind` (a sample or a
    tile), as a dataclass FastAPI reads with Depends(): the fields `first`
    (the path's and the route's own, no default), every option of the table
    (runtime.options.OPTIONS) for `kind` that travels as a query parameter of
    its name (not SPELLED), as option_query makes it with the table's
    default unless `special` gives (annotation, default), and the format.
    A new option of the table reaches the route without a line here."""
    fields = list(first)
    for option in OPTIONS:
        if kind in option.goes_with and option.name not in SPELLED:
            annotation, default = special.get(option.name) or (option_query(option.name), option.default)
            fields.append((option.name, annotation, dataclasses.field(default=default)))
    fields.append(("format", FormatQuery, dataclasses.field(default="glb")))
    made = dataclasses.make_dataclass(name, fields, namespace=namespace)
    made.__doc__ = doc
    return made


def sample_fields(self) -> dict:
    """The request's options given as query parameters, by name (the size's
    text read; no seed: 0, one request for one sample and one cache entry,
    but for the reconstruction)."""
    given = {name: getattr(self, name) for name in OPTION if hasattr(self, name)}
    given["size"] = generate.parse_size(self.size)
    given["seed"] = 0 if self.seed is None and not self.recon else self.seed
    return given


SampleQuery = query_model(
    "SampleQuery", "sample", [("name", str)], {"size": (SizeQuery, "1")},
    "What both sample routes take: the model's name (the path's) and the query parameters of a sample.",
    {"fields": sample_fields})


MAX_UPLOAD_BYTES = 4 << 20  # a layout of a coarse level is a few kB; a height map of 1024 x 1024 float32


async def upload(request: Request, what: str) -> bytes:
    """The request's body, of 1 byte to MAX_UPLOAD_BYTES: refused by its
    declared length before a byte of it is read, and read in chunks, each
    counted, when no length is declared (chunked), so that a large body
    costs the service nothing. A client gone midway is a ClientDisconnect (499)."""
    wanted = f"send {what} as the request body (1 byte to {MAX_UPLOAD_BYTES >> 20} MB)"
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > MAX_UPLOAD_BYTES:
        raise BodyTooLarge(f"{wanted}; it declares {int(declared) / 2**20:.1f} MB")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_UPLOAD_BYTES:
            raise BodyTooLarge(f"{wanted}; it sent more")
    if not body:
        raise InputError(wanted)
    return bytes(body)


def layout_suffix(data: bytes) -> str:
    """.vox or .npz, by the file's first bytes."""
    if data.startswith(b"VOX "):
        return ".vox"
    if data.startswith(b"PK"):
        return ".npz"
    raise InputError("the layout is neither a MagicaVoxel .vox nor an .npz file")


def one_line(error: RequestValidationError) -> str:
    """Pydantic's list of errors -> 'seed: Input should be a valid integer (got 'x')'."""
    parts = []
    for e in error.errors():
        where = ".".join(str(p) for p in e.get("loc", ()) if p not in ("query", "path"))
        got = f" (got {e['input']!r})" if "input" in e and e["input"] is not None else ""
        parts.append(f"{where}: {e.get('msg', 'invalid')}{got}")
    return "; ".join(parts)


def query_names(dependant) -> set:
    """The query parameters a route takes, its dependencies' included."""
    return {param.alias for param in dependant.query_params}.union(*map(query_names, dependant.dependencies))


async def known_query(request: Request) -> None:
    """A query parameter the route does not take is refused (422), never
    ignored: a misspelt option, or one this server is too old for, would
    otherwise be dropped without a word and the answer made without it."""
    taken = query_names(request.scope["route"].dependant)
    unknown = sorted(set(request.query_params) - taken)
    if unknown:
        raise HTTPException(422, f"{unknown[0]}: this route takes no such query parameter; it takes "
                                 f"{', '.join(sorted(taken)) or 'none'}")


routes = APIRouter(dependencies=[Depends(known_query)])  # the API
pages = APIRouter()  # the page, whose own state is its query


def find(request: Request, name: str):
    """The loaded model of this name (404 if none)."""
    loaded = request.app.state.models
    if name not in loaded:
        raise HTTPException(404, f"unknown model {name!r}; this server has {', '.join(loaded)}")
    return loaded[name]


async def answer(request: Request, model, job: Job) -> Response:
    """The file a job asks for, from the sampler's cache or made, with its headers."""
    work = partial(make_sample, model, job)
    made, hit = await request.app.state.sampler.get(job, work, request.is_disconnected)
    headers = {"X-Cache": "hit" if hit else "miss", "X-Sample-Seconds": f"{made.seconds:.3f}",
               "Content-Disposition": f'attachment; filename="{job.filename()}"'}
    if made.faces is not None:
        headers["X-Faces"] = str(made.faces)
    return http.file_answer(request, made.body, made.etag, MEDIA_TYPES.get(job.format, "application/octet-stream"),
                            headers)


@routes.get("/health", summary="Liveness: the server answers and how busy it is")
async def health(request: Request):
    state = request.app.state
    return {"status": "ok", "models": len(state.models), "slots": state.slots, **state.sampler.counts()}


@routes.get("/api/models", summary="The models this server samples")
async def list_models(request: Request):
    return [{**catalog.entry(name, m), "training_input": m.manifest.raw.get("source", {}).get("name")}
            for name, m in request.app.state.models.items()]


@routes.get("/api/models/{name}", summary="One model's manifest: levels, sizes, training input, config",
            responses=errors(404))
async def describe(request: Request, name: str):
    return catalog.summary(name, find(request, name))


@routes.get("/api/models/{name}/onnx", summary="The model file, as loaded and checked at start-up, sealed "
            "(format 3 or later: what the browser reads)", response_class=Response,
            responses={200: {"content": {"application/octet-stream": {}}},
                       304: {"description": "Not modified: If-None-Match named its ETag"}, **errors(404)})
async def model_file(request: Request, name: str):
    find(request, name)
    body, tag = request.app.state.files[name]  # a page's second visit fetches no model again: 304
    return http.file_answer(request, body, tag, "application/octet-stream",
                            {"Content-Disposition": f'attachment; filename="{name}.onnx"'})


@routes.get("/api/models/{name}/sample", summary="One sample as a file",
            response_class=Response, responses=FILE_ANSWERS)
async def sample(
    request: Request,
    q: Annotated[SampleQuery, Depends()],
    a: Annotated[SampleAssetQuery, Depends()],
    keep: option_query("keep") = [],
    grow: option_query("grow") = None,
    anchor: option_query("anchor") = None,
):
    model = find(request, q.name)
    where = None if anchor is None else generate.parse_triple(anchor, lambda v: 0 <= v <= 1,
                                                              "three fractions in [0, 1]", "anchor")
    wanted = SampleRequest.of({**q.fields(), "keep": tuple(keep), "grow": generate.parse_size(grow) if grow else None,
                               "anchor": where})
    return await answer(request, model, Job(q.name, resolved(model, wanted), q.format, asset=a.options(q.format)))


@routes.post("/api/models/{name}/sample", summary="One sample with the structure of an uploaded layout",
             response_class=Response, responses=FILE_ANSWERS)
async def sample_from_layout(
    request: Request,
    q: Annotated[SampleQuery, Depends()],
    resample_layout: Annotated[bool, Query(description="Fit a layout of another grid size to level 0's.")] = False,
):
    """The body is the layout file (.vox or .npz, as `sinrun layout` writes it, edited), at most 4 MB."""
    body = await upload(request, "the layout file")
    model = find(request, q.name)
    grid = await run_in_threadpool(layout_files.parse_layout, body, layout_suffix(body), "the layout")
    wanted = SampleRequest.of({**q.fields(), "layout": Layout.of(grid, resample_layout)})
    return await answer(request, model, Job(q.name, wanted, q.format))


@routes.get("/api/models/{name}/layout", summary="A sample's coarse layout, as `sinrun layout` writes it",
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
    model = find(request, name)
    factors = generate.parse_size(size)
    layout_files.check_fits(layout.grid_size(model, level, factors), format, "the layout")  # before making it
    wanted = Job(name, SampleRequest(seed, size=factors), format, layout.check_level(model, level))
    return await answer(request, model, wanted)


TileIndex = Annotated[int, Query(gt=-2**62, lt=2**62, description="A tile index along one horizontal axis.")]


TileQuery = query_model(
    "TileQuery", "tile", [("name", str), ("i", TileIndex), ("j", TileIndex)], {
        "seed": (SeedQuery, 0),
        "frame": (option_query("frame", description="tile: the training mesh's units from the tile's own corner "
                               "(any tile; X-Tile-Corner gives the corner in voxels); input or model: placed in the "
                               "world, near its origin."), "tile"),
        "arrange": (option_query("arrange", optional=True), None),  # None: what the model records, else blend
        # models: this server's models by name, once each (models=a&models=b); models_map as text: 0,1;1,0
    },
    "What both tile routes take: the model's name (the path's), the tile and how its world and it are made.")


async def tile_answer(request: Request, q: TileQuery, heights=None, asset=None) -> Response:
    model = find(request, q.name)
    given = {name: getattr(q, name) for name in OPTION if hasattr(q, name)}
    wanted = SampleRequest.of({**given, "tile": (q.i, q.j), "arrange": q.arrange or model.manifest.arrange,
                               "heights": heights, "models": tuple(str(find(request, other).path) for other in q.models),
                               "models_map": None if q.models_map is None else world_maps.ModelMap.of_text(q.models_map)})
    response = await answer(request, model, Job(q.name, wanted, q.format, asset=asset))
    response.headers["X-Tile-Corner"] = ",".join(map(str, world_tiles.tile_corner(model, (q.i, q.j))))
    return response


@routes.get("/api/models/{name}/tile", summary="One tile of a model's endless world as a file",
            response_class=Response, responses=FILE_ANSWERS)
async def tile(request: Request, q: Annotated[TileQuery, Depends()], a: Annotated[AssetQuery, Depends()]):
    """Tile (i, j) of the world of `seed`: it joins its neighbours without a seam, whatever else was asked."""
    return await tile_answer(request, q, asset=a.options(q.format))


@routes.post("/api/models/{name}/tile", summary="One tile of a world shaped by an uploaded height map",
             response_class=Response, responses=FILE_ANSWERS)
async def tile_of_map(
    request: Request,
    q: Annotated[TileQuery, Depends()],
    a: Annotated[AssetQuery, Depends()],
    relief: Annotated[float | None, Query(gt=0, allow_inf_nan=False, description="Voxels from a .png map's "
                                          "black to its white (default: 4 times the model's height).")] = None,
):
    """The body is the height map (.npy heights in voxels, or a greyscale .png), at most 4 MB: every tile
    of the world asks with the same map."""
    body = await upload(request, "the height map")
    suffix = ".npy" if body.startswith(b"\x93NUMPY") else ".png" if body.startswith(b"\x89PNG") else None
    if suffix is None:
        raise InputError("the height map is neither a .npy array nor a .png image")
    if suffix == ".png" and relief is None:
        tiling = world.world_tiling(find(request, q.name))
        relief = world_maps.RELIEF * tiling.stride[tiling.up]
    heights = await run_in_threadpool(world_maps.parse_height_map, body, suffix, "the height map", relief)
    return await tile_answer(request, q, heights, a.options(q.format))


@pages.get("/", include_in_schema=False)
async def page(request: Request):
    return await request.app.state.static.get_response("index.html", request.scope)


def add_error_answers(app: FastAPI) -> None:
    """Every error as {"detail": "one line"}: the library's by STATUSES, a
    client gone as 499 (nginx's "client closed request": nobody reads it),
    anything else a 500 whose traceback goes to the log."""

    @app.exception_handler(RequestValidationError)
    async def invalid(request, error):
        return JSONResponse({"detail": one_line(error)}, status_code=422)

    async def refused(request, error):
        status = next(STATUSES[kind] for kind in type(error).__mro__ if kind in STATUSES)
        return JSONResponse({"detail": str(error)}, status_code=status)

    async def gone(request, error):
        return Response(status_code=499)

    for kind in STATUSES:
        app.add_exception_handler(kind, refused)
    for kind in (ClientGone, ClientDisconnect):
        app.add_exception_handler(kind, gone)

    @app.exception_handler(Exception)
    async def failed(request, error):
        log.exception("failed: %s", request.url)
        return JSONResponse({"detail": f"internal error ({type(error).__name__}); see the server's log"},
                            status_code=500)


def create_app(loaded: dict, slots: int | None = None, timeout: float = 60.0,
               cache_bytes: int = 256 << 20, allowed_hosts=LOOPBACK) -> FastAPI:
    """The web app serving `loaded` ({name: runtime Model}).

    slots: samples made at once (default: the cores); timeout: seconds a
    request may take; cache_bytes: memory for finished files; allowed_hosts:
    the names a request's Host header may give (a page elsewhere that points
    a name of its own at this address, DNS rebinding, is refused).
    """
    if not (isinstance(timeout, (int, float)) and 0 < timeout < float("inf")):
        raise InputError(f"`timeout` must be a positive number of seconds, got {timeout}", "timeout")
    slots = slots or load.default_threads()

    @asynccontextmanager
    async def lifespan(app):
        app.state.sampler = Sampler(slots, timeout, cache_bytes)
        yield
        app.state.sampler.close()

    app = FastAPI(title="sinshape", version=importlib.metadata.version("sinshape"), lifespan=lifespan,
                  description="Sample new 3D shapes from sinshape models. No authentication.",
                  docs_url=None, redoc_url=None)  # their pages load scripts from a CDN; /openapi.json stays
    app.state.models, app.state.slots = loaded, slots
    sealed = {name: load.format3_bytes(model) for name, model in loaded.items()}  # never re-read from disk
    app.state.files = {name: (data, http.entity_tag(data)) for name, data in sealed.items()}
    app.state.static = http.StaticFiles(directory=STATIC)
    http.add_middleware(app, {name.lower().strip("[]") for name in allowed_hosts})
    add_error_answers(app)
    app.include_router(routes)
    app.include_router(pages)
    app.mount("/static", app.state.static, name="static")
    return app


def bind(host: str, port: int):
    """A listening socket, bound here so that a taken port is one line, not a server's traceback."""
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

    allowed = http.allowed_hosts(host, extra_hosts)
    application = create_app(loaded, timeout=timeout, allowed_hosts=allowed)
    sock = bind(host, port)
    shown = f"[{host}]" if ":" in host else host

    class Server(uvicorn.Server):
        async def startup(self, sockets=None):
            # Announced only now that uvicorn's own signal handlers are in place:
            # a SIGTERM that came earlier, during uvicorn's lazy imports, could
            # land in an import-lock callback, where Python ignores the exception.
            await super().startup(sockets)
            if ready and self.started:
                ready(f"http://{shown}:{sock.getsockname()[1]}/", allowed)

    server = Server(uvicorn.Config(application, log_level="warning", timeout_graceful_shutdown=5,
                                   http=http.json_400_protocol()))
    server.run(sockets=[sock])
