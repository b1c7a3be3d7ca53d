"""The `sinrun` command line (cli.main): parse, call one library function,
report.

At the top it imports click and sinshape.core (its errors and atomic
files); everything else, inside the command that needs it (torch only in
`train`, FastAPI only in `serve`), so that `sinrun --help` and `--version`
stay instant and every command but `train` works without torch. The library's InputError becomes one line and exit code 1, with
parameter names written as the options that set them.
"""

import os

# numpy asks the kernel for huge pages for every array of 4 MiB or more. Where
# the kernel gives them on request (transparent huge pages `madvise`), a new
# large array may wait while it compacts memory: the tower's asset at scale 4
# with 2048 maps spent 5.6 s of its 14.7 s in the kernel, and 1.4 of 10.3
# without (docs/BENCHMARKS.md, "Huge pages"). Off in this process and the
# workers it starts, unless the user set it; numpy reads it when first imported.
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
