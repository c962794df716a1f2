"""Sky grids: pixelised fields of view in the instrument frame, with a WCS."""

from rotmod.sky.grid import SkyGrid

__all__ = ["SkyGrid"]
