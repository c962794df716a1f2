"""The rotating-modulator instrument: a mask above a detector array."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_scalar
from rotmod.errors import ParameterError
from rotmod.geometry.detectors import DetectorArray
from rotmod.geometry.mask import Mask
from rotmod.materials import Material

__all__ = ["Instrument"]


@dataclass(frozen=True, eq=False)
class Instrument:
    """A rotating modulator.

    Parameters
    ----------
    mask : Mask
        The slat mask.
    detectors : DetectorArray
        The detector faces in z = 0.
    rotation_period : float or Quantity
        Time for one full (360 degree) turn of the mask (s), > 0.  The mask angle is
        ``xi(t) = 2 pi t / rotation_period`` (clockwise seen from +z; see conventions).
    """

    mask: Mask
    detectors: DetectorArray
    rotation_period: float = 60.0

    def __post_init__(self) -> None:
        if not isinstance(self.mask, Mask):
            raise ParameterError(f"instrument.mask must be a Mask, got {type(self.mask)}")
        if not isinstance(self.detectors, DetectorArray):
            raise ParameterError(
                f"instrument.detectors must be a DetectorArray, got {type(self.detectors)}"
            )
        T = as_scalar(self.rotation_period, "instrument.rotation_period", u.s, lo=0, lo_open=True)
        object.__setattr__(self, "rotation_period", T)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Instrument) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    @property
    def angular_speed(self) -> float:
        """``omega = 2 pi / rotation_period`` (rad/s)."""
        return 2 * np.pi / self.rotation_period

    def mask_angle(self, time: Any) -> u.Quantity:
        """Mask angle ``xi`` (Quantity in rad, not wrapped) at ``time`` (s)."""
        return self.angular_speed * as_array(time, "time", u.s) * u.rad

    def to_dict(self) -> dict[str, Any]:
        """Plain-number description for metadata and files (round-trips :meth:`from_dict`)."""
        return {
            "mask": self.mask.to_dict(),
            "detectors": self.detectors.to_dict(),
            "rotation_period": self.rotation_period,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Instrument:
        """Inverse of :meth:`to_dict`."""
        m = dict(d["mask"])
        material = Material(
            m.pop("material"), density=m.pop("density"), mass_attenuation=m.pop("mass_attenuation")
        )
        mu = m.pop("mu")
        mask = Mask(material=material, mu=mu, **m)
        det = DetectorArray(np.asarray(d["detectors"]["positions"]), d["detectors"]["diameter"])
        return cls(mask, det, d["rotation_period"])

    @classmethod
    def paper(
        cls,
        *,
        a: float = 4.0,
        b: float | None = None,
        c: float | None = None,
        h: float = 2.0,
        L: float = 100.0,
        sigma: float | None = 0.103,
        detector_xy: tuple[float, float] = (0.0, 0.0),
    ) -> Instrument:
        """The seed paper's simulation instrument: lead (11.34 g/cm3), L = 100 cm, one detector.

        ``b`` and ``c`` default to ``a``; ``sigma`` (cm2/g) defaults to the paper's 662 keV
        value (pass ``None`` to use the XCOM database at the requested energy).
        """
        b = a if b is None else b
        c = a if c is None else c
        mat = Material("Pb", density=11.34, mass_attenuation=sigma)
        return cls(Mask(a, b, h, L, mat), DetectorArray.single(c, *detector_xy))
