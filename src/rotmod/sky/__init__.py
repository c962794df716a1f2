"""The sky: pixelised fields of view (in the instrument frame, or on the celestial sphere with
a true celestial WCS) and the attitude that places the instrument frame on the sky."""

from typing import Any

from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.celestial import CelestialGrid
from rotmod.sky.grid import SkyGrid
from rotmod.sky.healpix import HealpixGrid

__all__ = ["Attitude", "AttitudeTable", "CelestialGrid", "HealpixGrid", "SkyGrid",
           "grid_from_dict"]


def grid_from_dict(d: dict[str, Any]) -> SkyGrid | CelestialGrid | HealpixGrid:
    """The grid a ``to_dict()`` describes (by its ``kind``; default an instrument grid)."""
    kinds = {"celestial": CelestialGrid, "healpix": HealpixGrid}
    return kinds.get(d.get("kind", ""), SkyGrid).from_dict(d)
