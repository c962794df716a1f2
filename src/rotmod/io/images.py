"""FITS images of reconstructions: primary image with the grid's TAN WCS, uncertainty
extension, parameters and fit history in the header; an atomic writer and a reader."""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rotmod.io.atomic import atomic_path
from rotmod.errors import ParameterError
from rotmod.io._fits import header_text, open_verified

__all__ = ["FitsImage", "read_image", "write_image"]


def _card_value(v: Any) -> Any:
    """A header value: numbers as they are, text made ASCII-safe and never cut (CONTINUE)."""
    if isinstance(v, str):
        return header_text(v)
    if isinstance(v, bool | int | float) or v is None:
        if isinstance(v, float) and not np.isfinite(v):
            return str(v)
        return "None" if v is None else v
    if isinstance(v, np.generic):
        return _card_value(v.item())
    return json.dumps(v, default=str)


@dataclass
class FitsImage:
    """A sky image read back from FITS.

    Attributes
    ----------
    image : ndarray (ny, nx)
    uncertainty : ndarray (ny, nx) or None
    wcs : astropy.wcs.WCS
    header : astropy.io.fits.Header
        The primary header.
    params : dict
        Reconstruction parameters (from the ``RECPARAM`` JSON cards).
    history : dict of str to ndarray
        Fit history per iteration, when it was stored (``HISTORY`` extension).
    """

    image: np.ndarray
    uncertainty: np.ndarray | None
    wcs: Any
    header: Any
    params: dict[str, Any]
    history: dict[str, np.ndarray]


