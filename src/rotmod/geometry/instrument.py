"""The rotating-modulator instrument: a mask above a detector array."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_scalar
from rotmod.conventions import source_direction
from rotmod.errors import ParameterError
from rotmod.geometry.detectors import DetectorArray
from rotmod.geometry.mask import Mask
from rotmod.materials import Material

__all__ = ["Instrument"]

#: The seed paper's instrument (Budden et al., Sec. 4): slat width, gap, thickness and height
#: (cm), the slats' material, the detector's diameter (cm) and the rotation period (s).
_PAPER_MASK = (4.0, 4.0, 2.0, 100.0)
_PAPER_MATERIAL = "lead"
_PAPER_DIAMETER = 4.0
_PAPER_PERIOD = 60.0


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
    # Field metadata: the field in files (see rotmod.geometry.Mask).
    rotation_period: float = field(default=60.0, metadata={
        "unit": "s", "fits": "ROT_PER", "doc": "mask rotation period"})

    def __post_init__(self) -> None:
        if not isinstance(self.mask, Mask):
            raise ParameterError(f"instrument.mask must be a Mask, got {type(self.mask)}")
        if not isinstance(self.detectors, DetectorArray):
            raise ParameterError(
                f"instrument.detectors must be a DetectorArray, got {type(self.detectors)}"
            )
        T = as_scalar(self.rotation_period, "instrument.rotation_period", u.s, lo=0, lo_open=True)
        object.__setattr__(self, "rotation_period", T)
        self._warn_if_mask_misses_detectors()

    def _warn_if_mask_misses_detectors(self) -> None:
        """Warn when a finite mask, turning about an offset axis, never passes over any
        detector: sources near the axis then cast no shadow and their profiles are flat.

        Not an error (a deliberate geometry, e.g. a calibration study, may want it); the
        bound ignores the axis tilt (at most 10 deg: a misalignment).
        """
        m = self.mask
        if m.outline is None:
            return
        # The area the turning mask sweeps: a disc of the outline's radius, or of a square's
        # half-diagonal, about where the axis crosses the mask.
        reach = m.outline_size * (np.sqrt(2.0) if m.outline == "square" else 1.0)
        centre = np.array([m.axis_offset_x, m.axis_offset_y])
        dist = np.hypot(*(self.detectors.positions - centre).T) - self.detectors.radius
        gap = float(dist.min()) - reach
        if gap <= 0:
            return
        # A ray to a source at zenith theta crosses the slab L tan(theta) to (L + h)
        # tan(theta) away from its detector point.
        theta = np.degrees(np.arctan(gap / (m.height + m.thickness)))
        size = "radius" if m.outline == "circle" else "half-width"
        warnings.warn(
            f"instrument: the mask ({m.outline} of {size} {m.outline_size:g} cm turning "
            f"about an axis offset by ({m.axis_offset_x:g}, {m.axis_offset_y:g}) cm) never "
            f"passes over a detector: the nearest detector edge is {gap:.3g} cm outside the "
            f"disc of radius {reach:.3g} cm it sweeps, so sources within "
            f"{theta:.3g} deg of the axis cast no shadow and their profiles are flat",
            stacklevel=3)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Instrument) and self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]

    @property
    def is_ideal(self) -> bool:
        """True for the paper's instrument: an ideal mask (:attr:`Mask.is_ideal`) over flat
        detector faces.  Only such instruments take the fast kernels of every model; the
        ``exact`` model and the Monte Carlo handle the others (docs/physics.md, "The
        instrument as built")."""
        return self.mask.is_ideal and self.detectors.is_flat

    def as_built_features(self) -> list[str]:
        """Names of the ways this instrument departs from the ideal one (empty if ideal)."""
        m = self.mask
        out = []
        if m.slat_edges is not None:
            out.append("mask.slat_edges")
        if m.axis_offset_x or m.axis_offset_y:
            out.append("mask.axis_offset")
        if m.tilt:
            out.append("mask.tilt")
        if m.outline is not None:
            out.append("mask.outline")
        if not self.detectors.is_flat:
            out.append("detectors.thickness")
        return out

    def source_positions(self, theta: np.ndarray, phi: np.ndarray,
                         distance: np.ndarray) -> np.ndarray:
        """Lab positions (cm), shape (n, 3), of sources at ``distance`` from the origin (the
        array centre in the detector plane) in the directions ``(theta, phi)`` (rad);
        ``inf`` rows stay ``inf`` (sources at infinity).

        Raises
        ------
        ParameterError
            A finite source that does not lie above the mask's top face (every ray from it
            must cross the whole slab).
        """
        th = np.asarray(theta, dtype=float)
        ph = np.asarray(phi, dtype=float)
        D = np.broadcast_to(np.asarray(distance, dtype=float), th.shape)
        with np.errstate(invalid="ignore"):  # inf * 0 where a source at infinity lies on an axis
            S = D[:, None] * source_direction(th, ph)
        S[~np.isfinite(D)] = np.inf
        fin = np.isfinite(D)
        if fin.any():
            Q, cm = self.mask.frame()
            height = (S[fin] - cm) @ Q[2]
            top = self.mask.thickness
            bad = np.flatnonzero(height <= top)
            if bad.size:
                i = int(np.flatnonzero(fin)[bad[0]])
                raise ParameterError(
                    f"distance must put every source above the mask's top face (L + h = "
                    f"{self.mask.height + top:g} cm on the axis), got {D[i]:g} cm for source "
                    f"{i} at theta = {np.degrees(th[i]):g} deg (height above the mask's bottom "
                    f"face {height[bad[0]]:g} cm)"
                )
        return S

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
        return cls(mask, DetectorArray.from_dict(d["detectors"]), d["rotation_period"])

    @classmethod
    def paper(
        cls,
        *,
        a: float | None = None,
        b: float | None = None,
        c: float | None = None,
        h: float | None = None,
        L: float | None = None,
        sigma: float | None = None,
        detector_xy: tuple[float, float] = (0.0, 0.0),
    ) -> Instrument:
        """The seed paper's simulation instrument with changes.

        Every value not given is the paper's (lead, a = b = c = 4 cm, h = 2 cm, L = 100 cm,
        one detector, a 60 s turn; the ``paper`` preset, ``rotmod/presets/paper.toml``,
        describes the same instrument, and tests/geometry/test_geometry.py checks that the two stay
        equal); ``b`` and ``c`` follow ``a`` when only ``a`` is given.  Like the preset, the
        slats' attenuation comes from XCOM at the energy asked for; ``sigma`` (cm2/g) fixes
        it at every energy instead (the paper's own scenarios:
        ``sigma=rotmod.materials.PAPER_SIGMA_662``).
        """
        # The numbers are the model's own (geometry reads no files): the instrument files
        # (rotmod.config) build on this module, never the other way round.
        base = cls(Mask(*_PAPER_MASK, Material(_PAPER_MATERIAL)),
                   DetectorArray.single(_PAPER_DIAMETER), _PAPER_PERIOD)
        m = base.mask
        a_ = m.slat_width if a is None else a
        b_ = (m.slat_gap if a is None else a_) if b is None else b
        c_ = (base.detectors.diameter if a is None else a_) if c is None else c
        mat = m.material
        if sigma is not None:
            mat = Material(mat.name, density=mat.density, mass_attenuation=sigma)
        mask = Mask(a_, b_, m.thickness if h is None else h, m.height if L is None else L, mat)
        return cls(mask, DetectorArray.single(c_, *detector_xy), base.rotation_period)
