"""Energies: the detectors' energy response, the atmosphere above a balloon, and source spectra.

Responses elsewhere in rotmod are monoenergetic: the modulation of one band.  This package
holds what turns them into spectra in physical units:

* :mod:`rotmod.spectral.models`: spectral models in astromodels' conventions;
* :mod:`rotmod.spectral.spectrum`: counts spectra with their response (RMF x ARF) and
  forward-folded Poisson fits (OGIP files in :mod:`rotmod.io.ogip`);
* :mod:`rotmod.spectral.detector`: the detectors' energy response (a Monte Carlo of photon
  transport in a cylinder, tabulated redistribution matrices);
* :mod:`rotmod.spectral.atmosphere`: the residual atmosphere's column and transmission above a
  balloon (NRLMSIS via pymsis);
* :mod:`rotmod.spectral.background`: the diffuse background at a balloon (CXB through the
  air, atmospheric continuum and 511 keV line, internal component) folded into counts per
  channel, along a flight.

The first two are re-exported here; the last three are imported from their modules (they load
numba kernels and astropy's coordinates, which a reader of spectra does not need).
"""

from rotmod.spectral.models import (
    Band,
    CutoffPowerLaw,
    Function,
    Gaussian,
    PowerLaw,
    SpectralModel,
)
from rotmod.spectral.spectrum import (
    CountsSpectrum,
    RateSpectrum,
    SpectralFit,
    SpectralResponse,
    StatisticMinimum,
    cash,
    fit_spectrum,
    minimise_statistic,
    wstat,
)

__all__ = [
    "Band",
    "CountsSpectrum",
    "CutoffPowerLaw",
    "Function",
    "Gaussian",
    "PowerLaw",
    "RateSpectrum",
    "SpectralFit",
    "SpectralModel",
    "SpectralResponse",
    "StatisticMinimum",
    "cash",
    "fit_spectrum",
    "minimise_statistic",
    "wstat",
]
