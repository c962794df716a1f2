"""Source detection: iterate TS map -> add the peak -> refit everything, until nothing is left.

An RM's sidelobes span the whole field: a bright source leaves a pattern of TS peaks
everywhere until it is in the model, and a crowded field cannot be read one source at a
time.  So detection is iterative (the matching-pursuit loop of coded-mask surveys):

1. fit the background (and any sources given) and compute the TS map of a test source
   against that model;
2. if its highest peak passes the seed threshold (``threshold / 2`` by default), add a
   candidate there, fit its position continuously, refit every flux and the background
   together and every position again (a position fitted while a neighbour was missing leans
   toward it: the neighbour's modulation is read as its own); otherwise stop;
3. prune: while the weakest candidate's TS is below ``threshold``, remove it and refit;
4. each source's TS (the model without it refitted), flux errors, upper limit and
   localisation region.

Candidates are added down to half the threshold and judged only at the end because an RM's
point-spread function has strong rings (the modulation is dominated by one spatial frequency,
the mask period over its height): a source fitted while a neighbour a few degrees away is
missing absorbs part of it, and the neighbour's residual TS falls below threshold although
the complete model would detect it (measured on a five-source field: with the threshold
applied at once, two sources of oracle TS 47 and 35 were lost).

The map maximum is taken over many pixels, so its null distribution is not the fixed-position
``1/2 chi2_0 + 1/2 chi2_1``: ``benchmarks/sources_calibration.py`` measures it on empty
fields and ``docs/sources.md`` states the threshold for a given false-detection rate (the
trials factor).

**Confusion.**  Sources too faint to detect still modulate the counts, and their sidelobes
cross the whole field: each pixel's significance then has a variance ``1 + sigma_c^2``
instead of 1, and TS peaks appear where no source is (``docs/sources_crowded.md``).  As
coded-mask surveys do, the field's noise is measured on the residual map, away from the
catalogued sources: a pixel's signed significance (``sqrt(TS)``, negative where the flux
would be) is ``N(0, 1)`` under a complete model, so its 84.13 % quantile, which needs only
the positive half, estimates the width ``sigma_w``; :func:`confusion_noise` returns
``sigma_c = sqrt(max(sigma_w^2 - 1, 0))`` and each source's ``TS / (1 + sigma_c^2)`` is its
TS with the confusion noise counted (the catalogue's ``TS_CONF``).  The estimate has the
noise of a quantile over the field's independent beams (+-0.22 in ``sigma_w`` for 48 beams).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rotmod._validate import as_angle_scalar
from rotmod.conventions import source_direction
from rotmod.errors import ParameterError
from rotmod.progress import ProgressArg
from rotmod.response.operator import ResponseOperator
from rotmod.sources.fitting import FitResult, SourceFitter, fit_with, geometric_scale
from rotmod.sources.localisation import Region, localise
from rotmod.sources.model import PointSource, SkyModel
from rotmod.sources.tsmap import TSMap, ts_map

__all__ = ["Detection", "confusion_noise", "detect", "pixel_position"]


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
    history : list of dict
        The search's steps (each candidate tried, each pruned).
    confusion : float
        The field's confusion noise ``sigma_c`` on the residual map (:func:`confusion_noise`;
        NaN when not measured).
    """

    result: FitResult
    regions: list[Region | None]
    ts_map: TSMap
    first_map: TSMap
    threshold: float
    history: list[dict[str, Any]] = field(default_factory=list)
    confusion: float = float("nan")

    @property
    def sources(self) -> tuple[PointSource, ...]:
        """The detected (and given) sources, fitted."""
        return self.result.model.sources

    @property
    def ts_confused(self) -> np.ndarray:
        """Each source's TS with the confusion noise counted: ``TS / (1 + sigma_c^2)``."""
        c = 0.0 if not np.isfinite(self.confusion) else self.confusion
        return np.asarray(self.result.ts, dtype=float) / (1.0 + c * c)


#: Quantile of a standard normal at +1 sigma.
_PLUS_ONE_SIGMA = 0.8413447460685429


def confusion_noise(ts_map: TSMap, sources: tuple[PointSource, ...] | list[PointSource] = (),
                    radius: float = 0.0) -> float:
    """The confusion noise ``sigma_c`` of a residual TS map (module notes).

    Parameters
    ----------
    ts_map : TSMap
        Against a model with the catalogued sources.
    sources : sequence of PointSource
        Those sources: pixels within ``radius`` of any are left out (their residuals are
        fitted away).
    radius : float
        Degrees, >= 0.

    Returns
    -------
    float
        ``sqrt(max(sigma_w^2 - 1, 0))``, ``sigma_w`` the 84.13 % quantile of the pixels'
        signed significance; NaN when fewer than 20 pixels are left.
    """
    if not (np.isfinite(radius) and radius >= 0):
        raise ParameterError(f"radius must be >= 0 deg, got {radius!r}")
    ts = np.asarray(ts_map.ts, dtype=float).ravel()
    keep = np.isfinite(ts)
    if len(sources) and radius > 0 and ts_map.grid is not None:
        th, ph = ts_map.grid.directions()
        if ts_map.grid.frame == "celestial":
            vec = ts_map.grid.attitude.to_sky(th, ph).cartesian.xyz.value.T
        else:
            vec = source_direction(th.to_value("rad"), ph.to_value("rad"))
        near = vec.reshape(-1, 3) @ np.stack([src.vector() for src in sources]).T
        keep &= ~np.any(near > np.cos(np.radians(radius)), axis=1)
    if keep.sum() < 20:
        return float("nan")
    flux = np.asarray(ts_map.flux, dtype=float).ravel()[keep]
    signed = np.where((ts[keep] > 0) & (flux > 0), np.sqrt(ts[keep]), -1.0)
    width = float(np.quantile(signed, _PLUS_ONE_SIGMA))
    return float(np.sqrt(max(width * width - 1.0, 0.0)))


