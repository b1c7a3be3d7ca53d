"""The one exception type that means "the user's input is bad".

Everything the user controls (a mesh, a pyramid, a model file, an option
value, an output path) is checked where it is read; a failed check raises
`InputError` with a message that fits on one line. The CLI prints that line
and exits non-zero; any other exception is a bug and keeps its traceback.

A message about one parameter calls it by the library's name for it
(`scale must be a positive number`) and sets `parameter`, so that a front
end can say it its own way (the CLI writes `--scale`). Where the name is
also an ordinary word of the message, the parameter is its last occurrence
(`x.h5 has 3 levels; levels 5 asks for more`). Parameters that cannot be
given together raise `ConflictError`, whose `parameter` names them all.
"""


class InputError(ValueError):
    """Bad user input, reported as one line without a traceback; `parameter`
    names the function parameter at fault, where there is one (a tuple: each
    of several)."""

    def __init__(self, message: str, parameter: str | tuple | None = None):
        super().__init__(message)
        self.parameter = parameter


class MemoryLimitError(InputError):
    """Work refused up front because it would need more memory than the
    limit (a `memory_limit` parameter, by default the memory available:
    core.budget.check_memory); the message gives the figure."""


class ConflictError(InputError):
    """Parameters given together that cannot be (or one given without another
    it needs): `parameter` is the tuple of them all. A command line reports it
    as a misuse of the command, with its usage."""
