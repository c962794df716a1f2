"""Slat materials and their photon attenuation.

Mass attenuation coefficients come from the NIST XCOM photon cross-section tables as shipped
(and maintained) by the `fisx <https://pypi.org/project/fisx/>`_ package: total attenuation
*with* coherent scattering, elements and chemical formulas (mixture rule by mass fraction),
tabulated from 1 keV to 100 GeV.  Energies outside that range are refused, because the
library would extrapolate silently.  Default element densities are fisx's; compounds need an
explicit density.

A material can also carry an explicit mass attenuation coefficient, and a mask an explicit
linear coefficient, which override the database (the seed paper's scenarios use
``sigma = 0.103 cm^2/g`` for lead at 662 keV).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_scalar
from rotmod.errors import MaterialError

__all__ = ["DATABASE_RANGE_KEV", "Material", "mass_attenuation"]

#: Energy range (keV) of the XCOM tables shipped with fisx.
DATABASE_RANGE_KEV = (1.0, 1.0e8)

#: Common names accepted besides element symbols and chemical formulas.
_ALIASES = {
    "lead": "Pb",
    "tungsten": "W",
    "tantalum": "Ta",
    "tin": "Sn",
    "copper": "Cu",
    "iron": "Fe",
    "steel": "Fe",
    "aluminium": "Al",
    "aluminum": "Al",
    "gold": "Au",
    "bismuth": "Bi",
}


@functools.cache
def _database() -> Any:
    """The fisx element database, built once (about a second)."""
    from fisx import Elements

    db = Elements()
    db.initializeAsPyMca()
    return db


def _formula(name: str) -> str:
    return _ALIASES.get(name.strip().lower(), name.strip())


def mass_attenuation(formula: str, energy: Any) -> np.ndarray:
    """Total mass attenuation coefficient (with coherent scattering) in cm^2/g.

    Parameters
    ----------
    formula : str
        Element symbol, chemical formula (``"CdZnTe"``, ``"Bi4Ge3O12"``) or a common name
        (``"lead"``).
    energy : float, array_like or Quantity
        Photon energy (keV if plain numbers).

    Returns
    -------
    numpy.ndarray
        ``sigma(E)`` with the shape of ``energy``.

    Raises
    ------
    MaterialError
        Unknown material, or an energy outside 1 keV to 100 GeV.
    """
    lo, hi = DATABASE_RANGE_KEV
    e = as_array(energy, "energy", u.keV, lo=0.0, lo_open=True)
    if np.any((e < lo) | (e > hi)):
        bad = e[(e < lo) | (e > hi)].ravel()[0]
        raise MaterialError(
            f"energy must lie within the attenuation database's range {lo:g} keV to "
            f"{hi:g} keV (NIST XCOM via fisx), got {bad:g} keV"
        )
    name = _formula(formula)
    try:
        table = _database().getMassAttenuationCoefficients(name, np.ravel(e).tolist())
    except ValueError as exc:
        raise MaterialError(
            f"material {formula!r} is not an element, known name or chemical formula "
            f"({exc})"
        ) from exc
    return np.asarray(table["total"], dtype=float).reshape(e.shape)


@dataclass(frozen=True)
class Material:
    """A slat material.

    Parameters
    ----------
    name : str
        Element symbol, chemical formula or common name (``"lead"``).
    density : float or Quantity, optional
        g/cm^3.  Defaults to the database value for elements; required for compounds.
    mass_attenuation : float or Quantity, optional
        A constant mass attenuation coefficient (cm^2/g) that overrides the database at
        every energy.

    Examples
    --------
    >>> Material("lead").linear_attenuation(662.0)  # doctest: +FLOAT_CMP
    array(1.24891...)
    """

    name: str
    density: float | None = None
    mass_attenuation: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise MaterialError(f"material.name must be a non-empty string, got {self.name!r}")
        formula = _formula(self.name)
        if self.density is None:
            try:
                rho = float(_database().getDensity(formula))
            except ValueError as exc:
                raise MaterialError(
                    f"material {self.name!r}: no default density (only elements have one); "
                    "give material.density in g/cm3"
                ) from exc
        else:
            rho = as_scalar(self.density, "material.density", u.g / u.cm**3, lo=0, lo_open=True)
        object.__setattr__(self, "density", rho)
        if self.mass_attenuation is not None:
            sig = as_scalar(
                self.mass_attenuation, "material.mass_attenuation", u.cm**2 / u.g, lo=0.0
            )
            object.__setattr__(self, "mass_attenuation", sig)
        else:
            # Fail early on unknown names rather than at the first energy.
            mass_attenuation(formula, 100.0)

    def mass_attenuation_at(self, energy: Any) -> np.ndarray:
        """Mass attenuation coefficient (cm^2/g) at ``energy`` (keV)."""
        if self.mass_attenuation is not None:
            e = as_array(energy, "energy", u.keV, lo=0.0, lo_open=True)
            return np.full(e.shape, self.mass_attenuation)
        return mass_attenuation(self.name, energy)

    def linear_attenuation(self, energy: Any) -> np.ndarray:
        """Linear attenuation coefficient ``mu = sigma * rho`` (1/cm) at ``energy`` (keV)."""
        return self.mass_attenuation_at(energy) * self.density
