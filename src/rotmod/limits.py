"""Resource checks made before any large allocation.

Every entry point whose memory grows with a number the user chose (sky pixels, time bins,
angles, photons, exposure time, detector rings) estimates what the request needs and refuses
it up front, with the estimate and the limit in the message, instead of dying with a
MemoryError after minutes (or swapping the machine to a halt).

The limit is the *memory budget*: by default half of the machine's physical memory; set the
environment variable ``ROTMOD_MEMORY_BUDGET`` (``"64GB"``, ``"512 MiB"``, a number of bytes)
to allow more or less.  Out-of-core work (``write_response``, matrix-free operators) is
checked per block, so a response larger than memory can still be streamed to disk.
"""

from __future__ import annotations

import os

import astropy.units as u

from rotmod.errors import RotmodError

__all__ = ["MemoryBudgetError", "check_memory", "format_bytes", "memory_budget"]

#: Share of the physical memory rotmod allows itself when no budget is set.
DEFAULT_FRACTION = 0.5


class MemoryBudgetError(RotmodError):
    """A request would need more memory than the budget allows."""


def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # not POSIX: assume a small machine
        return 8 * 2**30


def format_bytes(n: float) -> str:
    """``1.5 GiB``-style text."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # pragma: no cover - loop returns


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
        value = float(text)
        nbytes = value
    except ValueError:
        try:
            nbytes = u.Quantity(text.replace("GB", "GiB").replace("MB", "MiB")
                                .replace("TB", "TiB").replace("KB", "KiB")).to_value(u.byte)
        except (TypeError, ValueError, u.UnitsError):
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
