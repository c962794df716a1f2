"""Lists of single directions as sky geometries: where a source model asks for its columns.

A point source sits at a continuous position, not on a pixel.  Its response column is the
response of a one-pixel "grid" at that position, so a list of positions is a sky geometry
like any other (kind ``"directions"`` in the instrument frame, ``"positions"`` on the sky
through an attitude), and every response operator, spec and metadata path takes it
unchanged.  Images on them are pixel tables of shape ``(1, n)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod._validate import as_angle
from rotmod.errors import ParameterError
from rotmod.sky.attitude import Attitude
from rotmod.sky.geometry import GRID_KINDS, SkyGeometry

__all__ = ["DirectionList", "PositionList"]


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=float).ravel()
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class DirectionList(SkyGeometry):
    """Directions in the instrument frame (kind ``"directions"``).

    Parameters
    ----------
    theta, phi : array_like or Quantity, shape (n,)
        Zenith (``0 <= theta < 90`` deg: in front of the detectors) and azimuth (deg if
        plain numbers).  Held in degrees.
    """

    kind = "directions"
    frame = "instrument"

    theta: Any
    phi: Any

    def __post_init__(self) -> None:
        th = np.atleast_1d(np.degrees(as_angle(self.theta, "theta", lo=0.0, hi=90.0,
                                               hi_open=True)))
        ph = np.atleast_1d(np.degrees(as_angle(self.phi, "phi")))
        if th.shape != ph.shape or th.ndim != 1 or th.size == 0:
            raise ParameterError(f"theta and phi must be 1-D of one equal length >= 1, got "
                                 f"shapes {th.shape} and {ph.shape}")
        object.__setattr__(self, "theta", _frozen(th))
        object.__setattr__(self, "phi", _frozen(ph))

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, DirectionList) and np.array_equal(self.theta, other.theta)
                and np.array_equal(self.phi, other.phi))

    __hash__ = None  # type: ignore[assignment]

    @property
    def size(self) -> int:
        """Number of directions."""
        return int(self.theta.size)

    @property
    def shape(self) -> tuple[int, int]:
        """``(1, size)``: a list of pixels."""
        return (1, self.size)

    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad)."""
        return np.radians(self.theta) * u.rad, np.radians(self.phi) * u.rad

    def to_dict(self) -> dict[str, Any]:
        """Plain description (deg)."""
        return {"kind": self.kind, "theta": self.theta.tolist(), "phi": self.phi.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DirectionList:
        """Inverse of :meth:`to_dict`."""
        return cls(d["theta"], d["phi"])


@dataclass(frozen=True, eq=False)
class PositionList(SkyGeometry):
    """Positions on the sky (ICRS) seen through an attitude (kind ``"positions"``).

    Parameters
    ----------
    ra, dec : array_like or Quantity, shape (n,)
        ICRS coordinates (deg if plain numbers).  Held in degrees.
    attitude : Attitude
        The pointing and roll that place them in the instrument frame.

    Raises
    ------
    ParameterError
        A position 90 deg or more from the rotation axis (behind the detectors).
    """

    kind = "positions"
    frame = "celestial"

    ra: Any
    dec: Any
    attitude: Attitude

    def __post_init__(self) -> None:
        ra = np.atleast_1d(np.degrees(as_angle(self.ra, "ra")))
        dec = np.atleast_1d(np.degrees(as_angle(self.dec, "dec", lo=-90.0, hi=90.0)))
        if ra.shape != dec.shape or ra.ndim != 1 or ra.size == 0:
            raise ParameterError(f"ra and dec must be 1-D of one equal length >= 1, got "
                                 f"shapes {ra.shape} and {dec.shape}")
        if not isinstance(self.attitude, Attitude):
            raise ParameterError(f"attitude must be an Attitude, got {type(self.attitude)}")
        object.__setattr__(self, "ra", _frozen(np.mod(ra, 360.0)))
        object.__setattr__(self, "dec", _frozen(dec))
        theta, _ = self.directions()
        far = theta.to_value(u.deg) >= 90.0
        if np.any(far):
            k = int(np.argmax(far))
            raise ParameterError(
                f"position (ra {self.ra[k]:.4f}, dec {self.dec[k]:.4f}) deg is "
                f"{theta[k].to_value(u.deg):.2f} deg from the rotation axis: below the "
                f"instrument's horizon (must be < 90 deg)")

    @classmethod
    def from_coords(cls, coords: SkyCoord, attitude: Attitude) -> PositionList:
        """From a SkyCoord (any frame; taken to ICRS)."""
        if not isinstance(coords, SkyCoord):
            raise ParameterError(f"coords must be an astropy SkyCoord, got {type(coords)}")
        icrs = coords.icrs
        return cls(np.atleast_1d(icrs.ra.deg), np.atleast_1d(icrs.dec.deg), attitude)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, PositionList) and np.array_equal(self.ra, other.ra)
                and np.array_equal(self.dec, other.dec) and self.attitude == other.attitude)

    __hash__ = None  # type: ignore[assignment]

    @property
    def size(self) -> int:
        """Number of positions."""
        return int(self.ra.size)

    @property
    def shape(self) -> tuple[int, int]:
        """``(1, size)``: a list of pixels."""
        return (1, self.size)

    def sky_coords(self) -> SkyCoord:
        """The positions (ICRS)."""
        return SkyCoord(self.ra * u.deg, self.dec * u.deg, frame="icrs")

    def directions(self) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) in the instrument frame."""
        return self.attitude.to_instrument(self.sky_coords())

    def to_dict(self) -> dict[str, Any]:
        """Plain description (deg)."""
        a = self.attitude
        return {"kind": self.kind, "ra": self.ra.tolist(), "dec": self.dec.tolist(),
                "attitude": {"ra": a.ra, "dec": a.dec, "roll": a.roll}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PositionList:
        """Inverse of :meth:`to_dict`."""
        return cls(d["ra"], d["dec"], Attitude(**d["attitude"]))


GRID_KINDS.register(DirectionList.kind, DirectionList)
GRID_KINDS.register(PositionList.kind, PositionList)
