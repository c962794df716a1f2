"""Instrument geometry: the slat mask, the detector array and the rotating instrument.

All follow :mod:`rotmod.conventions`.
"""

from rotmod.geometry.detectors import DetectorArray, disc_flux
from rotmod.geometry.instrument import Instrument
from rotmod.geometry.mask import Mask

__all__ = ["DetectorArray", "Instrument", "Mask", "disc_flux"]
