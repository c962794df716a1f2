"""Square tangent-plane (gnomonic) sky grids in the instrument frame, tangent anywhere.

The instrument frame is drawn on a sphere of its own, longitude and latitude (``XLON``,
``XLAT`` in FITS), with the pointing axis (lab +z) at ``(0, 0)``, the lab +x axis toward +XLON
and +y toward +XLAT, i.e. a lab vector ``(x, y, z)`` is the spherical vector
``(X, Y, Z) = (z, x, y)`` (these are RA/Dec-like coordinates, but of the instrument, not of
the sky: images say so in their WCS, :meth:`SkyGrid.wcs`).  By default the projection is
tangent at the axis: a direction at zenith ``theta`` and azimuth ``phi`` has tangent-plane
coordinates (degrees)

    x = (180/pi) tan(theta) cos(phi),   y = (180/pi) tan(theta) sin(phi).

A grid may instead be tangent at any direction ``(theta0, phi0)`` (``tangent=``), e.g. the
centre of a field 48 deg off axis, where an axis-tangent grid would stretch its pixels by
``1/cos^2 theta0`` radially.  With ``n0`` the tangent direction and ``e_x``, ``e_y`` the unit
vectors toward +XLON and +XLAT there, the pixel at tangent-plane coordinates ``(x, y)`` (rad)
looks along ``n0 + x e_x + y e_y`` (the re-centred gnomonic projection).  These are exactly
the FITS ``TAN`` intermediate world coordinates about ``CRVAL`` = the tangent point, so the
WCS written with the images places every pixel where the response computed it (tested
against astropy).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.wcs import WCS

from rotmod._validate import as_angle, as_scalar
from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.limits import check_memory
from rotmod.sky.geometry import GRID_KINDS, WcsGeometry

__all__ = ["INSTRUMENT_LAT", "INSTRUMENT_LON", "INSTRUMENT_WCSNAME", "SkyGrid"]

#: CTYPE prefixes of the instrument frame's longitude and latitude (FITS user-defined
#: ``xLON``/``xLAT`` pair): non-celestial spherical axes.
INSTRUMENT_LON, INSTRUMENT_LAT = "XLON", "XLAT"
#: WCSNAME of instrument-frame images.
INSTRUMENT_WCSNAME = "rotmod instrument frame"


@dataclass(frozen=True)
class SkyGrid(WcsGeometry):
    """A square-pixel tangent-plane grid in the instrument frame (kind ``"instrument"``).

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` number of pixels; images are ``image[iy, ix]`` and flattened sky
        vectors use C order (``n = iy * nx + ix``).
    pixel_size : float or Quantity
        Pixel side (deg if a plain number), > 0.
    center : (float, float) or Quantity
        Tangent-plane coordinates ``(x, y)`` of the field centre (deg); default the tangent
        point.
    tangent : (float, float) or Quantity
        Instrument direction ``(theta, phi)`` (deg) where the projection plane touches the
        sky (``0 <= theta < 90``); default the rotation axis.
    """

    kind = "instrument"
    frame = "instrument"

    shape: tuple[int, int]
    pixel_size: float
    center: tuple[float, float] = (0.0, 0.0)
    tangent: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        try:
            ny, nx = (int(v) for v in self.shape)
        except (TypeError, ValueError) as exc:
            raise ParameterError(f"grid.shape must be (ny, nx), got {self.shape!r}") from exc
        if ny < 1 or nx < 1 or (ny, nx) != tuple(self.shape):
            raise ParameterError(f"grid.shape must be two integers >= 1, got {self.shape!r}")
        object.__setattr__(self, "shape", (ny, nx))
        pix = as_scalar(self.pixel_size, "grid.pixel_size", u.deg, lo=0.0, lo_open=True)
        object.__setattr__(self, "pixel_size", pix)
        cx = as_scalar(self.center[0], "grid.center[0]", u.deg)
        cy = as_scalar(self.center[1], "grid.center[1]", u.deg)
        object.__setattr__(self, "center", (cx, cy))
        try:
            t_theta, t_phi = self.tangent
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"grid.tangent must be (theta, phi) in deg, got {self.tangent!r}") from exc
        t_theta = float(np.degrees(as_angle(t_theta, "grid.tangent[0]", lo=0.0, hi=90.0,
                                            hi_open=True)))
        t_phi = float(np.degrees(as_angle(t_phi, "grid.tangent[1]")))
        object.__setattr__(self, "tangent", (t_theta, t_phi))
        half = np.degrees(np.arctan(1e3))  # theta < 89.94 deg: keep tan(theta) finite
        if max(abs(cx) + nx * pix / 2, abs(cy) + ny * pix / 2) > 180 / np.pi * 1e3:
            raise ParameterError(f"grid extends beyond theta = {half:.2f} deg; shrink it")

    def _basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lab unit vectors ``n0`` (the tangent point), ``e_x`` (+XLON) and ``e_y`` (+XLAT)
        there."""
        n0 = source_direction(*np.radians(self.tangent))
        ra0, dec0 = self._tangent_radec()
        ra0, dec0 = np.radians(ra0), np.radians(dec0)
        # Spherical (X, Y, Z) = lab (z, x, y): +XLON = (-sin a, cos a, 0), +XLAT = (-sin d
        # cos a, -sin d sin a, cos d) in spherical axes.
        ex = np.array([np.cos(ra0), 0.0, -np.sin(ra0)])
        ey = np.array([-np.sin(dec0) * np.sin(ra0), np.cos(dec0), -np.sin(dec0) * np.cos(ra0)])
        return n0, ex, ey

    def _tangent_radec(self) -> tuple[float, float]:
        """The tangent point in the instrument frame's longitude and latitude (deg)."""
        x, y, z = source_direction(*np.radians(self.tangent))
        return float(np.degrees(np.arctan2(x, z))), float(np.degrees(np.arcsin(y)))

    @classmethod
    def paper(cls) -> SkyGrid:
        """The seed paper's grid: 14 deg field in 12 arcmin pixels (70 x 70 = 4900)."""
        return cls((70, 70), 0.2)

    @classmethod
    def square(cls, fov: Any, pixel_size: Any, center: tuple[float, float] = (0.0, 0.0), *,
               tangent: tuple[float, float] = (0.0, 0.0)) -> SkyGrid:
        """A square field of side ``fov`` (deg) in pixels of ``pixel_size`` (deg), centred
        ``center`` (deg) from the tangent point ``tangent`` (an instrument direction)."""
        f = as_scalar(fov, "grid.fov", u.deg, lo=0.0, lo_open=True)
        p = as_scalar(pixel_size, "grid.pixel_size", u.deg, lo=0.0, lo_open=True)
        n = max(1, round(f / p))
        return cls((n, n), p, center, tangent)

    @property
    def size(self) -> int:
        """Number of pixels ``n_sky``."""
        return self.shape[0] * self.shape[1]

    def pixel_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """Tangent-plane coordinates ``(x, y)`` (deg) of pixel centres, each shape (ny, nx)."""
        ny, nx = self.shape
        # x, y here and theta, phi in directions(): four float64 values per pixel.
        check_memory(4 * 8.0 * nx * ny, f"a sky grid of {ny} x {nx} pixels",
                     hint="use larger pixels or a smaller field")
        x = self.center[0] + (np.arange(nx) - (nx - 1) / 2) * self.pixel_size
        y = self.center[1] + (np.arange(ny) - (ny - 1) / 2) * self.pixel_size
        return np.meshgrid(x, y)

    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) of every pixel centre, flattened (n_sky,).

        Raises
        ------
        ParameterError
            If a pixel looks at or below the detector plane (theta >= 90 deg).
        """
        theta, phi = self.from_tangent(*(v.ravel() for v in self.pixel_centers()))
        if theta.size and np.max(theta) >= 0.5 * np.pi * u.rad:
            raise ParameterError(
                f"grid: pixels reach theta = {np.max(theta).to_value(u.deg):.4g} deg, at or "
                "below the detector plane; shrink the field or move its tangent point")
        return theta, phi

    def to_tangent(self, theta: Any, phi: Any) -> tuple[np.ndarray, np.ndarray]:
        """Tangent-plane coordinates (deg) of directions ``(theta, phi)`` (deg if plain);
        NaN for directions 90 deg or more from the tangent point."""
        th, ph = as_angle(theta, "theta"), as_angle(phi, "phi")
        if self.tangent[0] == 0.0:  # tangent at the axis: the closed forms
            t = np.tan(th)
            return np.degrees(t * np.cos(ph)), np.degrees(t * np.sin(ph))
        d = source_direction(th, ph)
        n0, ex, ey = self._basis()
        dn = d @ n0
        with np.errstate(divide="ignore", invalid="ignore"):
            dn = np.where(dn > 0.0, dn, np.nan)
            return np.degrees((d @ ex) / dn), np.degrees((d @ ey) / dn)

    def from_tangent(self, x: Any, y: Any) -> tuple[u.Quantity, u.Quantity]:
        """Directions ``(theta, phi)`` (Quantities, rad) of tangent-plane coordinates (deg)."""
        xr, yr = as_angle(x, "x"), as_angle(y, "y")
        if self.tangent[0] == 0.0:  # tangent at the axis: the closed forms
            return np.arctan(np.hypot(xr, yr)) * u.rad, np.arctan2(yr, xr) * u.rad
        n0, ex, ey = self._basis()
        theta, phi = source_angles(n0 + xr[..., None] * ex + yr[..., None] * ey)
        return theta * u.rad, phi * u.rad

    def wcs(self) -> WCS:
        """An `astropy.wcs.WCS` (TAN) for images on this grid (see module notes).

        The axes are ``XLON-TAN``/``XLAT-TAN``, a user-defined spherical coordinate pair of
        the FITS standard (Calabretta & Greisen 2002, sec. 2), named ``WCSNAME = 'rotmod
        instrument frame'``: longitude and latitude of the instrument frame drawn on the
        sphere, with no ``RADESYS`` -- not RA and Dec, so astropy, ds9 and gammapy do not
        place the image on the celestial sky (an instrument-frame image has no sky position
        without the attitude; :class:`~rotmod.sky.CelestialGrid` images have one).  Longitude
        increases with ``+x`` (``CDELT1 > 0``: lab +x to the right, +y up).
        """
        ny, nx = self.shape
        w = WCS(naxis=2)
        w.wcs.ctype = [f"{INSTRUMENT_LON}-TAN", f"{INSTRUMENT_LAT}-TAN"]
        w.wcs.name = INSTRUMENT_WCSNAME
        w.wcs.cunit = ["deg", "deg"]
        w.wcs.crval = list(self._tangent_radec())
        w.wcs.cdelt = [self.pixel_size, self.pixel_size]
        # Pixel (1-based FITS) whose centre is the tangent point (x, y) = (0, 0).
        w.wcs.crpix = [
            (nx + 1) / 2 - self.center[0] / self.pixel_size,
            (ny + 1) / 2 - self.center[1] / self.pixel_size,
        ]
        return w

    def to_dict(self) -> dict[str, Any]:
        """Plain description (deg) for metadata."""
        return {
            "shape": list(self.shape),
            "pixel_size": self.pixel_size,
            "center": list(self.center),
            "tangent": list(self.tangent),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SkyGrid:
        """Inverse of :meth:`to_dict` (grids stored before ``tangent`` existed are tangent at
        the axis)."""
        return cls(tuple(d["shape"]), d["pixel_size"], tuple(d["center"]),
                   tuple(d.get("tangent", (0.0, 0.0))))


GRID_KINDS.register(SkyGrid.kind, SkyGrid)