def detect(
    response: ResponseOperator,
    data: Any,
    model: SkyModel | None = None,
    *,
    threshold: float = 25.0,
    seed_threshold: float | None = None,
    max_sources: int = 50,
    fit_positions: bool = True,
    localise_sources: bool = True,
    systematic: Any = 0.0,
    ul_confidence: float = 0.95,
    exact_above: float | None = None,
    progress: ProgressArg = None,
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
    seed_threshold : float, optional
        TS a map peak must reach to be tried as a candidate (default ``threshold / 2``):
        candidates are added down to it, then pruned to ``threshold`` one at a time (the
        weakest first, everything refitted).  Adding the weaker ones before judging lets
        every position be fitted with its neighbours in the model; judging them at
        ``threshold`` directly loses sources in a crowded field (see the module notes).
    max_sources : int
        Stop after adding this many candidates, >= 0.
    fit_positions : bool
        Fit the new sources' positions continuously (else they stay on pixel centres).
    localise_sources : bool
        Compute each source's localisation region.
    systematic : float or Quantity
        Systematic position error per axis (deg if plain) folded into the regions.
    ul_confidence : float
        Confidence of the upper limits.
    exact_above : float, optional
        Screen each TS map (:func:`~rotmod.sources.ts_map`'s ``exact_above``: the score
        test everywhere, the likelihood ratio where TS nears this value): what a wide field
        needs.  At or below ``seed_threshold``, every peak the search reads is exact.
        Default: every pixel of every map exact.
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
    seed = float(threshold) / 2.0 if seed_threshold is None else float(seed_threshold)
    if not (np.isfinite(seed) and 0 < seed <= threshold):
        raise ParameterError(f"seed_threshold must be in (0, threshold = {threshold:g}], got "
                             f"{seed_threshold!r}")
    fitter = SourceFitter(response, data)
    model = SkyModel() if model is None else model
    given = len(model.sources)
    model = fitter.maximise(model)[0]
    first = current = ts_map(response, fitter.data, model, fitter=fitter, progress=progress,
                             ul_confidence=ul_confidence, exact_above=exact_above)
    history: list[dict[str, Any]] = []
    excluded: set[int] = set()
    added = 0
    while added < max_sources:
        ts = np.where(np.isfinite(current.ts), current.ts, -np.inf).ravel()
        if excluded:
            ts[list(excluded)] = -np.inf
        pixel = int(np.argmax(ts))
        if ts[pixel] < seed:
            break
        # The next free name "S<n>" (a given catalogue may hold "S1" already).
        taken = {src.name for src in model.sources}
        name = next(f"S{n}" for n in range(len(model.sources) + 1, 2 * len(taken) + 3)
                    if f"S{n}" not in taken)
        trial = model.replace(sources=(*model.sources, PointSource(
            pixel_position(response, pixel), name=name, free_position=fit_positions)))
        trial = fitter.maximise(trial)[0]
        if fit_positions:
            trial = fitter.fit_positions(trial, only=[len(trial.sources) - 1])
        # A peak that the refit does not keep above the seed threshold (a sidelobe of a
        # source already in the model) is excluded, not added.
        ll = fitter.maximise(trial)[1].loglike
        ts_new = fitter.source_ts(trial, len(trial.sources) - 1, ll)
        history.append({"pixel": pixel, "map_ts": float(ts[pixel]), "fit_ts": ts_new,
                        "added": ts_new >= seed})
        if ts_new < seed:
            excluded.add(pixel)
            continue
        model = trial
        added += 1
        if fit_positions and len(model.sources) > 1:
            # Every position again with the new source in the model: a position fitted
            # while a neighbour was missing leans toward it (the neighbour's modulation is
            # read as its own), which biases its flux and hides the neighbour's residual.
            model = fitter.fit_positions(model)
        # Read only for its peak: TS only (limits and sensitivity are most of a map's cost).
        current = ts_map(response, fitter.data, model, fitter=fitter, progress=progress,
                         limits=False, exact_above=exact_above)
    # Prune: the weakest candidate below threshold goes, the rest are refitted, until every
    # found source passes (the sources given are kept whatever their TS).
    while len(model.sources) > given:
        ll = fitter.maximise(model)[1].loglike
        ts_all = [fitter.source_ts(model, k, ll) for k in range(given, len(model.sources))]
        weakest = int(np.argmin(ts_all))
        if ts_all[weakest] >= threshold:
            break
        k = given + weakest
        history.append({"pruned": model.sources[k].name, "fit_ts": ts_all[weakest]})
        model = model.replace(sources=model.sources[:k] + model.sources[k + 1:])
        added -= 1
        if fit_positions:
            model = fitter.fit_positions(fitter.maximise(model)[0])
    result = fit_with(fitter, model, ul_confidence=ul_confidence)
    # The residual map with its limits: the first map if no candidate was ever kept (the
    # loop's own maps are TS only).
    kept = any(h.get("added") for h in history)
    final = ts_map(response, fitter.data, result.model, fitter=fitter, progress=progress,
                   ul_confidence=ul_confidence, exact_above=exact_above) if kept else first
    regions: list[Region | None] = [None] * len(result.model.sources)
    if localise_sources:
        regions = [localise(fitter, result.model, k, systematic=systematic)
                   for k in range(len(result.model.sources))]
    # The field's confusion noise, away from the catalogued sources (their residuals are
    # fitted away within about the instrument's angular scale).
    radius = 0.0 if response.instrument is None else np.degrees(2 * geometric_scale(response))
    confusion = confusion_noise(final, result.model.sources, radius)
    return Detection(result, regions, final, first, float(threshold), history, confusion)
