"""Slat materials and their photon attenuation.

Mass attenuation coefficients come from the NIST XCOM photon cross-section tables (public-domain
data) as distributed by the `fisx <https://pypi.org/project/fisx/>`_ package (version 1.3.2,
MIT-licensed): total attenuation *with* coherent scattering, elements H to Fm (Z = 1-100) and
chemical formulas (mixture rule by mass fraction), tabulated from 1 keV to 100 GeV.  Energies
outside that range are refused, because interpolation would silently become extrapolation.

rotmod ships the tables it uses, with fisx's element data (atomic masses, default densities),
as package data, ``xcom.npz`` (269 KiB), made from fisx 1.3.2 by ``scripts/extract_xcom.py``
(the file's ``provenance`` entry says how and when): fisx is a C++ extension published only as
source, and installing rotmod should need no compiler.  Default element densities are fisx's
(except tin, see ``_DENSITY_OVERRIDES``); compounds need an explicit density.

We interpolate the tables ourselves rather than with fisx's interpolator: fisx interpolates the
pair-production cross-section log-log from its zero at the 1022 keV threshold, which puts lead
at 1.05 cm^2/g at 1022.5 keV (XCOM: 0.070).  Here each partial cross-section is interpolated
log-log between positive table values and linearly in energy where one end is zero (the pair
threshold), and summed.  Formulas become mass fractions as fisx made them (atoms times atomic
mass, over the sum in alphabetical order of symbols), so coefficients are those rotmod computed
with fisx, to the bit.

A material can also carry an explicit mass attenuation coefficient, and a mask an explicit
linear coefficient, which override the database (the seed paper's scenarios use
``sigma = 0.103 cm^2/g`` for lead at 662 keV).
"""

from __future__ import annotations

import copy
import functools
import importlib.resources
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_energy, as_energy_scalar, as_scalar
from rotmod.errors import MaterialError, ParameterError
from rotmod.materials._formula import atom_counts

__all__ = [
    "DATABASE_RANGE_KEV", "PAPER_SIGMA_662", "PARTIAL_PROCESSES", "Material", "database_provenance",
    "mass_attenuation", "partial_attenuation",
]

#: The processes of :func:`partial_attenuation`, in the order of its last axis (XCOM's).
PARTIAL_PROCESSES = ("coherent", "incoherent", "photoelectric", "pair")

#: Mass attenuation of lead at 662 keV (cm^2/g) that the seed paper's Sec. 4 scenarios use
#: (XCOM gives 0.110).  It is the paper's number at the paper's energy, so rotmod never
#: applies it by default: pass it explicitly (``Instrument.paper(sigma=PAPER_SIGMA_662)``,
#: ``mass_attenuation = "0.103 cm2/g"`` in a file) to reproduce the paper's figures.
PAPER_SIGMA_662 = 0.103

#: Energy range (keV) of the XCOM tables (rows below 1 keV exist but are not offered).
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


#: Densities (g/cm^3) where fisx's default is not the form used for slats: fisx gives tin
#: 5.31 (grey alpha-tin); metallic white tin is 7.31.
_DENSITY_OVERRIDES = {"Sn": 7.31}

#: The package data file: XCOM tables and element data (see ``scripts/extract_xcom.py``).
_DATA_FILE = "xcom.npz"


@dataclass(frozen=True)
class _Element:
    """One element of the database: atomic number, atomic mass (g/mol), fisx's default density
    (g/cm^3) and the XCOM table (columns energy in keV, then the coherent, incoherent,
    photoelectric and pair cross-sections in cm^2/g; rows in increasing energy, an absorption
    edge being a repeated energy)."""

    z: int
    atomic_mass: float
    density: float
    table: np.ndarray


@functools.cache
def _load() -> tuple[dict[str, _Element], dict[str, Any]]:
    """The package data, read once: element symbol -> :class:`_Element`, and the provenance."""
    with importlib.resources.files(__name__).joinpath(_DATA_FILE).open("rb") as f:
        data = np.load(f, allow_pickle=False)
        table, offset = data["table"], data["offset"]
        elements = {
            str(s): _Element(int(z), float(m), float(rho), table[offset[k]:offset[k + 1]])
            for k, (s, z, m, rho) in enumerate(
                zip(data["symbol"], data["z"], data["atomic_mass"], data["density"], strict=True)
            )
        }
        return elements, json.loads(str(data["provenance"]))


