"""TS maps as FITS: every per-pixel reading of a :class:`rotmod.sources.TSMap` in one file.

Each map is written in its grid's own FITS form (:meth:`rotmod.sky.SkyGeometry.image_hdus`,
as :func:`rotmod.io.images.write_image` writes images): a WCS image extension for an
instrument-frame or celestial grid, a pixel table (HEALPix: ``PIX``, ``VALUE``) otherwise.
The extensions are named after the maps:

=================  =====  ==============================================================
extension          unit   map
=================  =====  ==============================================================
``TS``                    test statistic of a point source in each pixel
``SQRT_TS``               its square root (sigma at a fixed, pre-chosen pixel)
``FLUX``           s-1    fitted flux (photons/s on one unmasked detector face)
``FLUX_ERR``       s-1    its curvature error
``FLUX_UL``        s-1    upper limit at the confidence ``UL_CONF``
``SENSITIVITY``    s-1    flux whose Asimov data set reaches ``TS = SENS_TS``
=================  =====  ==============================================================

A screened map (``ts_map(..., exact_above=)``) adds ``EXACT`` (1 where a pixel's readings
are the likelihood's, 0 where they are the score screen's) and the cards ``EXACTAB`` and
``SCRNCUT`` (its ``exact_above`` and ``screen_cut``).

The primary HDU is empty and carries the provenance cards, ``UL_CONF``, ``SENS_TS`` and the
grid's description (``GRID``, JSON), from which :func:`read_ts_map` rebuilds the grid.
Pixels the data cannot see are NaN.  ds9 and astropy open the WCS extensions directly.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from astropy.io import fits
from astropy.wcs import WCS

from rotmod.errors import ParameterError
from rotmod.io._fits import open_verified
from rotmod.io.atomic import atomic_path, check_overwrite
from rotmod.io.images import add_meta_cards, stamp_header
from rotmod.sky.geometry import SkyGeometry, grid_from_dict, image_from_hdus

if TYPE_CHECKING:
    from rotmod.sources import TSMap

__all__ = ["TSMapFile", "read_ts_map", "write_ts_map"]

#: The maps of a TS-map file: extension name -> (TSMap attribute, unit).
MAPS: dict[str, tuple[str, str]] = {
    "TS": ("ts", ""),
    "SQRT_TS": ("sqrt_ts", ""),
    "FLUX": ("flux", "s-1"),
    "FLUX_ERR": ("flux_err", "s-1"),
    "FLUX_UL": ("flux_ul", "s-1"),
    "SENSITIVITY": ("sensitivity", "s-1"),
}


@dataclass(frozen=True)
class TSMapFile:
    """A TS-map file read back.

    Attributes
    ----------
    maps : dict of str to ndarray
        Each map of :data:`MAPS` by extension name, of the grid's image shape (``(1, n)``
        for a pixel table).
    grid : SkyGeometry or None
        The grid, rebuilt from the ``GRID`` card (None when the file has none).
    wcs : astropy.wcs.WCS or None
        The maps' WCS (None for pixel tables).
    ul_confidence, sensitivity_ts : float
    header : astropy.io.fits.Header
        The primary header.
    exact : ndarray of bool or None
        A screened map's ``EXACT`` (``None``: every pixel exact).
    """

    maps: dict[str, np.ndarray]
    grid: SkyGeometry | None
    wcs: Any
    ul_confidence: float
    sensitivity_ts: float
    header: Any
    exact: np.ndarray | None = None


def _map_hdus(grid: SkyGeometry, name: str, values: np.ndarray, unit: str) -> list[Any]:
    """The extensions of one map: the grid's FITS form, named ``name``."""
    hdus = grid.image_hdus(values, None, unit)
    out = []
    if hdus[0].data is not None:  # a WCS image: the primary of image_hdus, as an extension
        out.append(fits.ImageHDU(hdus[0].data, hdus[0].header, name=name))
    for h in hdus[1:]:  # a pixel table
        h.name = name
        out.append(h)
    return out


def write_ts_map(
    ts_map: TSMap, path: str | os.PathLike, *, overwrite: bool = False, seed: Any = None,
    command: str | Sequence[str] | None = None, meta: dict[str, Any] | None = None,
) -> Path:
    """Write every map of a TS map to one FITS file (module notes).

    Parameters
    ----------
    ts_map : TSMap
    path : str or path-like
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
        An existing file without ``overwrite``, or maps not of the grid's shape.
    """
    p = check_overwrite(path, overwrite)
    grid = ts_map.grid
    if not isinstance(grid, SkyGeometry):
        raise ParameterError(f"ts_map.grid must be a sky grid (a SkyGeometry), got "
                             f"{type(grid).__name__}")
    primary = fits.PrimaryHDU()
    h = primary.header
    stamp_header(h, seed=seed, command=command)
    h["HDUCLAS1"] = ("TSMAP", "TS map of a test point source")
    h["UL_CONF"] = (float(ts_map.ul_confidence), "confidence of FLUX_UL")
    h["SENS_TS"] = (float(ts_map.sensitivity_ts), "TS that defines SENSITIVITY")
    h["SKYFRAME"] = (grid.frame, "pixels: celestial or instrument frame")
    h["GRID"] = (json.dumps(grid.to_dict()), "the grid (JSON)")
    add_meta_cards(h, meta)
    hdus: list[Any] = [primary]
    for name, (attr, unit) in MAPS.items():
        values = np.asarray(getattr(ts_map, attr), dtype=float)
        if values.shape != tuple(grid.shape):
            raise ParameterError(f"ts_map.{attr} must have the grid's shape {grid.shape}, got "
                                 f"{values.shape}")
        hdus += _map_hdus(grid, name, values, unit)
    if ts_map.exact is not None:
        h["EXACTAB"] = (float(ts_map.exact_above), "screened map: LR exact above this TS")
        h["SCRNCUT"] = (float(ts_map.screen_cut), "screen TS from which pixels are exact")
        hdus += _map_hdus(grid, "EXACT", np.asarray(ts_map.exact, dtype=np.uint8), "")
    with atomic_path(p) as tmp:
        fits.HDUList(hdus).writeto(tmp, overwrite=True, checksum=True)
    return p


def read_ts_map(path: str | os.PathLike) -> TSMapFile:
    """Read a TS-map file written by :func:`write_ts_map`.

    Raises
    ------
    RotmodError
        A missing, unreadable or corrupt file.
    ParameterError
        A file without the maps.
    """
    p = Path(path)
    maps: dict[str, np.ndarray] = {}
    wcs = None
    with open_verified(p) as hl:
        hdr = hl[0].header.copy()
        missing = [name for name in MAPS if name not in hl]
        if missing:
            raise ParameterError(f"path {str(p)!r} is not a TS-map file: no "
                                 f"{', '.join(missing)} extension")
        for name in [*MAPS, *(["EXACT"] if "EXACT" in hl else [])]:
            hdu = hl[name]
            if isinstance(hdu, fits.ImageHDU):
                maps[name] = np.array(hdu.data, dtype=float)
                wcs = WCS(hdu.header)
            else:
                maps[name] = image_from_hdus(fits.HDUList([fits.PrimaryHDU(), hdu]), str(p))[0]
    grid = grid_from_dict(json.loads(hdr["GRID"])) if "GRID" in hdr else None
    exact = maps.pop("EXACT") > 0.5 if "EXACT" in maps else None
    return TSMapFile(maps, grid, wcs, float(hdr.get("UL_CONF", np.nan)),
                     float(hdr.get("SENS_TS", np.nan)), hdr, exact)
