"""Energies: the detectors' energy response, the atmosphere above a balloon, and source spectra.

Responses elsewhere in rotmod are monoenergetic: the modulation of one band.  This package
holds what turns them into spectra in physical units: the redistribution of a photon's energy
in a detector (:mod:`rotmod.spectral.detector`), the residual atmosphere's attenuation
(:mod:`rotmod.spectral.atmosphere`) and spectral models (:mod:`rotmod.spectral.models`).
"""
