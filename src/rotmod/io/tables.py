"""Astropy tables as files (ECSV, CSV), and the attitude tables written as them.

Every table rotmod writes goes through :func:`write_table`: the one overwrite policy, then an
atomic write.  An attitude table (:class:`~rotmod.sky.AttitudeTable`) is an ECSV file with
columns ``time`` (s), ``ra``, ``dec`` and ``roll`` (deg).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np
from astropy.table import Table

from rotmod.errors import ParameterError
from rotmod.io.atomic import atomic_path, check_overwrite
from rotmod.sky.attitude import AttitudeTable

__all__ = ["read_attitude_table", "write_attitude_table", "write_table"]

#: astropy's format of each table extension rotmod writes (anything else: CSV).
TABLE_FORMATS = {".ecsv": "ascii.ecsv", ".csv": "ascii.csv"}


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

    Raises
    ------
    ParameterError
        Unreadable file or missing columns.
    """
    try:
        t = Table.read(path)
        cols = {c.lower(): t[c] for c in t.colnames}
        q: list[Any] = [u.Quantity(cols[k]) if cols[k].unit else np.asarray(cols[k])
                        for k in ("time", "ra", "dec", "roll")]
    except (OSError, ValueError, KeyError) as exc:
        raise ParameterError(f"attitude file {str(path)!r}: needs columns time, ra, dec, "
                             f"roll ({type(exc).__name__}: {exc})") from exc
    return AttitudeTable(*q)
