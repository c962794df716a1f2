"""Source catalogues: one row per source, as FITS or ECSV tables that astropy and gammapy read.

A catalogue is written from a detection (:func:`rotmod.sources.detect`) or a fit
(:func:`rotmod.sources.fit`, with the localisation regions if any) by
:func:`write_detection` / :func:`write_catalogue` (or ``rotmod.io.write``), with a unit on
every column:

=====================  =====  =================================================================
column                 unit   meaning
=====================  =====  =================================================================
``NAME``                      the source's name
``RA``, ``DEC``        deg    position (ICRS), for sources on the sky; or
``THETA``, ``PHI``     deg    zenith and azimuth in the instrument frame
``R68``, ``R90``       deg    radius of the circle about the position holding 68 % / 90 % of
                              its probability (:meth:`rotmod.sources.Region.radius`; NaN
                              without a region)
``SYS_ERR``            deg    systematic position error per axis folded into the region
``TS``, ``SQRT_TS``           test statistic of the source and its square root (sigma at a
                              fixed position)
``TS_CONF``                   ``TS / (1 + CONFUSN^2)``: the TS with the field's confusion
                              noise counted (a detection's catalogue only)
``FLUX``               1/s    photons per second on one unmasked detector face (the
                              response's sky unit)
``FLUX_ERRN/ERRP``     1/s    profile-likelihood 1-sigma errors below / above ``FLUX``
``FLUX_UL``            1/s    upper limit at the confidence ``UL_CONF`` (header)
=====================  =====  =================================================================

The header (ECSV: the metadata) holds ``UL_CONF``, the detection threshold ``THRESH`` (a TS)
and the confusion noise ``CONFUSN`` (:func:`rotmod.sources.detection.confusion_noise`, in
units of the statistical sigma) when a detection made the catalogue, ``SKYFRAME``
(``celestial`` or ``instrument``), ``RADESYS = 'ICRS'`` for sky positions and the
provenance cards
(:mod:`rotmod.io.provenance`).  The position columns are those gammapy's catalogues take
(``RA``/``DEC``), and ``NAME`` is the source-name key to give them.

:func:`read_catalogue` reads these files and any other table with positions -- ``RA``/``DEC``
(or ``RAJ2000``/``DEJ2000``) or ``THETA``/``PHI``, any case, in deg unless the column has a
unit -- and optional ``NAME`` (or ``Source_Name``) and ``FLUX`` columns, as a
:class:`SourceCatalogue`; :func:`rotmod.sources.catalogue.read_sky_model` turns one into the
sky model that seeds a fit.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.table import MaskedColumn, Table

from rotmod.errors import ParameterError
from rotmod.io._fits import open_verified
from rotmod.io.tables import product_format, write_product_table

if TYPE_CHECKING:
    from rotmod.sources import Detection, FitResult, Region

__all__ = ["SourceCatalogue", "catalogue_table", "read_catalogue", "write_catalogue",
           "write_detection"]

#: ``EXTNAME`` of a catalogue's table (also in an ECSV catalogue's metadata).
EXTNAME = "CATALOG"
#: Unit of the flux columns: photons/s on one unmasked detector face.
FLUX_UNIT = u.Unit("1 / s")
#: Containments of the two radius columns.
RADII = {"R68": 0.68, "R90": 0.90}
#: Comments of the header cards of a catalogue.
CARD_COMMENTS = {
    "UL_CONF": "confidence of the flux upper limits FLUX_UL",
    "THRESH": "TS a source had to reach to be detected",
    "CONFUSN": "confusion sigma: TS_CONF = TS/(1+CONFUSN^2)",
    "SKYFRAME": "positions: celestial (RA/DEC) or instrument (THETA/PHI)",
    "RADESYS": "frame of RA/DEC",
    "FLUXDEF": "FLUX: photons/s on one unmasked detector face",
}
#: Pairs of position columns a reader accepts (lower case), with the frame they are in.
POSITION_COLUMNS = (("ra", "dec", "icrs"), ("raj2000", "dej2000", "icrs"),
                    ("raj2000", "decj2000", "fk5"), ("theta", "phi", "instrument"))
#: Name columns a reader accepts (lower case).
NAME_COLUMNS = ("name", "source_name")


@dataclass(frozen=True)
class SourceCatalogue:
    """A catalogue read from a file: the positions, names and fluxes of its sources.

    Attributes
    ----------
    names : tuple of str
        One per source (``""`` where the table has no name column).
    frame : {"celestial", "instrument"}
        Where the positions are.
    positions : SkyCoord or (ndarray, ndarray)
        ICRS positions, or instrument directions ``(theta, phi)`` in deg.
    flux : ndarray
        Flux of each source (1/s, photons on one unmasked detector face); NaN where the table
        gives none.
    table : astropy.table.Table
        The whole table as read (with its metadata).
    """

    names: tuple[str, ...]
    frame: str
    positions: Any
    flux: np.ndarray
    table: Table

    def __len__(self) -> int:
        return len(self.names)

    @property
    def threshold(self) -> float | None:
        """The detection threshold (TS) of the catalogue, if it records one."""
        value = self.table.meta.get("THRESH")
        return None if value is None else float(value)

    @property
    def ul_confidence(self) -> float | None:
        """The confidence of the upper limits, if the catalogue records it."""
        value = self.table.meta.get("UL_CONF")
        return None if value is None else float(value)


def _position_columns(source: Any) -> dict[str, np.ndarray]:
    pos = source.position
    if isinstance(pos, SkyCoord):
        return {"RA": pos.icrs.ra.deg, "DEC": pos.icrs.dec.deg}
    return {"THETA": pos[0], "PHI": pos[1]}


def catalogue_table(result: FitResult, regions: Sequence[Region | None] | None = None, *,
                    threshold: float | None = None, frame: str | None = None,
                    confusion: float | None = None) -> Table:
    """The catalogue of a fit as an astropy table (module notes for the columns).

    Parameters
    ----------
    result : FitResult
        The fitted sources, with TS, flux errors and upper limits.
    regions : sequence of Region or None, optional
        The localisation region of each source (``None`` entries: none).
    threshold : float, optional
        The detection threshold (TS), for the ``THRESH`` card.
    frame : {"celestial", "instrument"}, optional
        Frame of the position columns; required only when ``result`` has no sources.
    confusion : float, optional
        The field's confusion noise (``CONFUSN``, and the ``TS_CONF`` column); NaN or
        ``None``: not measured.

    Raises
    ------
    ParameterError
        ``regions`` of another length than the sources, sources in a frame other than
        ``frame``, or neither sources nor ``frame``.
    """
    sources = result.model.sources
    n = len(sources)
    regions = [None] * n if regions is None else list(regions)
    if len(regions) != n:
        raise ParameterError(f"regions must have one entry per source ({n}), got "
                             f"{len(regions)}")
    frames = {s.frame for s in sources}
    if frame is not None and frame not in ("celestial", "instrument"):
        raise ParameterError(f"frame must be 'celestial' or 'instrument', got {frame!r}")
    if frame is not None and frames - {frame}:
        raise ParameterError(f"frame {frame!r} does not match the sources' {sorted(frames)}")
    frame = frame or (frames.pop() if frames else None)
    if frame is None:
        raise ParameterError("frame: give the frame ('celestial' or 'instrument') of a "
                             "catalogue without sources")
    t = Table()
    t["NAME"] = np.array([s.name for s in sources], dtype=str) if n else np.array([], "U1")
    names = ("RA", "DEC") if frame == "celestial" else ("THETA", "PHI")
    pos = [_position_columns(s) for s in sources]
    for name in names:
        t[name] = np.array([p[name] for p in pos], dtype=float) * u.deg
    for name, q in RADII.items():
        t[name] = np.array([np.nan if r is None else r.radius(q) for r in regions]) * u.deg
    t["SYS_ERR"] = np.array([np.nan if r is None else r.systematic for r in regions]) * u.deg
    ts = np.asarray(result.ts, dtype=float).reshape(n)
    t["TS"] = ts
    t["SQRT_TS"] = np.sqrt(np.maximum(ts, 0.0))  # NaN stays NaN: not computed
    if confusion is not None and np.isfinite(confusion):
        t["TS_CONF"] = ts / (1.0 + float(confusion) ** 2)
        t.meta["CONFUSN"] = float(confusion)
    err = np.asarray(result.flux_err, dtype=float).reshape(n, 2)
    t["FLUX"] = np.array([s.flux for s in sources], dtype=float) * FLUX_UNIT
    t["FLUX_ERRN"] = err[:, 0] * FLUX_UNIT
    t["FLUX_ERRP"] = err[:, 1] * FLUX_UNIT
    t["FLUX_UL"] = np.asarray(result.flux_ul, dtype=float).reshape(n) * FLUX_UNIT
    t.meta["UL_CONF"] = float(result.ul_confidence)
    if threshold is not None:
        t.meta["THRESH"] = float(threshold)
    t.meta["SKYFRAME"] = frame
    if frame == "celestial":
        t.meta["RADESYS"] = "ICRS"
    t.meta["FLUXDEF"] = "photons/s on one unmasked detector face"
    return t


def write_catalogue(
    result: FitResult, path: str | os.PathLike, *,
    regions: Sequence[Region | None] | None = None, threshold: float | None = None,
    frame: str | None = None, confusion: float | None = None, overwrite: bool = False,
    seed: Any = None, command: str | Sequence[str] | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    """Write the catalogue of a fit: FITS (``.fits``, ``.fits.gz``) or ECSV (``.ecsv``).

    Parameters
    ----------
    result : FitResult
    path : str or path-like
    regions, threshold, frame, confusion
        As for :func:`catalogue_table`.
    overwrite : bool
        Replace an existing file (default: refuse).
    seed, command, meta
        Provenance and extra header cards (as :func:`rotmod.io.images.write_image`'s).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ParameterError
        Another extension, an existing file without ``overwrite``, or what
        :func:`catalogue_table` refuses.
    """
    product_format(path)  # before any work: the name says FITS or ECSV
    table = catalogue_table(result, regions, threshold=threshold, frame=frame,
                            confusion=confusion)
    return write_product_table(table, path, extname=EXTNAME, overwrite=overwrite, seed=seed,
                               command=command, meta=meta, comments=CARD_COMMENTS)


def write_detection(detection: Detection, path: str | os.PathLike, *, overwrite: bool = False,
                    seed: Any = None, command: str | Sequence[str] | None = None,
                    meta: dict[str, Any] | None = None) -> Path:
    """Write the catalogue of a detection (its final fit, regions and threshold).

    As :func:`write_catalogue`, with the positions in the frame of the detection's grid (so
    that a detection of no source writes a valid empty catalogue) and its confusion noise.
    """
    return write_catalogue(detection.result, path, regions=detection.regions,
                           threshold=detection.threshold, frame=detection.ts_map.grid.frame,
                           confusion=detection.confusion, overwrite=overwrite, seed=seed,
                           command=command, meta=meta)


def _read_table(p: Path) -> Table:
    if product_format(p) == "ecsv":
        try:
            return Table.read(p, format="ascii.ecsv")
        except (OSError, ValueError) as exc:
            raise ParameterError(f"path {str(p)!r} is not a readable ECSV table: {exc}") \
                from exc
    with open_verified(p) as hl:
        tables = [h for h in hl[1:] if isinstance(h, fits.BinTableHDU | fits.TableHDU)]
        hdu = hl[EXTNAME] if EXTNAME in hl else (tables[0] if tables else None)
        if hdu is None:
            raise ParameterError(f"path {str(p)!r} has no table")
        if not isinstance(hdu, fits.BinTableHDU | fits.TableHDU):
            raise ParameterError(f"path {str(p)!r}: the {EXTNAME} extension must be a table, "
                                 f"got {type(hdu).__name__}")
        with warnings.catch_warnings():
            # Units outside the FITS standard (a foreign catalogue) are read as they are.
            warnings.simplefilter("ignore", u.UnitsWarning)
            return Table.read(hdu)


def _values(table: Table, name: str, unit: u.UnitBase, path: Path) -> np.ndarray:
    col = table[name]
    data = col.filled(np.nan) if isinstance(col, MaskedColumn) else col
    try:
        values = np.asarray(data, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"path {str(path)!r}: column {name} must hold numbers") from exc
    if values.ndim != 1:
        raise ParameterError(f"path {str(path)!r}: column {name} must hold one number per row, "
                             f"got {values.shape[1:]} per row")
    if col.unit is None:
        return values
    try:
        return (values * col.unit).to_value(unit)
    except u.UnitConversionError as exc:
        raise ParameterError(f"path {str(path)!r}: column {name} must be in units of "
                             f"{unit.to_string()}, got {col.unit}") from exc


def read_catalogue(path: str | os.PathLike) -> SourceCatalogue:
    """Read a source catalogue: rotmod's, or any FITS/ECSV table with positions.

    Parameters
    ----------
    path : str or path-like
        A FITS table (the ``CATALOG`` extension, else the first table) or an ECSV file with
        ``RA``/``DEC`` (also ``RAJ2000``/``DEJ2000``) or ``THETA``/``PHI`` columns (any
        case; deg unless a column has a unit), and optional ``NAME`` (or ``Source_Name``) and
        ``FLUX`` (1/s) columns.

    Returns
    -------
    SourceCatalogue

    Raises
    ------
    ParameterError
        A missing or unreadable file, no position columns (or two that differ only in case),
        a position that is not finite, a declination outside [-90, 90] or a right ascension
        outside [0, 360] deg, a column in units of the wrong kind or with more than one value
        per row, an infinite flux, or two sources of one name.
    """
    p = Path(path)
    if p.is_dir():
        raise ParameterError(f"path {str(p)!r} is a folder; give a catalogue file (FITS or ECSV)")
    if not p.is_file():
        raise ParameterError(f"path {str(p)!r} does not exist")
    table = _read_table(p)
    lower: dict[str, str] = {}
    for c in table.colnames:
        if c.lower() in lower:  # which one holds the positions would be a guess
            raise ParameterError(f"path {str(p)!r}: columns {lower[c.lower()]} and {c} differ "
                                 "only in case; keep one")
        lower[c.lower()] = c
    found = next(((lon, lat, frame) for lon, lat, frame in POSITION_COLUMNS
                  if lon in lower and lat in lower), None)
    if found is None:
        raise ParameterError(
            f"path {str(p)!r}: a catalogue needs position columns RA and DEC (ICRS, deg) or "
            f"THETA and PHI (instrument frame, deg); the table has {', '.join(table.colnames)}")
    lon, lat = (_values(table, lower[c], u.deg, p) for c in found[:2])
    bad = ~(np.isfinite(lon) & np.isfinite(lat))
    name_col = next((lower[c] for c in NAME_COLUMNS if c in lower), None)
    if name_col is None:
        names: tuple[str, ...] = ("",) * len(table)
    else:  # an empty name reads back from ECSV as a masked entry
        col = table[name_col]
        col = col.filled("") if isinstance(col, MaskedColumn) else col
        names = tuple(str(x).strip() for x in col)
    seen: dict[str, int] = {}
    for k, name in enumerate(names):
        if name and name in seen:  # a light curve or a map per source could not tell them apart
            raise ParameterError(f"path {str(p)!r}: the names must differ, got {name!r} in rows "
                                 f"{seen[name]} and {k}")
        seen.setdefault(name, k)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise ParameterError(
            f"path {str(p)!r}: the position of row {k}{' (' + names[k] + ')' if names[k] else ''}"
            f" is not finite ({lower[found[0]]} {lon[k]}, {lower[found[1]]} {lat[k]})")
    positions: Any
    if found[2] == "instrument":
        frame = "instrument"
        positions = (lon, lat)
    else:
        frame = "celestial"
        if np.any(np.abs(lat) > 90.0):
            k = int(np.argmax(np.abs(lat) > 90.0))
            raise ParameterError(f"path {str(p)!r}: {lower[found[1]]} of row {k} must be in "
                                 f"[-90, 90] deg, got {lat[k]}")
        # A right ascension outside [0, 360] deg would wrap silently onto another source
        # (400 onto 40); such a value is a mistake (a unit, a column), not a position.
        if np.any((lon < 0.0) | (lon > 360.0)):
            k = int(np.argmax((lon < 0.0) | (lon > 360.0)))
            raise ParameterError(f"path {str(p)!r}: {lower[found[0]]} of row {k} must be in "
                                 f"[0, 360] deg, got {lon[k]}")
        c = SkyCoord(lon * u.deg, lat * u.deg, frame=found[2]).icrs
        positions = SkyCoord(c.ra, c.dec, frame="icrs")
    flux = (_values(table, lower["flux"], FLUX_UNIT, p) if "flux" in lower
            else np.full(len(table), np.nan))
    if np.any(np.isinf(flux)):  # NaN (or empty) means no flux given; inf is no flux at all
        k = int(np.argmax(np.isinf(flux)))
        raise ParameterError(f"path {str(p)!r}: {lower['flux']} of row {k} must be finite (or "
                             f"empty: none given), got {flux[k]}")
    return SourceCatalogue(names, frame, positions, flux, table)
