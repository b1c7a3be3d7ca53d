"""The `sinrun` command line (cli.main): parse, call one library function,
report.

At the top it imports click and sinshape.core (its errors and atomic
files); everything else, inside the command that needs it (torch only in
`train`, FastAPI only in `serve`), so that `sinrun --help` and `--version`
stay instant and every command but `train` works without torch. The library's InputError becomes one line and exit code 1, with
parameter names written as the options that set them.
"""
