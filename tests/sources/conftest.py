"""What the source tests share: a small survey-like field (7 detectors of 5 cm under a
3 cm / 3 cm / 3 cm lead mask 1 m up, the issue's survey instrument with one ring; 300 keV,
60 mask-angle bins, a 12 x 12 grid of 1 deg pixels), and the energy-resolved columns of two
sources in it seen by 5 cm NaI crystals (the spectral fits' and the threeML plugin's)."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod.energy import EnergyResolution
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import Material
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import SpectralColumns, spectral_columns
from rotmod.spectral.detector import tabulate_response

NAI = Material("NaI", density=3.67)
NODES = np.geomspace(60.0, 3000.0, 48)
CHANNELS = np.geomspace(50.0, 2500.0, 25)


@pytest.fixture(scope="package")
def survey_instrument() -> Instrument:
    return Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=1),
                      rotation_period=60)


@pytest.fixture(scope="package")
def field(survey_instrument):
    """The instrument-frame response of the field (float64)."""
    return build_response(survey_instrument, SkyGrid.square(12, 1.0), 60, energy=300,
                          dtype=np.float64)


def spectral_instrument(mask_material: Material | None = None) -> Instrument:
    """7 detectors of 5 cm x 5 cm NaI under 3/3/3 cm slats 1 m up (the survey instrument's
    unit cell)."""
    hexa = DetectorArray.hexagonal(5.0, rings=1)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0, material=NAI)
    mask = Mask(3.0, 3.0, 3.0, 100.0, material=mask_material or Material("Pb"))
    return Instrument(mask, det, rotation_period=60.0)


@pytest.fixture(scope="package")
def detector_response():
    inst = spectral_instrument()
    return tabulate_response(inst.detectors, NODES, [0.0, 10.0, 40.0], CHANNELS,
                             resolution=EnergyResolution.nai(), n_photons=2000, seed=1)


@pytest.fixture(scope="package")
def two_sources(detector_response):
    """Two sources 5 deg and 3 deg off axis on opposite sides, 24 mask-angle bins."""
    resp = build_response(spectral_instrument(), SkyGrid.square(4, 1.0), 24, energy=300.0)
    return spectral_columns(resp, ([5.0, 3.0], [30.0, 200.0]), detector_response)


@pytest.fixture(scope="package")
def columns(two_sources):
    """The first of them alone (its columns are computed per source: the same numbers as
    ``spectral_columns(resp, (5.0, 30.0), ...)``, bit for bit, without a second build)."""
    c = two_sources
    return SpectralColumns(c.columns[:1], c.redistribution[:1], c.energies, c.channel_edges,
                           c.theta[:1])
