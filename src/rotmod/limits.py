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

Time is budgeted too: :func:`check_time` estimates the wall time of a request whose work
grows with a number the user chose (Monte Carlo photons, bootstrap replicas, design scans,
Radon table rows, attitude pieces) from a measured rate (:data:`RATES`) and refuses it when
the estimate exceeds the *time budget* (default one hour; ``ROTMOD_TIME_BUDGET`` or the
command line's ``--time-budget`` allow more: ``"3h"``, ``"90m"``, ``"2d"``, a number of
seconds or ``"inf"``, read by :func:`dask.utils.parse_timedelta`).  An estimate above
:data:`ANNOUNCE_SECONDS` that fits the budget is announced in the log before the work starts.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from dask.utils import format_bytes, format_time, parse_bytes, parse_timedelta

from rotmod.errors import RotmodError

__all__ = ["RATES", "DiskSpaceError", "MemoryBudgetError", "TimeBudgetError", "check_disk",
           "check_memory", "check_time", "format_bytes", "format_size", "free_disk",
           "measure_rate", "memory_budget", "time_budget"]

log = logging.getLogger(__name__)

#: Share of the physical memory rotmod allows itself when no budget is set.
DEFAULT_FRACTION = 0.5
#: The time budget when ``ROTMOD_TIME_BUDGET`` is not set (s).
DEFAULT_TIME_BUDGET = 3600.0
#: Estimates longer than this (s) that fit the budget are announced in the log.
ANNOUNCE_SECONDS = 30.0

#: Units of work per second of rotmod's long kernels, used by :func:`check_time`.  Measured
#: with ``benchmarks/bench_limits.py`` on the development machine (2 cores shared with other
#: jobs, load average 5-9; medians of 3; docs/reliability.md): a faster machine finishes
#: sooner than estimated, a loaded one later; measured to within a factor of 2 there, enough
#: to tell a minute from a week.
RATES: dict[str, float] = {
    # exact-model profile values (detector x angle x source) in rotmod design's scans:
    # measured 1.7e6/s at load 8 on 49 designs x 2 energies x 20000 angles x 12 sources.
    "design_values": 1.7e6,
    # Monte Carlo photons (simulate_profiles, simulate_observation): measured 4.8e7/s at
    # load 5 and 2.3-2.6e7/s at load 9 on 10 sources x 100 angles x 1e4 photons.
    "mc_photons": 3.0e7,
    # attitude pieces (AttitudeTable.intervals: one slerp and one SkyCoord each): 600/s
    # at load 5, 510/s at load 9.
    "attitude_pieces": 600.0,
    # Radon table values interpolated from the profile values (radon._table_rows, 4 taps):
    # 5.2e8/s on two idle threads (the wide field's 2.4e8 in 0.46 s); a third of that here.
    "radon_table_values": 1.7e8,
}


class MemoryBudgetError(RotmodError):
    """A request would need more memory than the budget allows."""


