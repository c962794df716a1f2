"""The response store format: chunked, compressed, checksummed zarr with full provenance.

Layout of a store ``<path>`` (a zarr v3 group directory)::

    <path>/zarr.json     group attributes: "rotmod_response" = JSON metadata (below),
                         "complete" = true once finalised
    <path>/P/            array P[d, t, n], chunks (n_det, bt, bn), Zstd-compressed
                         (store kind "dense")
    <path>/table/        or the table of a Radon response, chunks of whole rows
                         (store kind "radon", metadata ``operator = {"kind": "radon", ...}``)

The metadata is :meth:`~rotmod.response.ResponseOperator.metadata` (instrument, grid, time
binning, model, energy, dtype, shape, rotmod version) plus ``format_version`` (and
``p_max``, the largest valid value, for thick detectors); the JSON string keeps ``inf``
attenuation coefficients (opaque masks) exact.  Every chunk carries a CRC-32C checksum and
is checked when it is read back.

Writing is atomic: a store is written as ``<path>.partial`` and renamed to ``<path>`` by
:func:`finalise` once complete.  A resumable writer marks each chunk written with a file
``<path>.partial/_done/<i>`` (:func:`mark_done`), so a marker always means a complete chunk.

This module owns the files; what is stored (and how an operator is rebuilt from it) is the
response layer's (:mod:`rotmod.response.stored`).  zarr is imported where it is used: it is
needed only by code that reads or writes stores.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from rotmod.errors import ParameterError, RotmodError
from rotmod.io.atomic import check_overwrite

__all__ = [
    "FORMAT_VERSION",
    "as_store_path",
    "check_complete",
    "create_dense",
    "dense_array",
    "disk_bytes",
    "finalise",
    "mark_done",
    "marked_done",
    "open_partial",
    "open_store",
    "partial_path",
    "read_checked",
    "read_table",
    "verified",
    "write_table",
]

FORMAT_VERSION = 1
_ATTR = "rotmod_response"
_PARTIAL = ".partial"
_DONE = "_done"


def _zarr() -> Any:
    # zarr is needed only to read or write stores (a heavy import for everything else).
    import zarr

    return zarr


def _compressors() -> list[Any]:
    zarr = _zarr()
    # CRC-32C after compression: every chunk is checked when it is read back.
    return [zarr.codecs.ZstdCodec(), zarr.codecs.Crc32cCodec()]


# ---------------------------------------------------------------------------------- paths
def as_store_path(path: Any) -> Path:
    """``path`` as a :class:`~pathlib.Path` (the ``.partial`` suffix is reserved).

    Raises
    ------
    ParameterError
    """
    try:
        p = Path(os.fspath(path))
    except TypeError:
        raise ParameterError(f"path must be a file-system path, got {path!r}") from None
    if p.name.endswith(_PARTIAL):
        raise ParameterError(f"path must not end with {_PARTIAL!r} (reserved), got {str(p)!r}")
    return p


def partial_path(path: Path) -> Path:
    """Where the store at ``path`` is written until it is complete."""
    return path.with_name(path.name + _PARTIAL)


def disk_bytes(path: Path) -> int:
    """Bytes held by the files under ``path`` (0 when it does not exist)."""
    if not path.is_dir():
        return 0
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


# ------------------------------------------------------------------------------- metadata
def _read_meta(group: Any, path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(group.attrs[_ATTR])
    except KeyError:
        raise ParameterError(f"path {str(path)!r} is not a rotmod response store") from None
    except (TypeError, ValueError) as exc:
        raise RotmodError(f"response store {str(path)!r}: its metadata is damaged ({exc}); "
                          "rebuild it with write_response") from exc
    if not isinstance(meta, dict):
        raise RotmodError(f"response store {str(path)!r}: its metadata is damaged (not a "
                          "table); rebuild it with write_response")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ParameterError(
            f"path {str(path)!r} has response format_version "
            f"{meta.get('format_version')!r}; this rotmod reads {FORMAT_VERSION}"
        )
    return meta


def _new_group(partial: Path, meta: dict[str, Any]) -> Any:
    g = _zarr().open_group(str(partial), mode="w")
    g.attrs[_ATTR] = json.dumps({**meta, "format_version": FORMAT_VERSION})
    g.attrs["complete"] = False
    return g


def open_store(path: Path) -> tuple[Any, dict[str, Any]]:
    """The zarr group and metadata of the finished store at ``path``.

    Raises
    ------
    ParameterError
        No such store, not a rotmod response, another format version, or an unfinished
        store.
    RotmodError
        The store cannot be opened or its metadata is damaged.
    """
    if not path.exists():
        hint = (" (an unfinished .partial store exists: resume write_response)"
                if partial_path(path).exists() else "")
        raise ParameterError(f"path {str(path)!r} does not exist{hint}")
    try:
        g = _zarr().open_group(str(path), mode="r")
        attrs_ok = g.attrs.get("complete") is True
    except Exception as exc:  # unreadable zarr.json: zarr raises several kinds
        raise RotmodError(f"response store {str(path)!r} cannot be opened "
                          f"({type(exc).__name__}: {exc}); rebuild it with write_response"
                          ) from exc
    meta = _read_meta(g, path)
    if not attrs_ok:
        raise ParameterError(f"path {str(path)!r} is an unfinished response store")
    return g, meta


# ------------------------------------------------------------------------ dense (P chunks)
def create_dense(partial: Path, meta: dict[str, Any], chunks: tuple[int, int]) -> Any:
    """A new store at ``partial`` with an empty (NaN) array ``P`` of ``meta["shape"]``,
    chunks ``(n_det, *chunks)``, and an empty folder of done markers; returns the array."""
    nd, nt, nn = meta["shape"]
    g = _new_group(partial, meta)
    arr = g.create_array(
        "P", shape=(nd, nt, nn), chunks=(nd, *chunks), dtype=meta["dtype"], fill_value=np.nan,
        compressors=_compressors(),
    )
    (partial / _DONE).mkdir()
    return arr


def open_partial(partial: Path) -> tuple[Any, dict[str, Any]]:
    """The array ``P`` and metadata of an unfinished store (to resume writing it)."""
    g = _zarr().open_group(str(partial), mode="r+")
    meta = _read_meta(g, partial)
    (partial / _DONE).mkdir(exist_ok=True)
    return g["P"], meta


def dense_array(group: Any, path: Path, meta: dict[str, Any]) -> Any:
    """The array ``P`` of a finished store, its shape checked against the metadata.

    Raises
    ------
    RotmodError
    """
    try:
        arr = group["P"]
    except Exception as exc:
        raise RotmodError(f"response store {str(path)!r} has no readable array P ({exc}); "
                          "rebuild it with write_response") from exc
    if tuple(arr.shape) != tuple(meta.get("shape", arr.shape)):
        raise RotmodError(f"response store {str(path)!r}: array P has shape {arr.shape}, its "
                          f"metadata says {meta['shape']}; rebuild it")
    return arr


def mark_done(partial: Path, index: int) -> None:
    """Record that chunk ``index`` is on disk (after it was written)."""
    (partial / _DONE / str(index)).touch()


def marked_done(partial: Path) -> set[int]:
    """Indices of the chunks marked written."""
    return {int(f.name) for f in (partial / _DONE).iterdir() if f.name.isdigit()}


def read_checked(array: Any, ts: slice, ns: slice, store: Path, p_max: float = 1.0) -> np.ndarray:
    """Read ``P[:, ts, ns]`` and refuse what is not a profile value.

    Chunks carry a CRC-32C checksum (a flipped bit or a truncated chunk fails to decode);
    a missing chunk reads as the NaN fill value; both, and any value outside [0, p_max]
    (1, or for thick detectors the bound :attr:`ResponsePlan.p_max` stored as ``p_max``),
    are an error naming the store and the chunk instead of numbers that look fine.

    Raises
    ------
    RotmodError
    """
    where = f"response store {str(store)!r}, chunk t {ts.start}:{ts.stop}, n {ns.start}:{ns.stop}"
    try:
        blk = np.asarray(array[:, ts, ns])
    except Exception as exc:  # zarr/numcodecs raise ValueError, RuntimeError, OSError...
        raise RotmodError(f"{where} cannot be read ({type(exc).__name__}: {exc}); the store "
                          "is damaged: rebuild it with write_response") from exc
    bad = ~((blk >= 0) & (blk <= p_max))  # also true for NaN
    if bad.any():
        v = blk[bad].ravel()[0]
        what = ("is missing (reads as NaN)" if np.isnan(v)
                else f"holds {v:g}, not in [0, {p_max:g}]")
        raise RotmodError(f"{where} {what}; the store is damaged: rebuild it with "
                          "write_response")
    return blk


def verified(array: Any, blocks: list[Any], store: Path, p_max: float = 1.0) -> list[int]:
    """Indices of ``blocks`` whose chunk reads back as valid profile values."""
    ok = []
    for i, ((t0, t1), (n0, n1)) in enumerate(blocks):
        try:
            read_checked(array, slice(t0, t1), slice(n0, n1), store, p_max)
        except RotmodError:
            continue
        ok.append(i)
    return ok


def check_complete(arr: Any, blocks: list[Any], store: Path, p_max: float = 1.0) -> None:
    """Every chunk must read back valid before the store may be marked complete.

    Raises
    ------
    RotmodError
    """
    bad = sorted(set(range(len(blocks))) - set(verified(arr, blocks, store, p_max)))
    if bad:
        raise RotmodError(f"response store {str(store)!r}: {len(bad)} chunk(s) did not read "
                          f"back valid after writing (first: {blocks[bad[0]]}); not marked "
                          "complete")


# ------------------------------------------------------------------------ radon (a table)
def write_table(partial: Path, meta: dict[str, Any], table: np.ndarray) -> None:
    """Write a Radon response's table (checksummed chunks of whole rows) and verify it."""
    g = _new_group(partial, meta)
    rows = max(1, (16 << 20) // max(1, table.shape[1] * table.itemsize))
    arr = g.create_array(
        "table", shape=table.shape, chunks=(rows, table.shape[1]), dtype=table.dtype,
        fill_value=np.nan, compressors=_compressors(),
    )
    arr[...] = table
    read_table(g, partial)


def read_table(group: Any, store: Path) -> np.ndarray:
    """A stored Radon table, every chunk checked (checksum, NaN, values in [0, 1]).

    Raises
    ------
    RotmodError
    """
    where = f"response store {str(store)!r}, array table"
    try:
        table = np.asarray(group["table"][...])
    except Exception as exc:  # zarr/numcodecs raise KeyError, ValueError, RuntimeError...
        raise RotmodError(f"{where} cannot be read ({type(exc).__name__}: {exc}); the store "
                          "is damaged: rebuild it with rotmod response") from exc
    bad = ~((table >= 0) & (table <= 1))
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise RotmodError(f"{where}, row {row} holds values that are not profile values "
                          "(NaN or outside [0, 1]); the store is damaged: rebuild it")
    return table


# -------------------------------------------------------------------------------- finish
def finalise(partial: Path, path: Path, overwrite: bool) -> None:
    """Remove the done markers, mark the store complete and rename it to ``path`` (an
    existing ``path`` is replaced only now, with ``overwrite``).

    Raises
    ------
    ParameterError
        ``path`` exists (created meanwhile) and ``overwrite`` is false.
    """
    shutil.rmtree(partial / _DONE, ignore_errors=True)
    g = _zarr().open_group(str(partial), mode="r+")
    g.attrs["complete"] = True
    check_overwrite(path, overwrite)
    trash = None
    if path.exists():
        trash = path.with_name(path.name + ".old")
        shutil.rmtree(trash, ignore_errors=True)
        os.replace(path, trash)
    os.replace(partial, path)
    if trash is not None:
        shutil.rmtree(trash, ignore_errors=True)
