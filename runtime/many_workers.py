"""Where a job's items are made: one Worker (the model loaded once, each
item's file bytes and figures sent back), in this process, in worker
processes on this machine, or in Ray actors on a cluster; only the
driver (many) writes."""

import contextlib
import dataclasses
import multiprocessing
import os
import queue
import signal
import socket
import tempfile
import threading
import time
from multiprocessing import resource_tracker
from pathlib import Path

from sinshape.core.errors import InputError

from . import world_tiles, write
from .load import load_model

ENGINES = ("local", "ray")


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
