"""The sky: pixelised fields of view in the instrument frame (with a WCS), and the attitude
that places the instrument frame on the celestial sphere."""

from rotmod.sky.attitude import Attitude
from rotmod.sky.grid import SkyGrid

__all__ = ["Attitude", "SkyGrid"]
