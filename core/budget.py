"""Refuse work up front, with the figure: the one memory check of every command.

Each stage estimates the bytes its work needs from the sizes it is given
(a sample's levels, a meshing grid, a picture, a procedural shape's grid, a
training level) before it allocates anything, and calls `check_memory`,
which compares the estimate with a limit: a `memory_limit` parameter, by
default the memory available now. The refusal is a MemoryLimitError that
says "needs about N GiB of memory (limit M GiB)", on the command line and
in the web API alike.
"""

import numbers
import os
from decimal import Decimal

from .errors import InputError, MemoryLimitError

# The memory limit where the machine does not say how much memory is available.
FALLBACK_MEMORY_LIMIT = 4 << 30


def available_memory() -> int:
    """Bytes of memory available to new work: the machine's (machine_memory),
    or less where the process's address space is limited (`ulimit -v`,
    RLIMIT_AS): what the limit leaves of it."""
    machine = machine_memory()
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, OSError, ValueError):  # no resource module (Windows)
        return machine
    if limit == resource.RLIM_INFINITY:
        return machine
    return max(0, min(machine, limit - address_space()))


def address_space() -> int:
    """Bytes of address space this process uses now (VmSize), 0 where unknown."""
    return proc_kib("/proc/self/status", "VmSize:") or 0


def machine_memory() -> int:
    """Bytes of the machine's memory available to new work: MemAvailable on
    Linux (it counts reclaimable caches), else the free physical pages, else
    FALLBACK_MEMORY_LIMIT."""
    available = proc_kib("/proc/meminfo", "MemAvailable:")
    if available is not None:
        return available
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_MEMORY_LIMIT


def proc_kib(path: str, field: str) -> int | None:
    """A 'Field: N kB' line of a Linux /proc file, in bytes; None where there is none."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(field):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(needed: int, what: str, limit: int | None = None) -> None:
    """Refuse work up front, with the figure, if it needs more than `limit`
    bytes (None: the memory available now)."""
    if limit is not None and not isinstance(limit, numbers.Real):
        raise InputError(f"`memory_limit` must be a number of bytes, got {limit!r}", "memory_limit")
    limit = available_memory() if limit is None else limit
    if needed > limit:
        raise MemoryLimitError(f"{what} needs about {gib(needed)} GiB of memory (limit {gib(limit)} GiB)")


def gib(size) -> str:
    """Bytes as GiB for a message, absurd sizes too (past what a float holds)."""
    value = Decimal(int(size)) / 2**30
    return f"{value:.1f}" if value < 10**15 else f"{value:.3g}"
