"""The rotating mask of parallel slats."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_scalar
from rotmod.errors import ParameterError
from rotmod.materials import Material

__all__ = ["Mask"]


@dataclass(frozen=True)
class Mask:
    """A mask of parallel slats (infinite in extent) rotating about the lab z axis.

    Parameters
    ----------
    slat_width : float or Quantity
        ``a``, width of a slat (cm), >= 0.
    slat_gap : float or Quantity
        ``b``, gap between slats (cm), >= 0; ``a + b`` must be > 0.
    thickness : float or Quantity
        ``h``, slat thickness (cm), >= 0.
    height : float or Quantity
        ``L``, height of the mask's bottom face above the detector plane (cm), > 0.
    material : Material or str
        Slat material (default lead).
    mu : float or Quantity, optional
        Linear attenuation coefficient (1/cm) overriding the material at every energy;
        ``numpy.inf`` gives perfectly opaque slats, 0 transparent ones.

    Notes
    -----
    At mask angle 0 the slats are parallel to y and a gap is centred on the rotation axis:
    slats occupy ``b/2 + k(a+b) <= u <= b/2 + a + k(a+b)`` in the mask coordinate ``u``.
    """

    # ``unit`` metadata: the unit a plain number means and the unit instrument files write
    # (rotmod.config derives the file schema from these fields).
    slat_width: float = field(metadata={"unit": "cm"})
    slat_gap: float = field(metadata={"unit": "cm"})
    thickness: float = field(metadata={"unit": "cm"})
    height: float = field(metadata={"unit": "cm"})
    material: Material = field(default_factory=lambda: Material("Pb"),
                               metadata={"section": "material"})
    mu: float | None = field(default=None, metadata={"unit": "1/cm"})

    def __post_init__(self) -> None:
        cm = u.cm
        a = as_scalar(self.slat_width, "mask.slat_width", cm, lo=0.0)
        b = as_scalar(self.slat_gap, "mask.slat_gap", cm, lo=0.0)
        if a + b <= 0:
            raise ParameterError(
                f"mask.slat_width + mask.slat_gap must be > 0 cm, got {a:g} + {b:g} cm"
            )
        h = as_scalar(self.thickness, "mask.thickness", cm, lo=0.0)
        L = as_scalar(self.height, "mask.height", cm, lo=0.0, lo_open=True)
        if L > 1e9 * (a + b):
            # The slat phase (L tan(theta) mod a + b) would keep fewer than ~6 significant
            # digits in float64: no profile computed at such a height means anything.
            raise ParameterError(
                f"mask.height must be <= 1e9 slat periods (a + b = {a + b:g} cm), got "
                f"{L:g} cm; check the unit (cm)"
            )
        object.__setattr__(self, "slat_width", a)
        object.__setattr__(self, "slat_gap", b)
        object.__setattr__(self, "thickness", h)
        object.__setattr__(self, "height", L)
        mat = self.material
        if isinstance(mat, str):
            mat = Material(mat)
        if not isinstance(mat, Material):
            raise ParameterError(f"mask.material must be a Material or a name, got {mat!r}")
        object.__setattr__(self, "material", mat)
        if self.mu is not None:
            mu = self.mu
            q = isinstance(mu, u.Quantity) and mu.unit.is_equivalent(1 / cm)
            opaque = np.isposinf(mu.to_value(1 / cm) if q else mu) if q or isinstance(
                mu, int | float | np.floating) else False
            if opaque:  # +inf: perfectly opaque slats (as_scalar refuses non-finite values)
                object.__setattr__(self, "mu", np.inf)
            else:
                object.__setattr__(self, "mu", as_scalar(mu, "mask.mu", 1 / cm, lo=0.0))

    @property
    def period(self) -> float:
        """Slat period ``a + b`` (cm)."""
        return self.slat_width + self.slat_gap

    @property
    def open_fraction(self) -> float:
        """Geometric open fraction ``b / (a + b)``."""
        return self.slat_gap / self.period

    def linear_attenuation(self, energy: Any = None) -> float:
        """Linear attenuation coefficient of the slats (1/cm) at ``energy`` (keV).

        Raises
        ------
        ParameterError
            If neither ``mu`` nor the material's mass attenuation is fixed and no energy
            is given.
        """
        # A given energy is checked even when the attenuation is fixed: a NaN or negative
        # energy is a mistake whatever the mask.
        e = None if energy is None else as_scalar(energy, "energy", u.keV, lo=0.0, lo_open=True)
        if self.mu is not None:
            return float(self.mu)
        if self.material.mass_attenuation is not None:
            return float(self.material.mass_attenuation * self.material.density)
        if e is None:
            raise ParameterError(
                "energy is required: mask.mu is not set, so the attenuation comes from the "
                f"material database ({self.material.name})"
            )
        return float(self.material.linear_attenuation(e))

    def slat_fraction(self, u0: np.ndarray) -> np.ndarray:
        """1 where mask coordinate ``u0`` lies in a slat, 0 in a gap (edges count as slat)."""
        p = self.period
        w = np.mod(np.asarray(u0, dtype=float) - self.slat_gap / 2, p)
        return (w <= self.slat_width).astype(float)

    def to_dict(self) -> dict[str, Any]:
        """Plain-number description (cm, 1/cm, g/cm3, cm2/g) for metadata and files."""
        return {
            "slat_width": self.slat_width,
            "slat_gap": self.slat_gap,
            "thickness": self.thickness,
            "height": self.height,
            "material": self.material.name,
            "density": self.material.density,
            "mass_attenuation": self.material.mass_attenuation,
            "mu": None if self.mu is None else float(self.mu),
        }
