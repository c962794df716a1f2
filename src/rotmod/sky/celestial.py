"""Sky grids on the celestial sphere: images with a true celestial WCS.

A :class:`CelestialGrid` is a tangent-plane (TAN) image centred on any RA/Dec, with the
astronomers' orientation (north up, east left: ``CDELT1 < 0``).  Seen through an
:class:`~rotmod.sky.attitude.Attitude`, each pixel centre is a direction in the instrument
frame, so the grid serves every response operator exactly as a
:class:`~rotmod.sky.grid.SkyGrid` does (``directions()``, ``size``, ``shape``), and images
reconstructed on it are placed on the right part of the sky by astropy, ds9 or gammapy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord
from astropy.wcs import WCS

from rotmod._validate import as_angle_scalar
from rotmod.errors import ParameterError
from rotmod.limits import check_memory
from rotmod.sky.attitude import Attitude
from rotmod.sky.geometry import GRID_KINDS, WcsGeometry

__all__ = ["CelestialGrid"]


@dataclass(frozen=True)
class CelestialGrid(WcsGeometry):
    """A TAN image of ``shape`` pixels of ``pixel_size`` centred on ``(ra, dec)`` (kind
    ``"celestial"``).

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)``.
    pixel_size : float or Quantity
        Pixel side at the centre (deg if plain).
    ra, dec : float or Quantity
        Image centre (ICRS; deg if plain).
    attitude : Attitude
        The instrument's pointing and roll, which turn pixel positions into instrument
        directions.
    """

    kind = "celestial"
    frame = "celestial"

    shape: tuple[int, int]
    pixel_size: Any
    ra: Any
    dec: Any
    attitude: Attitude

    def __post_init__(self) -> None:
        try:
            ny, nx = (int(v) for v in self.shape)
        except (TypeError, ValueError) as exc:
            raise ParameterError(f"grid.shape must be (ny, nx), got {self.shape!r}") from exc
        if ny < 1 or nx < 1 or (ny, nx) != tuple(self.shape):
            raise ParameterError(f"grid.shape must be two integers >= 1, got {self.shape!r}")
        object.__setattr__(self, "shape", (ny, nx))
        pix = np.degrees(as_angle_scalar(self.pixel_size, "grid.pixel_size", lo=0.0,
                                         lo_open=True))
        object.__setattr__(self, "pixel_size", float(pix))
        object.__setattr__(self, "ra", float(np.degrees(as_angle_scalar(self.ra, "grid.ra"))))
        object.__setattr__(self, "dec", float(np.degrees(
            as_angle_scalar(self.dec, "grid.dec", lo=-90.0, hi=90.0))))
        if not isinstance(self.attitude, Attitude):
            raise ParameterError(f"grid.attitude must be an Attitude, got {type(self.attitude)}")
        check_memory(6 * 8.0 * nx * ny, f"a celestial grid of {ny} x {nx} pixels",
                     hint="use larger pixels or a smaller field")

    @classmethod
    def around(cls, center: SkyCoord, shape: tuple[int, int], pixel_size: Any,
               attitude: Attitude) -> CelestialGrid:
        """The grid centred on ``center``, a SkyCoord in any frame (taken to ICRS).

        Raises
        ------
        ParameterError
            ``center`` is not one SkyCoord, or a field is invalid.
        """
        if not isinstance(center, SkyCoord) or not center.isscalar:
            raise ParameterError(f"center must be one astropy SkyCoord, got {center!r}")
        icrs = center.icrs
        return cls(shape, pixel_size, icrs.ra, icrs.dec, attitude)

    @property
    def size(self) -> int:
        """Number of pixels ``n_sky``."""
        return self.shape[0] * self.shape[1]

    def wcs(self) -> WCS:
        """The image's celestial WCS (ICRS, TAN, east left)."""
        ny, nx = self.shape
        w = WCS(naxis=2)
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.cunit = ["deg", "deg"]
        w.wcs.radesys = "ICRS"
        w.wcs.crval = [self.ra, self.dec]
        w.wcs.cdelt = [-self.pixel_size, self.pixel_size]
        w.wcs.crpix = [(nx + 1) / 2, (ny + 1) / 2]
        return w

    def sky_coords(self) -> SkyCoord:
        """Pixel centres on the sky, flattened (n_sky,) in C order (row ``iy``, column ``ix``)."""
        ny, nx = self.shape
        iy, ix = np.mgrid[0:ny, 0:nx]
        return self.wcs().pixel_to_world(ix.ravel(), iy.ravel())

    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) of every pixel centre in the instrument frame."""
        return self.attitude.to_instrument(self.sky_coords())

    def to_dict(self) -> dict[str, Any]:
        """Plain description (deg) for metadata; :meth:`from_dict` reads it back."""
        a = self.attitude
        return {
            "kind": self.kind, "shape": list(self.shape), "pixel_size": self.pixel_size,
            "ra": self.ra, "dec": self.dec,
            "attitude": {"ra": a.ra, "dec": a.dec, "roll": a.roll},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CelestialGrid:
        """Inverse of :meth:`to_dict`."""
        return cls(tuple(d["shape"]), d["pixel_size"], d["ra"], d["dec"],
                   Attitude(**d["attitude"]))


GRID_KINDS.register(CelestialGrid.kind, CelestialGrid)
