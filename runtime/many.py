"""Many samples as one resumable job: seeds (or the tiles of a world) spread
over worker processes on this machine, or over a Ray cluster.

Workers load the model once and send back each seed's file bytes and
figures; only this process writes, atomically, then appends the seed to an
index file beside the outputs (JSON lines with the file's size and SHA-256,
fsynced, so it is valid after a crash), whose first line records the job
(the model's SHA-256, the files' names, the request). A rerun resumes only
that job (another is refused, naming the difference, unless `restart`), and
skips a seed only if its file is the one the index recorded (same size and
hash): a missing, truncated or changed file is made again, and the index is
rewritten first with one line per seed it still vouches for. Ctrl-C leaves
no partial file.
Seeds are taken lazily, a few ahead of the workers, so a range of any length
costs nothing up front.
"""

import contextlib
import dataclasses
import hashlib
import itertools
import json
import multiprocessing
import os
import queue
import re
import signal
import socket
import stat
import tempfile
import threading
import time
from dataclasses import dataclass
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Callable

from sinshape.core import files
from sinshape.core.budget import check_memory
from sinshape.core.errors import ConflictError, InputError

from . import world, world_tiles, write
from .load import default_threads, load_model
from .request import SampleRequest

ENGINES = ("local", "ray")


@dataclass(frozen=True)
class Varying:
    """What each item of a job sets: a field of the request (seed, or tile),
    spelled {field} in the output names and recorded under its name in the index."""

    field: str
    name_pattern: str  # a regular expression matching an item's text in a file name
    text: Callable  # item -> its text in file names
    item: Callable  # an index record's value -> the item, checked

    @property
    def placeholder(self) -> str:
        return "{" + self.field + "}"

    def path(self, pattern: Path, item) -> Path:
        return pattern.with_name(pattern.name.replace(self.placeholder, self.text(item)))


