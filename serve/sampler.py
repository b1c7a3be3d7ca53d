"""Bounded work for a server: at most `slots` jobs at once on a thread pool,
each within a time limit, identical jobs in flight shared, finished results
kept in an LRU cache bounded in bytes and in count, and a job given up when
every client waiting for it has left.

It knows no HTTP: its outcomes are its own exceptions (NoSlot, OutOfTime,
ClientGone), which the routes answer as 503, 504 and 499. A job is a key
(hashable, equal for equal work) and a function work(checkpoint) that runs
in a worker thread, calls checkpoint() now and then (it raises Cancelled
once the job is given up) and returns a result with its bytes in `.body`.
"""

import asyncio
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor

DISCONNECT_POLL = 0.25  # seconds between checks that a waiting client is still there


class NoSlot(Exception):
    """No slot came free within the time limit."""


class OutOfTime(Exception):
    """The job took longer than the time limit; it is stopped at its next checkpoint."""


class ClientGone(Exception):
    """The client left before its result was made."""


class Cancelled(Exception):
    """Raised by a checkpoint inside a worker thread whose job ran out of time, or whose clients all left."""


class Sampler:
    """At most `slots` jobs at once, each within `timeout` seconds, results
    kept in an LRU cache of at most `cache_bytes` and `cache_entries`.

    Lives on the event loop's thread; only the jobs' work runs in the pool.
    """

    def __init__(self, slots: int, timeout: float, cache_bytes: int, cache_entries: int = 256):
        self.slots = asyncio.Semaphore(slots)
        self.pool = ThreadPoolExecutor(max_workers=slots, thread_name_prefix="sample")
        self.timeout = timeout
        self.cache = OrderedDict()  # key -> result, least recently used first
        self.cache_bytes, self.cache_entries, self.cached_bytes = cache_bytes, cache_entries, 0
        self.pending = {}  # key -> asyncio.Task
        self.running = self.most_running = 0  # jobs being worked on now, and at most so far
        self.cancels = set()  # one Event per job being worked on
        self.waiting = {}  # key -> clients waiting for it

    async def get(self, key, work, gone=None) -> tuple:
        """(result, True if it came from the cache). `gone`, an async
        function, says whether the client has left: when every client
        waiting for a job has left, it is stopped (ClientGone)."""
        if key in self.cache:
            self.cache.move_to_end(key)
            return self.cache[key], True
        task = self.pending.get(key)
        if task is None:
            task = asyncio.ensure_future(self.compute(key, work))
            self.pending[key] = task
            self.waiting[key] = 0
            task.add_done_callback(lambda _: (self.pending.pop(key, None), self.waiting.pop(key, None)))
        self.waiting[key] += 1
        try:
            while True:
                done, _ = await asyncio.wait({task}, timeout=DISCONNECT_POLL)
                if done:
                    return task.result(), False
                if gone is not None and await gone():
                    raise ClientGone
        except ClientGone:
            if key in self.waiting:
                self.waiting[key] -= 1
                if self.waiting[key] == 0:  # nobody wants it any more: free the slot
                    task.cancel()
            raise

    async def compute(self, key, work):
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout
        try:
            await asyncio.wait_for(self.slots.acquire(), self.timeout)
        except asyncio.TimeoutError:
            raise NoSlot(f"busy: no sampling slot came free within {self.timeout:g} s; try again later") from None
        cancel = threading.Event()
        self.cancels.add(cancel)
        self.running += 1
        self.most_running = max(self.most_running, self.running)

        def checkpoint(*_):
            if cancel.is_set():
                raise Cancelled

        future = loop.run_in_executor(self.pool, work, checkpoint)
        future.add_done_callback(lambda f: self.finished(f, cancel))
        try:
            result = await asyncio.wait_for(asyncio.shield(future), max(0.0, deadline - loop.time()))
        except asyncio.CancelledError:  # every client has gone
            cancel.set()
            raise
        except asyncio.TimeoutError:
            cancel.set()
            raise OutOfTime(f"sampling took longer than the {self.timeout:g} s limit; "
                            "ask for a smaller size or scale") from None
        self.store(key, result)
        return result

    def finished(self, future, cancel: threading.Event) -> None:
        """The slot is freed when the thread ends, not when the request gives up on it."""
        self.cancels.discard(cancel)
        self.running -= 1
        self.slots.release()
        if not future.cancelled():
            future.exception()  # retrieved, so a cut-off job's Cancelled is not logged as lost

    def store(self, key, result) -> None:
        if len(result.body) > self.cache_bytes // 4:
            return  # a few huge files would flush everything else
        self.cache[key] = result
        self.cached_bytes += len(result.body)
        while self.cached_bytes > self.cache_bytes or len(self.cache) > self.cache_entries:
            _, dropped = self.cache.popitem(last=False)
            self.cached_bytes -= len(dropped.body)

    def counts(self) -> dict:
        """How busy it is: jobs being worked on (now and at most), in flight, and what the cache holds."""
        return {"sampling": self.running, "most_sampling": self.most_running, "in_flight": len(self.pending),
                "cached_files": len(self.cache), "cached_bytes": self.cached_bytes}

    def close(self) -> None:
        """Stop: jobs being worked on stop at their next checkpoint, queued ones never start."""
        for cancel in self.cancels:
            cancel.set()
        self.pool.shutdown(wait=False, cancel_futures=True)