def write_image(
    path: str | os.PathLike[str],
    result: Any = None,
    *,
    image: Any = None,
    grid: Any = None,
    uncertainty: Any = None,
    bunit: str = "ph s-1 pixel-1",
    meta: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a reconstruction (or a bare image) as FITS.

    Parameters
    ----------
    path : str or PathLike
    result : ReconstructionResult, optional
        Supplies image, uncertainty, grid, method, parameters and history.
    image, grid, uncertainty : optional
        Override or replace the result's (``grid`` is required when the result has none).
    bunit : str
        ``BUNIT`` of the image: the response's sky unit (photon rate per pixel on one
        unobstructed detector face).
    meta : dict, optional
        Extra header cards (long keys become HIERARCH cards).
    overwrite : bool
        Replace an existing file (default False: raise).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ParameterError
        Existing file without ``overwrite``, missing grid, or shapes that do not match.

    Notes
    -----
    The file is written to a temporary name in the same directory and renamed into place,
    so readers never see a partial file.  HDUs: primary (image + WCS), ``UNCERTAINTY``
    (same WCS; only if given), ``HISTORY`` (binary table of the fit statistic per
    iteration; only for results).
    """
    from astropy.io import fits
    from astropy.table import Table

    p = Path(path)
    if p.exists() and not overwrite:
        raise ParameterError(f"path {str(p)!r} exists; pass overwrite=True to replace it")
    img = image if image is not None else (None if result is None else result.image)
    if img is None:
        raise ParameterError("image is required (give a result or image=)")
    img = np.asarray(img, dtype=float)
    g = grid if grid is not None else getattr(result, "grid", None)
    if g is None:
        raise ParameterError("grid is required: the result has no sky grid")
    if img.shape != tuple(g.shape):
        raise ParameterError(f"image must have the grid's shape {g.shape}, got {img.shape}")
    unc = uncertainty if uncertainty is not None else getattr(result, "uncertainty", None)
    # HEALPix grids have no WCS: their image is a table of explicit pixel indices.
    healpix = hasattr(g, "pixels")
    hdr = fits.Header() if healpix else g.wcs().to_header()
    hdr["BUNIT"] = (bunit, "sky units of the response")
    hdr["ORIGIN"] = "rotmod"
    if result is not None:
        hdr["RECMETH"] = (result.method, "reconstruction method")
        hdr["NITER"] = (int(result.n_iter), "iterations")
        hdr["STOPREAS"] = (header_text(str(result.stop_reason)), "stop reason")
        hdr["RUNTIME"] = (float(result.run_time), "[s] reconstruction wall time")
        hdr["CHI2"] = (float(result.chi2), "Pearson chi2 of the final model")
        hdr["DEVIANCE"] = (float(result.deviance), "Poisson deviance of the final model")
        hdr["DOF"] = (int(result.dof), "degrees of freedom")
        hdr["CHI2DOF"] = (float(result.chi2_dof), "chi2 per dof")
        for k, v in sorted(result.params.items()):
            hdr[f"HIERARCH RECPAR {k.upper()}"] = _card_value(v)
        hdr["RECPARAM"] = json.dumps(result.params, default=str)  # whole, via CONTINUE
    for k, v in (meta or {}).items():
        # Short names are standard cards (EXPOSURE, E_MIN, E_MAX, TELESCOP, OBS_ID...).
        key = k.upper() if re.fullmatch(r"[A-Za-z0-9_-]{1,8}", k) else f"HIERARCH {k}"
        hdr[key] = _card_value(v)
    if healpix:
        hdus = [fits.PrimaryHDU(header=hdr), _healpix_hdu(g, img, unc, bunit)]
    else:
        hdus = [fits.PrimaryHDU(img, header=hdr)]
    if unc is not None and not healpix:
        u_arr = np.asarray(unc, dtype=float)
        if u_arr.shape != img.shape:
            raise ParameterError(
                f"uncertainty must have the image's shape {img.shape}, got {u_arr.shape}"
            )
        uh = g.wcs().to_header()
        uh["BUNIT"] = bunit
        uh["EXTNAME"] = "UNCERTAINTY"
        hdus.append(fits.ImageHDU(u_arr, header=uh, name="UNCERTAINTY"))
    if result is not None and result.history:
        t = Table({k: np.asarray(v, dtype=float) for k, v in result.history.items()})
        th = fits.table_to_hdu(t)
        th.name = "HISTORY"
        th.header["PARAMS"] = "see primary RECPAR cards"
        params_json = json.dumps(result.params, default=str)
        for i in range(0, len(params_json), 60):
            th.header.add_comment(params_json[i : i + 60])
        hdus.append(th)
    with atomic_path(p) as tmp:
        fits.HDUList(hdus).writeto(tmp, overwrite=True, checksum=True)
    return p


def _healpix_hdu(grid: Any, img: np.ndarray, unc: Any, bunit: str) -> Any:
    """A HEALPix FITS table (explicit indexing, the convention healpy and gammapy read)."""
    from astropy.io import fits

    cols = [fits.Column("PIXEL", "K", array=np.asarray(grid.pixels, dtype=np.int64)),
            fits.Column("INTENSITY", "D", unit=bunit, array=img.ravel())]
    if unc is not None:
        u_arr = np.asarray(unc, dtype=float)
        if u_arr.shape != img.shape:
            raise ParameterError(
                f"uncertainty must have the image's shape {img.shape}, got {u_arr.shape}"
            )
        cols.append(fits.Column("UNCERTAINTY", "D", unit=bunit, array=u_arr.ravel()))
    tab = fits.BinTableHDU.from_columns(cols, name="HEALPIX")
    h = tab.header
    h["PIXTYPE"] = ("HEALPIX", "HEALPix pixelisation")
    h["ORDERING"] = (grid.order.upper(), "pixel ordering scheme")
    h["NSIDE"] = (grid.nside, "HEALPix resolution parameter")
    h["INDXSCHM"] = ("EXPLICIT", "pixel indices in the PIXEL column")
    h["OBJECT"] = ("PARTIAL", "a cone, not the whole sky")
    h["COORDSYS"] = ("C", "celestial (ICRS)")
    return tab


def read_image(path: str | os.PathLike[str]) -> FitsImage:
    """Read a FITS image written by :func:`write_image` (or any 2-D image with a WCS).

    Raises
    ------
    ParameterError
        Missing file or no 2-D primary image.
    """
    from astropy.wcs import WCS

    p = Path(path)
    with open_verified(p) as hl:
        hdr = hl[0].header.copy()
        if hl[0].data is None or hl[0].data.ndim != 2:
            raise ParameterError(f"path {str(p)!r} has no 2-D primary image")
        img = np.array(hl[0].data, dtype=float)
        unc = np.array(hl["UNCERTAINTY"].data, dtype=float) if "UNCERTAINTY" in hl else None
        hist: dict[str, np.ndarray] = {}
        if "HISTORY" in hl:
            data = hl["HISTORY"].data
            hist = {n: np.array(data[n], dtype=float) for n in data.columns.names}
        params: dict[str, Any] = {}
        for card in hdr.cards:
            if card.keyword.startswith("RECPAR "):
                params[card.keyword[len("RECPAR "):].lower()] = card.value
    return FitsImage(img, unc, WCS(hdr), hdr, params, hist)
