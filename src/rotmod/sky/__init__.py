"""The sky: pixelised fields of view (in the instrument frame, or on the celestial sphere with
a true celestial WCS) and the attitude that places the instrument frame on the sky."""

from typing import Any

from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.celestial import CelestialGrid
from rotmod.sky.grid import SkyGrid

__all__ = ["Attitude", "AttitudeTable", "CelestialGrid", "SkyGrid", "grid_from_dict"]


def grid_from_dict(d: dict[str, Any]) -> SkyGrid | CelestialGrid:
    """The grid a ``to_dict()`` describes (``kind`` "celestial", or an instrument-frame grid)."""
    return CelestialGrid.from_dict(d) if d.get("kind") == "celestial" else SkyGrid.from_dict(d)
