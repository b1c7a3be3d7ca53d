"""What a user waits for: `sinrun sample` wall time and peak memory, this
checkout against another install (a release), side by side in one run.

    python benchmarks/sinrun_speed.py --before /path/to/release/venv/bin/sinrun [--now PATH] [--rounds 3]

Install both the same way (`pip install .`, not `-e`: an editable install's
import hook alone adds about 20 ms to every start).

Each command runs in a fresh process, `before` and `now` alternated (the
order flips every round, so a machine that slows down during the run does not
favour one); peak memory is the process's max RSS. Then the start-up in
detail, for the first command: the stages of one sample timed in one
process, and the slowest imports (`python -X importtime`), for both.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMANDS = [  # (what, arguments after `sinrun`, the target in seconds)
    ("terrain, scale 1", ["sample", "terrain", "--seed", "1", "-o", "t.ply"], 0.4),
    ("default model, scale 8", ["sample", "--seed", "3", "--scale", "8", "-o", "d8.ply"], 2.5),
    ("towerruins, scale 16", ["sample", "towerruins", "--seed", "3", "--scale", "16", "-o", "s16.ply"], 10.0),
]

STAGES = """
import sys, time
started = time.perf_counter()
from sinshape import models, runtime
from sinshape.runtime import write
imported = time.perf_counter()
model = runtime.load_model(models.find("terrain"))
loaded = time.perf_counter()
triplane = runtime.sample(model, 1)
sampled = time.perf_counter()
write.write_sample(model, triplane, sys.argv[1])
written = time.perf_counter()
print(f"{imported - started:.3f} {loaded - imported:.3f} {sampled - loaded:.3f} {written - sampled:.3f}")
"""


def timed(command: list, folder: str) -> tuple:
    """(wall seconds, peak MB) of one process."""
    started = time.perf_counter()
    process = subprocess.Popen(command, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode:
        raise SystemExit(f"{' '.join(command)} failed:\n{process.stderr.read().decode()}")
    return seconds, usage.ru_maxrss / 1024


def import_profile(python: str, top: int = 6) -> tuple:
    """(total import seconds, the `top` slowest top-level imports) of `sinrun sample`'s modules."""
    code = "from sinshape.cli.main import main\nfrom sinshape.runtime import load, generate, edit, write, mesh"
    result = subprocess.run([python, "-X", "importtime", "-c", code], capture_output=True, text=True, check=True)
    rows = []
    for line in result.stderr.splitlines():
        if line.startswith("import time:") and "|" in line and "cumulative" not in line:
            _, cumulative, name = line.split("|")
            if not name.startswith("  "):  # a top-level import (nested ones are indented further)
                rows.append((int(cumulative) / 1e6, name.strip()))
    return sum(s for s, _ in rows), sorted(rows, reverse=True)[:top]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", required=True, help="the other install's sinrun executable")
    parser.add_argument("--now", default=str(Path(sys.executable).with_name("sinrun")),
                        help="this checkout's sinrun (default: the one beside this python)")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    installs = {"before": args.before, "now": args.now}

    print("| command | before: wall s (each round) | peak MB | now: wall s | peak MB | speed-up | target |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for what, arguments, target in COMMANDS:
            runs = {name: [] for name in installs}
            for round_ in range(args.rounds):
                for name in (list(installs) if round_ % 2 == 0 else list(installs)[::-1]):
                    runs[name].append(timed([installs[name], *arguments], folder))
            best = {name: min(s for s, _ in measured) for name, measured in runs.items()}
            cells = [f"{' / '.join(f'{s:.2f}' for s, _ in runs[name])} | {max(m for _, m in runs[name]):.0f}"
                     for name in installs]
            print(f"| `sinrun {' '.join(arguments)}` ({what}) | {cells[0]} | {cells[1]} | "
                  f"{best['before'] / best['now']:.1f}x | {target:g} s |", flush=True)

        print("\nOne terrain sample in one process (s): import | load_model | sample | mesh and write .ply")
        for name, sinrun in installs.items():
            python = str(Path(sinrun).with_name("python"))
            result = subprocess.run([python, "-c", STAGES, str(Path(folder) / "stages.ply")],
                                    capture_output=True, text=True, check=True)
            print(f"- {name}: {' | '.join(result.stdout.split())}")

    print("\nImports of `sinrun sample` (python -X importtime; cumulative, top level):")
    for name, sinrun in installs.items():
        total, slowest = import_profile(str(Path(sinrun).with_name("python")))
        print(f"- {name}: {total:.3f} s in all; " + ", ".join(f"{module} {s:.3f}" for s, module in slowest))


if __name__ == "__main__":
    main()
