"""Many samples as one resumable job: seeds (or the tiles of a world) spread
over worker processes on this machine, or over a Ray cluster
(many_workers).

Workers load the model once and send back each seed's file bytes and
figures; only this process writes, atomically, then appends the seed to
the job's index beside the outputs (many_index). A rerun resumes only that
job (another is refused, naming the difference, unless `restart`), and
skips a seed only if its file is the one the index recorded (same size and
hash): a missing, truncated or changed file is made again, and the index is
rewritten first with one line per seed it still vouches for. Ctrl-C leaves
no partial file.
Seeds are taken lazily, a few ahead of the workers, so a range of any length
costs nothing up front.
"""

import dataclasses
import hashlib
import itertools
import json
from pathlib import Path

from sinshape.core import files
from sinshape.core.errors import ConflictError, InputError

from . import world, world_tiles, write
from .load import default_threads, load_model
from .many_index import (SEEDS, TILES, Appender, Varying, check_existing_outputs, check_same_job, index_path,
                         job_record, rewrite_index, scan_index, verified)
from .many_workers import InProcess, Processes, RayActors
from .request import SampleRequest

ENGINES = ("local", "ray")


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
