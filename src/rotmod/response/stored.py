"""Responses on disk: the lazy operator, the store kinds, saving and opening.

The file format (zarr layout, metadata, checksummed chunks, atomic finalisation) is
:mod:`rotmod.io.response_store`; the resumable computation of a store is
:func:`~rotmod.response.write_response` (:mod:`rotmod.response.writer`).

Each operator declares how it is stored (:attr:`ResponseOperator.store_kind`), a name in
:data:`STORE_KINDS`: ``"dense"`` stores the values ``P`` in chunks (any operator, through
its :meth:`~ResponseOperator.block`) and opens as a lazy :class:`StoredResponse`;
``"radon"`` stores a :class:`~rotmod.response.RadonResponse`'s table (megabytes where ``P``
would take terabytes) and opens as the same operator.

Before anything is written, the store's size is bounded (:meth:`StoreKind.estimate`: what it
holds, uncompressed) and refused when the free disk space where it goes cannot hold it
(:func:`check_store_disk`, :func:`rotmod.limits.check_disk`).
"""

from __future__ import annotations

import shutil
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from rotmod.errors import ParameterError, RotmodError
from rotmod.io import response_store as fmt
from rotmod.io.atomic import check_overwrite
from rotmod.io.lock import PathLock
from rotmod.limits import check_disk
from rotmod.registry import Registry
from rotmod.response.materialised import MaterialisedResponse
from rotmod.response.operator import BlockwiseResponse, ResponseOperator
from rotmod.response.parallel import Block, block_grid, block_ranges, iter_blocks
from rotmod.response.spec import ResponseSpec, check_response_matches, restore_fields
from rotmod.sky.geometry import grid_from_dict

__all__ = [
    "STORE_KINDS",
    "StoreKind",
    "StoredResponse",
    "check_response_matches",
    "check_store_disk",
    "default_chunks",
    "dense_estimate",
    "load_response",
    "open_response",
    "save_response",
]


#: What to change when a store of the values ``P`` does not fit on the disk.
DENSE_DISK_HINT = ("use larger pixels or a smaller field, fewer time bins or detectors, or "
                   "write the store to a disk with more free space")


def dense_estimate(shape: tuple[int, int, int], dtype: Any) -> tuple[float, str]:
    """Bytes of the values ``P`` of ``shape`` uncompressed, and their description."""
    nd, nt, nn = (int(v) for v in shape)
    dt = np.dtype(dtype)
    # A float product: shapes a user may ask for overflow no int64 here, and the bound is
    # an estimate, not an allocation.
    return (float(nd) * nt * nn * dt.itemsize,
            f"a response store of {nd} detector(s) x {nt} time bins x {nn} pixels {dt.name}")


def check_store_disk(path: Path, nbytes: float, what: str, *, hint: str = DENSE_DISK_HINT,
                     written: float = 0.0) -> None:
    """Refuse a store of up to ``nbytes`` (less ``written``, already on disk in its
    ``.partial`` form) that the free disk space at ``path`` cannot hold.

    Raises
    ------
    rotmod.limits.DiskSpaceError
    """
    check_disk(max(0.0, nbytes - written), path, what, hint=hint)


class StoreKind(ABC):
    """How one kind of operator is written to and rebuilt from a store."""

    #: What to change when a store of this kind does not fit on the disk.
    disk_hint: ClassVar[str] = DENSE_DISK_HINT

    @classmethod
    def estimate(cls, response: ResponseOperator) -> tuple[float, str]:
        """Upper bound of the store's size in bytes (what it holds, uncompressed) and its
        description for a refusal; by default the values ``P`` (a kind that stores something
        else overrides it)."""
        return dense_estimate((response.n_det, response.n_time, response.n_sky),
                              response.dtype)

    @classmethod
    @abstractmethod
    def write(cls, partial: Path, response: ResponseOperator, meta: dict[str, Any],
              chunks: tuple[int, int] | None) -> None:
        """Write ``response`` (described by ``meta``) as a new store at ``partial`` and
        verify it (the caller finalises it)."""

    @classmethod
    @abstractmethod
    def open(cls, group: Any, path: Path, meta: dict[str, Any]) -> ResponseOperator:
        """The operator of the finished store ``group`` at ``path``."""


