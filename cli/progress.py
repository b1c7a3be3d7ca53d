"""What `sinrun` shows while it works: progress bars and times, on stderr."""

import sys
import time

import click

class TrainProgress:
    """One line per level: click's progress bar on a terminal, with the
    losses beside it; elsewhere (a log file, CI) a line every 10%, where
    click's bar would print only its label. `log` prints the trainer's other
    lines (the plan, level starts, checkpoints); quiet shows nothing."""

    def __init__(self, stream=sys.stderr, quiet: bool = False):
        self.stream = stream
        self.quiet = quiet
        self.tty = stream.isatty()
        self.level = None
        self.bar = None
        self.started = 0.0
        self.reported = -1

    def __call__(self, p) -> None:
        if self.quiet:
            return
        losses = "  ".join(f"{k} {v:+.4f}" for k, v in p.losses.items())
        head = f"level {p.level + 1}/{p.levels} {'x'.join(map(str, p.size))}"
        if p.level != self.level:
            self.level, self.started, self.reported = p.level, time.monotonic(), -1
            if self.tty:
                self.bar = click.progressbar(length=p.iters, label=head, file=self.stream, show_pos=True,
                                             item_show_func=lambda text: text)
                self.bar.__enter__()
        if self.tty:
            self.bar.update(p.iteration - self.bar.pos, losses)
            if p.iteration == p.iters:
                self.close()
            return
        if p.iteration * 10 // p.iters != self.reported or p.iteration == p.iters:
            self.reported = p.iteration * 10 // p.iters
            left = (time.monotonic() - self.started) / p.iteration * (p.iters - p.iteration)
            self.stream.write(f"{head} {p.iteration}/{p.iters}  {losses}  {format_seconds(left)} left\n")
            self.stream.flush()

    def log(self, message: str) -> None:
        if not self.quiet:
            click.echo(message, err=True)

    def close(self) -> None:
        """End the bar's line and show the cursor again."""
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None

    def __enter__(self):
        return self

    def __exit__(self, *error) -> None:
        self.close()  # also after Ctrl-C, before the command says where it saved


def format_seconds(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def progress_bar(length: int, label: str):
    """A progress bar on stderr, shown only on a terminal and for more than one step."""
    if length < 2 or not sys.stderr.isatty():
        return HiddenBar()
    return click.progressbar(length=length, label=label, file=sys.stderr)


class HiddenBar:
    """A bar that shows nothing: click's, even hidden, costs a 20 ms import
    that a small sample notices."""

    pos = 0

    def __enter__(self):
        return self

    def __exit__(self, *error) -> None:
        pass

    def update(self, steps: int, current_item=None) -> None:
        self.pos += steps


class StageProgress:
    """A bar per stage of work that reports progress(stage, done, total) (on a terminal)."""

    def __init__(self):
        self.stage, self.bar = None, None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage != self.stage:
            self.__exit__(None, None, None)
            self.stage, self.bar = stage, progress_bar(total, stage).__enter__()
        self.bar.update(done - self.bar.pos)

    def __enter__(self):
        return self

    def __exit__(self, *error) -> None:
        if self.bar is not None:
            self.bar.__exit__(*error)
            self.bar = None
