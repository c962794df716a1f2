"""Flat circular detectors in the plane z = 0."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_int, as_scalar
from rotmod.errors import ParameterError
from rotmod.limits import check_memory

__all__ = ["DetectorArray"]


@dataclass(frozen=True, eq=False)
class DetectorArray:
    """Circular detector faces of one diameter ``c`` centred at ``(x0, y0)`` in z = 0.

    Parameters
    ----------
    positions : array_like or Quantity, shape (n, 2)
        Detector centres (cm), relative to the rotation axis.
    diameter : float or Quantity
        ``c`` (cm), > 0.
    """

    positions: np.ndarray
    diameter: float

    def __post_init__(self) -> None:
        pos = as_array(self.positions, "detectors.positions", u.cm)
        if pos.ndim == 1 and pos.shape == (2,):
            pos = pos[None, :]
        if pos.ndim != 2 or pos.shape[1] != 2 or pos.shape[0] == 0:
            raise ParameterError(
                f"detectors.positions must have shape (n, 2) with n >= 1, got {pos.shape}"
            )
        pos = pos.copy()
        pos.flags.writeable = False
        object.__setattr__(self, "positions", pos)
        c = as_scalar(self.diameter, "detectors.diameter", u.cm, lo=0.0, lo_open=True)
        object.__setattr__(self, "diameter", c)

    def __len__(self) -> int:
        return self.positions.shape[0]

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, DetectorArray)
            and self.diameter == other.diameter
            and np.array_equal(self.positions, other.positions)
        )

    __hash__ = None  # type: ignore[assignment]

    @property
    def radius(self) -> float:
        """Detector radius ``c/2`` (cm)."""
        return self.diameter / 2

    @classmethod
    def single(cls, diameter: Any, x0: Any = 0.0, y0: Any = 0.0) -> DetectorArray:
        """One detector of ``diameter`` centred at ``(x0, y0)``."""
        x = as_scalar(x0, "detectors.x0", u.cm)
        y = as_scalar(y0, "detectors.y0", u.cm)
        return cls(np.array([[x, y]]), diameter)

    @classmethod
    def hexagonal(cls, diameter: Any, *, rings: int = 2, pitch: Any = None) -> DetectorArray:
        """A hexagonal close-packed array: 1 + 3 rings (rings + 1) detectors.

        ``rings = 2`` gives the 19-detector array of the paper's lab prototype.

        Parameters
        ----------
        diameter : float or Quantity
            Detector diameter (cm).
        rings : int
            Number of hexagonal rings around the centre detector (>= 0).
        pitch : float or Quantity, optional
            Centre-to-centre distance of neighbours (cm); default ``1.05 * diameter``
            (a little room for housings).  Must be >= diameter so faces do not overlap.
        """
        c = as_scalar(diameter, "detectors.diameter", u.cm, lo=0.0, lo_open=True)
        rings = as_int(rings, "detectors.rings", 0)
        d = 1.05 * c if pitch is None else as_scalar(pitch, "detectors.pitch", u.cm)
        if d < c:
            raise ParameterError(
                f"detectors.pitch must be >= detectors.diameter ({c:g} cm), got {d:g} cm"
            )
        side = 2 * rings + 1
        # The (q, r) square and the positions, sort keys and order: ~10 float64 per point.
        check_memory(10 * 8.0 * side * side, f"a hexagonal array of {rings} rings "
                     f"({1 + 3 * rings * (rings + 1)} detectors)", hint="use fewer rings")
        # Axial hex coordinates (q, r) with |q|, |r|, |q + r| <= rings.
        q, r = np.meshgrid(np.arange(-rings, rings + 1), np.arange(-rings, rings + 1),
                           indexing="ij")
        keep = np.abs(q + r) <= rings
        q, r = q[keep], r[keep]
        x, y = d * (q + r / 2), d * r * np.sqrt(3) / 2
        # Centre first, then ring by ring, counter-clockwise from +x (rounded so that equal
        # radii and angles compare equal despite round-off).
        order = np.lexsort((np.round(np.arctan2(y, x), 9), np.round(np.hypot(x, y), 9)))
        return cls(np.stack([x[order], y[order]], axis=1), c)

    def to_dict(self) -> dict[str, Any]:
        """Plain-number description (cm) for metadata and files."""
        return {"diameter": self.diameter, "positions": self.positions.tolist()}