def record_seed(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**63:
        raise ValueError("a seed is an integer in [0, 2**63)")
    return value


def record_tile(value) -> tuple:
    if not isinstance(value, list):
        raise ValueError("a tile is a list")
    return world.check_tile(tuple(value))


SEEDS = Varying("seed", r"\d+", str, record_seed)
TILES = Varying("tile", r"-?\d+_-?\d+", lambda tile: f"{tile[0]}_{tile[1]}", record_tile)


def index_path(pattern, varying: Varying = SEEDS) -> Path:
    """The index beside the outputs: out/{seed}.glb -> out/index.jsonl,
    out/tower_seed{seed}.ply -> out/tower_index.jsonl (the same for {tile})."""
    pattern = Path(pattern)
    field = re.escape(varying.field)
    return pattern.with_name(Path(re.sub(rf"({field})?\{{{field}\}}", "index", pattern.name)).stem + ".jsonl")


MAX_INDEX_LINE = 4096  # bytes of one record: a seed or tile, a file name, a size and a hash
INDEX_FORMAT = 1  # the job record's version: the index's first line, {"job": {...}}
INDEX_BYTES_PER_BYTE = 8  # memory its records take as read, per byte of the index


@dataclass(frozen=True)
class IndexFile:
    """An index as read: the job its first line records (None: no job line,
    an index from before they were recorded), {item: its last record}, how
    many item lines it has and whether it ends with a whole line."""

    job: dict | None
    records: dict
    lines: int
    whole: bool


def scan_index(path: Path, varying: Varying = SEEDS) -> IndexFile | None:
    """The index at `path` (None when there is none), each field it is read
    by checked (the item, the file's size and hash), read a line at a time
    and each line bounded, so that no file makes it read more than it holds
    or block: one that is not a regular file is refused. A last line cut
    short by a crash is dropped."""
    try:
        mode = os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as error:
        raise InputError(f"{path}: cannot read the job's index ({error.strerror})") from None
    if not stat.S_ISREG(mode.st_mode):
        raise InputError(f"{path}: the job's index is {files.kind_of(mode.st_mode)}, not a regular file; move it away or choose another "
                         "output name")
    check_memory(mode.st_size * INDEX_BYTES_PER_BYTE, f"reading the job's index {path}")
    job, records, lines, whole = None, {}, 0, True
    with open(path, "rb") as f:
        for number in itertools.count(1):
            line = f.readline(MAX_INDEX_LINE + 1)
            if not line:
                break
            if not line.endswith(b"\n") and len(line) <= MAX_INDEX_LINE:
                whole = False  # cut short by a crash
                break
            try:
                if len(line) > MAX_INDEX_LINE:
                    raise ValueError(f"longer than {MAX_INDEX_LINE} bytes")
                record = json.loads(line)
                if not isinstance(record, dict):
                    raise ValueError("not a JSON object")
                if number == 1 and set(record) == {"job"} and isinstance(record["job"], dict):
                    job = record["job"]
                    continue
                item = varying.item(record[varying.field])
                size, digest = record.get("bytes"), record.get("sha256")
                if not (size is None or isinstance(size, int) and not isinstance(size, bool) and size >= 0) \
                        or not (digest is None or isinstance(digest, str)):
                    raise ValueError("a file size or hash of the wrong type")
                records[item] = record
                lines += 1
            except (ValueError, KeyError, TypeError, RecursionError, InputError):
                raise InputError(f"{path}: not a sinshape index (line {number} is not a {varying.field}'s JSON "
                                 "record); move it away or choose another output name") from None
    return IndexFile(job, records, lines, whole)


def read_index(path: Path, varying: Varying = SEEDS) -> dict:
    """{item: its last record} of an index (scan_index)."""
    index = scan_index(path, varying)
    return index.records if index else {}


def job_record(model, request, pattern: Path, varying: Varying) -> dict:
    """What a job is, as its index's first line records it: the model (its
    bytes' SHA-256), the files' names and format, and the request each item
    fills in (for a world, its seed with the rest)."""
    fields = {}
    for field in dataclasses.fields(request):
        value = getattr(request, field.name)
        if field.name == varying.field:
            continue
        if field.name == "layout" and value is not None:
            value = {"shape": value.shape, "sha256": hashlib.sha256(value.bits).hexdigest(), "resample": value.resample}
        elif field.name in ("heights", "models_map") and value is not None:
            value = {"shape": value.shape, "sha256": hashlib.sha256(value.data).hexdigest()}
        elif field.name == "models":  # what the other models are, wherever their files lie
            value = [(file_digest(Path(path)) or (None, None))[1] for path in value]
        elif field.name == "keep":
            value = [part if isinstance(part, str) else dataclasses.asdict(part) for part in value]
        fields[field.name] = value
    return json.loads(json.dumps({"index": INDEX_FORMAT, "model": hashlib.sha256(model.data).hexdigest(),
                                  "model_name": model.path.name, "files": pattern.name, "request": fields}))


def job_difference(recorded: dict, job: dict) -> str:
    """How a recorded job differs from this one, in words: the first field that does."""
    if recorded.get("index") != job["index"]:
        return f"index format {json.dumps(recorded.get('index'))[:20]}, not {job['index']}"
    if recorded.get("model") != job["model"]:
        return f"another model ({str(recorded.get('model_name'))[:100]}, sha256 {str(recorded.get('model'))[:12]}...)"
    if recorded.get("files") != job["files"]:
        return f"files {json.dumps(recorded.get('files'))[:100]}, not {json.dumps(job['files'])}"
    if recorded.get("asset") != job.get("asset"):
        return f"asset {json.dumps(recorded.get('asset'))[:100]}, not {json.dumps(job.get('asset'))[:100]}"
    asked = recorded.get("request") if isinstance(recorded.get("request"), dict) else {}
    for name, value in job["request"].items():
        if asked.get(name, "missing") != value:
            return f"{name} {json.dumps(asked.get(name))[:100]}, not {json.dumps(value)[:100]}"
    return "a request with other fields"


def check_same_job(index: IndexFile | None, job: dict, path: Path, restart: bool) -> IndexFile | None:
    """The index a job resumes from: refused, naming the difference, when it
    records another job (or none), unless `restart`, which starts it afresh
    (its files are made again). An index without any line is no index."""
    if index is None or (index.job is None and not index.records):
        return None
    if index.job == job:
        return index
    if not restart:
        what = (f"records another job ({job_difference(index.job, job)})" if index.job is not None else
                "records no job (an index from before sinshape recorded its jobs), so it cannot vouch for its files")
        raise InputError(f"{path}: {what}; `restart` makes the files again, or choose another output name", "restart")
    return None


def file_digest(path: Path) -> tuple:
    """(size, SHA-256 hex) of a file, or None if it cannot be read."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
            return f.tell(), digest.hexdigest()
    except OSError:
        return None


def verified(records: dict, pattern: Path, varying: Varying = SEEDS) -> dict:
    """The records whose file is there and is what they recorded."""
    kept = {}
    for item, record in records.items():
        path = varying.path(pattern, item)
        if path.is_file() and file_digest(path) == (record.get("bytes"), record.get("sha256")):
            kept[item] = record
    return kept


def rewrite_index(path: Path, job: dict, records: dict) -> None:
    """The index with its job and one line per item it vouches for, written atomically."""
    text = "".join(json.dumps(record) + "\n" for record in [{"job": job}, *records.values()])
    files.atomic_write(path, lambda f: f.write(text.encode()))


class Worker:
    """One worker's model, loaded once, and the request each item's file is
    made by, with the item in its `field`."""

    def __init__(self, model, suffix: str, threads: int, request, field: str = "seed", asset=None):
        if isinstance(model, bytes):  # sent over the network (Ray): load it from a local copy
            with tempfile.NamedTemporaryFile(suffix=".onnx") as f:
                f.write(model)
                f.flush()
                self.model = load_model(f.name, threads=threads)
        else:
            self.model = load_model(model, threads=threads)
        self.suffix, self.threads, self.request, self.field, self.asset = suffix, threads, request, field, asset

    def run(self, item) -> tuple:
        """(file bytes, index record without the file name) of one item."""
        started = time.perf_counter()
        request = dataclasses.replace(self.request, **{self.field: item})
        label = "_".join(map(str, item)) if isinstance(item, tuple) else item  # an asset's name: seed3, tile2_-1
        data, mesh = write.request_bytes(self.model, request, f"{self.field}{label}{self.suffix}", self.threads,
                                         asset=self.asset)
        record = {self.field: item, "vertices": None, "faces": None, "watertight": None, "volume": None}
        if self.field == "tile":  # where the tile lies: its files may hold it in its own frame
            record["corner"] = world_tiles.tile_corner(self.model, item)
        if self.asset is not None:  # an asset's figures: the full mesh's counts and each level's
            record.update(vertices=mesh["dense_vertices"], faces=mesh["dense_triangles"], levels=mesh["levels"])
        elif mesh is not None:
            record.update(vertices=len(mesh.vertices), faces=len(mesh.faces),
                          watertight=bool(mesh.is_watertight), volume=round(float(mesh.volume), 6))
        record["seconds"] = round(time.perf_counter() - started, 3)
        return data, record


_worker = None  # a pool process's Worker


def _start_process(*args) -> None:
    global _worker
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGTERM})  # Ctrl-C stays held: the driver's to handle
    _worker = Worker(*args)


def _run_in_process(item) -> tuple:
    return _worker.run(item)


@contextlib.contextmanager
def signals_deferred(*signums):
    """Signals that come during the block act after it (in the main thread,
    where they are handled), and the processes it starts hold them back until
    they let them in: a worker still starting would print Ctrl-C's
    traceback, or, its driver gone before sending it its work, an EOFError's."""
    resource_tracker.ensure_running()  # first: starting, it lets SIGINT and SIGTERM in again
    came, handlers = [], {}
    if threading.current_thread() is threading.main_thread():
        handlers = {signum: signal.signal(signum, lambda signum, frame: came.append(signum)) for signum in signums}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, signums)  # what started processes inherit
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
        for signum in came[:1]:
            signal.raise_signal(signum)


