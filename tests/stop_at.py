"""Run sinrun, sending it a signal at a stated point of its work:

    python stop_at.py POINT SIGNALS SINRUN-ARGUMENTS...

POINT is one of
  import:MODULE      as MODULE's import begins (a lazy import of the command)
  call:NAME[@FILE]   as a Python function NAME (in a file whose path holds FILE) is called
  c_call:NAME        as a built-in function NAME is called (fsync: the output being written)
SIGNALS is INT (sent to the process group, as a terminal sends Ctrl-C) or
TERM (to the command alone, as `kill` does), or several joined by `+`:
each after the first is sent as the one before it is handled, so that it
lands in the first clean-up the command runs (a second Ctrl-C while the
first unwinds). The point is found by the interpreter's profiling hook, not
by waiting, so a test of it cannot pass or fail by when a signal lands.
"""

import importlib.abc
import os
import signal
import sys

from sinshape.cli.main import main

STOPS = (signal.SIGINT, signal.SIGTERM)


def send(signum) -> None:
    if signum == signal.SIGINT:
        os.killpg(os.getpgid(0), signum)
    else:
        os.kill(os.getpid(), signum)


class StopAt(importlib.abc.MetaPathFinder):
    """The point (found by `profile`, or as an import by `find_spec`) and the signals to send."""

    def __init__(self, point: str, signals: str):
        self.kind, _, self.name = point.partition(":")
        self.signals = [signal.Signals["SIG" + name] for name in signals.split("+")]

    def reached(self) -> None:
        sys.setprofile(None)  # the rest at full speed
        self.kind = None
        send(self.signals.pop(0))

    def profile(self, frame, event, arg) -> None:
        if event == self.kind == "call":
            function, _, where = self.name.partition("@")
            if frame.f_code.co_name == function and where in frame.f_code.co_filename:
                self.reached()
        elif event == self.kind == "c_call" and getattr(arg, "__name__", None) == self.name:
            self.reached()

    def find_spec(self, fullname, path=None, target=None):
        if self.kind == "import" and fullname == self.name:
            self.reached()
        return None  # the import itself goes on as usual

    def handled(self, handler):
        """`handler` for sinrun's SIGINT or SIGTERM, sending the next signal as it returns or raises."""
        def then_the_next(signum, frame):
            try:
                return handler(signum, frame)
            finally:
                if self.signals:
                    send(self.signals.pop(0))
        return then_the_next


if __name__ == "__main__":
    stop = StopAt(sys.argv[1], sys.argv[2])
    sys.argv[1:3] = []
    install = signal.signal
    signal.signal = lambda signum, handler: install(signum, stop.handled(handler) if signum in STOPS
                                                     and callable(handler) else handler)
    sys.meta_path.insert(0, stop)
    sys.setprofile(stop.profile)
    main()
