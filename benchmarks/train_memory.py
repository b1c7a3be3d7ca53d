"""Training memory: the peak of one iteration per level size, against the
estimate `sinrun train` refuses work with (trainer/memory.py, level_memory).

    python benchmarks/train_memory.py             # the table in docs/RELIABILITY.md
    python benchmarks/train_memory.py --box 16    # with --box 16

Each size runs in a fresh process, on the CPU in float32: a coarse 16^3
level, then one level of the size, two iterations (the first allocates).
The figure is the process's peak resident memory less its resident memory
just before the level: what the level itself adds.
"""

import argparse
import json
import subprocess
import sys

SIZES = [(32, 16, 16), (48, 24, 24), (64, 32, 32), (96, 28, 44), (64, 64, 64), (128, 36, 60)]


def measure(size, box) -> int:
    """Bytes one iteration at `size` adds to the process (run in a child)."""
    import resource

    import numpy as np

    from sinshape.prep.pyramid import Pyramid
    from sinshape.trainer import device, train
    from sinshape.trainer.config import make_config

    x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in size], indexing="ij")
    finest = z < 0.4 * np.sin(3 * x) * np.cos(2 * y)
    coarse = np.zeros((16, 16, 16), bool)
    coarse[:, :, :8] = True
    pyramid = Pyramid([coarse, finest], (0, 0, 0), (1, 1, 1), "wavy", "0" * 64, "pyramid")
    config = make_config("tiny", box=box, precision="fp32")
    trainer = train.Trainer(config, pyramid, device.choose("cpu", "fp32"))
    trainer.begin_level()
    trainer.iterate(trainer.recon_inputs())
    trainer.finish_level()
    trainer.begin_level()
    with open("/proc/self/statm") as f:
        before = int(f.read().split()[1]) * resource.getpagesize()
    recon = trainer.recon_inputs()
    for _ in range(2):
        trainer.iterate(recon)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--box", type=int, default=0, help="sinrun train --box")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(measure(tuple(json.loads(args.child)), args.box))
        return
    from sinshape.trainer.config import make_config
    from sinshape.trainer.memory import level_memory

    config = make_config("tiny", box=args.box)
    print("| level size | voxels | measured MiB | estimate MiB |")
    print("|---|---|---|---|")
    for size in SIZES:
        command = [sys.executable, __file__, "--child", json.dumps(size)]
        if args.box:
            command += ["--box", str(args.box)]
        measured = int(subprocess.run(command, check=True, capture_output=True, text=True).stdout)
        voxels = size[0] * size[1] * size[2]
        print(f"| {'x'.join(map(str, size))} | {voxels} | {measured / 2**20:.0f} | "
              f"{level_memory(size, config) / 2**20:.0f} |", flush=True)


if __name__ == "__main__":
    main()