@contextlib.contextmanager
def handler_kept(signum: int):
    """The handler of `signum` after the block as before it (in the main
    thread: elsewhere signals are not this thread's to set)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signum)
    try:
        yield
    finally:
        signal.signal(signum, previous)


class InProcess:
    """One worker: this process."""

    def __init__(self, model_path, suffix, threads, request, field, asset=None):
        self.worker, self.done = Worker(model_path, suffix, threads, request, field, asset), []

    slots = 1

    def submit(self, item) -> None:
        self.done.append(self.worker.run(item))

    def next_result(self) -> tuple:
        return self.done.pop(0)

    def close(self) -> None:
        pass


class Processes:
    """Worker processes on this machine (multiprocessing, spawned)."""

    def __init__(self, model_path, suffix, threads, request, field, workers: int, asset=None):
        with signals_deferred(signal.SIGINT, signal.SIGTERM):
            self.pool = multiprocessing.get_context("spawn").Pool(
                workers, initializer=_start_process, initargs=(str(model_path), suffix, threads, request, field, asset))
        self.results = queue.Queue()
        self.slots = 2 * workers  # one running and one waiting per worker

    def submit(self, item) -> None:
        self.pool.apply_async(_run_in_process, (item,), callback=self.results.put,
                              error_callback=self.results.put)

    def next_result(self) -> tuple:
        result = self.results.get()
        if isinstance(result, BaseException):
            raise result
        return result

    def close(self) -> None:
        self.pool.terminate()
        self.pool.join()


def check_reachable(address: str | None, timeout: float = 5.0) -> None:
    """Refuse a host:port that does not answer within `timeout` seconds:
    ray.init would retry it for minutes."""
    if not address or address in ("auto", "local"):
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout).close()
    except (OSError, ValueError) as error:
        reason = getattr(error, "strerror", None) or "give HOST:PORT"
        raise InputError(f"cannot reach the Ray cluster at {address} ({reason})", "address") from None


class RayActors:
    """Ray actors, each holding a Worker; Ray's own default cluster unless
    `address` names one."""

    def __init__(self, model_path, suffix, threads, request, field, workers: int | None, address: str | None,
                 asset=None):
        try:
            import ray  # the ray extra
        except ImportError:
            raise InputError("the ray engine needs Ray, which is not installed: "
                             "pip install 'sinshape[ray]'", "engine") from None
        self.ray, self.started = ray, not ray.is_initialized()
        if self.started:
            check_reachable(address)
            try:
                with handler_kept(signal.SIGTERM):  # not Ray's handler: it exits 1 with a stack dump
                    ray.init(address=address, include_dashboard=False, logging_level="ERROR",
                             log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as error:
                where = address or os.environ.get("RAY_ADDRESS") or "a local Ray"
                raise InputError(f"cannot reach the Ray cluster at {where}: {str(error).splitlines()[0]}",
                                 "address") from None
        self.actors = []
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if workers is None:
            workers = max(1, cpus // threads)
        if workers * threads > cpus:  # Ray would wait for CPUs it cannot get, for ever
            self.close()
            raise InputError(f"`workers` {workers} of {threads} thread{'s' * (threads > 1)} each need "
                             f"{workers * threads} CPUs; the Ray cluster has {cpus}", "workers")
        actor = ray.remote(num_cpus=threads)(Worker)
        model = ray.put(Path(model_path).read_bytes())
        self.actors = [actor.remote(model, suffix, threads, request, field, asset) for _ in range(workers)]
        self.free = self.actors * 2  # one running and one waiting per actor
        self.slots = len(self.free)
        self.pending = {}  # object ref -> actor

    def submit(self, item) -> None:
        actor = self.free.pop()
        self.pending[actor.run.remote(item)] = actor

    def next_result(self) -> tuple:
        (ready,), _ = self.ray.wait(list(self.pending), num_returns=1)
        self.free.append(self.pending.pop(ready))
        try:
            return self.ray.get(ready)
        except self.ray.exceptions.RayTaskError as error:
            raise error.cause from None  # an InputError of the item, say, rather than Ray's report

    def close(self) -> None:
        for actor in self.actors:
            self.ray.kill(actor)
        if self.started:
            self.ray.shutdown()


class Appender:
    """The index, opened for appending when the first record comes (a job
    that fails before its first file leaves no index behind), its job's line
    first if it is new."""

    def __init__(self, path: Path, job: dict):
        self.path, self.job, self.file = path, job, None

    def __enter__(self):
        return self

    def write(self, text: str) -> None:
        if self.file is None:
            self.file = open(self.path, "a")
            if self.file.tell() == 0:
                text = json.dumps({"job": self.job}) + "\n" + text
        self.file.write(text)
        self.file.flush()
        os.fsync(self.file.fileno())

    def __exit__(self, *_):
        if self.file is not None:
            self.file.close()


def check_existing_outputs(pattern: Path, inputs, varying: Varying = SEEDS) -> None:
    """Every file already there that the job could replace (a name the
    pattern makes) is checked before the first item, not when its turn comes."""
    name = re.compile(re.escape(pattern.name).replace(re.escape(varying.placeholder), varying.name_pattern))
    folder = pattern.parent if str(pattern.parent) else Path(".")
    try:
        entries = [Path(folder, e.name) for e in os.scandir(folder) if name.fullmatch(e.name)]
    except OSError:
        return  # check_writable has said what is wrong with the folder
    for path in entries:
        files.check_replaceable(path)
        files.check_not_input(path, inputs)


def sample_many(model_path, seeds, pattern, engine: str = "local", workers: int | None = None,
                threads: int | None = None, address: str | None = None, progress=None, request=None,
                restart: bool = False, asset=None, **fields) -> dict:
    """Write one file per seed, `pattern` with {seed} filled in, resumably:
    the sample `request` (a request.SampleRequest with no seed; None: the
    plain one), with `fields` of SampleRequest replaced, for each seed; with
    `asset` (an asset.AssetOptions), each as a game asset (.glb).

    seeds: any iterable of seeds, read lazily. engine 'local': `workers`
    processes (None: one per core; 1: this process), or 'ray': Ray actors
    (None: one per CPU of the cluster) on the cluster at `address` (None:
    Ray's default). threads: per worker (None: the cores divided among the
    local workers; 1 on Ray). Each sample is made in memory.
    progress(seed, record or None if skipped) after each seed. An index
    beside the outputs that records another job is refused, unless
    `restart`, which makes its files again.
    Returns {"written", "skipped", "index"}.
    """
    request = dataclasses.replace(request or SampleRequest(), **fields)
    if request.seed is not None or request.recon:
        one = "recon" if request.recon else "seed"
        raise ConflictError(f"give `seeds` or `{one}`, not both", ("seeds", one))
    return run_job(model_path, seeds, pattern, SEEDS, request, engine, workers, threads, address, progress, restart,
                   asset)


def run_job(model_path, items, pattern, varying: Varying, request, engine: str = "local",
            workers: int | None = None, threads: int | None = None, address: str | None = None,
            progress=None, restart: bool = False, asset=None) -> dict:
    """One file per item (`varying` says which field of `request` each item
    sets, and how it is named), resumably, on the engine asked for: the
    job `sample_many` and `write_tiles` run; with `asset` (an
    asset.AssetOptions) each item's game asset (.glb). It resumes only the
    job its index records (check_same_job)."""
    pattern = Path(pattern)
    if varying.placeholder in str(pattern.parent):
        raise InputError(f"{pattern}: {varying.placeholder} fills in the file's name, not its folder "
                         f"{pattern.parent}", "pattern")
    if varying.placeholder not in pattern.name:
        raise InputError(f"{pattern.name}: many {varying.field}s need {varying.placeholder} in the output file "
                         "name", "pattern")
    if engine not in ENGINES:
        raise InputError(f"unknown `engine` {engine!r}; choose {' or '.join(ENGINES)}", "engine")
    if workers is not None and workers < 1:
        raise InputError(f"`workers` must be at least 1, got {workers}", "workers")
    if threads is not None and threads < 1:
        raise InputError(f"`threads` must be at least 1, got {threads}", "threads")
    write.output_kind(pattern)
    if asset is not None and pattern.suffix.lower() != ".glb":
        raise InputError(f"{pattern.name}: an asset is written as .glb (glTF's binary), not {pattern.suffix}", "lods")
    if not pattern.parent.exists():  # a job's folder is made for it, as a world's tiles' is
        try:
            pattern.parent.mkdir(parents=True)
        except OSError as error:
            raise InputError(f"{pattern.parent}: cannot make the folder ({error.strerror})") from None
    files.check_writable(pattern.with_name(pattern.name.replace(varying.placeholder, "0")), [model_path])
    check_existing_outputs(pattern, [model_path], varying)
    identity = job_record(load_model(model_path, threads=1), request, pattern, varying)  # a bad model: one line here
    if asset is not None:  # an asset job is another job than the plain one, and than an asset of other levels
        identity["asset"] = {"lods": list(asset.lods), "texture": asset.texture, "ao": asset.ao}
    index = index_path(pattern, varying)
    found = check_same_job(scan_index(index, varying), identity, index, restart)
    done = verified(found.records, pattern, varying) if found else {}
    if found is None and index.exists() or found and (len(done) != len(found.records) or not found.whole
                                                      or found.lines != len(found.records)):
        rewrite_index(index, identity, done)
    job = (model_path, pattern.suffix, threads or 1, request, varying.field)
    if engine == "ray":
        pool = RayActors(*job, workers, address, asset=asset)
    else:
        if workers is not None and workers > default_threads():
            raise InputError(f"`workers` must be 1 to {default_threads()} (this machine's cores), got {workers}",
                             "workers")
        workers = default_threads() if workers is None else workers
        job = (model_path, pattern.suffix, threads or max(1, default_threads() // workers), request, varying.field)
        pool = InProcess(*job, asset=asset) if workers == 1 else Processes(*job, workers, asset=asset)
    written = skipped = running = 0
    try:
        with Appender(index, identity) as log:
            def finish():
                nonlocal written, running
                data, record = pool.next_result()
                running -= 1
                item = record[varying.field]
                path = varying.path(pattern, item)
                files.check_not_input(path, [model_path])  # never over the model, under any name
                files.atomic_write(path, lambda f: f.write(data))
                log.write(json.dumps({varying.field: item, "file": path.name, **record, "bytes": len(data),
                                      "sha256": hashlib.sha256(data).hexdigest()}) + "\n")
                written += 1
                if progress:
                    progress(item, record)

            for item in items:
                if item in done:
                    skipped += 1
                    if progress:
                        progress(item, None)
                    continue
                if running == pool.slots:
                    finish()
                pool.submit(item)
                running += 1
            while running:
                finish()
    finally:
        pool.close()
    return {"written": written, "skipped": skipped, "index": index}


# Worker processes a world's job uses on this machine unless told: one, with
# every core's threads. Neighbouring tiles share their windows, which a
# worker keeps; workers given tiles in turn each make most windows again
# (on 2 cores, two wrote 36 tiles as fast as one did, 7.0 and 6.4 tiles/s
# for the terrain, and, while a tile's normals still made neighbours'
# windows, 1.4 to 1.6 times slower). More cores: --workers.
LOCAL_WORKERS = 1


def write_tiles(model_path, tiles, pattern, request, engine: str = "local", workers: int | None = None,
                threads: int | None = None, address: str | None = None, progress=None,
                restart: bool = False, asset=None) -> dict:
    """Write one file per tile of `tiles` ((i, j) pairs, read lazily), `pattern`
    with {tile} filled in as I_J: the world of `request` (a
    request.SampleRequest with a seed and no tile), resumably, on the cores
    or a Ray cluster as `run_job` does (an index of another job is
    refused unless `restart`); with `asset` (an asset.AssetOptions), each
    tile's game asset (.glb), whose levels keep the tile's whole border.
    Returns {"written", "skipped", "index"}."""
    if request.tile is not None:
        raise InputError("give the tiles to write, not one tile in the request", "tile")
    if engine == "ray" and request.models:
        raise InputError("a Ray cluster is sent the first model only: write a world of several models on this "
                         "machine's cores (engine local)", "models")
    tiles = iter(tiles)
    first = next(tiles, None)
    if first is None:
        raise InputError("no tiles to write", "tile")
    dataclasses.replace(request, tile=first)  # what a tile refuses, refused before the first is made
    loaded = load_model(model_path, threads=1)
    world.check_lod(loaded, request.lod)
    if request.frame != "tile":
        world_tiles.check_placement(loaded, first, request.frame)
    tiles = itertools.chain([first], tiles)
    if engine == "local" and workers is None:
        workers = LOCAL_WORKERS
    return run_job(model_path, tiles, pattern, TILES, request, engine, workers, threads, address, progress, restart,
                   asset)
