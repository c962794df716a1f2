"""Sources: sky models fitted to the counts -- detection, significance, positions, fluxes.
"""

from rotmod.sources.fit import FitResult, SourceFitter, fit
from rotmod.sources.model import PointSource, SkyModel

__all__ = ["FitResult", "PointSource", "SkyModel", "SourceFitter", "fit"]
