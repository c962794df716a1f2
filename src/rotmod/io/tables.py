"""Astropy tables as files (ECSV, CSV, FITS), and the attitude tables written as them.

Every table rotmod writes goes through :func:`write_table`: the one overwrite policy, then an
atomic write.  A table that is a product (a source catalogue, a light curve) goes through
:func:`write_product_table`, which adds the provenance cards (:mod:`rotmod.io.provenance`)
and writes FITS (``.fits``) or ECSV (``.ecsv``).  An attitude table
(:class:`~rotmod.sky.AttitudeTable`) is an ECSV file with columns ``time`` (s), ``ra``,
``dec`` and ``roll`` (deg).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np
from astropy.io import fits
from astropy.table import Table

from rotmod.errors import ParameterError
from rotmod.io.atomic import atomic_path, check_overwrite
from rotmod.io.images import stamp_header
from rotmod.io.provenance import fitting_comment, provenance_cards
from rotmod.sky.attitude import AttitudeTable

if TYPE_CHECKING:
    from rotmod.sources.lightcurve import LightCurve

__all__ = ["read_attitude_table", "write_attitude_table", "write_light_curve",
           "write_product_table", "write_table"]

#: astropy's format of each table extension rotmod writes (anything else: CSV).
TABLE_FORMATS = {".ecsv": "ascii.ecsv", ".csv": "ascii.csv"}
#: The file-name endings of an attitude table and astropy's format for each.
ATTITUDE_FORMATS = {".ecsv": "ascii.ecsv", ".csv": "ascii.csv", ".fits": "fits",
                    ".fit": "fits", ".fits.gz": "fits"}
#: The file-name endings of a product table (:func:`write_product_table`) and their form.
PRODUCT_FORMATS = {".fits": "fits", ".fits.gz": "fits", ".ecsv": "ecsv"}


def product_format(path: str | os.PathLike, parameter: str = "path") -> str:
    """``"fits"`` or ``"ecsv"``: the form of a product table named ``path``.

    Raises
    ------
    ParameterError
        Another extension.
    """
    name = Path(path).name.lower()
    for ext, form in PRODUCT_FORMATS.items():
        if name.endswith(ext):
            return form
    raise ParameterError(f"{parameter} {str(path)!r}: must end with "
                         f"{', '.join(PRODUCT_FORMATS)} (FITS or ECSV), got "
                         f"{Path(path).suffix or 'no extension'!r}")


def write_product_table(
    table: Table, path: str | os.PathLike, *, extname: str, overwrite: bool = False,
    seed: Any = None, command: str | Sequence[str] | None = None,
    meta: dict[str, Any] | None = None, comments: dict[str, str] | None = None,
) -> Path:
    """Write a product table with its provenance: FITS (``.fits``) or ECSV (``.ecsv``).

    Parameters
    ----------
    table : astropy.table.Table
        Columns with their units; ``table.meta`` holds header keywords (FITS keyword names).
    path : str or path-like
    extname : str
        ``EXTNAME`` of the FITS table (also kept in the ECSV metadata, so that a reader
        knows what the file holds).
    overwrite : bool
        Replace an existing file (default: refuse).
    seed, command
        Provenance (:func:`rotmod.io.provenance.provenance_cards`).
    meta : dict, optional
        Extra header cards (as :func:`rotmod.io.images.write_image`'s).
    comments : dict, optional
        Comments of the FITS cards of ``table.meta`` (keyword -> comment).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ParameterError
        An extension other than FITS or ECSV, or an existing file without ``overwrite``.
    """
    form = product_format(path)
    p = check_overwrite(path, overwrite)
    cards = provenance_cards(seed=seed, command=command)
    out = table.copy(copy_data=False)
    out.meta = dict(table.meta)
    if form == "ecsv":
        out.meta["EXTNAME"] = extname
        out.meta.update({k: v for k, v, _ in cards})
        out.meta.update({k.upper(): v for k, v in (meta or {}).items()})
        with atomic_path(p) as tmp:
            out.write(tmp, format="ascii.ecsv", overwrite=True)
        return p
    hdu = fits.table_to_hdu(out)
    hdu.name = extname
    for key, comment in (comments or {}).items():
        if key in hdu.header:
            hdu.header.comments[key] = fitting_comment(key, hdu.header[key], comment)
    primary = fits.PrimaryHDU()
    for h in (primary.header, hdu.header):  # the primary too: where tools look first
        stamp_header(h, meta=meta, cards=cards)
    with atomic_path(p) as tmp:
        fits.HDUList([primary, hdu]).writeto(tmp, overwrite=True, checksum=True)
    return p


def write_table(table: Table, path: str | os.PathLike, *, format: str | None = None,
                overwrite: bool = False) -> Path:
    """Write an astropy table atomically: as ``format`` (an astropy table format), by default
    ECSV for ``.ecsv`` and CSV for anything else.

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false.
    """
    p = check_overwrite(path, overwrite)
    fmt = format or TABLE_FORMATS.get(p.suffix.lower(), "ascii.csv")
    with atomic_path(p) as tmp:
        table.write(tmp, format=fmt, overwrite=True)
    return p


def write_light_curve(
    light_curve: LightCurve, path: str | os.PathLike, *, overwrite: bool = False, seed: Any = None,
    command: str | Sequence[str] | None = None, meta: dict[str, Any] | None = None,
) -> Path:
    """Write a light curve (:class:`rotmod.sources.LightCurve`) as FITS or ECSV: its
    :meth:`~rotmod.sources.LightCurve.to_table` (one row per interval, one entry per source in
    each flux column) with the provenance cards (:func:`write_product_table`, extension
    ``LIGHTCURVE``).

    Raises
    ------
    ParameterError
        Another extension than FITS or ECSV, or an existing file without ``overwrite``.
    """
    product_format(path)
    return write_product_table(
        light_curve.to_table(), path, extname="LIGHTCURVE", overwrite=overwrite, seed=seed,
        command=command, meta=meta,
        comments={"SOURCES": "the sources of the flux columns, in order",
                  "UL_CONF": "confidence of the flux upper limits"})


def write_attitude_table(table: AttitudeTable, path: str | os.PathLike, *,
                         overwrite: bool = False) -> Path:
    """Write an attitude table as ECSV (time in s, angles in deg), atomically.

    Raises
    ------
    ParameterError
        ``path`` exists and ``overwrite`` is false.
    """
    t = Table({"time": table.time * u.s, "ra": table.ra * u.deg, "dec": table.dec * u.deg,
               "roll": table.roll * u.deg})
    return write_table(t, path, format="ascii.ecsv", overwrite=overwrite)


def read_attitude_table(path: str | os.PathLike) -> AttitudeTable:
    """Read an attitude table (ECSV or FITS with columns time, ra, dec, roll and units).

    The format is the file name's (``.ecsv``, ``.csv``, ``.fits``/``.fit``/``.fits.gz``),
    never guessed from the contents: a file of another kind is refused by name, not with
    astropy's list of every format it knows.

    Raises
    ------
    ParameterError
        Another extension, an unreadable file or missing columns.
    """
    name = str(path).lower()
    fmt = next((f for ext, f in ATTITUDE_FORMATS.items() if name.endswith(ext)), None)
    if fmt is None:
        raise ParameterError(
            f"attitude file {str(path)!r}: must be a table named .ecsv, .csv or .fits "
            f"(columns time, ra, dec, roll), got {Path(path).name!r}")
    try:
        with warnings.catch_warnings():  # a FITS file's first table is the attitude's
            warnings.filterwarnings("ignore", message="hdu= was not specified")
            t = Table.read(path, format=fmt)
    except (OSError, ValueError, TypeError) as exc:
        raise ParameterError(f"attitude file {str(path)!r}: is not a readable {fmt} table "
                             f"({type(exc).__name__}: {exc})") from exc
    cols = {c.lower(): t[c] for c in t.colnames}
    missing = [k for k in ("time", "ra", "dec", "roll") if k not in cols]
    if missing:
        raise ParameterError(f"attitude file {str(path)!r}: needs columns time, ra, dec, "
                             f"roll; missing {', '.join(missing)}")
    try:
        q: list[Any] = [u.Quantity(cols[k]) if cols[k].unit else np.asarray(cols[k])
                        for k in ("time", "ra", "dec", "roll")]
    except (ValueError, TypeError) as exc:
        raise ParameterError(f"attitude file {str(path)!r}: columns time, ra, dec, roll "
                             f"must be numbers with units ({exc})") from exc
    return AttitudeTable(*q)
