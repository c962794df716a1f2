"""Source spectra and detector energy resolution.

A :class:`PowerLaw` source is simulated as a few narrow bands: the slats' attenuation is
evaluated at each band's centre (it varies slowly with energy), and each photon's true
energy is drawn from the power law within its band.

Resolution: how a line's photons spread in measured energy.

A scintillator measures a photopeak photon's energy with a Gaussian spread whose relative
width falls with energy; the common parametrisation, and NaI(Tl)'s usual numbers, are

    FWHM(E) / E = r_ref (E / E_ref)^index,   r_ref = 7 % at E_ref = 662 keV, index = -1/2

(photo-statistics: the number of scintillation photons grows like E).  Folding with an energy
window around a line (``fold(..., energy_band=)``, ``rotmod fold --band``) then selects that
line's photopeak.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rotmod._validate import as_energy, as_energy_scalar, as_int, as_scalar
from rotmod.errors import ParameterError
from rotmod.limits import check_memory

__all__ = ["EnergyResolution", "PowerLaw"]

#: FWHM = 2 sqrt(2 ln 2) sigma for a Gaussian.
FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))


@dataclass(frozen=True)
class EnergyResolution:
    """Gaussian energy resolution with ``FWHM/E = fraction (E / reference)^index``.

    Parameters
    ----------
    fraction : float
        Relative FWHM at ``reference`` (0.07 = 7 %), > 0.
    reference : float or Quantity
        Energy of ``fraction`` (keV), > 0.
    index : float
        Power of ``E / reference`` (-0.5: photo-statistics).
    """

    fraction: float = 0.07
    reference: Any = 662.0
    index: float = -0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "fraction", as_scalar(self.fraction, "resolution.fraction",
                                                       lo=0.0, lo_open=True))
        object.__setattr__(self, "reference",
                           as_energy_scalar(self.reference, "resolution.reference"))
        object.__setattr__(self, "index", as_scalar(self.index, "resolution.index"))

    @classmethod
    def nai(cls) -> EnergyResolution:
        """NaI(Tl): 7 % FWHM at 662 keV, scaling like ``E^-1/2``."""
        return cls(0.07, 662.0, -0.5)

    def fwhm(self, energy: Any) -> np.ndarray:
        """FWHM (keV) at ``energy`` (keV).

        Raises
        ------
        ParameterError
            An energy whose FWHM overflows (``index`` too large for it).
        """
        e = as_energy(energy, "energy")
        with np.errstate(over="ignore"):
            width = self.fraction * e * (e / self.reference) ** self.index
        if not np.all(np.isfinite(width)):
            bad = float(np.atleast_1d(e)[~np.isfinite(np.atleast_1d(width))][0])
            raise ParameterError(
                f"resolution: the FWHM at {bad:g} keV is not finite (fraction {self.fraction:g} "
                f"x (E / {self.reference:g} keV)^{self.index:g} overflows); give a smaller "
                "resolution.index")
        return width

    def smear(self, energy: Any, rng: np.random.Generator) -> np.ndarray:
        """Measured energies (keV, float32) of photons of true ``energy`` (keV)."""
        if not isinstance(rng, np.random.Generator):
            raise ParameterError(f"rng must be a numpy Generator (np.random.default_rng(seed)), "
                                 f"got {type(rng).__name__}")
        e = as_energy(energy, "energy")
        measured = rng.normal(e, self.fwhm(e) / FWHM_PER_SIGMA)
        # A pulse height is positive; the tail below 0 is ~10 sigma away for any real detector.
        return np.maximum(measured, np.finfo(np.float32).tiny).astype(np.float32)


@dataclass(frozen=True)
class PowerLaw:
    """A photon power law ``dN/dE ~ E^-index`` between ``e_min`` and ``e_max`` (keV).

    Parameters
    ----------
    index : float
        Photon index (2 for a typical hard X-ray source).
    e_min, e_max : float or Quantity
        Energy range (keV), ``0 < e_min < e_max``.
    """

    index: float
    e_min: Any
    e_max: Any

    def __post_init__(self) -> None:
        object.__setattr__(self, "index", as_scalar(self.index, "spectrum.index"))
        lo = as_energy_scalar(self.e_min, "spectrum.e_min")
        hi = as_energy_scalar(self.e_max, "spectrum.e_max")
        if not lo < hi:
            raise ParameterError(f"spectrum.e_min must be < e_max, got {lo:g} and {hi:g} keV")
        object.__setattr__(self, "e_min", lo)
        object.__setattr__(self, "e_max", hi)

    def _cdf_inverse(self, lo: np.ndarray, hi: np.ndarray, q: np.ndarray) -> np.ndarray:
        # Written with the ratio of the band's ends in [0, 1] raised to |1 - index|, so that
        # no power overflows however steep the spectrum (an index of 1000 included).
        g = 1.0 - self.index
        if abs(g) < 1e-12:  # index 1: uniform in log E
            return lo * (hi / lo) ** q
        with np.errstate(under="ignore"):
            if g > 0:  # E^g from lo^g to hi^g: scaled by hi^g
                r = (lo / hi) ** g
                return hi * (r + q * (1.0 - r)) ** (1.0 / g)
            r = (hi / lo) ** g  # scaled by lo^g
            return lo * (1.0 + q * (r - 1.0)) ** (1.0 / g)

    def _fractions(self, edges: np.ndarray) -> np.ndarray:
        """Photon fraction in each band of ``edges`` (from ``e_min`` to ``e_max``), computed
        on the primitive scaled to [0, 1] (no overflow for any index)."""
        g = 1.0 - self.index
        if abs(g) < 1e-12:
            prim = np.log(edges / edges[0])
            return np.diff(prim) / prim[-1]
        with np.errstate(under="ignore"):
            if g > 0:
                y = (edges / edges[-1]) ** g  # rises to 1
                return np.diff(y) / (1.0 - y[0])
            y = (edges / edges[0]) ** g  # falls from 1
            return -np.diff(y) / (1.0 - y[-1])

    def bands(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``n`` log-spaced bands: ``(lo, hi, photon fraction)`` each of shape (n,)."""
        n = as_int(n, "n_bands", 1)
        check_memory(40.0 * n, f"{n} energy bands", hint="use fewer bands")
        edges = np.geomspace(self.e_min, self.e_max, n + 1)
        return edges[:-1], edges[1:], self._fractions(edges)

    def draw(self, lo: Any, hi: Any, rng: np.random.Generator) -> np.ndarray:
        """True energies (keV) following the power law within ``[lo, hi]`` (element-wise).

        Raises
        ------
        ParameterError
            A band that is not ``0 < lo <= hi`` (keV), or ``rng`` not a numpy Generator.
        """
        if not isinstance(rng, np.random.Generator):
            raise ParameterError(f"rng must be a numpy Generator (np.random.default_rng(seed)), "
                                 f"got {type(rng).__name__}")
        lo_ = as_energy(lo, "lo")
        hi_ = as_energy(hi, "hi")
        try:
            shape = np.broadcast(lo_, hi_).shape
        except ValueError:
            raise ParameterError(f"lo and hi must broadcast together, got shapes {lo_.shape} "
                                 f"and {hi_.shape}") from None
        if np.any(hi_ < lo_):
            raise ParameterError("lo must be <= hi (keV) in every band")
        return self._cdf_inverse(lo_, hi_, rng.random(shape))
