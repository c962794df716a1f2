"""The sky: pixelised fields of view (in the instrument frame, or on the celestial sphere with
a true celestial WCS), the attitude that places the instrument frame on the sky, and the
point sources that are the sky's truth.

Every grid is a :class:`SkyGeometry`; :func:`grid_from_dict` reads any grid's ``to_dict()``
back through the registry :data:`GRID_KINDS` (see :mod:`rotmod.sky.geometry`).
"""

from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.celestial import CelestialGrid
from rotmod.sky.geometry import GRID_KINDS, SkyGeometry, WcsGeometry, grid_from_dict
from rotmod.sky.grid import SkyGrid
from rotmod.sky.healpix import HealpixGrid
from rotmod.sky.points import DirectionList, PositionList
from rotmod.sky.sources import PointSources

__all__ = ["GRID_KINDS", "Attitude", "AttitudeTable", "CelestialGrid", "DirectionList",
           "HealpixGrid", "PointSources", "PositionList", "SkyGeometry", "SkyGrid",
           "WcsGeometry", "grid_from_dict"]
