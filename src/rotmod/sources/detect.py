"""Source detection: iterate TS map -> add the peak -> refit everything, until nothing is left.

An RM's sidelobes span the whole field: a bright source leaves a pattern of TS peaks
everywhere until it is in the model, and a crowded field cannot be read one source at a
time.  So detection is iterative (the matching-pursuit loop of coded-mask surveys):

1. fit the background (and any sources given) and compute the TS map of a test source
   against that model;
2. if its highest peak passes ``threshold``, add a source there, fit its position
   continuously and refit every flux and the background together; otherwise stop;
3. after the loop, refit every position once more with all the others in the model, then
   each source's TS (the model without it refitted), flux errors, upper limit and
   localisation region.

The map maximum is taken over many pixels, so its null distribution is not the fixed-position
``1/2 chi2_0 + 1/2 chi2_1``: ``benchmarks/sources_calibration.py`` measures it on empty
fields and ``docs/sources.md`` states the threshold for a given false-detection rate (the
trials factor).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rotmod._validate import as_angle_scalar
from rotmod.errors import ParameterError
from rotmod.progress import Progress
from rotmod.response.operator import ResponseOperator
from rotmod.sources.fit import FitResult, SourceFitter, fit_with
from rotmod.sources.localise import Region, localise
from rotmod.sources.model import PointSource, SkyModel
from rotmod.sources.tsmap import TSMap, scan_grid, ts_map

__all__ = ["Detection", "detect", "pixel_position"]


def pixel_position(response: ResponseOperator, pixel: int) -> Any:
    """The position of a pixel of the response's grid: SkyCoord or ``(theta, phi)`` deg."""
    th, ph = response.grid.directions()
    t, p = th[pixel], ph[pixel]
    if response.grid.frame == "celestial":
        return response.grid.attitude.to_sky(t, p)
    return (float(t.to_value("deg")), float(p.to_value("deg")))


@dataclass(frozen=True)
class Detection:
    """What :func:`detect` found.

    Attributes
    ----------
    result : FitResult
        The final joint fit (every source, the background), with TS, flux errors and
        upper limits per source.
    regions : list of Region
        Localisation region of each source (``None`` entries when not computed).
    ts_map : TSMap
        The residual TS map against the final model (what is left undetected).
    first_map : TSMap
        The TS map against the background alone (the first step).
    threshold : float
        The TS a map peak had to pass.
    """

    result: FitResult
    regions: list[Region | None]
    ts_map: TSMap
    first_map: TSMap
    threshold: float
    history: list[dict[str, Any]] = field(default_factory=list)

    @property
    def sources(self) -> tuple[PointSource, ...]:
        """The detected (and given) sources, fitted."""
        return self.result.model.sources


def detect(
    response: ResponseOperator,
    data: Any,
    model: SkyModel | None = None,
    *,
    threshold: float = 25.0,
    max_sources: int = 50,
    fit_positions: bool = True,
    localise_sources: bool = True,
    systematic: Any = 0.0,
    ul_confidence: float = 0.95,
    progress: Progress = None,
) -> Detection:
    """Find the sources in ``data``: the iterative TS-map search (module notes).

    Parameters
    ----------
    response : ResponseOperator
        On the sky geometry to search (instrument, celestial, HEALPix grid).
    data : PoissonData or FoldedProfiles
    model : SkyModel, optional
        Known sources to start from (kept, refitted); default: background only.
    threshold : float
        TS a map peak must reach to be added (25: 5 sigma at a fixed position; see the
        module notes for the map maximum), > 0.
    max_sources : int
        Stop after adding this many sources, >= 0.
    fit_positions : bool
        Fit the new sources' positions continuously (else they stay on pixel centres).
    localise_sources : bool
        Compute each source's localisation region.
    systematic : float or Quantity
        Systematic position error per axis (deg if plain) folded into the regions.
    ul_confidence : float
        Confidence of the upper limits.
    progress : bool or callable, optional
        Progress of each TS map.

    Returns
    -------
    Detection
    """
    if not (np.isfinite(threshold) and threshold > 0):
        raise ParameterError(f"threshold must be a TS > 0, got {threshold!r}")
    if isinstance(max_sources, bool) or not isinstance(max_sources, int | np.integer) \
            or max_sources < 0:
        raise ParameterError(f"max_sources must be an integer >= 0, got {max_sources!r}")
    as_angle_scalar(systematic, "systematic", lo=0.0)
    fitter = SourceFitter(response, data)
    model = SkyModel() if model is None else model
    model = fitter.maximise(model)[0]
    first = ts_map(response, fitter.data, model, fitter=fitter, progress=progress)
    # The search reads only the TS of the maps in between: their upper limits and
    # sensitivities (~90 % of a map's cost) are computed for the first and the final map.
    current = first.ts
    history: list[dict[str, Any]] = []
    excluded: set[int] = set()
    added = 0
    while added < max_sources:
        ts = np.where(np.isfinite(current), current, -np.inf).ravel()
        if excluded:
            ts[list(excluded)] = -np.inf
        pixel = int(np.argmax(ts))
        if ts[pixel] < threshold:
            break
        name = f"S{len(model.sources) + 1}"
        trial = model.replace(sources=(*model.sources, PointSource(
            pixel_position(response, pixel), name=name, free_position=fit_positions)))
        trial = fitter.maximise(trial)[0]
        if fit_positions:
            trial = fitter.fit_positions(trial, only=[len(trial.sources) - 1])
        # A peak that the refit does not keep above threshold (a sidelobe of a source
        # already in the model) is excluded, not added.
        ll = fitter.maximise(trial)[1].loglike
        ts_new = fitter.source_ts(trial, len(trial.sources) - 1, ll)
        history.append({"pixel": pixel, "map_ts": float(ts[pixel]), "fit_ts": ts_new,
                        "added": ts_new >= threshold})
        if ts_new < threshold:
            excluded.add(pixel)
            continue
        model = trial
        added += 1
        current = scan_grid(response, fitter, model, 0.0, 0.0, progress)[:, 0]
    if fit_positions and len(model.sources) > 1:
        # Every position once more, with every other source now in the model.
        model = fitter.fit_positions(model)
    result = fit_with(fitter, model, ul_confidence=ul_confidence)
    final = ts_map(response, fitter.data, result.model, fitter=fitter, progress=progress) \
        if added else first
    regions: list[Region | None] = [None] * len(result.model.sources)
    if localise_sources:
        regions = [localise(fitter, result.model, k, systematic=systematic)
                   for k in range(len(result.model.sources))]
    return Detection(result, regions, final, first, float(threshold), history)
