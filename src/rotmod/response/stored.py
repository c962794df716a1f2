"""Responses on disk: chunked, compressed zarr stores with full provenance.

Layout of a store ``<path>`` (a zarr v3 group directory)::

    <path>/zarr.json     group attributes: "rotmod_response" = JSON metadata (below),
                         "complete" = true once finalised
    <path>/P/            array P[d, t, n], chunks (n_det, bt, bn), Zstd-compressed

The metadata is :meth:`~rotmod.response.ResponseOperator.metadata` (instrument, grid, time
binning, model, energy, dtype, shape, rotmod version) plus ``format_version``; the JSON
string keeps ``inf`` attenuation coefficients (opaque masks) exact.

A :class:`~rotmod.response.RadonResponse` is stored as its table instead of ``P`` (array
``table``, metadata ``operator = {"kind": "radon", ...}``): megabytes where ``P`` would take
terabytes, and :func:`open_response` gives back the same operator.

Writing is atomic and resumable.  :func:`write_response` computes the response chunk by
chunk into ``<path>.partial``: each chunk is written and then a marker file
``<path>.partial/_done/<i>`` is created, so a marker always means a complete chunk.  An
interrupted run leaves only the ``.partial`` store (never opened by :func:`open_response`);
running the same call again checks that the ``.partial`` store was started for the same
inputs and computes only the chunks without a marker.  At the end the markers are
removed, ``complete`` is set and the directory is renamed to ``<path>``.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rotmod.errors import InstrumentMismatchError, ParameterError, RotmodError
from rotmod.io.lock import PathLock
from rotmod.profiles.base import DEFAULT_MODEL
from rotmod.response.operator import ResponseOperator

if TYPE_CHECKING:
    from rotmod.response.materialised import MaterialisedResponse

__all__ = [
    "StoredResponse",
    "check_response_matches",
    "load_response",
    "open_response",
    "save_response",
    "write_response",
]

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
_ATTR = "rotmod_response"
_PARTIAL = ".partial"
_DONE = "_done"


# ----------------------------------------------------------------------------- metadata
def _flatten(obj: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    if isinstance(obj, dict):
        for k in obj:  # insertion order: the most telling field (e.g. "model") first
            yield from _flatten(obj[k], f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(obj, list | tuple):
        yield f"{prefix}.len", len(obj)
        for i, v in enumerate(obj):
            yield from _flatten(v, f"{prefix}[{i}]")
    else:
        yield prefix, obj


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return a == b or (np.isnan(a) and np.isnan(b)) or bool(np.isclose(a, b, rtol=1e-12, atol=0))
    return a == b


def _compare(field: str, stored: Any, given: Any) -> None:
    s = dict(_flatten(stored, field))
    g = dict(_flatten(given, field))
    shared = [k for k in s if k in g]
    only = [k for k in s if k not in g] + [k for k in g if k not in s]
    for key in shared + only:
        if key not in s or key not in g or not _same(s[key], g[key]):
            raise InstrumentMismatchError(
                f"the stored response does not match: {key} is "
                f"{s.get(key, '<absent>')!r} in the store but {g.get(key, '<absent>')!r} here"
            )


def check_response_matches(
    metadata: dict[str, Any],
    *,
    instrument: Any = None,
    grid: Any = None,
    time_bins: Any = None,
    model: Any = None,
    energy: Any = None,
    distance: Any = None,
) -> None:
    """Refuse a stored response computed for something else than the given inputs.

    Each argument that is not ``None`` is compared with the stored metadata.

    Raises
    ------
    InstrumentMismatchError
        Naming the first field that differs (e.g. ``instrument.mask.thickness``).
    """
    from rotmod.profiles.base import get_model
    from rotmod.binning import TimeBinning

    if instrument is not None:
        _compare("instrument", metadata.get("instrument"), instrument.to_dict())
    if grid is not None:
        _compare("grid", metadata.get("grid"), grid.to_dict())
    if time_bins is not None:
        _compare("time_bins", metadata.get("time_bins"), TimeBinning.coerce(time_bins).to_dict())
    if model is not None:
        _compare("model", metadata.get("model"), get_model(model).describe())
    if energy is not None:
        e = float(getattr(energy, "to_value", lambda _u: energy)("keV"))
        _compare("energy", metadata.get("energy"), e)
    if distance is not None:
        d = float(getattr(distance, "to_value", lambda _u: distance)("cm"))
        _compare("distance", metadata.get("distance"), None if np.isinf(d) else d)


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


def _restore(meta: dict[str, Any]) -> dict[str, Any]:
    """Rebuild instrument, grid, time binning and model objects from stored metadata."""
    from rotmod.geometry import Instrument
    from rotmod.profiles.base import MODELS, get_model
    from rotmod.binning import TimeBinning
    from rotmod.sky import grid_from_dict

    out: dict[str, Any] = {"energy": meta.get("energy"), "distance": meta.get("distance")}
    out["instrument"] = None if meta.get("instrument") is None else Instrument.from_dict(
        meta["instrument"]
    )
    out["grid"] = None if meta.get("grid") is None else grid_from_dict(meta["grid"])
    tb = meta.get("time_bins")
    out["time_bins"] = None if tb is None else TimeBinning.from_dict(tb)
    model = None
    desc = meta.get("model")
    if desc is not None and desc.get("model") in MODELS:
        m = get_model(desc["model"])
        model = m if m.describe() == desc else None
        if model is None and desc.get("model") == "standard":
            from rotmod.profiles import StandardModel

            model = StandardModel(desc.get("transmission", 0.0))
    out["model"] = model
    return out


# ----------------------------------------------------------------------------- operator
class StoredResponse(ResponseOperator):
    """A response read lazily from a zarr store, one chunk at a time.

    Open with :func:`open_response`.  ``forward``/``adjoint`` stream the chunks (memory: one
    chunk); :meth:`load` reads everything into a
    :class:`~rotmod.response.MaterialisedResponse`.

    Attributes
    ----------
    path : Path
    array : zarr.Array
        The stored ``P[d, t, n]``.
    meta : dict
        The stored metadata.
    """

    def __init__(self, path: Path, array: Any, meta: dict[str, Any]) -> None:
        self.path = path
        self.array = array
        self.meta = meta
        self.n_det, self.n_time, self.n_sky = (int(v) for v in array.shape)
        self.dtype = np.dtype(array.dtype)
        for k, v in _restore(meta).items():
            setattr(self, k, v)

    def metadata(self) -> dict[str, Any]:
        """The stored metadata (as written, whatever version wrote it)."""
        return {k: v for k, v in self.meta.items() if k != "format_version"}

    def _chunks(self) -> Iterator[tuple[slice, slice]]:
        _, bt, bn = self.array.chunks
        for t0 in range(0, self.n_time, bt):
            for n0 in range(0, self.n_sky, bn):
                yield slice(t0, min(self.n_time, t0 + bt)), slice(n0, min(self.n_sky, n0 + bn))

    def _block(self, ts: slice, ns: slice) -> np.ndarray:
        return read_checked(self.array, ts, ns, self.path, self.meta.get("p_max", 1.0))

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        x = np.asarray(sky, dtype=self.dtype)
        out = np.zeros((self.n_det, self.n_time), dtype=self.dtype)
        for ts, ns in self._chunks():
            blk = self._block(ts, ns)
            out[:, ts] += (blk.reshape(-1, blk.shape[2]) @ x[ns]).reshape(blk.shape[:2])
        return out

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        y = np.asarray(counts, dtype=self.dtype)
        out = np.zeros(self.n_sky, dtype=self.dtype)
        for ts, ns in self._chunks():
            blk = self._block(ts, ns)
            out[ns] += y[:, ts].ravel() @ blk.reshape(-1, blk.shape[2])
        return out

    def load(self) -> MaterialisedResponse:
        """Read the whole matrix into a :class:`~rotmod.response.MaterialisedResponse`."""
        from rotmod.response.materialised import MaterialisedResponse

        full = np.empty(self.array.shape, dtype=self.dtype)
        for ts, ns in self._chunks():
            full[:, ts, ns] = self._block(ts, ns)
        return MaterialisedResponse(
            full,
            instrument=self.instrument,
            grid=self.grid,
            time_bins=self.time_bins,
            model=self.model,
            energy=self.energy,
            distance=self.distance,
        )


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


def _verified(array: Any, blocks: list[Any], store: Path, p_max: float = 1.0) -> list[int]:
    """Indices of ``blocks`` whose chunk reads back as valid profile values."""
    ok = []
    for i, ((t0, t1), (n0, n1)) in enumerate(blocks):
        try:
            read_checked(array, slice(t0, t1), slice(n0, n1), store, p_max)
        except RotmodError:
            continue
        ok.append(i)
    return ok


# ----------------------------------------------------------------------------- writing
def _as_path(path: Any) -> Path:
    try:
        p = Path(os.fspath(path))
    except TypeError:
        raise ParameterError(f"path must be a file-system path, got {path!r}") from None
    if p.name.endswith(_PARTIAL):
        raise ParameterError(f"path must not end with {_PARTIAL!r} (reserved), got {str(p)!r}")
    return p


def _check_target(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise ParameterError(
            f"path {str(path)!r} already exists; pass overwrite=True to replace it"
        )


def _finalise(partial: Path, path: Path, overwrite: bool) -> None:
    import zarr

    shutil.rmtree(partial / _DONE, ignore_errors=True)
    g = zarr.open_group(str(partial), mode="r+")
    g.attrs["complete"] = True
    _check_target(path, overwrite)
    trash = None
    if path.exists():
        trash = path.with_name(path.name + ".old")
        shutil.rmtree(trash, ignore_errors=True)
        os.replace(path, trash)
    os.replace(partial, path)
    if trash is not None:
        shutil.rmtree(trash, ignore_errors=True)


def _default_chunks(shape: tuple[int, int, int], itemsize: int) -> tuple[int, int]:
    from rotmod.response.parallel import block_grid

    (t0, t1), (n0, n1) = block_grid(shape, None, itemsize=itemsize, target_bytes=16 << 20)[0]
    return (t1 - t0, n1 - n0)


def _create(partial: Path, meta: dict[str, Any], chunks: tuple[int, int]) -> Any:
    import zarr

    nd, nt, nn = meta["shape"]
    g = zarr.open_group(str(partial), mode="w")
    g.attrs[_ATTR] = json.dumps(meta)
    g.attrs["complete"] = False
    # CRC-32C after compression: every chunk is checked when it is read back.
    arr = g.create_array(
        "P", shape=(nd, nt, nn), chunks=(nd, *chunks), dtype=meta["dtype"], fill_value=np.nan,
        compressors=[zarr.codecs.ZstdCodec(), zarr.codecs.Crc32cCodec()],
    )
    (partial / _DONE).mkdir()
    return arr


def write_response(
    path: Any,
    instrument: Any,
    grid: Any,
    time_bins: Any,
    model: Any = DEFAULT_MODEL,
    energy: Any = None,
    *,
    dtype: Any = np.float32,
    detectors: Any = None,
    chunks: tuple[int, int] | None = None,
    overwrite: bool = False,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
    on_chunk: Callable[[int, int], None] | None = None,
    distance: Any = None,
) -> StoredResponse:
    """Compute a response chunk by chunk straight into a zarr store (atomic, resumable).

    Parameters
    ----------
    path : str or Path
        Store directory to create.
    instrument, grid, time_bins, model, energy, dtype, detectors, distance
        As :func:`rotmod.response.build_response`.
    chunks : (int, int), optional
        ``(time bins, sky pixels)`` per chunk (every chunk holds all detectors); default
        ~16 MB chunks.  Each chunk is one unit of work.
    overwrite : bool
        Replace an existing store at ``path`` (only once the new one is complete).
    scheduler, client, progress
        Run the chunks on a Dask cluster / show a progress bar; see
        :func:`rotmod.response.parallel.map_blocks`.
    on_chunk : callable, optional
        Called as ``on_chunk(done, total)`` after each chunk is safely on disk (for
        monitoring; an exception raised there interrupts the run, which resumes later).

    Returns
    -------
    StoredResponse
        The finished store, opened lazily.

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false, or bad inputs.
    InstrumentMismatchError
        A ``.partial`` store from an earlier run at ``path`` was started for other inputs
        (delete it or pass other ``path``).
    """

    import rotmod
    from rotmod.response._plan import make_plan

    path = _as_path(path)
    _check_target(path, overwrite)
    plan = make_plan(instrument, grid, time_bins, model, energy, dtype=dtype, detectors=detectors,
                     distance=distance)
    meta = {
        "instrument": plan.instrument.to_dict(),
        "grid": grid.to_dict(),
        "time_bins": plan.time_bins.to_dict(),
        "model": plan.model.describe(),
        "energy": plan.energy,
        "dtype": plan.dtype.name,
        "shape": list(plan.shape),
        "rotmod_version": rotmod.__version__,
        "format_version": FORMAT_VERSION,
    }
    # Only for the instrument as built, so that other stores are described as before.
    if plan.distance is not None:
        meta["distance"] = plan.distance
    if plan.p_max != 1.0:
        meta["p_max"] = plan.p_max
    partial = path.with_name(path.name + _PARTIAL)
    if chunks is None:
        chunks = _default_chunks(plan.shape, plan.dtype.itemsize)
    with PathLock(path):
        return _write_locked(path, partial, plan, meta, chunks, overwrite, scheduler, client,
                             progress, on_chunk)


def _write_locked(path: Path, partial: Path, plan: Any, meta: dict[str, Any],
                  chunks: tuple[int, ...], overwrite: bool, scheduler: Any, client: Any,
                  progress: bool, on_chunk: Any) -> StoredResponse:
    import zarr

    from rotmod.response.parallel import _eval_block, block_grid, map_blocks

    if partial.exists():
        g = zarr.open_group(str(partial), mode="r+")
        old = _read_meta(g, partial)
        for key in ("instrument", "grid", "time_bins", "model", "energy", "dtype", "shape",
                    "distance"):
            _compare(key, old.get(key), meta.get(key))
        arr = g["P"]
        chunks = tuple(arr.chunks[1:])
        (partial / _DONE).mkdir(exist_ok=True)
        log.info("resuming %s", partial)
    else:
        arr = _create(partial, meta, chunks)
    blocks = block_grid(plan.shape, chunks)
    marked = {int(f.name) for f in (partial / _DONE).iterdir() if f.name.isdigit()}
    # A marker says a chunk was written, not that it is still whole: read those back.
    p_max = meta.get("p_max", 1.0)
    done = marked & set(_verified(arr, blocks, partial, p_max)) if marked else set()
    if marked - done:
        log.warning("%s: %d chunk(s) marked done are missing or damaged; recomputing them",
                    partial, len(marked - done))
    todo = [i for i in range(len(blocks)) if i not in done]
    log.info("%d of %d chunks to compute", len(todo), len(blocks))
    n_done = len(done)
    for j, res in map_blocks(
        _eval_block, [blocks[i] for i in todo], plan,
        scheduler=scheduler, client=client, progress=progress, desc="response chunks",
    ):
        i = todo[j]
        (t0, t1), (n0, n1) = blocks[i]
        arr[:, t0:t1, n0:n1] = res
        (partial / _DONE / str(i)).touch()
        n_done += 1
        if on_chunk is not None:
            on_chunk(n_done, len(blocks))
    _check_complete(arr, blocks, partial, p_max)
    _finalise(partial, path, overwrite)
    return open_response(path)


def _check_complete(arr: Any, blocks: list[Any], store: Path, p_max: float = 1.0) -> None:
    """Every chunk must read back valid before the store may be marked complete."""
    bad = sorted(set(range(len(blocks))) - set(_verified(arr, blocks, store, p_max)))
    if bad:
        raise RotmodError(f"response store {str(store)!r}: {len(bad)} chunk(s) did not read "
                          f"back valid after writing (first: {blocks[bad[0]]}); not marked "
                          "complete")


def _save_table(partial: Path, meta: dict[str, Any], table: np.ndarray) -> None:
    """Write a Radon response's table (checksummed chunks of whole rows) and verify it."""
    import zarr

    g = zarr.open_group(str(partial), mode="w")
    g.attrs[_ATTR] = json.dumps(meta)
    g.attrs["complete"] = False
    rows = max(1, (16 << 20) // max(1, table.shape[1] * table.itemsize))
    arr = g.create_array(
        "table", shape=table.shape, chunks=(rows, table.shape[1]), dtype=table.dtype,
        fill_value=np.nan, compressors=[zarr.codecs.ZstdCodec(), zarr.codecs.Crc32cCodec()],
    )
    arr[...] = table
    _read_table(g, partial)


def _read_table(group: Any, store: Path) -> np.ndarray:
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


def save_response(
    path: Any,
    response: ResponseOperator,
    *,
    chunks: tuple[int, int] | None = None,
    overwrite: bool = False,
) -> ResponseOperator:
    """Write an existing response (materialised, matrix-free, Radon or stored) atomically.

    Parameters
    ----------
    path : str or Path
    response : ResponseOperator
        Needs ``todense()`` or ``block(t=, n=)`` (all rotmod responses have one), or is a
        :class:`~rotmod.response.RadonResponse` (stored as its table).
    chunks, overwrite
        As :func:`write_response`.

    Returns
    -------
    StoredResponse or RadonResponse
        The store, opened (see :func:`open_response`).
    """
    path = _as_path(path)
    _check_target(path, overwrite)
    meta = response.metadata()
    meta["format_version"] = FORMAT_VERSION
    partial = path.with_name(path.name + _PARTIAL)
    shutil.rmtree(partial, ignore_errors=True)
    shape = (response.n_det, response.n_time, response.n_sky)
    if chunks is None:
        chunks = _default_chunks(shape, np.dtype(response.dtype).itemsize)
    from rotmod.response.parallel import block_grid
    from rotmod.response.radon import RadonResponse

    if isinstance(response, RadonResponse):
        _save_table(partial, meta, response.table)
        _finalise(partial, path, overwrite)
        return open_response(path)
    arr = _create(partial, meta, chunks)
    dense = response.todense() if hasattr(response, "todense") else None
    for (t0, t1), (n0, n1) in block_grid(shape, chunks):
        if dense is not None:
            blk = dense[:, t0:t1, n0:n1]
        elif hasattr(response, "block"):
            blk = response.block(t=(t0, t1), n=(n0, n1))
        else:
            raise ParameterError(
                f"response must have todense() or block(), got {type(response).__name__}"
            )
        arr[:, t0:t1, n0:n1] = blk
    _check_complete(arr, block_grid(shape, chunks), partial)
    _finalise(partial, path, overwrite)
    return open_response(path)


# ----------------------------------------------------------------------------- reading
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
        A store of ``P`` opens lazily (chunks read on each product; ``.load()`` reads it
        all); a store of a Radon table opens as the :class:`~rotmod.response.RadonResponse`
        it was written from.

    Raises
    ------
    ParameterError
        No such store, not a rotmod response, or an unfinished (``.partial``) store.
    InstrumentMismatchError
        The store was computed for other inputs (the message names the field).
    """
    import zarr

    p = _as_path(path)
    if not p.exists():
        hint = " (an unfinished .partial store exists: resume write_response)" if p.with_name(
            p.name + _PARTIAL
        ).exists() else ""
        raise ParameterError(f"path {str(p)!r} does not exist{hint}")
    try:
        g = zarr.open_group(str(p), mode="r")
        attrs_ok = g.attrs.get("complete") is True
    except Exception as exc:  # unreadable zarr.json: zarr raises several kinds
        raise RotmodError(f"response store {str(p)!r} cannot be opened ({type(exc).__name__}: "
                          f"{exc}); rebuild it with write_response") from exc
    meta = _read_meta(g, p)
    if not attrs_ok:
        raise ParameterError(f"path {str(p)!r} is an unfinished response store")
    check_response_matches(
        meta, instrument=instrument, grid=grid, time_bins=time_bins, model=model, energy=energy,
        distance=distance,
    )
    operator = meta.get("operator") or {}
    if operator.get("kind") == "radon":
        return _open_radon(g, p, meta)
    try:
        arr = g["P"]
    except Exception as exc:
        raise RotmodError(f"response store {str(p)!r} has no readable array P ({exc}); "
                          "rebuild it with write_response") from exc
    if tuple(arr.shape) != tuple(meta.get("shape", arr.shape)):
        raise RotmodError(f"response store {str(p)!r}: array P has shape {arr.shape}, its "
                          f"metadata says {meta['shape']}; rebuild it")
    return StoredResponse(p, arr, meta)


def _open_radon(group: Any, path: Path, meta: dict[str, Any]) -> ResponseOperator:
    from rotmod.response.radon import RadonResponse

    table = _read_table(group, path)
    r = _restore(meta)
    try:
        return RadonResponse(r["instrument"], r["grid"], r["time_bins"], r["energy"],
                             tolerance=meta["operator"]["tolerance"], dtype=meta["dtype"],
                             table=table)
    except (KeyError, TypeError) as exc:
        raise RotmodError(f"response store {str(path)!r}: its metadata is damaged ({exc}); "
                          "rebuild it with rotmod response") from exc


def load_response(path: Any, **expected: Any) -> MaterialisedResponse:
    """Open (see :func:`open_response`) and read the whole response into memory.

    Returns
    -------
    MaterialisedResponse
    """
    r = open_response(path, **expected)
    return r.materialise() if hasattr(r, "materialise") else r.load()
