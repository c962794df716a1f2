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

For every other tool (``xarray.open_zarr(path)``, zarr, any zarr v3 reader) a store is also
self-describing, in the CF conventions' terms (:func:`write_axes`, at finalisation):

* ``P`` has the zarr v3 ``dimension_names`` ``("detector", "time_bin", "pixel")`` (:data:`DIMS`;
  a Radon ``table`` has ``("detector_offset", "direction_node")``), and the attributes
  ``units``, ``long_name`` and ``coordinates`` (the names of its coordinate arrays);
* coordinate arrays, one per axis quantity, each with ``units`` and ``long_name``:
  ``mask_angle`` (deg, each time bin's centre), ``detector_x``/``detector_y`` (cm),
  ``theta``/``phi`` (deg, each pixel's direction in the instrument frame), ``ra``/``dec``
  (deg, ICRS, for grids fixed on the sky), ``pixel_y``/``pixel_x`` (the image row and column
  of a WCS grid's pixel: ``ds.set_index(pixel=["pixel_y", "pixel_x"]).unstack("pixel")``
  gives images), ``healpix_index`` (HEALPix grids);
* group attributes in words (``title``, ``instrument``, ``sky_grid``, ``time_bins``,
  ``model``, ``energy`` with its unit, ``source_distance``, ``dtype``, ``rotmod_version``,
  ``rotmod_commit``, ``date_created``);
* consolidated metadata (one read opens the store; xarray opens it without a warning).

rotmod itself reads only the JSON metadata and ``P``/``table``: stores written before these
additions (the same ``format_version``) open as before, and older rotmod opens the new ones.

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
import time
import warnings
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np

from rotmod.errors import ParameterError, RotmodError
from rotmod.io.atomic import atomic_dir, check_overwrite, replace_dir, sibling
from rotmod.io.lock import lock_path
from rotmod.io.provenance import git_commit
from rotmod.sky.celestial import CelestialGrid
from rotmod.sky.geometry import SkyGeometry, WcsGeometry
from rotmod.sky.healpix import HealpixGrid

__all__ = [
    "DIMS",
    "FORMAT_VERSION",
    "TABLE_DIMS",
    "as_store_path",
    "axis_coords",
    "check_complete",
    "check_partial",
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
    "store_paths",
    "verified",
    "write_axes",
    "write_table",
]

FORMAT_VERSION = 1
_ATTR = "rotmod_response"
_PARTIAL = ".partial"
_DONE = "_done"

#: Names of the axes of ``P[d, t, n]`` (zarr v3 ``dimension_names``; xarray's ``dims``).
DIMS = ("detector", "time_bin", "pixel")
#: Names of the axes of a Radon table ``Psi[j, k r]``: the detector's offset within one mask
#: period (rows), and the nodes of the projected direction (slope ``k``, obliquity ring ``r``).
TABLE_DIMS = ("detector_offset", "direction_node")
#: Coordinate values per chunk (float64: 8 MB), so a huge grid's coordinates stream too.
_COORD_CHUNK = 1 << 20

#: A coordinate: its dimension names, values and CF attributes (``units``, ``long_name``).
_Coord = tuple[tuple[str, ...], np.ndarray, dict[str, str]]


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
    """Where the store at ``path`` is written until it is complete (``<path>.partial``, a
    shortened name with a hash when that would be too long: :func:`rotmod.io.atomic.sibling`)."""
    return sibling(path, _PARTIAL)


def store_paths(path: Path) -> tuple[Path, Path]:
    """The names a writer of the store ``path`` uses beside it: its unfinished form
    (:func:`partial_path`) and its lock (:func:`rotmod.io.lock.lock_path`)."""
    return partial_path(path), lock_path(path)


def check_partial(partial: Path) -> bool:
    """Whether an unfinished store of an earlier run is at ``partial`` (to resume or replace).

    Raises
    ------
    ParameterError
        Something else holds the name: a file, or a folder without a rotmod response's
        metadata (a run killed before it wrote any, or a folder that is not rotmod's), which
        is never removed here.
    """
    if not (partial.exists() or partial.is_symlink()):
        return False
    try:
        _read_meta(_zarr().open_group(str(partial), mode="r"), partial)
    except Exception:  # zarr raises several kinds for a folder that is no zarr group
        raise ParameterError(
            f"{str(partial)!r} is where the unfinished store is written, but it holds no "
            "unfinished rotmod response (no readable rotmod metadata: a run killed before "
            "it wrote any, or a file or folder that is not rotmod's); it is left as it is: "
            "remove it, or write the store under another name"
        ) from None
    return True


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
    # Made whole in a temporary folder and renamed: an interrupted start never leaves a
    # .partial store without its array to resume.
    with atomic_dir(partial) as tmp:
        g = _new_group(tmp, meta)
        g.create_array(
            "P", shape=(nd, nt, nn), chunks=(nd, *chunks), dtype=meta["dtype"],
            fill_value=np.nan, compressors=_compressors(), dimension_names=DIMS,
        )
        (tmp / _DONE).mkdir()
    return _zarr().open_group(str(partial), mode="r+")["P"]


def open_partial(partial: Path) -> tuple[Any, dict[str, Any]]:
    """The array ``P`` and metadata of an unfinished store (to resume writing it)."""
    g = _zarr().open_group(str(partial), mode="r+")
    meta = _read_meta(g, partial)
    if "P" not in g:
        raise ParameterError(
            f"{str(partial)!r} is an unfinished rotmod store with nothing to resume (no array "
            "P: a Radon table's, or a run stopped as it began); remove it and run again")
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
        fill_value=np.nan, compressors=_compressors(), dimension_names=TABLE_DIMS,
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


# ------------------------------------------------------------------ axes, for other tools
def axis_coords(instrument: Any, grid: SkyGeometry | None, time_bins: Any) -> dict[str, _Coord]:
    """The coordinates of the axes of ``P`` that ``instrument``, ``grid`` and ``time_bins``
    give (each may be ``None``: its coordinates are left out).

    Returns
    -------
    dict
        Name -> ``(dims, values, attrs)``: see the module notes for the names.
    """
    out: dict[str, _Coord] = {}
    if time_bins is not None:
        out["mask_angle"] = (("time_bin",), np.degrees(time_bins.angles()), {
            "units": "deg", "long_name": "mask angle at the centre of the time bin"})
    if instrument is not None:
        pos = np.asarray(instrument.detectors.positions, dtype=float)
        for i, axis in enumerate("xy"):
            out[f"detector_{axis}"] = (("detector",), pos[:, i], {
                "units": "cm", "long_name": f"{axis} of the detector's centre (instrument frame)"})
    if grid is None:
        return out
    theta, phi = grid.directions()
    out["theta"] = (("pixel",), theta.to_value(u.deg), {
        "units": "deg", "long_name": "zenith angle of the pixel centre (instrument frame)"})
    out["phi"] = (("pixel",), phi.to_value(u.deg), {
        "units": "deg", "long_name": "azimuth of the pixel centre (instrument frame)"})
    # The grids fixed on the sky know their pixels' celestial coordinates (sky_coords);
    # an instrument-frame grid has none without an attitude.
    if isinstance(grid, CelestialGrid | HealpixGrid):
        c = grid.sky_coords().icrs
        out["ra"] = (("pixel",), c.ra.to_value(u.deg), {
            "units": "deg", "long_name": "right ascension of the pixel centre (ICRS)"})
        out["dec"] = (("pixel",), c.dec.to_value(u.deg), {
            "units": "deg", "long_name": "declination of the pixel centre (ICRS)"})
    if isinstance(grid, WcsGeometry):
        iy, ix = np.divmod(np.arange(grid.size, dtype=np.int64), grid.shape[1])
        out["pixel_y"] = (("pixel",), iy, {"units": "1", "long_name": "image row of the pixel"})
        out["pixel_x"] = (("pixel",), ix, {"units": "1",
                                           "long_name": "image column of the pixel"})
    if isinstance(grid, HealpixGrid):
        out["healpix_index"] = (("pixel",), np.asarray(grid.pixels, dtype=np.int64), {
            "units": "1", "long_name": f"HEALPix index (nside {grid.nside}, {grid.order} "
                                       "order, ICRS)"})
    return out


def _describe(meta: dict[str, Any], grid: SkyGeometry | None) -> dict[str, str]:
    """The store's metadata in words (group attributes for people and other tools)."""
    out = {"title": "rotmod response"}
    inst = meta.get("instrument") or {}
    mask, det = inst.get("mask") or {}, inst.get("detectors") or {}
    if mask:
        n_det = meta.get("shape", [None])[0]
        out["instrument"] = (
            f"{n_det} detector(s) of {det.get('diameter')} cm under a {mask.get('material')} "
            f"slat mask: slats {mask.get('slat_width')} cm, gaps {mask.get('slat_gap')} cm, "
            f"{mask.get('thickness')} cm thick, {mask.get('height')} cm above the detectors")
    if grid is not None:
        ny, nx = grid.shape
        out["sky_grid"] = (f"{grid.kind} grid ({type(grid).__name__}) of {grid.size} pixels "
                           f"({ny} x {nx}), fixed in the {grid.frame} frame")
    tb = meta.get("time_bins")
    if tb:
        out["time_bins"] = (f"{tb.get('n_bins')} mask-angle bins per rotation, mode "
                            f"{tb.get('mode')!r}, {tb.get('n_sub')} sub-sample(s) per bin")
    model = meta.get("model") or {}
    if model:
        out["model"] = str(model.get("model"))
    energy = meta.get("energy")
    out["energy"] = "not given" if energy is None else f"{energy:g} keV"
    distance = meta.get("distance")
    if mask:  # a spec's metadata leaves the distance out for sources at infinity
        out["source_distance"] = "infinity" if distance is None else f"{distance:g} cm"
    op = meta.get("operator") or {}
    if op:
        out["operator"] = f"{op.get('kind')} (tolerance {op.get('tolerance')})"
    for key in ("dtype", "rotmod_version"):
        if meta.get(key) is not None:
            out[key] = str(meta[key])
    # Provenance in words, as every FITS product carries it (rotmod.io.provenance); not in
    # the JSON metadata, which describes what the response is, not when it was made.
    out["rotmod_commit"] = git_commit() or "unknown"
    out["date_created"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return out


def write_axes(partial: Path, meta: dict[str, Any], instrument: Any,
               grid: SkyGeometry | None, time_bins: Any) -> None:
    """Make the store at ``partial`` self-describing (see the module notes): the coordinate
    arrays of :func:`axis_coords`, the CF attributes of ``P`` (or ``table``) and the group's
    attributes in words.  A coordinate whose length is not its axis's in ``meta["shape"]``
    (e.g. an instrument of more detectors than the response) is left out."""
    g = _zarr().open_group(str(partial), mode="r+")
    sizes = dict(zip(DIMS, meta.get("shape") or (), strict=False))
    names = []
    for name, (dims, values, attrs) in axis_coords(instrument, grid, time_bins).items():
        if any(sizes.get(d) != n for d, n in zip(dims, values.shape, strict=True)):
            continue
        arr = g.create_array(name, shape=values.shape, dtype=values.dtype, overwrite=True,
                             chunks=tuple(min(n, _COORD_CHUNK) or 1 for n in values.shape),
                             compressors=_compressors(), dimension_names=dims)
        arr[...] = values
        arr.attrs.update(attrs)
        names.append(name)
    if "P" in g:
        g["P"].attrs.update({
            "units": "1", "coordinates": " ".join(names),
            "long_name": "characteristic profile: the fraction of a pixel's rate on an "
                         "unobstructed detector face that the detector counts in the time bin"})
    if "table" in g:
        g["table"].attrs.update({
            "units": "1",
            "long_name": "Radon table of profile values by detector offset and projected "
                         "direction (rotmod.response.RadonResponse)"})
    g.attrs.update(_describe(meta, grid))


# -------------------------------------------------------------------------------- finish
def finalise(partial: Path, path: Path, overwrite: bool) -> None:
    """Remove the done markers, mark the store complete, consolidate its metadata and rename
    it to ``path`` (an existing ``path`` is replaced only now, with ``overwrite``).

    Raises
    ------
    ParameterError
        ``path`` exists (created meanwhile) and ``overwrite`` is false.
    """
    shutil.rmtree(partial / _DONE, ignore_errors=True)
    zarr = _zarr()
    g = zarr.open_group(str(partial), mode="r+")
    g.attrs["complete"] = True
    with warnings.catch_warnings():
        # zarr warns that consolidated metadata is not (yet) in the zarr v3 specification;
        # zarr-python and xarray read it (xarray warns when it is absent), and a reader that
        # does not know it reads each array's own zarr.json, which stays.
        warnings.simplefilter("ignore", zarr.errors.ZarrUserWarning)
        zarr.consolidate_metadata(str(partial))
    check_overwrite(path, overwrite)
    replace_dir(partial, path)
