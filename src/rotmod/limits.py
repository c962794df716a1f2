"""Resource checks made before any large allocation.

Every entry point whose memory grows with a number the user chose (sky pixels, time bins,
angles, photons, exposure time, detector rings) estimates what the request needs and refuses
it up front, with the estimate and the limit in the message, instead of dying with a
MemoryError after minutes (or swapping the machine to a halt).

The limit is the *memory budget*: by default half of the machine's physical memory; set the
environment variable ``ROTMOD_MEMORY_BUDGET`` (``"64GB"``, ``"512 MiB"``, a number of bytes;
read by :func:`dask.utils.parse_bytes`, as Dask reads its ``memory_limit``: ``GB`` is 10^9
bytes, ``GiB`` 2^30) to allow more or less.  Out-of-core work (``write_response``, matrix-free
operators) is checked per block, so a response larger than memory can still be streamed to
disk.

Files are budgeted the same way: :func:`check_disk` refuses an output (a response store)
larger than the free space where it goes, before any work.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from dask.utils import format_bytes, parse_bytes

from rotmod.errors import RotmodError

__all__ = ["DiskSpaceError", "MemoryBudgetError", "check_disk", "check_memory", "format_bytes",
           "free_disk", "memory_budget"]

#: Share of the physical memory rotmod allows itself when no budget is set.
DEFAULT_FRACTION = 0.5


class MemoryBudgetError(RotmodError):
    """A request would need more memory than the budget allows."""


def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # not POSIX: assume a small machine
        return 8 * 2**30


def memory_budget() -> int:
    """The memory budget in bytes (``ROTMOD_MEMORY_BUDGET`` or half the physical memory).

    Raises
    ------
    MemoryBudgetError
        ``ROTMOD_MEMORY_BUDGET`` is set but is not a positive amount of memory.
    """
    text = os.environ.get("ROTMOD_MEMORY_BUDGET")
    if not text:
        return int(DEFAULT_FRACTION * _physical_memory())
    try:
        nbytes = parse_bytes(text)
    except (TypeError, ValueError):
        raise MemoryBudgetError(
            f"ROTMOD_MEMORY_BUDGET must be an amount of memory like '16GB' or a number "
            f"of bytes, got {text!r}"
        ) from None
    if not nbytes > 0:
        raise MemoryBudgetError(f"ROTMOD_MEMORY_BUDGET must be > 0, got {text!r}")
    return int(nbytes)


def check_memory(nbytes: float, what: str, *, hint: str = "") -> None:
    """Refuse a request that needs more than :func:`memory_budget` bytes.

    Parameters
    ----------
    nbytes : float
        Estimated peak memory of the request (bytes).
    what : str
        The request in the user's words (``"a response of 19 x 560 x 4900 float32"``).
    hint : str, optional
        What to do instead (a smaller request, the out-of-core path).

    Raises
    ------
    MemoryBudgetError
        With the estimate, the budget and how to change it.
    """
    budget = memory_budget()
    if nbytes > budget:
        extra = f"; {hint}" if hint else ""
        raise MemoryBudgetError(
            f"{what} needs about {format_bytes(nbytes)} of memory, more than rotmod's memory "
            f"budget of {format_bytes(budget)} (half the machine's memory unless "
            f"ROTMOD_MEMORY_BUDGET says otherwise){extra}"
        )


class DiskSpaceError(RotmodError):
    """An output would need more disk space than is free where it goes."""


def free_disk(path: str | os.PathLike) -> int:
    """Free bytes (for this user) on the file system that holds ``path``.

    ``path`` need not exist yet: its nearest existing parent folder is asked.
    """
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        p = p.parent
    return int(shutil.disk_usage(p).free)


def check_disk(nbytes: float, path: str | os.PathLike, what: str, *, hint: str = "") -> None:
    """Refuse to write more than the free disk space at ``path`` can hold.

    Parameters
    ----------
    nbytes : float
        Upper bound of the output's size (bytes): uncompressed, so a compressed store fits
        whenever the check passes.
    path : str or path-like
        Where the output goes (it need not exist yet).
    what : str
        The output in the user's words (``"a response store of 19 x 560 x 4900 float32"``).
    hint : str, optional
        What to change to need less (larger pixels, fewer time bins, another disk).

    Raises
    ------
    DiskSpaceError
        With the estimate, the free space and the path.
    """
    free = free_disk(path)
    if nbytes > free:
        extra = f"; {hint}" if hint else ""
        raise DiskSpaceError(
            f"{what} needs up to {format_bytes(nbytes)} of disk (uncompressed), more than the "
            f"{format_bytes(free)} free at {os.fspath(path)!r}{extra}"
        )
