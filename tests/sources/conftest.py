"""A small survey-like field shared by the source tests: 7 detectors of 5 cm under a
3 cm / 3 cm / 3 cm lead mask 1 m up (the issue's survey instrument with one ring), 300 keV,
60 mask-angle bins, a 12 x 12 grid of 1 deg pixels."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.response import build_response
from rotmod.sky import SkyGrid


@pytest.fixture(scope="package")
def survey_instrument() -> Instrument:
    return Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=1),
                      rotation_period=60)


@pytest.fixture(scope="package")
def field(survey_instrument):
    """The instrument-frame response of the field (float64)."""
    return build_response(survey_instrument, SkyGrid.square(12, 1.0), 60, energy=300,
                          dtype=np.float64)
