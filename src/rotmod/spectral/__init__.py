"""Energies: the detectors' energy response, the atmosphere above a balloon, and source spectra.

Responses elsewhere in rotmod are monoenergetic: the modulation of one band.  This package
holds what turns them into spectra in physical units: spectral models in astromodels'
conventions (:mod:`rotmod.spectral.models`), counts spectra with their response (RMF x ARF) and
forward-folded Poisson fits (:mod:`rotmod.spectral.spectrum`; OGIP files in
:mod:`rotmod.io.ogip`).
"""

from rotmod.spectral.models import Band, CutoffPowerLaw, Gaussian, PowerLaw, SpectralModel
from rotmod.spectral.spectrum import (
    CountsSpectrum,
    SpectralFit,
    SpectralResponse,
    cash,
    fit_spectrum,
    wstat,
)

__all__ = [
    "Band",
    "CountsSpectrum",
    "CutoffPowerLaw",
    "Gaussian",
    "PowerLaw",
    "SpectralFit",
    "SpectralModel",
    "SpectralResponse",
    "cash",
    "fit_spectrum",
    "wstat",
]
