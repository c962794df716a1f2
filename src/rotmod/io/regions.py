"""Localisation regions as files: DS9 region files and HEALPix probability maps.

* :func:`write_ds9` -- a DS9 region file (ICRS) with, per source, a ``point`` at the best
  position and the ``polygon`` outlines of its 90 % and 68 % regions
  (:meth:`rotmod.sources.Region.contour`), each labelled.  Only sources on the sky: an
  instrument-frame position has no place on the sky without the attitude, and DS9 has no
  frame for it (its ``image``/``physical`` frames are pixels of one image), so instrument-frame
  regions are refused with a message rather than written in a pseudo-sky frame that ds9 would
  place on the real sky.
* :class:`HealpixProbability`, :func:`write_probability_map`, :func:`read_probability_map` --
  a source's position probability as a partial-sky HEALPix FITS table with explicit pixel
  indices (columns ``PIXEL``, ``PROB``; ``ORDERING``, ``NSIDE``, ``INDXSCHM = 'EXPLICIT'``,
  ``OBJECT = 'PARTIAL'``, ``COORDSYS = 'C'``), the form ``healpy.read_map(...,
  partial=True)`` reads (pixels outside it are ``UNSEEN``).  The probabilities sum to 1.
  :func:`rotmod.sources.catalogue.probability_map` computes one from a region.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from astropy.coordinates import SkyCoord
from astropy.io import fits

from rotmod.errors import ParameterError
from rotmod.io._fits import open_verified
from rotmod.io.atomic import atomic_path, check_overwrite, write_text
from rotmod.io.images import stamp_header
from rotmod.io.provenance import creator
from rotmod.sky.healpix import add_healpix_cards

if TYPE_CHECKING:
    from rotmod.sources import Region

__all__ = ["HealpixProbability", "read_probability_map", "write_ds9",
           "write_probability_map"]

#: ``EXTNAME`` of a probability map's table.
PROB_EXTNAME = "PROBMAP"
#: The outlines of each source in a DS9 file: containment -> (colour, dashed).
DS9_LEVELS = {0.9: ("green", 0), 0.68: ("cyan", 1)}


def _ds9_text(text: str) -> str:
    """A label DS9 keeps whole: braces delimit it, so none inside."""
    return text.replace("{", "(").replace("}", ")")


def write_ds9(regions: Sequence[Region], path: str | os.PathLike, *,
              overwrite: bool = False) -> Path:
    """Write the localisation regions of sources on the sky as a DS9 region file (ICRS).

    Per source: a ``point`` (cross) at the position labelled with its name, and the
    ``polygon`` outline(s) of its 90 % (green) and 68 % (cyan, dashed) regions labelled
    ``NAME 90%`` / ``NAME 68%``.

    Parameters
    ----------
    regions : sequence of Region
        Regions of sources on the sky (``None`` entries, sources not localised, are left
        out).
    path : str or path-like
    overwrite : bool
        Replace an existing file (default: refuse).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ParameterError
        An existing file without ``overwrite``, or a region of an instrument-frame source.
    """
    p = check_overwrite(path, overwrite)
    kept = [r for r in regions if r is not None]
    for r in kept:
        if r.source.frame != "celestial":
            raise ParameterError(
                f"regions: source {r.source.name or '(unnamed)'!r} is in the instrument frame "
                "(theta, phi), which has no place on the sky without the attitude; DS9 region "
                "files are written for sources on the sky (a celestial or HEALPix grid)")
    lines = ["# Region file format: DS9 version 4.1",
             f"# {creator()}: localisation regions, the best position (point) and the "
             f"{' and '.join(f'{q:.0%}' for q in DS9_LEVELS)} containment outlines (polygons)",
             'global color=green width=1 font="helvetica 10 normal roman" select=1 '
             "highlite=1 dash=0 fixed=0 edit=1 move=1 delete=1 include=1 source=1",
             "icrs"]
    for k, r in enumerate(kept):
        name = _ds9_text(r.source.name or f"source {k}")
        pos = r.source.position
        lines.append(f"point({pos.ra.deg:.7f},{pos.dec.deg:+.7f}) # point=cross "
                     f"text={{{name}}}")
        for q, (colour, dash) in DS9_LEVELS.items():
            for poly in r.contour(q):
                c: SkyCoord = poly
                ra, dec = np.round(c.ra.deg, 7), np.round(c.dec.deg, 7)
                # Vertices as written, each once: contour lines repeat a vertex where they
                # cross a grid line, and end where they start (DS9 closes polygons itself).
                new = np.r_[True, (np.diff(ra) != 0) | (np.diff(dec) != 0)]
                ra, dec = ra[new], dec[new]
                if ra.size > 1 and ra[0] == ra[-1] and dec[0] == dec[-1]:
                    ra, dec = ra[:-1], dec[:-1]
                if ra.size < 3:
                    continue
                pts = ",".join(f"{a:.7f},{b:+.7f}" for a, b in zip(ra, dec, strict=True))
                lines.append(f"polygon({pts}) # color={colour} dash={dash} "
                             f"text={{{name} {q:.0%}}}")
    return write_text(p, "\n".join(lines) + "\n")


@dataclass(frozen=True)
class HealpixProbability:
    """A position's probability on HEALPix pixels (ICRS).

    Attributes
    ----------
    nside : int
        HEALPix resolution (a power of 2).
    pixels : ndarray of int64
        The pixels with probability, increasing.
    prob : ndarray
        Probability of each pixel (sums to 1).
    order : {"nested", "ring"}
    name : str
        The source's name.
    """

    nside: int
    pixels: np.ndarray
    prob: np.ndarray
    order: str = "nested"
    name: str = ""

    def __post_init__(self) -> None:
        nside = int(self.nside)
        if nside < 1 or nside & (nside - 1):
            raise ParameterError(f"nside must be a power of 2, got {self.nside}")
        if self.order not in ("nested", "ring"):
            raise ParameterError(f"order must be 'nested' or 'ring', got {self.order!r}")
        pix = np.asarray(self.pixels, dtype=np.int64).ravel()
        prob = np.asarray(self.prob, dtype=float).ravel()
        if pix.shape != prob.shape or pix.size == 0:
            raise ParameterError(f"pixels and prob must be of one length >= 1, got "
                                 f"{pix.size} and {prob.size}")
        if np.any((pix < 0) | (pix >= 12 * nside**2)) or np.unique(pix).size != pix.size:
            raise ParameterError(f"pixels must be distinct HEALPix indices of nside {nside}")
        if not np.all(np.isfinite(prob)) or np.any(prob < 0) or \
                not np.isclose(prob.sum(), 1.0, rtol=1e-9, atol=0):
            raise ParameterError(f"prob must be finite, >= 0 and sum to 1, got sum "
                                 f"{prob.sum()!r}")
        order = np.argsort(pix)
        object.__setattr__(self, "nside", nside)
        object.__setattr__(self, "pixels", pix[order])
        object.__setattr__(self, "prob", prob[order])


def write_probability_map(
    prob: HealpixProbability, path: str | os.PathLike, *, overwrite: bool = False,
    seed: Any = None, command: str | Sequence[str] | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    """Write a probability map as a partial-sky HEALPix FITS table (module notes).

    Parameters
    ----------
    prob : HealpixProbability
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
        An existing file without ``overwrite``.
    """
    p = check_overwrite(path, overwrite)
    primary = fits.PrimaryHDU()
    table = fits.BinTableHDU.from_columns(
        [fits.Column("PIXEL", "K", array=prob.pixels),
         fits.Column("PROB", "D", unit="", array=prob.prob)], name=PROB_EXTNAME)
    for h in (primary.header, table.header):
        stamp_header(h, seed=seed, command=command, meta=meta)
    h = table.header
    add_healpix_cards(h, prob.nside, prob.order)
    h["INDXSCHM"] = ("EXPLICIT", "pixel indices in the PIXEL column")
    h["OBJECT"] = ("PARTIAL", "a part of the sky; no probability elsewhere")
    h["HDUCLAS1"] = ("PROBMAP", "position probability of a source")
    h["SRCNAME"] = (prob.name, "the source")
    with atomic_path(p) as tmp:
        fits.HDUList([primary, table]).writeto(tmp, overwrite=True, checksum=True)
    return p


def read_probability_map(path: str | os.PathLike) -> HealpixProbability:
    """Read a probability map written by :func:`write_probability_map`.

    Raises
    ------
    RotmodError
        A missing, unreadable or corrupt file.
    ParameterError
        A file without the ``PROBMAP`` table.
    """
    p = Path(path)
    with open_verified(p) as hl:
        if PROB_EXTNAME not in hl:
            raise ParameterError(f"path {str(p)!r} is not a probability map: no "
                                 f"{PROB_EXTNAME} extension")
        hdu = hl[PROB_EXTNAME]
        h = hdu.header
        return HealpixProbability(int(h["NSIDE"]), np.array(hdu.data["PIXEL"]),
                                  np.array(hdu.data["PROB"], dtype=float),
                                  str(h["ORDERING"]).lower(), str(h.get("SRCNAME", "")))
