"""Point sources at infinity: the sky's truth, the input of the Monte Carlo's observation mode."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_angle, as_array, as_energy
from rotmod.energy import PowerLaw
from rotmod.errors import ParameterError

__all__ = ["PointSources"]


def _broadcast(name: str, arr: np.ndarray, n: int) -> np.ndarray:
    if arr.size == 1:
        return np.full(n, float(arr.ravel()[0]))
    if arr.shape != (n,):
        raise ParameterError(f"{name} must have one value per source ({n}), got shape {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class PointSources:
    """A list of point sources at infinity, each a plane wave of photons.

    Parameters
    ----------
    theta, phi : array_like or Quantity, shape (n,)
        Zenith (0 <= theta < 90 deg) and azimuth of each source (deg if plain numbers),
        following :mod:`rotmod.conventions`.  Held as Quantities (rad).
    rate : array_like or Quantity, shape (n,) or scalar
        Photons per second incident on *each* detector face with no mask (1/s), >= 0.
    energy : array_like or Quantity, shape (n,) or scalar
        Photon energy of each source (keV), > 0 (lines; the mask attenuation is evaluated
        at it).
    spectrum : PowerLaw, optional
        With ``band``: each source is one band of this spectrum (see :meth:`with_spectrum`).
    band : array_like, shape (n, 2), optional
        Each source's energy band (keV): its photons' true energies follow ``spectrum``
        within it, while ``energy`` (the band centre) sets the attenuation.

    Examples
    --------
    >>> src = PointSources([6.0], [0.0], rate=100.0, energy=662.0)  # degrees
    >>> len(src)
    1
    """

    theta: np.ndarray
    phi: np.ndarray
    rate: Any = 1.0
    energy: Any = 662.0
    spectrum: Any = None
    band: Any = None

    def __post_init__(self) -> None:
        th = as_angle(self.theta, "theta", lo=0.0, hi=90.0, hi_open=True, ndim=1)
        ph = as_angle(self.phi, "phi", ndim=1)
        n = max(th.size, ph.size)
        if n == 0:
            raise ParameterError("sources must contain at least one source, got 0")
        th = _broadcast("theta", th, n)
        ph = _broadcast("phi", ph, n)
        rate = _broadcast("rate", as_array(self.rate, "rate", 1 / u.s, lo=0.0, ndim=1), n)
        energy = _broadcast("energy", as_energy(self.energy, "energy", ndim=1), n)
        for name, arr in (("theta", th), ("phi", ph), ("rate", rate), ("energy", energy)):
            arr = np.array(arr, dtype=float)
            arr.flags.writeable = False
            # Angles leave as Quantities so that passing them on can't be misread as degrees.
            object.__setattr__(self, name, arr * u.rad if name in ("theta", "phi") else arr)
        if (self.spectrum is None) != (self.band is None):
            raise ParameterError("spectrum and band go together: give both or neither")
        if self.band is not None:
            band = as_energy(self.band, "band")
            if band.shape != (n, 2) or np.any(band[:, 0] >= band[:, 1]):
                raise ParameterError(f"band must be ({n}, 2) increasing keV pairs, got "
                                     f"shape {band.shape}")
            object.__setattr__(self, "band", band)

    @classmethod
    def with_spectrum(
        cls, theta: Any, phi: Any, rate: Any, spectrum: Any, n_bands: int = 8
    ) -> PointSources:
        """Sources of total photon ``rate`` each, with a :class:`~rotmod.energy.PowerLaw`.

        Each direction becomes ``n_bands`` sources, one per log-spaced band, with the
        band's share of the rate and its geometric-mean energy for the attenuation.
        """
        th = np.atleast_1d(as_angle(theta, "theta"))
        ph = np.broadcast_to(np.atleast_1d(as_angle(phi, "phi")), th.shape)
        r = np.broadcast_to(np.atleast_1d(as_array(rate, "rate", 1 / u.s, lo=0.0)), th.shape)
        lo, hi, frac = spectrum.bands(n_bands)
        k = lo.size
        return cls(
            np.repeat(th, k) * u.rad, np.repeat(ph, k) * u.rad,
            (r[:, None] * frac[None, :]).ravel(), np.tile(np.sqrt(lo * hi), th.size),
            spectrum, np.tile(np.stack([lo, hi], axis=1), (th.size, 1)),
        )

    def __len__(self) -> int:
        return self.theta.size

    def __repr__(self) -> str:
        return f"<PointSources {len(self)} sources, {float(self.rate.sum()):g} photons/s in all>"

    @classmethod
    def from_image(
        cls, theta: Any, phi: Any, image: Any, *, energy: Any = 662.0, keep_zero: bool = False
    ) -> PointSources:
        """Sources from a sky image given as pixel directions and rates.

        Parameters
        ----------
        theta, phi : array_like or Quantity
            Direction of each pixel centre (any shape; e.g. from a sky grid's
            ``directions()``), deg if plain numbers.
        image : array_like or Quantity
            Rate of each pixel (photons/s on each detector face with no mask), same size.
        energy : float or Quantity
            Photon energy (keV).
        keep_zero : bool
            Keep pixels of zero rate (default: drop them, they emit nothing).
        """
        th = np.ravel(as_angle(theta, "theta")) * u.rad
        ph = np.ravel(as_angle(phi, "phi")) * u.rad
        img = np.ravel(as_array(image, "image", 1 / u.s, lo=0.0))
        if not (th.size == ph.size == img.size):
            raise ParameterError(
                f"theta, phi and image must have the same size, got {th.size}, {ph.size} "
                f"and {img.size}"
            )
        keep = np.ones(img.size, bool) if keep_zero else img > 0
        if not keep.any():
            raise ParameterError("image must have at least one pixel with rate > 0")
        return cls(th[keep], ph[keep], img[keep], energy)

    @classmethod
    def from_sky(
        cls, coords: Any, attitude: Any, *, rate: Any = 1.0, energy: Any = 662.0
    ) -> PointSources:
        """Sources at sky positions ``coords`` (SkyCoord), seen with ``attitude``.

        Parameters
        ----------
        coords : astropy.coordinates.SkyCoord
            Source positions (any frame astropy converts to ICRS).
        attitude : rotmod.sky.Attitude
            The instrument's pointing and roll.
        rate : float or array_like
            Photons/s per source.
        energy : float, array_like or PowerLaw
            Lines (keV), or a spectrum (:meth:`with_spectrum`).
        """
        theta, phi = attitude.to_instrument(coords)
        if isinstance(energy, PowerLaw):
            return cls.with_spectrum(theta, phi, rate, energy)
        return cls(np.atleast_1d(theta), np.atleast_1d(phi), rate, energy)

    def to_dict(self) -> dict[str, Any]:
        """Plain lists (deg, 1/s, keV) for metadata; :meth:`from_dict` reads them back."""
        return {
            "theta": self.theta.to_value(u.deg).tolist(),
            "phi": self.phi.to_value(u.deg).tolist(),
            "rate": self.rate.tolist(),
            "energy": self.energy.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PointSources:
        """Inverse of :meth:`to_dict`."""
        return cls(d["theta"], d["phi"], d["rate"], d["energy"])
