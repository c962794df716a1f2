"""Light curves of known sources: every flux refitted per time interval, with the background.

Each interval's events are folded with the response's binning and the sky model is fitted
to them with positions held: all the sources' fluxes and every detector's background level
are free, so a background that drifts through an observation is followed interval by
interval (the background "trend" of a long observation).  Per interval and source the
light curve holds the flux, its profile-likelihood errors, TS and the upper limit.  An
interval with no good time has no measurement: its exposure is 0 and its values NaN (a
documented result, never a silent zero).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.table import Table

from rotmod._validate import as_array
from rotmod.binning import EnergyBand
from rotmod.errors import ParameterError
from rotmod.events.eventlist import EventList
from rotmod.events.folding import fold
from rotmod.progress import ProgressArg, progress_callbacks
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import map_blocks
from rotmod.sources.fitting import SourceFitter, fit_with, ul_threshold
from rotmod.sources.model import SkyModel

__all__ = ["LightCurve", "light_curve"]


@dataclass(frozen=True)
class LightCurve:
    """Fluxes of sources per time interval.

    Attributes
    ----------
    time_edges : ndarray, shape (n + 1,)
        Interval edges (s, the event list's time).
    exposure : ndarray, shape (n,)
        Good time in each interval (s); 0 where there is none.
    names : list of str
        The sources, in the model's order.
    flux, ts, flux_ul : ndarray, shape (n, k)
        Flux (the response's sky unit), TS and upper limit per interval and source.
    flux_err : ndarray, shape (n, k, 2)
        Profile-likelihood ``(lower, upper)`` errors.
    ul_confidence : float
    """

    time_edges: np.ndarray
    exposure: np.ndarray
    names: list[str]
    flux: np.ndarray
    flux_err: np.ndarray
    ts: np.ndarray
    flux_ul: np.ndarray
    ul_confidence: float

    def to_table(self) -> Table:
        """One row per interval, one column entry per source (gammapy's light-curve layout:
        ``time_min``, ``time_max``, ``flux``, ``flux_errn``, ``flux_errp``, ``flux_ul``, ``ts``,
        ``sqrt_ts``), with units and the source names in the metadata."""
        unit = u.Unit("1 / s")
        t = Table()
        t["time_min"] = self.time_edges[:-1] * u.s
        t["time_max"] = self.time_edges[1:] * u.s
        t["exposure"] = self.exposure * u.s
        t["flux"] = self.flux * unit
        t["flux_errn"] = self.flux_err[:, :, 0] * unit
        t["flux_errp"] = self.flux_err[:, :, 1] * unit
        t["flux_ul"] = self.flux_ul * unit
        t["ts"] = self.ts
        t["sqrt_ts"] = np.sqrt(np.maximum(self.ts, 0.0))
        t.meta["SOURCES"] = ",".join(self.names)
        t.meta["UL_CONF"] = self.ul_confidence
        return t


def _fit_interval(interval: tuple[float, float], response: ResponseOperator,
                  events: EventList, model: SkyModel, band: EnergyBand | None,
                  ul_confidence: float) -> tuple[Any, ...] | None:
    """Fit one interval: ``(exposure, flux, flux_err, ts, flux_ul)``, ``None`` without good
    time."""
    part = events.within(*interval)
    if part is None:
        return None
    res = fit_with(SourceFitter(response, fold(part, response.time_bins, band)), model,
                   ul_confidence=ul_confidence)
    return (part.exposure, [s.flux for s in res.model.sources], res.flux_err, res.ts,
            res.flux_ul)


def light_curve(
    response: ResponseOperator,
    events: EventList,
    model: SkyModel,
    time_edges: Any,
    *,
    energy_band: Any = None,
    ul_confidence: float = 0.95,
    progress: ProgressArg = None,
    scheduler: str | None = None,
    client: Any = None,
) -> LightCurve:
    """Fit the fluxes of ``model``'s sources in each interval of ``time_edges``.

    Parameters
    ----------
    response : ResponseOperator
        The response of each interval's folded data (one pointing through the
        observation; for a drifting one, the drift response of the observation).
    events : EventList
    model : SkyModel
        The sources (positions held; start fluxes); the background is refitted per interval.
    time_edges : array_like or Quantity, shape (n + 1,)
        Increasing interval edges (s), at least two.
    energy_band : EnergyBand or (float, float), optional
        Events to keep (keV), as for :func:`rotmod.events.fold`.
    ul_confidence : float
        Confidence of the upper limits.
    progress : bool or callable, optional
        Progress over the intervals.
    scheduler, client : optional
        Fit the intervals on a Dask cluster (address or ``distributed.Client``), one task
        each; default local.

    Returns
    -------
    LightCurve
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    if not isinstance(model, SkyModel) or not model.sources:
        raise ParameterError("model must be a SkyModel with at least one source")
    ul_threshold(ul_confidence)
    edges = as_array(time_edges, "time_edges", u.s, ndim=1)
    if edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ParameterError(f"time_edges must be at least two increasing times (s), got "
                             f"{edges.size} values")
    band = None if energy_band is None else EnergyBand.coerce(energy_band)
    held = model.replace(sources=tuple(dataclasses.replace(s, free_flux=True,
                                                           free_position=False)
                                       for s in model.sources))
    n, k = edges.size - 1, len(model.sources)
    flux, ts, ul = (np.full((n, k), np.nan) for _ in range(3))
    err = np.full((n, k, 2), np.nan)
    exposure = np.zeros(n)
    update, close = progress_callbacks(progress, n, "light curve", "interval")
    blocks = list(itertools.pairwise(edges))
    done = 0
    try:
        # One task per interval (locally in order, or on a Dask cluster as responses' blocks
        # are); each result lands in its own row, so the curve is the same either way.
        for i, res in map_blocks(_fit_interval, blocks, response, events, held, band,
                                 ul_confidence, scheduler=scheduler, client=client):
            if res is not None:
                exposure[i], flux[i], err[i], ts[i], ul[i] = res
            done += 1
            update(done, n)
    finally:
        close()
    names = [s.name or f"source {j}" for j, s in enumerate(model.sources)]
    return LightCurve(edges, exposure, names, flux, err, ts, ul, ul_confidence)
