"""A stopped command ends the same way whichever it is: exit 130 after Ctrl-C
(SIGINT, sent to the whole process group as a terminal does) and 143 after
SIGTERM (`kill`, sent to the command alone), with one line on stderr, no
traceback, and no partial output file. Each command runs as a real process
and is signalled at stated points of its work (importing, loading, working,
writing: tests/stop_at.py finds them with the interpreter's profiling hook),
so that no test passes or fails by when its signal lands; the others are
signalled once a line or a process says where they are. Commands that
finish at once (info, models, layout, shape, export-web) have no work to
stop; they share the handler in cli.main with the ones tested here."""

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc/PID/maps")

SINRUN = [sys.executable, "-c", "from sinshape.cli.main import main; main()"]
ENDINGS = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated")}


@contextlib.contextmanager
def running(args, folder):
    """sinrun ARGS in `folder`, in a process group of its own, with Ctrl-C
    acting as in a terminal (a shell's background job would ignore it)."""
    process = subprocess.Popen(SINRUN + [str(a) for a in args], cwd=folder, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        yield process
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()


def wait_for(process, ready, what: str) -> None:
    deadline = time.monotonic() + 300  # a hang guard only: the work is minutes long
    while not ready():
        if process.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"never {what}: {process.communicate()}")
        time.sleep(0.05)


def stop(process, signum) -> str:
    """Send the signal as it comes in use; assert the exit status; returns stderr's last line."""
    if signum == signal.SIGINT:
        os.killpg(process.pid, signum)
    else:
        process.send_signal(signum)
    _, err = process.communicate(timeout=120)
    assert process.returncode == ENDINGS[signum][0] and "Traceback" not in err, err
    return err.strip().splitlines()[-1]


def starting_workers(process):
    """Ready once the command has started a worker (its second child, after
    multiprocessing's resource tracker), which is still importing."""
    return lambda: len(Path(f"/proc/{process.pid}/task/{process.pid}/children").read_text().split()) >= 2


def lines_in(path):
    return lambda: path.is_file() and path.read_bytes().count(b"\n") > 0


# Each command, and the points of it the signal is sent at (tests/stop_at.py finds them).
COMMANDS = {
    "sample": ["sample", "terrain", "--scale", 2, "-o", "out.ply"],
    "interpolate": ["interpolate", "terrain", "--seeds", 0, 1, "--steps", 2, "-o", "out.ply"],
    "render": ["render", "terrain", "--seeds", "0", "--image-size", 64, "-o", "out.png"],
    "eval": ["eval", "terrain", "--reference", "box.obj", "-n", 2, "--json", "out.json"],
}
POINTS = {"importing": "import:onnxruntime",  # the command's lazy import of its runtime
          "loading": "call:read_model",  # the model file being opened
          "working": "call:run@onnxruntime",  # a level of the generator running
          "writing": "c_call:fsync"}  # the output, written to its temporary, flushed to disk
# sample at every point with either signal; the others at every point, with one or the other
CASES = [(command, point, signals) for command in COMMANDS for number, point in enumerate(POINTS)
         for signals in (("INT", "TERM") if command == "sample" else (("INT", "TERM")[number % 2],))]
CASES += [("sample", "writing", "INT+INT"), ("sample", "writing", "TERM+INT"), ("sample", "importing", "INT+TERM")]
STOP_AT = Path(__file__).with_name("stop_at.py")


@pytest.mark.parametrize("command, point, signals", CASES, ids=["-".join(case) for case in CASES])
def test_a_command_stopped_at_a_stated_point(tmp_path, command, point, signals):
    """Ctrl-C or SIGTERM at each stated point ends the command in one line,
    with the status of the signal that came first, and no output or
    temporary file; a second signal in the clean-up is let pass."""
    import trimesh

    trimesh.creation.box((2, 1, 1)).export(tmp_path / "box.obj")
    args = [sys.executable, STOP_AT, POINTS[point], signals, *COMMANDS[command]]
    process = subprocess.run([str(a) for a in args], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                             start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    status, line = ENDINGS[signal.Signals["SIG" + signals.split("+")[0]]]
    assert process.returncode == status and "Traceback" not in process.stderr, process.stderr
    assert process.stderr.strip().splitlines()[-1] == line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.obj"]


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="two worker processes need two cores")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_many_samples_on_worker_processes(tmp_path, signum):
    """Ctrl-C reaches the workers too: they leave it to the command, even
    while they start (the signal comes then)."""
    with running(["sample", "terrain", "--seeds", "0-999", "--scale", 4, "--workers", 2, "-o", "{seed}.ply"],
                 tmp_path) as process:
        wait_for(process, starting_workers(process), "started workers")
        assert stop(process, signum) == ENDINGS[signum][1]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file


def test_many_samples_on_ray(tmp_path):
    """Ray's driver has its own SIGTERM handler (exit 1 and a stack dump): the command's stays."""
    pytest.importorskip("ray", reason="the ray extra is not installed: pip install 'sinshape[ray]'")
    with running(["sample", "terrain", "--seeds", "0-999", "--scale", 4, "--engine", "ray", "-o", "{seed}.ply"],
                 tmp_path) as process:
        wait_for(process, lines_in(tmp_path / "index.jsonl"), "wrote a sample")
        assert stop(process, signal.SIGTERM) == "terminated"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_serve(tmp_path, signum):
    pytest.importorskip("uvicorn", reason="the serve extra is not installed")
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    with running(["serve", "terrain", "--port", port], tmp_path) as process:
        assert "Ctrl-C stops" in process.stderr.readline()  # listening
        assert stop(process, signum) == ENDINGS[signum][1]


def test_train_terminated_saves_a_checkpoint(tmp_path, tiny_pyramid):
    """As Ctrl-C does (tests/test_cli_train.py), with the exit status of SIGTERM."""
    pytest.importorskip("torch")
    out = tmp_path / "m.onnx"
    with running(["train", tiny_pyramid, "-o", out, "--preset", "tiny", "--iters", 100000], tmp_path) as process:
        for line in process.stderr:  # training is under way
            if "level 1/2" in line and "/100000" in line:
                break
        assert stop(process, signal.SIGTERM).endswith("; --resume continues from it")
    assert out.with_name("m.ckpt.pt").exists() and not out.exists()


def test_a_signal_inside_an_import_is_found_down_the_chain_of_causes():
    # onnxruntime turns a SIGTERM that lands while it imports numpy into a fresh ImportError, whose
    # context is another error of the import: the stop is read from anywhere down the chain.
    from sinshape.cli import main

    def chained(*errors):
        for outer, inner in zip(errors, errors[1:]):
            outer.__context__ = inner
        return errors[0]

    stop = main.Terminated()
    assert main.interruption(chained(ImportError("import numpy failed"), ImportError("numpy"), stop)) is stop
    assert main.interruption(chained(ImportError("no such module"), ValueError("bad"))) is None
    # Ctrl-C that left no trace in the chain: the handler remembers it, and lets a second one pass.
    try:
        with pytest.raises(KeyboardInterrupt):
            main.stopped(signal.SIGINT, None)
        main.stopped(signal.SIGTERM, None)  # while the first unwinds: no second exception
        assert isinstance(main.interruption(ImportError("import numpy failed")), KeyboardInterrupt)
        assert not isinstance(main.interruption(ImportError("import numpy failed")), main.Terminated)
    finally:
        main.stopped.first = None
