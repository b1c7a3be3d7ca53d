"""Mesh work off Blender's main thread, its results applied on it.

Work runs on one worker thread: onnxruntime and numpy's large operations
release the GIL, so Blender's event loop keeps running while a sample is
made (docs/BLENDER.md measures how well). Each object has at most one job
waiting: a newer request for it replaces the waiting one, and a running one
stops at its next slab of meshing (its progress callback raises
Superseded). Results and errors go back through a queue that a
bpy.app.timers function empties on the main thread, the only thread that
touches Blender data; it also keeps the status bar's progress.

In background mode (bpy.app.background) no event loop runs timers: a job
runs at once, before `submit` returns, and its errors reach the caller.
"""

import threading
import traceback
from collections import OrderedDict, deque

import bpy

from sinshape.core.errors import InputError

POLL_SECONDS = 0.05


class Superseded(Exception):
    """A newer request for the same object came while this one ran."""


class Job:
    """One piece of work for one object (`key`): compute(job) runs on the
    worker and hands each result to job.deliver; apply(result) and
    fail(error) run on the main thread."""

    def __init__(self, key: str, label: str, compute, apply, fail):
        self.key, self.label, self.compute, self.apply, self.fail = key, label, compute, apply, fail
        self.cancelled = threading.Event()
        self.fraction = 0.0
        self.deliver = None  # set by the Worker that runs it

    def progress(self, done: int, total: int) -> None:
        """The runtime's progress callback: records how far, and stops superseded work."""
        if self.cancelled.is_set():
            raise Superseded
        self.fraction = done / max(total, 1)


class Worker:
    """synchronous: run each job at once (None: in background mode, where no timer runs)."""

    def __init__(self, synchronous: bool | None = None):
        self.synchronous = bpy.app.background if synchronous is None else synchronous
        self.lock = threading.Lock()
        self.waiting = OrderedDict()  # key -> Job
        self.running = None
        self.finished = deque()  # (job, result, error) for the main thread
        self.thread = None

    def submit(self, job: Job) -> None:
        if self.synchronous:
            job.deliver = job.apply
            job.compute(job)
            return
        job.deliver = lambda result: self.finished.append((job, result, None))
        with self.lock:
            self.waiting.pop(job.key, None)
            if self.running is not None and self.running.key == job.key:
                self.running.cancelled.set()
            self.waiting[job.key] = job
            if self.thread is None:
                self.thread = threading.Thread(target=self.run, name="sinshape", daemon=True)
                self.thread.start()
        if not bpy.app.background and not bpy.app.timers.is_registered(self.poll):
            bpy.app.timers.register(self.poll, first_interval=POLL_SECONDS, persistent=True)

    def run(self) -> None:
        while True:
            with self.lock:
                if not self.waiting:
                    self.running = self.thread = None
                    return
                _, job = self.waiting.popitem(last=False)
                self.running = job
            try:
                job.compute(job)
            except Superseded:
                pass
            except Exception as error:  # handed to the main thread: InputError is reported, the rest is a bug
                self.finished.append((job, None, error))

    def busy(self) -> bool:
        return bool(self.running or self.waiting or self.finished)

    def status(self) -> tuple:
        """(text, fraction done) of the running job, or None."""
        job = self.running
        return (job.label, job.fraction) if job else None

    def poll(self):
        """The timer: apply what is finished, redraw the progress; stop when idle."""
        while self.finished:
            job, result, error = self.finished.popleft()
            if job.cancelled.is_set():
                continue
            if error is None:
                job.apply(result)
            elif isinstance(error, InputError):
                job.fail(error)
            else:
                traceback.print_exception(error)  # a bug: its traceback, and the timer goes on
        redraw_status()
        return POLL_SECONDS if self.busy() else None

    def clear(self) -> None:
        """Drop every job (another file is opened: their objects are gone)."""
        with self.lock:
            for job in [*self.waiting.values(), *([self.running] if self.running else [])]:
                job.cancelled.set()
            self.waiting.clear()
            self.finished.clear()


WORKER = Worker()


def draw_status(header, context) -> None:
    """Appended to the status bar: the running job's progress."""
    status = WORKER.status()
    if status:
        header.layout.progress(factor=status[1], text=f"sinshape: {status[0]}")


SHOWN = {"status": None}  # what the status bar last drew


def redraw_status() -> None:
    """Ask each window's status bar to redraw when what it shows changed
    by a step (clearing its status text: the one call that reaches it from
    Python), except in a window where a modal operator shows its own."""
    status = WORKER.status()
    status = status and (status[0], round(status[1], 2))
    if status == SHOWN["status"]:
        return
    SHOWN["status"] = status
    for window in bpy.context.window_manager.windows:
        if window.modal_operators:
            continue
        with bpy.context.temp_override(window=window):
            bpy.context.workspace.status_text_set_internal(None)