def format_size(nbytes: float) -> str:
    """``nbytes`` for a message: Dask's ``format_bytes`` up to 1000 PiB, then powers of ten
    (``3.2e+21 B``); a non-finite estimate (an overflow) reads as ``>1e308 B``."""
    if not math.isfinite(nbytes):
        return ">1e308 B"
    if nbytes < 1000 * 2**50:
        return format_bytes(int(nbytes))
    return f"{nbytes:.3g} B"


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
    if not nbytes <= budget:  # NaN (an overflowed estimate) is refused too
        extra = f"; {hint}" if hint else ""
        raise MemoryBudgetError(
            f"{what} needs about {format_size(nbytes)} of memory, more than rotmod's memory "
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
    if not nbytes <= free:
        extra = f"; {hint}" if hint else ""
        raise DiskSpaceError(
            f"{what} needs up to {format_size(nbytes)} of disk (uncompressed), more than the "
            f"{format_bytes(free)} free at {os.fspath(path)!r}{extra}"
        )


class TimeBudgetError(RotmodError):
    """A request would take longer than the time budget allows."""


def time_budget() -> float:
    """The time budget in seconds (``ROTMOD_TIME_BUDGET``, default one hour; ``inf``: none).

    Raises
    ------
    TimeBudgetError
        ``ROTMOD_TIME_BUDGET`` (which ``--time-budget`` sets) is not a positive duration.
    """
    text = os.environ.get("ROTMOD_TIME_BUDGET", "").strip()
    if not text:
        return DEFAULT_TIME_BUDGET
    if text.lower() in ("inf", "infinity", "none"):
        return math.inf
    try:
        seconds = float(parse_timedelta(text))
    except (TypeError, ValueError, KeyError):
        seconds = math.nan
    if not seconds > 0:
        raise TimeBudgetError(
            f"the time budget (--time-budget or ROTMOD_TIME_BUDGET) must be a duration > 0 "
            f"like '3h', '90m', '2d', a number of seconds or 'inf', got {text!r}"
        )
    return seconds


def _duration(seconds: float) -> str:
    """``seconds`` for a message (Dask's ``format_time``; years past a thousand days)."""
    if not math.isfinite(seconds):
        return "forever"
    if seconds > 1000 * 86400:
        return f"{seconds / (365.25 * 86400):.3g} years"
    return format_time(seconds)


def check_time(units: float, rate: str | float, what: str, *, unit: str = "",
               hint: str = "") -> float:
    """Estimate the wall time of ``units`` of work at ``rate`` and refuse it when it exceeds
    :func:`time_budget`; announce (log) an estimate above :data:`ANNOUNCE_SECONDS`.

    Parameters
    ----------
    units : float
        The amount of work in the rate's unit (photons, profile values, pieces).
    rate : str or float
        A key of :data:`RATES`, or a rate measured by the caller (units per second; e.g. one
        bootstrap replica per the main run's wall time).
    what : str
        The request in the user's words, naming the parameter (``"n_photons = 1e10 photons
        in each of 360 cells"``).
    unit : str, optional
        The unit's name for a measured ``rate`` (default: the ``RATES`` key).
    hint : str, optional
        What to ask for instead.

    Returns
    -------
    float
        The estimate (s).

    Raises
    ------
    TimeBudgetError
        With the estimate, the rate it came from, the budget and how to allow more.
    """
    per_s = RATES[rate] if isinstance(rate, str) else float(rate)
    seconds = float(units) / per_s if per_s > 0 else math.inf
    budget = time_budget()
    unit = unit or str(rate).replace("_", " ")
    if not seconds <= budget:
        extra = f"; {hint}" if hint else ""
        hours = math.ceil(seconds / 3600.0) if math.isfinite(seconds) else math.inf
        allow = f"{hours}h" if hours < 1e6 else "inf"
        raise TimeBudgetError(
            f"{what} would take about {_duration(seconds)} ({float(units):.3g} {unit} at "
            f"~{per_s:.2g}/s), more than rotmod's time budget of {_duration(budget)}{extra}; "
            f"to run it anyway allow the time: --time-budget {allow} (or "
            f"ROTMOD_TIME_BUDGET={allow})"
        )
    if seconds > ANNOUNCE_SECONDS:
        log.info("%s: estimated %s (%.3g %s at ~%.2g/s)", what, _duration(seconds),
                 float(units), unit, per_s)
    return seconds


def measure_rate(work: Callable[[], object], units: float, repeats: int = 3) -> float:
    """Units of work per second of ``work()``, a small sample of a long request (a few ms):
    the median of ``repeats`` timings (one timing of ~1 ms is at a scheduler's mercy), after
    one untimed call that compiles and warms the caches.  For costs too uneven for a stated
    rate (:data:`RATES`): a Radon table, a response's profile values."""
    work()
    took = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        work()
        took.append(time.perf_counter() - t0)
    return units / max(sorted(took)[len(took) // 2], 1e-9)
