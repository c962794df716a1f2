"""FITS images of reconstructions: the image and its uncertainty in the grid's FITS form (a
primary image with the grid's WCS, or a pixel table; see :mod:`rotmod.sky.geometry`),
parameters and fit history in the header; an atomic writer and a reader."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from astropy.io import fits
from astropy.table import Table

from rotmod.errors import ParameterError
from rotmod.io._fits import header_text, open_verified
from rotmod.io.atomic import atomic_path, check_overwrite
from rotmod.io.provenance import fitting_comment, provenance_cards
from rotmod.sky.geometry import SkyGeometry, image_from_hdus

__all__ = ["FitsImage", "add_meta_cards", "read_image", "write_image"]


#: Comments (OGIP ``[unit]`` first) of the standard cards a caller passes in ``meta``.
_META_COMMENTS = {
    "EXPOSURE": "[s] exposure",
    "ONTIME": "[s] sum of good time intervals",
    "LIVETIME": "[s] live time",
    "TSTART": "[s] start of the observation",
    "TSTOP": "[s] end of the observation",
    "E_MIN": "[keV] low edge of the energy band",
    "E_MAX": "[keV] high edge of the energy band",
    "TELESCOP": "mission or telescope",
    "INSTRUME": "instrument",
}


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


def add_meta_cards(hdr: Any, meta: dict[str, Any] | None) -> None:
    """Add a caller's ``meta`` to a FITS header: short names as standard cards (``EXPOSURE``,
    ``E_MIN``, ``TELESCOP``, ``OBS_ID``, ... with their unit in the comment), long ones as
    HIERARCH cards; every product writer of rotmod names its extra cards this way."""
    for k, v in (meta or {}).items():
        key = k.upper() if re.fullmatch(r"[A-Za-z0-9_-]{1,8}", k) else f"HIERARCH {k}"
        value = _card_value(v)
        hdr[key] = (value, fitting_comment(key, value, _META_COMMENTS.get(key, "")))


def stamp_header(hdr: Any, *, seed: Any = None, command: Any = None,
                 meta: dict[str, Any] | None = None, cards: Any = None) -> None:
    """Stamp a product's FITS header: ``ORIGIN``, the provenance cards
    (:func:`~rotmod.io.provenance.provenance_cards` of ``seed`` and ``command``, or the given
    ``cards``) and the caller's ``meta`` (:func:`add_meta_cards`)."""
    hdr["ORIGIN"] = ("rotmod", "organisation or software that made the file")
    for key, value, comment in (provenance_cards(seed=seed, command=command) if cards is None
                                else cards):
        hdr[key] = (value, comment)
    add_meta_cards(hdr, meta)


@dataclass
class FitsImage:
    """A sky image read back from FITS.

    Attributes
    ----------
    image : ndarray (ny, nx)
        ``(1, n_sky)`` for a pixel table (e.g. a HEALPix image).
    uncertainty : ndarray (ny, nx) or None
    wcs : astropy.wcs.WCS or None
        None for a pixel table.
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
    grid: SkyGeometry | None = None,
    uncertainty: Any = None,
    bunit: str = "ph s-1 pixel-1",
    meta: dict[str, Any] | None = None,
    seed: Any = None,
    command: str | Sequence[str] | None = None,
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
        Extra header cards (long keys become HIERARCH cards); ``TELESCOP``/``INSTRUME``
        here replace the default ``rotmod``, and the standard ``EXPOSURE`` (s), ``E_MIN``,
        ``E_MAX`` (keV) carry their unit in the comment.
    seed : int, SeedSequence or Generator, optional
        The randomness of the run (the ``SEED`` card).
    command : str or sequence of str, optional
        The command line or parameters that made the image (the ``COMMAND`` card).
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
    so readers never see a partial file.  HDUs: the image in the grid's form
    (:meth:`~rotmod.sky.SkyGeometry.image_hdus`: primary image + WCS and an ``UNCERTAINTY``
    image if given, or an empty primary and a pixel table), then ``HISTORY`` (binary table
    of the fit statistic per iteration; only for results).
    """
    p = check_overwrite(path, overwrite)
    img = image if image is not None else (None if result is None else result.image)
    if img is None:
        raise ParameterError("image is required (give a result or image=)")
    img = np.asarray(img, dtype=float)
    g = grid if grid is not None else getattr(result, "grid", None)
    if g is None:
        raise ParameterError("grid is required: the result has no sky grid")
    if not isinstance(g, SkyGeometry):
        raise ParameterError(f"grid must be a sky grid (a SkyGeometry), got {type(g).__name__}")
    if img.shape != tuple(g.shape):
        raise ParameterError(f"image must have the grid's shape {g.shape}, got {img.shape}")
    unc = uncertainty if uncertainty is not None else getattr(result, "uncertainty", None)
    if unc is not None:
        unc = np.asarray(unc, dtype=float)
        if unc.shape != img.shape:
            raise ParameterError(
                f"uncertainty must have the image's shape {img.shape}, got {unc.shape}"
            )
    hdus = g.image_hdus(img, unc, bunit)
    hdr = hdus[0].header
    stamp_header(hdr, seed=seed, command=command)
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
    add_meta_cards(hdr, meta)
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


def read_image(path: str | os.PathLike[str]) -> FitsImage:
    """Read a FITS image written by :func:`write_image` (or any 2-D image with a WCS).

    Raises
    ------
    ParameterError
        Missing file, or neither a 2-D primary image nor a pixel table.
    """
    p = Path(path)
    with open_verified(p) as hl:
        hdr = hl[0].header.copy()
        img, unc, wcs = image_from_hdus(hl, str(p))
        hist: dict[str, np.ndarray] = {}
        if "HISTORY" in hl:
            data = hl["HISTORY"].data
            hist = {n: np.array(data[n], dtype=float) for n in data.columns.names}
        params: dict[str, Any] = {}
        for card in hdr.cards:
            if card.keyword.startswith("RECPAR "):
                params[card.keyword[len("RECPAR "):].lower()] = card.value
    return FitsImage(img, unc, wcs, hdr, params, hist)
