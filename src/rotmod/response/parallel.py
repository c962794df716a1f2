"""Dask helpers: run blocks of a response computation locally or on a cluster.

The unit of work is a *block* of the response, ``P[:, t0:t1, n0:n1]`` (all detectors, a
range of time bins, a range of sky pixels), evaluated from a picklable
:class:`~rotmod.response._plan.ResponsePlan`.  Locally the blocks run one after another and
each profile kernel uses numba's threads; on a Dask cluster (``scheduler=`` address or
``client=``) each block is a task and the workers' own threads evaluate it.  Partial
products are always combined on the caller's side in a fixed block order, so a distributed
result equals the local one bit for bit.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from rotmod._deps import optional_import
from rotmod.errors import ParameterError

__all__ = ["Progress", "block_grid", "block_ranges", "get_client", "iter_blocks", "map_blocks"]

log = logging.getLogger(__name__)

Block = tuple[tuple[int, int], tuple[int, int]]

#: Default target size of one float64 block (bytes).
DEFAULT_BLOCK_BYTES = 32 << 20


def block_grid(
    shape: tuple[int, int, int],
    block_size: tuple[int, int] | None = None,
    *,
    itemsize: int = 8,
    target_bytes: int = DEFAULT_BLOCK_BYTES,
) -> list[Block]:
    """Split ``(n_det, n_time, n_sky)`` into blocks ``((t0, t1), (n0, n1))``.

    Parameters
    ----------
    shape : (int, int, int)
        Response shape.
    block_size : (int, int), optional
        ``(time bins, sky pixels)`` per block.  Default: all sky pixels and as many time bins
        as fit ``target_bytes`` (all detectors are in every block).
    itemsize : int
        Bytes per element used for the default.
    target_bytes : int
        Target block size for the default.

    Raises
    ------
    ParameterError
        If ``block_size`` is not two positive integers.
    """
    nd, nt, nn = shape
    if block_size is None:
        bn = nn
        bt = max(1, min(nt, target_bytes // max(1, nd * nn * itemsize)))
        if bt == 1 and nd * nn * itemsize > target_bytes:
            bn = max(1, target_bytes // max(1, nd * itemsize))
    else:
        try:
            bt, bn = (int(v) for v in block_size)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"block_size must be (time bins, sky pixels), got {block_size!r}"
            ) from exc
        if bt < 1 or bn < 1:
            raise ParameterError(f"block_size must be two integers >= 1, got {block_size!r}")
    return [
        ((t0, min(nt, t0 + bt)), (n0, min(nn, n0 + bn)))
        for t0 in range(0, nt, bt)
        for n0 in range(0, nn, bn)
    ]


def _axis_range(name: str, value: Any, size: int, size_name: str) -> tuple[int, int]:
    """``(start, stop)`` of a block along one axis (``None``: the whole axis)."""
    if value is None:
        return (0, size)
    try:
        a, b = value
    except (TypeError, ValueError):
        a = b = None
    if not all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in (a, b)):
        raise ParameterError(f"{name} must be a pair of integers ({name}0, {name}1) with "
                             f"0 <= {name}0 < {name}1 <= {size_name} = {size}, got {value!r}")
    a, b = int(a), int(b)
    if not 0 <= a < b <= size:
        raise ParameterError(f"{name} must satisfy 0 <= {name}0 < {name}1 <= {size_name} = "
                             f"{size}, got {value!r}")
    return (a, b)


def block_ranges(t: Any, n: Any, n_time: int, n_sky: int) -> Block:
    """The block ``((t0, t1), (n0, n1))`` that ``t`` and ``n`` ask for: the one check of
    every ``block(t=, n=)`` (``None``: the whole axis).

    Raises
    ------
    ParameterError
        Naming ``t`` or ``n``, the value and the rule: two integers with
        ``0 <= t0 < t1 <= n_time`` and ``0 <= n0 < n1 <= n_sky`` (a non-empty range).
    """
    return (_axis_range("t", t, n_time, "n_time"), _axis_range("n", n, n_sky, "n_sky"))


@contextlib.contextmanager
def get_client(scheduler: str | None = None, client: Any = None) -> Iterator[Any]:
    """Yield a ``distributed.Client`` (or ``None`` for local work).

    A client created here from a ``scheduler`` address is closed on exit; a ``client``
    passed in is left open.

    Raises
    ------
    ParameterError
        If both ``scheduler`` and ``client`` are given, or ``client`` is not a Client.
    """
    if scheduler is not None and client is not None:
        raise ParameterError("pass either scheduler or client, not both")
    if client is not None:
        Client = optional_import("distributed", "distributed", "Dask clusters").Client

        if not isinstance(client, Client):
            raise ParameterError(
                f"client must be a distributed.Client, got {type(client).__name__}"
            )
        yield client
        return
    if scheduler is None:
        yield None
        return
    if not isinstance(scheduler, str):
        raise ParameterError(f"scheduler must be an address string, got {scheduler!r}")
    c = optional_import("distributed", "distributed", "Dask clusters").Client(scheduler)
    try:
        yield c
    finally:
        c.close()


#: Seconds between progress lines when stderr is not a terminal (logs, batch jobs, CI).
PROGRESS_INTERVAL = 5.0


def _interactive() -> bool:
    """Whether a progress bar is seen: stderr is a terminal, or a Jupyter kernel (whose
    stderr is no TTY but shows tqdm's widget) imported this process's code."""
    return sys.stderr.isatty() or "ipykernel" in sys.modules


class Progress:
    """Progress of ``total`` steps: a tqdm bar on a terminal, log lines everywhere else.

    On a terminal (stderr is a TTY) or in a Jupyter kernel it draws a tqdm bar.  Off a
    terminal (a log file, a batch job) a bar would be a wall of carriage returns, so it logs
    ``desc: done/total (pct), elapsed`` on the ``rotmod.response.parallel`` logger at INFO
    every ``interval`` seconds instead (configure :mod:`logging` to see them; the command
    line does), from a daemon thread:
    the line comes even while no step completes (numba compiling the first kernel can take
    minutes), so a long job is never silent.  The first line comes after ``interval``
    seconds, so short work logs nothing.

    Use as a context manager; :meth:`update` adds steps and :meth:`update_to` has the
    ``progress(done, total)`` signature of the library's callbacks
    (:func:`rotmod.montecarlo.simulate_observation`, ...).

    Parameters
    ----------
    total : int or None
        Number of steps (``None``: unknown, e.g. solver iterations).
    desc : str
        What is progressing (the start of each line).
    unit : str
        Name of a step.
    interval : float
        Seconds between log lines off a terminal.
    tty : bool, optional
        Force the bar (``True``) or the log lines (``False``); default a bar when stderr is
        a TTY or the code runs in a Jupyter kernel.
    """

    def __init__(self, total: int | None, desc: str, unit: str = "it", *,
                 interval: float = PROGRESS_INTERVAL, tty: bool | None = None) -> None:
        self.total, self.desc, self.unit, self.done = total, desc, unit, 0
        self.interval = float(interval)
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._bar: Any = None
        self._thread: threading.Thread | None = None
        if _interactive() if tty is None else tty:
            from tqdm.auto import tqdm  # only with a progress bar (~20 ms)

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr)
        else:
            self._thread = threading.Thread(target=self._beat, name="rotmod-progress",
                                            daemon=True)
            self._thread.start()

    def line(self) -> str:
        """The progress line: ``desc: done/total unit (pct), elapsed s``."""
        elapsed = time.monotonic() - self._t0
        if self.total:
            return (f"{self.desc}: {self.done}/{self.total} {self.unit} "
                    f"({100.0 * self.done / self.total:.0f}%), {elapsed:.0f} s")
        return f"{self.desc}: {self.done} {self.unit}, {elapsed:.0f} s"

    def _beat(self) -> None:
        while not self._stop.wait(self.interval):
            log.info("%s", self.line())

    def update(self, n: int = 1) -> None:
        """``n`` more steps done."""
        self.done += int(n)
        if self._bar is not None:
            self._bar.update(int(n))

    def update_to(self, done: int, total: int | None = None) -> None:
        """``done`` steps of ``total`` (a ``progress(done, total)`` callback)."""
        if total is not None and total != self.total:
            self.total = int(total)
            if self._bar is not None:
                self._bar.total = self.total
        self.update(int(done) - self.done)

    def close(self) -> None:
        """Stop the bar or the log lines (logging a last line if any was logged)."""
        self._stop.set()
        if self._bar is not None:
            self._bar.close()
        elif time.monotonic() - self._t0 >= self.interval:
            log.info("%s (done)", self.line())

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _progress(total: int, enabled: bool, desc: str) -> Any:
    if not enabled:
        return contextlib.nullcontext(None)
    return Progress(total, desc, "block")


def map_blocks(
    func: Callable[..., Any],
    blocks: list[Any],
    *args: Any,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
    desc: str = "response blocks",
) -> Iterator[tuple[int, Any]]:
    """Evaluate ``func(block, *args)`` for every block; yield ``(index, result)``.

    Locally the results come in block order.  On a cluster ``args`` are scattered once
    (broadcast) and results are yielded as they complete (any order), so the caller can
    write or accumulate them while others still run; combine them by index when the order
    matters.
    """
    with get_client(scheduler, client) as cl, _progress(len(blocks), progress, desc) as bar:
        if cl is None:
            for i, blk in enumerate(blocks):
                res = func(blk, *args)
                if bar is not None:
                    bar.update(1)
                yield i, res
            return
        from distributed import as_completed  # optional (Dask clusters)

        # hash=False: unique keys, so a release of an earlier identical scatter cannot race.
        scattered = [cl.scatter(a, broadcast=True, hash=False) for a in args]
        futures = [cl.submit(func, blk, *scattered, pure=False) for blk in blocks]
        index = {f.key: i for i, f in enumerate(futures)}
        log.debug("submitted %d blocks to %s", len(futures), cl)
        try:
            for fut in as_completed(futures):
                res = fut.result()
                if bar is not None:
                    bar.update(1)
                yield index[fut.key], res
                fut.release()
        finally:
            for f in futures:
                f.cancel()


def _block_of(blk: Block, source: Any, *args: Any, reduce: Callable[..., Any] | None = None
              ) -> Any:
    p = source.block(t=blk[0], n=blk[1])
    return p if reduce is None else reduce(p, blk, *args)


def iter_blocks(
    source: Any,
    blocks: list[Block],
    *args: Any,
    reduce: Callable[..., Any] | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
    desc: str = "response blocks",
) -> Iterator[tuple[int, Block, Any]]:
    """The one walk over blocks of a response: yield ``(index, block, result)``.

    ``result`` is ``P[:, t0:t1, n0:n1] = source.block(t=(t0, t1), n=(n0, n1))`` for each
    ``block = ((t0, t1), (n0, n1))`` of ``blocks`` (:func:`block_grid`), or, with
    ``reduce``, ``reduce(P_block, block, *args)`` computed where the block was evaluated (on
    a Dask worker, only the reduced result travels back).  ``source`` is anything with
    ``block(t=, n=)``: a :class:`~rotmod.response._plan.ResponsePlan` (picklable, for
    clusters) or a response operator.

    Results come in block order locally and in completion order on a cluster (see
    :func:`map_blocks`): combine them by ``index`` where the order of a sum matters.
    """
    func = _block_of if reduce is None else functools.partial(_block_of, reduce=reduce)
    for i, res in map_blocks(func, blocks, source, *args, scheduler=scheduler, client=client,
                             progress=progress, desc=desc):
        yield i, blocks[i], res
