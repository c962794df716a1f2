"""Sources: sky models fitted to the counts -- detection, significance, positions, fluxes.

* :class:`PointSource`, :class:`SkyModel` -- sources at continuous positions, a diffuse
  image and a per-detector background that is fitted; the model predicts and simulates
  counts through any response;
* :func:`fit` -- the Poisson likelihood maximised over fluxes (>= 0), background levels and
  positions, with each source's TS, profile-likelihood errors and upper limit;
* :func:`ts_map` -- TS, flux, upper limit and sensitivity of a test source in every pixel;
* :func:`detect` -- the iterative search (TS map, add the peak, refit all) and
  :func:`localise` -- regions from the likelihood surface with a systematic term;
* :func:`light_curve` -- fluxes of known sources per time interval.

See ``docs/sources.md``.
"""

from rotmod.sources.detection import Detection, detect
from rotmod.sources.fitting import FitResult, SourceFitter, fit
from rotmod.sources.lightcurve import LightCurve, light_curve
from rotmod.sources.localisation import Region, localise
from rotmod.sources.model import PointSource, SkyModel
from rotmod.sources.tsmap import TSMap, ts_map

__all__ = ["Detection", "FitResult", "LightCurve", "PointSource", "Region", "SkyModel",
           "SourceFitter", "TSMap", "detect", "fit", "light_curve", "localise", "ts_map"]