def _database() -> dict[str, _Element]:
    return _load()[0]


def database_provenance() -> dict[str, Any]:
    """Where the attenuation data come from: source, the fisx version they were taken from,
    the date and script that extracted them, the table's columns (a JSON-ready dict, for
    records of a run's environment)."""
    return copy.deepcopy(_load()[1])


def _composition(name: str) -> dict[str, float]:
    """Mass fractions of the elements of formula ``name``, keyed in alphabetical order.

    Computed as fisx computed them, so that coefficients stay identical to the bit: atoms
    times atomic mass per element, summed in alphabetical order, each divided by the sum.
    (A plain loop, not ``sum``: Python 3.12's ``sum`` of floats is compensated.)

    Raises
    ------
    MaterialError
        Not a formula, or a symbol that is not an element of the database; the message
        says which (the caller names the material).
    """
    db = _database()
    counts = atom_counts(name)
    unknown = [s for s in counts if s not in db]
    if unknown:
        raise MaterialError(
            f"unknown element symbol {unknown[0]!r}; the database covers H to Fm, Z = 1 to 100"
        )
    masses = {s: counts[s] * db[s].atomic_mass for s in sorted(counts)}
    total = 0.0
    for m in masses.values():
        total += m
    return {s: m / total for s, m in masses.items()}


