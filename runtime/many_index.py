"""A job's index: what a job of many seeds or tiles has written, kept
beside its outputs so that a rerun resumes it (many).

JSON lines: the first records the job (the model's SHA-256, the files'
names, the request), each after it one file (its seed or tile, name, size
and SHA-256), appended whole and fsynced, so the index is valid up to its
last whole line after a crash. A rerun resumes only the job its index
records, and vouches only for files still as recorded."""

import dataclasses
import hashlib
import itertools
import json
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from sinshape.core import files
from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError

from . import world
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


def later_defaults(recorded: dict | None, job: dict) -> dict | None:
    """A recorded job with the request fields it lacks (added to requests
    since its index was written) at their defaults, which ask for what
    the files were made as then: an older index resumes."""
    if not (isinstance(recorded, dict) and isinstance(recorded.get("request"), dict)):
        return recorded
    defaults = {field.name: field.default for field in dataclasses.fields(SampleRequest)
                if field.default is not dataclasses.MISSING}
    lacking = {name: defaults[name] for name in job["request"] if name not in recorded["request"] and name in defaults}
    return {**recorded, "request": {**recorded["request"], **json.loads(json.dumps(lacking))}}


def check_same_job(index: IndexFile | None, job: dict, path: Path, restart: bool) -> IndexFile | None:
    """The index a job resumes from: refused, naming the difference, when it
    records another job (or none), unless `restart`, which starts it afresh
    (its files are made again). An index without any line is no index."""
    if index is None or (index.job is None and not index.records):
        return None
    if later_defaults(index.job, job) == job:  # the same job (an older index: its missing fields at their defaults)
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
