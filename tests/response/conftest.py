"""Fixtures the response tests share."""

from __future__ import annotations

import pytest

from rotmod.geometry import DetectorArray, Instrument
from rotmod.materials import PAPER_SIGMA_662


@pytest.fixture(scope="module")
def inst() -> Instrument:
    """The paper's lead mask (662 keV sigma) over a 7-detector hexagonal array (c = 3.8 cm <
    a = 4 cm)."""
    return Instrument(Instrument.paper(sigma=PAPER_SIGMA_662).mask,
                      DetectorArray.hexagonal(3.8, rings=1))
