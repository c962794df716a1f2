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
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from rotmod._deps import optional_import
from rotmod.errors import ParameterError
from rotmod.progress import Progress

__all__ = ["block_grid", "block_ranges", "get_client", "iter_blocks", "map_blocks"]

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
