"""Where the instrument points: from celestial coordinates to the instrument frame and back.

An :class:`Attitude` is the pointing of the rotation axis (RA, Dec) and the *roll*, the
position angle (east of north) of the instrument's +y axis on the sky.  The instrument frame
is rotmod's lab frame (:mod:`rotmod.conventions`): +z along the rotation axis toward the sky,
and, seen by an observer looking out along +z, +x toward the east when the roll is 0 (x, y, z
= east, north, up is right-handed).  A source at zenith ``theta`` and azimuth ``phi`` then lies
``theta`` from the pointing at position angle

    PA = roll + 90 deg - phi        (equivalently phi = roll + 90 deg - PA).

Every transformation goes through :class:`astropy.coordinates.SkyOffsetFrame` (origin = the
pointing, ``rotation`` = the roll), which is exact everywhere, the celestial poles included.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import ICRS, SkyCoord, SkyOffsetFrame

from rotmod._validate import as_angle, as_angle_scalar
from rotmod.errors import ParameterError

__all__ = ["Attitude"]


@dataclass(frozen=True)
class Attitude:
    """A fixed pointing and roll of the instrument.

    Parameters
    ----------
    ra, dec : float or Quantity
        Direction of the rotation axis (ICRS; deg if plain numbers), ``-90 <= dec <= 90``.
    roll : float or Quantity
        Position angle (east of north) of the instrument's +y axis (deg if plain).

    Examples
    --------
    >>> att = Attitude(ra=83.63, dec=22.01, roll=30.0)
    >>> theta, phi = att.to_instrument(SkyCoord(84.0 * u.deg, 23.0 * u.deg))
    """

    ra: Any
    dec: Any
    roll: Any = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "ra", np.degrees(as_angle_scalar(self.ra, "attitude.ra")))
        object.__setattr__(
            self, "dec", np.degrees(as_angle_scalar(self.dec, "attitude.dec", lo=-90, hi=90))
        )
        object.__setattr__(self, "roll", np.degrees(as_angle_scalar(self.roll, "attitude.roll")))

    @property
    def pointing(self) -> SkyCoord:
        """The rotation axis on the sky (ICRS)."""
        return SkyCoord(self.ra * u.deg, self.dec * u.deg, frame="icrs")

    @property
    def frame(self) -> SkyOffsetFrame:
        """The sky frame centred on the pointing with its latitude axis along instrument +y."""
        return SkyOffsetFrame(origin=self.pointing.frame, rotation=self.roll * u.deg)

    def to_instrument(self, coords: SkyCoord) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) of sky positions in the instrument frame.

        Raises
        ------
        ParameterError
            ``coords`` is not a SkyCoord.
        """
        if not isinstance(coords, SkyCoord):
            raise ParameterError(f"coords must be an astropy SkyCoord, got {type(coords)}")
        c = coords.transform_to(self.frame).cartesian
        # Offset frame: x toward the pointing, y toward +longitude (east at roll 0), z toward
        # +latitude (the roll's direction).  Instrument (x, y, z) = offset (y, z, x): a cyclic
        # permutation, so both are right-handed.
        x, y, z = (np.asarray(getattr(c, k).value, dtype=float) for k in ("y", "z", "x"))
        theta = np.arctan2(np.hypot(x, y), z)
        phi = np.arctan2(y, x)
        return theta * u.rad, phi * u.rad

    def to_sky(self, theta: Any, phi: Any) -> SkyCoord:
        """Sky positions (ICRS) of instrument directions ``(theta, phi)`` (deg if plain)."""
        th = as_angle(theta, "theta", lo=0.0, hi=180.0)
        ph = as_angle(phi, "phi")
        th, ph = np.broadcast_arrays(th, ph)
        st = np.sin(th)
        offset = SkyCoord(
            x=np.cos(th), y=st * np.cos(ph), z=st * np.sin(ph), representation_type="cartesian",
            frame=self.frame,
        )
        out = offset.transform_to(ICRS())
        return SkyCoord(out.ra, out.dec, frame="icrs")