def _element_partials(symbol: str, e: np.ndarray) -> np.ndarray:
    """Partial mass attenuations of one element at energies ``e`` (keV, 1-D): shape
    ``(e.size, 4)``, the columns of :data:`PARTIAL_PROCESSES`."""
    table = _database()[symbol].table
    grid = table[:, 0]
    # Last row with E <= e, so at an absorption edge (a repeated energy) the value above the
    # edge is used; the final row is folded into the last interval.
    i = np.clip(np.searchsorted(grid, e, side="right") - 1, 0, grid.size - 2)
    e0, e1 = grid[i], grid[i + 1]
    out = np.empty((e.size, table.shape[1] - 1))
    for col in range(1, table.shape[1]):
        y0, y1 = table[i, col], table[i + 1, col]
        positive = (y0 > 0) & (y1 > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            loglog = y0 * np.exp(np.log(y1 / y0) * np.log(e / e0) / np.log(e1 / e0))
        linear = y0 + (y1 - y0) * (e - e0) / (e1 - e0)
        out[:, col - 1] = np.where(positive, loglog, linear)
    return out


def _element_attenuation(symbol: str, e: np.ndarray) -> np.ndarray:
    """Total mass attenuation of one element at energies ``e`` (keV, 1-D).

    The partials are summed left to right, as they always were, so totals keep their bits."""
    parts = _element_partials(symbol, e)
    total = np.zeros(e.shape)
    for col in range(parts.shape[1]):
        total += parts[:, col]
    return total


def _formula(name: str) -> str:
    return _ALIASES.get(name.strip().lower(), name.strip())


def _checked(energy: Any) -> np.ndarray:
    """``energy`` in keV, refused outside the database's range."""
    lo, hi = DATABASE_RANGE_KEV
    e = as_energy(energy, "energy")
    if np.any((e < lo) | (e > hi)):
        bad = e[(e < lo) | (e > hi)].ravel()[0]
        raise MaterialError(
            f"energy must lie within the attenuation database's range {lo:g} keV to "
            f"{hi:g} keV (NIST XCOM via fisx), got {bad:g} keV"
        )
    return e


def mass_fractions(formula: str | Mapping[str, float]) -> dict[str, float]:
    """Mass fractions of the elements of a formula or name, or of a mixture given as
    ``{symbol: fraction}`` (normalised to 1; air is ``{"N": 0.7553, "O": 0.2318, "Ar":
    0.0128, "C": 0.0001}``), keyed by symbol in alphabetical order: the weights of the
    mixture rule behind :func:`mass_attenuation`.

    Raises
    ------
    MaterialError
        Not an element, known name, formula or mixture.
    """
    if isinstance(formula, Mapping):
        db = _database()
        bad = [k for k in formula if k not in db]
        if bad or not formula:
            raise MaterialError(
                f"a mixture maps element symbols (H to Fm) to mass fractions; got {dict(formula)!r}"
            )
        w = {k: as_scalar(v, f"mass fraction of {k}", lo=0.0) for k, v in formula.items()}
        total = sum(w.values())
        if not total > 0:
            raise MaterialError(f"a mixture's mass fractions must not all be 0, got {w!r}")
        return {k: v / total for k, v in sorted(w.items())}
    try:
        return _composition(_formula(formula))
    except MaterialError as exc:
        raise MaterialError(
            f"material {formula!r} is not an element, known name or chemical formula ({exc})"
        ) from None


def mass_attenuation(formula: str | Mapping[str, float], energy: Any) -> np.ndarray:
    """Total mass attenuation coefficient (with coherent scattering) in cm^2/g.

    Parameters
    ----------
    formula : str or mapping
        Element symbol, chemical formula (``"CdZnTe"``, ``"Bi4Ge3O12"``), a common name
        (``"lead"``), or a mixture ``{symbol: mass fraction}``.
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
    e = _checked(energy)
    composition = mass_fractions(formula)
    flat = np.ravel(e).astype(float)
    sigma = sum(w * _element_attenuation(el, flat) for el, w in composition.items())
    return np.asarray(sigma).reshape(e.shape)


def partial_attenuation(formula: str | Mapping[str, float], energy: Any) -> np.ndarray:
    """Mass attenuation coefficients (cm^2/g) of each process: coherent (Rayleigh) and
    incoherent (Compton) scattering, photoelectric absorption and pair production (nuclear
    and electron fields together), as :data:`PARTIAL_PROCESSES`.

    Parameters
    ----------
    formula : str or mapping
        As for :func:`mass_attenuation`.
    energy : float, array_like or Quantity
        Photon energy (keV if plain numbers).

    Returns
    -------
    numpy.ndarray
        Shape ``energy.shape + (4,)``; the sum over the last axis is
        :func:`mass_attenuation` (to rounding).
    """
    e = _checked(energy)
    composition = mass_fractions(formula)
    flat = np.ravel(e).astype(float)
    out = np.zeros((flat.size, len(PARTIAL_PROCESSES)))
    for el, w in composition.items():
        out += w * _element_partials(el, flat)
    return out.reshape(*e.shape, len(PARTIAL_PROCESSES))


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
    density: float | None = field(default=None, metadata={"unit": "g/cm3"})
    mass_attenuation: float | None = field(default=None, metadata={"unit": "cm2/g"})

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise MaterialError(f"material.name must be a non-empty string, got {self.name!r}")
        formula = _formula(self.name)
        if self.density is None:
            element = _database().get(formula)
            if element is None:
                if self.mass_attenuation is None:
                    # A name that is no material at all: say so, rather than ask for a density.
                    mass_attenuation(formula, 100.0)
                raise MaterialError(
                    f"material {self.name!r}: no default density (only elements have one); "
                    "give material.density in g/cm3"
                )
            rho = _DENSITY_OVERRIDES.get(formula, element.density)
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
            e = as_energy(energy, "energy")
            return np.full(e.shape, self.mass_attenuation)
        return mass_attenuation(self.name, energy)

    def linear_attenuation(self, energy: Any) -> np.ndarray:
        """Linear attenuation coefficient ``mu = sigma * rho`` (1/cm) at ``energy`` (keV)."""
        return self.mass_attenuation_at(energy) * self.density

    def coefficient(self, energy: Any, whose: str, hint: str = "") -> float | np.ndarray:
        """``mu`` (1/cm) at ``energy`` (keV): the fixed coefficient when the material has one
        (``energy`` may then be None), else the database's.

        Parameters
        ----------
        energy : float, array_like, Quantity or None
            One energy (a float is returned) or several (an array of their shape).
        whose, hint : str
            Whose attenuation it is (``"the detectors'"``) and what else the user could do,
            for the error message.

        Raises
        ------
        ParameterError
            No fixed coefficient and no energy, or an energy that is not a positive finite
            number (checked also when the coefficient is fixed).
        """
        if energy is None:
            if self.mass_attenuation is None:
                raise ParameterError(
                    f"energy is required: {whose} attenuation comes from the material "
                    f"database ({self.name}){hint}"
                )
            return float(self.mass_attenuation * self.density)
        if np.ndim(energy) == 0:
            return float(self.linear_attenuation(as_energy_scalar(energy, "energy")))
        return np.asarray(self.linear_attenuation(as_energy(energy, "energy")), dtype=float)