#: Store kinds by name (:attr:`ResponseOperator.store_kind`; ``operator.kind`` in a store's
#: metadata, absent for "dense").
STORE_KINDS: Registry[type[StoreKind]] = Registry("store kind")


def default_chunks(shape: tuple[int, int, int], itemsize: int) -> tuple[int, int]:
    """``(time bins, sky pixels)`` of ~16 MB chunks of all detectors."""
    (t0, t1), (n0, n1) = block_grid(shape, None, itemsize=itemsize, target_bytes=16 << 20)[0]
    return (t1 - t0, n1 - n0)


# ----------------------------------------------------------------------------- operator
class StoredResponse(BlockwiseResponse):
    """A response read lazily from a zarr store, one chunk at a time.

    Open with :func:`open_response`.  ``forward``/``adjoint`` stream the chunks (memory: one
    chunk); :meth:`materialise` reads everything into a
    :class:`~rotmod.response.MaterialisedResponse`.

    Attributes
    ----------
    path : Path
    array : zarr.Array
        The stored ``P[d, t, n]``.
    meta : dict
        The stored metadata.
    spec : ResponseSpec or None
        What the store was computed for (``None`` when its metadata does not describe a
        whole spec, e.g. a matrix from elsewhere).
    """

    def __init__(self, path: Path, array: Any, meta: dict[str, Any]) -> None:
        self.path = path
        self.array = array
        self.meta = meta
        self.n_det, self.n_time, self.n_sky = (int(v) for v in array.shape)
        self.dtype = np.dtype(array.dtype)
        try:
            spec = ResponseSpec.from_dict(meta)
        except ParameterError:
            # Metadata that does not describe a whole spec (a matrix from elsewhere, or a
            # model this rotmod does not know): keep what it does describe.
            fields = restore_fields(meta)
            for k in ("instrument", "grid", "time_bins", "model", "energy", "distance"):
                setattr(self, k, fields[k])
        else:
            if spec.shape != tuple(array.shape) or spec.dtype != self.dtype:
                raise RotmodError(
                    f"response store {str(path)!r}: its metadata describes a {spec.shape} "
                    f"{spec.dtype} response, array P is {tuple(array.shape)} {self.dtype}; "
                    "rebuild it")
            self._adopt(spec)
            if meta.get("sum_of"):
                self.sum_of = [(None if part["weights"] is None else np.asarray(part["weights"]),
                                spec.replace(grid=grid_from_dict(part["grid"])))
                               for part in meta["sum_of"]]
        # Products walk the stored chunks (every bin is stored: no half turn to fold).
        self.blocks = block_grid(tuple(array.shape), tuple(array.chunks[1:]))

    def metadata(self) -> dict[str, Any]:
        """The stored metadata (as written, whatever version wrote it)."""
        return {k: v for k, v in self.meta.items() if k != "format_version"}

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` read from the store and checked
        (:func:`rotmod.io.response_store.read_checked`)."""
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        return fmt.read_checked(self.array, slice(t0, t1), slice(n0, n1), self.path,
                                self.meta.get("p_max", 1.0))

    def _materialise_blocks(self) -> list[Block]:
        # The stored chunks: each is read once, and an error names it.
        return self.blocks


@STORE_KINDS.register("dense")
class DenseStore(StoreKind):
    """The values ``P[d, t, n]`` in chunks of all detectors; opens as a
    :class:`StoredResponse`."""

    @classmethod
    def write(cls, partial: Path, response: ResponseOperator, meta: dict[str, Any],
              chunks: tuple[int, int] | None) -> None:
        shape = (response.n_det, response.n_time, response.n_sky)
        if chunks is None:
            chunks = default_chunks(shape, np.dtype(response.dtype).itemsize)
        arr = fmt.create_dense(partial, meta, chunks)
        blocks = block_grid(shape, chunks)
        for _, ((t0, t1), (n0, n1)), p in iter_blocks(response, blocks):
            arr[:, t0:t1, n0:n1] = p
        fmt.check_complete(arr, blocks, partial)

    @classmethod
    def open(cls, group: Any, path: Path, meta: dict[str, Any]) -> ResponseOperator:
        return StoredResponse(path, fmt.dense_array(group, path, meta), meta)


def _kind_of(meta: dict[str, Any]) -> str:
    return (meta.get("operator") or {}).get("kind", "dense")


# ------------------------------------------------------------------------ save and open
def save_response(
    path: Any,
    response: ResponseOperator,
    *,
    chunks: tuple[int, int] | None = None,
    overwrite: bool = False,
) -> ResponseOperator:
    """Write an existing response (materialised, matrix-free, Radon, stored...) atomically.

    Parameters
    ----------
    path : str or Path
    response : ResponseOperator
        Stored as its :attr:`~ResponseOperator.store_kind` says (:data:`STORE_KINDS`).
    chunks : (int, int), optional
        ``(time bins, sky pixels)`` per chunk of a dense store (default ~16 MB).
    overwrite : bool
        Replace an existing store at ``path`` (only once the new one is complete).

    Returns
    -------
    StoredResponse or RadonResponse
        The store, opened (see :func:`open_response`).

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false.
    rotmod.limits.DiskSpaceError
        The store (uncompressed) would not fit in the free disk space at ``path``; refused
        before anything is written.
    rotmod.io.lock.LockedError
        Another process is writing the same store.
    """
    path = fmt.as_store_path(path)
    check_overwrite(path, overwrite)
    kind = STORE_KINDS.get(response.store_kind)
    nbytes, what = kind.estimate(response)
    check_store_disk(path, nbytes, what, hint=kind.disk_hint)
    partial = fmt.partial_path(path)
    # The lock keeps a write_response of the same path from losing its .partial store here.
    with PathLock(path):
        if fmt.check_partial(partial):  # an earlier run's, never a folder of the user's
            shutil.rmtree(partial)
        meta = response.metadata()
        kind.write(partial, response, meta, chunks)
        fmt.write_axes(partial, meta, response.instrument, response.grid, response.time_bins)
        fmt.finalise(partial, path, overwrite)
    return open_response(path)


def open_response(
    path: Any,
    *,
    instrument: Any = None,
    grid: Any = None,
    time_bins: Any = None,
    model: Any = None,
    energy: Any = None,
    distance: Any = None,
) -> ResponseOperator:
    """Open a finished response store lazily, checking it against the given inputs.

    Parameters
    ----------
    path : str or Path
    instrument, grid, time_bins, model, energy, distance : optional
        What the caller will use the response with; each one given must equal the stored
        one (see :func:`check_response_matches`).

    Returns
    -------
    StoredResponse or RadonResponse
        A store of ``P`` opens lazily (chunks read on each product; :meth:`materialise`
        reads it all); a store of a Radon table opens as the
        :class:`~rotmod.response.RadonResponse` it was written from.

    Raises
    ------
    ParameterError
        No such store, not a rotmod response, or an unfinished (``.partial``) store.
    InstrumentMismatchError
        The store was computed for other inputs (the message names the field).
    """
    p = fmt.as_store_path(path)
    group, meta = fmt.open_store(p)
    check_response_matches(meta, instrument=instrument, grid=grid, time_bins=time_bins,
                           model=model, energy=energy, distance=distance)
    return STORE_KINDS.get(_kind_of(meta)).open(group, p, meta)


def load_response(path: Any, **expected: Any) -> MaterialisedResponse:
    """Open (see :func:`open_response`) and read the whole response into memory.

    Returns
    -------
    MaterialisedResponse
    """
    return open_response(path, **expected).materialise()
