"""Extended sources on the sky, as many point sources: a uniform disc or a 2-D Gaussian.

Both are sampled deterministically on a sunflower (Vogel) spiral: point ``k`` of ``n`` sits at
position angle ``k`` times the golden angle and at the radius that encloses a fraction
``(k + 1/2)/n`` of the source's flux, so ``n`` equal-flux points tile the shape evenly without
random clumps.  With ``PointSources.from_sky(points, attitude, rate=total / n)`` an extended
source goes through the same simulation, folding and imaging path as a point source.
"""

from __future__ import annotations

from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod._validate import as_angle_scalar, as_int
from rotmod.errors import ParameterError

__all__ = ["disc_points", "gaussian_points"]

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))


def _spiral(center: SkyCoord, radii_deg: np.ndarray) -> SkyCoord:
    if not isinstance(center, SkyCoord) or not center.isscalar:
        raise ParameterError(f"center must be one astropy SkyCoord, got {center!r}")
    k = np.arange(radii_deg.size)
    pa = np.degrees(k * _GOLDEN) % 360.0
    return center.directional_offset_by(pa * u.deg, radii_deg * u.deg)


def disc_points(center: SkyCoord, radius: Any, n: int = 64) -> SkyCoord:
    """``n`` equal-flux points filling a uniform disc of angular ``radius`` (deg if plain)."""
    r = np.degrees(as_angle_scalar(radius, "radius", lo=0.0, lo_open=True, hi=90.0))
    n = as_int(n, "n", 1)
    return _spiral(center, r * np.sqrt((np.arange(n) + 0.5) / n))


def gaussian_points(center: SkyCoord, sigma: Any, n: int = 64) -> SkyCoord:
    """``n`` equal-flux points of a circular 2-D Gaussian of width ``sigma`` (deg if plain)."""
    s = np.degrees(as_angle_scalar(sigma, "sigma", lo=0.0, lo_open=True, hi=30.0))
    n = as_int(n, "n", 1)
    # Rayleigh radius enclosing a flux fraction q: sigma sqrt(-2 ln(1 - q)).
    q = (np.arange(n) + 0.5) / n
    return _spiral(center, s * np.sqrt(-2.0 * np.log1p(-q)))
