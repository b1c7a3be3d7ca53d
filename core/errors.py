"""The one exception type that means "the user's input is bad".

Everything the user controls (a mesh, a pyramid, a model file, an option
value, an output path) is checked where it is read; a failed check raises
`InputError` with a message that fits on one line. The CLI prints that line
and exits non-zero; any other exception is a bug and keeps its traceback.

A message that names a parameter marks the name in backticks, so that the
name is never confused with the same ordinary word (``a height map holds
values``, ``x.h5 has 3 levels; `levels` 5 asks for more``): `str(error)` is
the message with the library's plain name (what the HTTP routes and Blender
print), and a front end with names of its own writes them by `spelled` (the
CLI: `--levels`). `parameter` says which parameter is at fault (a tuple:
each of several). Parameters that cannot be given together raise
`ConflictError`, whose `parameter` names them all.
"""

import re

NAME = re.compile(r"`(\w+)`")  # a parameter's name, as a message marks it


def spelled(message: str, spell=lambda name: name) -> str:
    """`message` with each name it marks written as `spell(name)`."""
    return NAME.sub(lambda found: spell(found.group(1)), message)


def named(parameters, between: str = ", ") -> str:
    """Several parameters' marked names in one phrase (`grow`, `layout`)."""
    return between.join(f"`{name}`" for name in parameters)


class NamesParameters:
    """An exception whose message marks the parameters it names: `template`
    keeps the marks, str() gives the plain names."""

    @property
    def template(self) -> str:
        return str(self.args[0]) if self.args else ""

    def __str__(self) -> str:
        return spelled(self.template)


class InputError(NamesParameters, ValueError):
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
