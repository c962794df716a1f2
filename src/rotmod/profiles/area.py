"""Effective area of a detector of the instrument, with no mask (docs/physics.md)."""

from __future__ import annotations

import dataclasses
from typing import Any

import astropy.units as u
import numpy as np

from rotmod.geometry import Instrument
from rotmod.profiles.base import get_model

__all__ = ["effective_area"]


def effective_area(instrument: Instrument, theta: Any, energy: Any = None, *,
                   phi: Any = 0.0) -> u.Quantity:
    """Effective area of one detector for sources at infinity (no mask): the rate of counts
    per unit photon flux (photons / cm^2 / s across the beam).

    A flat face gives its projected area ``pi R^2 cos(theta)``; a cylinder gives
    ``pi R^2 cos(theta) E0``, ``E0`` the counts per photon crossing the top face, which
    includes photons entering through the side (``E0 = 1 - exp(-mu H)`` on axis, ``1 +
    2 H tan(theta) / (pi R)`` for a black detector).

    Parameters
    ----------
    instrument : Instrument
    theta : array_like or Quantity
        Zenith angles (deg if plain numbers), < 90 deg.
    energy : float or Quantity, optional
        Photon energy (keV); needed for thick detectors unless their attenuation is fixed.
    phi : float or Quantity
        Azimuth (deg); the area of a cylinder does not depend on it.

    Returns
    -------
    Quantity
        cm^2, the shape of ``theta`` (1-D).
    """
    th = np.atleast_1d(u.Quantity(theta, u.deg) if not isinstance(theta, u.Quantity)
                       else theta)
    det = instrument.detectors.with_positions([[0.0, 0.0]])
    clear = Instrument(dataclasses.replace(instrument.mask, mu=0.0, outline=None,
                                           outline_size=None), det)
    E0 = get_model("exact").profile(clear, th, np.broadcast_to(phi, th.shape), [0.0],
                                    energy)[0, 0]
    return np.pi * det.radius**2 * np.cos(th.to_value(u.rad)) * E0 * u.cm**2
