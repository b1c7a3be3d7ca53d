"""gzip, once per file: the `.gz` copies `sinrun export-web` writes beside
the site's files, and the static files `sinrun serve` keeps compressed in
memory.

Level 9, mtime 0 and no file name in the header: a file always gives the
same bytes (with the same zlib), so two exports are byte-identical. A copy
is kept only where it pays: the page's text and onnxruntime-web's `.wasm`
shrink to a quarter or less, a model's float weights by about a tenth,
which is not worth a second copy of the model on disk or in memory.
"""

import gzip
from pathlib import Path

from sinshape.core import files

LEVEL = 9  # the .wasm: 3.65 MB in 1 s of CPU, once; level 6 gives 3.67 MB
SUFFIXES = frozenset({".html", ".js", ".mjs", ".css", ".json", ".wasm", ".onnx"})  # what the page fetches
MIN_BYTES = 1024  # smaller files gain a few hundred bytes at most
WORTH = 0.8  # keep a copy at most this fraction of the file's size


def worth_trying(path: Path, size: int) -> bool:
    """Whether a file of this name and size may be worth compressing."""
    return path.suffix in SUFFIXES and size >= MIN_BYTES


def packed(data: bytes) -> bytes | None:
    """`data` gzipped (deterministic), or None where gzip saves less than a fifth."""
    out = gzip.compress(data, compresslevel=LEVEL, mtime=0)
    return out if len(out) <= WORTH * len(data) else None


def write_beside(folder: Path) -> list:
    """Write FILE.gz beside every file under `folder` worth compressing;
    returns the copies written, in a fixed order."""
    written = []
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        if worth_trying(path, path.stat().st_size) and (data := packed(path.read_bytes())) is not None:
            target = path.with_name(path.name + ".gz")
            files.atomic_write(target, lambda f: f.write(data))
            written.append(target)
    return written
