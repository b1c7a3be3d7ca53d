"""The one exception type that means "the user's input is bad".

Everything the user controls (a mesh, a pyramid, a model file, an option
value, an output path) is checked where it is read; a failed check raises
`InputError` with a message that fits on one line. The CLI prints that line
and exits non-zero; any other exception is a bug and keeps its traceback.
"""


class InputError(ValueError):
    """Bad user input, reported as one line without a traceback."""


class MemoryLimitError(InputError):
    """Work refused up front because it would need more memory than the
    limit (runtime.generate.MEMORY_LIMIT); the message gives the figure."""
