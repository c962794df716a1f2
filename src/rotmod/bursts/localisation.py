"""Where a burst is: its unfolded counts fitted on the sky, coarse to fine.

The counts of a window around the burst are kept in time bins aligned with the mask-angle
bins (:func:`bin_events`); the model of bin ``k`` of detector ``d`` is

    mu[d, k] = E_k (F w_k P_j(k)[d, t(k), n] + beta_d B_d(t_k)),

with ``E_k`` the bin's good time, ``w_k`` the burst's light curve (its shape, from the
Bayesian blocks of :mod:`rotmod.bursts.measure`), ``P_j`` the folded response of the
attitude segment ``j`` the bin falls in, ``B_d`` the background rate fitted outside the
burst and ``beta_d`` a free level per detector (the background's normalisation during the
burst is fitted with the burst, as in the source fits).  The response is an
:class:`~rotmod.response.UnfoldedResponse`, so the source layer does the rest:

1. **coarse**: a TS map (:func:`rotmod.sources.ts_map`) on a HEALPix cone over the visible
   sky, with pixels about the instrument's scale ``b / L``;
2. **fine**: the best few local maxima refitted with a continuous position
   (:func:`rotmod.sources.fit`), the highest likelihood kept;
3. **region**: :func:`rotmod.sources.localise` -- the likelihood surface, with a settable
   systematic term, its 68 % and 90 % contours and a HEALPix probability map.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod._validate import as_angle_scalar, as_int
from rotmod.binning import TimeBinning
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.progress import ProgressArg
from rotmod.reconstruction.data import PoissonData
from rotmod.response import UnfoldedResponse, aligned_edges, build_response
from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.geometry import SkyGeometry
from rotmod.sky.healpix import HealpixGrid
from rotmod.sources.detection import pixel_position
from rotmod.sources.fitting import FitResult, SourceFitter, fit, fit_with, geometric_scale
from rotmod.sources.localisation import Region, localise
from rotmod.sources.model import PointSource, SkyModel
from rotmod.sources.tsmap import TSMap, ts_map

__all__ = ["BurstCounts", "BurstPosition", "bin_events", "burst_response", "localise_burst"]

#: Attitude segments of at most this many seconds (a balloon's pointing moves by well under
#: the instrument's scale in that time; a fast slew can pass a shorter step).
MAX_ATTITUDE_STEP = 10.0


@dataclass(frozen=True, eq=False)
class BurstCounts:
    """Counts of a window in time bins aligned with the mask-angle bins.

    Attributes
    ----------
    events : EventList
        Where the counts come from (its instrument, energy band, metadata).
    edges : ndarray, shape (n_time + 1,)
        Bin edges (s).
    counts : ndarray, shape (n_det, n_time)
    exposure : ndarray, shape (n_time,)
        Good time in each bin (s): 0 in gaps.
    phase : ndarray of int, shape (n_time,)
        Mask-angle bin of each time bin.
    segment : ndarray of int, shape (n_time,)
        Attitude segment of each time bin.
    attitudes : tuple of Attitude
        One per segment.
    time_bins : TimeBinning
        The mask-angle bins.
    """

    events: EventList
    edges: np.ndarray
    counts: np.ndarray
    exposure: np.ndarray
    phase: np.ndarray
    segment: np.ndarray
    attitudes: tuple[Attitude, ...]
    time_bins: TimeBinning

    @property
    def centres(self) -> np.ndarray:
        """Bin centres (s)."""
        return 0.5 * (self.edges[:-1] + self.edges[1:])

    def data(self, background_rate: np.ndarray) -> PoissonData:
        """The counts with their exposure and ``background_rate`` ``(n_det, n_time)`` (1/s)
        as the template of a background fitted per detector."""
        return PoissonData(self.counts, np.broadcast_to(self.exposure, self.counts.shape),
                           background=background_rate, fit_background=True)


def _attitude_of(events: EventList, attitude: Any) -> Attitude | AttitudeTable:
    att = events.attitude if attitude is None else attitude
    if not isinstance(att, Attitude | AttitudeTable):
        raise ParameterError(
            "attitude must be an Attitude or AttitudeTable (the events carry none): a "
            "burst is placed on the sky through the attitude")
    return att


def bin_events(events: EventList, t_start: Any, t_stop: Any, *,
               time_bins: TimeBinning | int = 32, attitude: Any = None,
               max_step: float = MAX_ATTITUDE_STEP) -> BurstCounts:
    """The events of ``[t_start, t_stop]`` in time bins on the mask-angle bin boundaries.

    Parameters
    ----------
    events : EventList
    t_start, t_stop : float or Quantity
        The window (s); widened to the nearest mask-angle bin boundaries.
    time_bins : TimeBinning or int
        Mask-angle bins per rotation: the time bins are ``rotation_period / n_bins`` long.
    attitude : Attitude or AttitudeTable, optional
        Default the events' attitude.  A table is cut in segments of at most ``max_step``
        seconds, each with its own attitude.
    max_step : float
        Longest attitude segment (s), > 0.
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    tb = TimeBinning.coerce(time_bins)
    inst = events.instrument
    edges = aligned_edges(t_start, t_stop, tb, inst.rotation_period,
                          events.start_phase.to_value(u.deg))
    t0, t1 = float(edges[0]), float(edges[-1])
    n_t, n_det = edges.size - 1, len(inst.detectors)
    # Good time in each bin: the overlap of the bin with every good-time interval.
    lo = np.maximum(edges[:-1, None], events.gti[None, :, 0])
    hi = np.minimum(edges[1:, None], events.gti[None, :, 1])
    exposure = np.clip(hi - lo, 0.0, None).sum(axis=1)
    if not np.any(exposure > 0):
        raise ParameterError(f"the window {t0:g}..{t1:g} s holds no good time")
    sel = (events.time >= t0) & (events.time < t1)
    k = np.clip(np.searchsorted(edges, events.time[sel], side="right") - 1, 0, n_t - 1)
    counts = np.bincount(events.detector[sel] * n_t + k, minlength=n_det * n_t)
    centres = 0.5 * (edges[:-1] + edges[1:])
    xi = 2.0 * np.pi * centres / inst.rotation_period + events.start_phase.to_value(u.rad)
    att = _attitude_of(events, attitude)
    if isinstance(att, Attitude):
        segment, attitudes = np.zeros(n_t, np.int64), (att,)
    else:
        pieces = att.intervals(t0, t1, max_step)
        cuts = np.array([p[1] for p in pieces[:-1]])
        segment = np.searchsorted(cuts, centres, side="right").astype(np.int64)
        attitudes = tuple(p[2] for p in pieces)
    return BurstCounts(events, edges, counts.reshape(n_det, n_t).astype(float), exposure,
                       tb.bin_of(xi), segment, attitudes, tb)


def burst_response(counts: BurstCounts, grid_for: Callable[[Attitude], SkyGeometry], *,
                   energy: Any, model: Any = "exact", weight: Any = None
                   ) -> UnfoldedResponse:
    """The unfolded response of ``counts``: one folded response per attitude segment on
    the grid ``grid_for(attitude)``, read per time bin and weighted by the light curve
    ``weight`` ``(n_time,)`` (default constant)."""
    inst = counts.events.instrument
    used = np.unique(counts.segment)
    parts = []
    for j in range(len(counts.attitudes)):
        att = counts.attitudes[j] if j in used else counts.attitudes[int(used[0])]
        parts.append(build_response(inst, grid_for(att), counts.time_bins, model=model,
                                    energy=energy, dtype=np.float64))
    return UnfoldedResponse(parts, counts.segment, counts.phase, weight, counts.edges)


def coarse_nside(response_scale: float) -> int:
    """The HEALPix ``nside`` whose pixels (``58.6 deg / nside``) are at most ~the
    instrument's scale ``b / L`` (rad): finer pixels than the likelihood's features."""
    nside = 1
    while 58.6 / nside > 1.1 * np.degrees(response_scale) and nside < 8192:
        nside *= 2
    return nside


@dataclass(frozen=True)
class BurstPosition:
    """The burst on the sky.

    Attributes
    ----------
    position : SkyCoord
        Best position (ICRS).
    theta, phi : float
        The same in the instrument frame at the trigger's attitude (deg).
    region : Region
        The likelihood surface with the systematic term: 68 % and 90 % contours, radii,
        areas, the probability map.
    fit : FitResult
        The fitted model (burst flux, background levels) with the burst's TS and flux
        errors.
    coarse : TSMap
        The TS map of the visible sky the search started from.
    response : UnfoldedResponse
        The response of the fit (its light curve weights).
    """

    position: SkyCoord
    theta: float
    phi: float
    region: Region
    fit: FitResult
    coarse: TSMap
    response: UnfoldedResponse

    @property
    def ts(self) -> float:
        """The burst's TS against the background alone."""
        return float(self.fit.ts[0])

    @property
    def sqrt_ts(self) -> float:
        """``sqrt(TS)``."""
        return float(np.sqrt(max(self.ts, 0.0)))

    @property
    def flux(self) -> float:
        """Fitted flux ``F`` at light-curve weight 1 (photons/s on one unobstructed face)."""
        return float(self.fit.model.sources[0].flux)


def _local_maxima(tsm: TSMap, grid: HealpixGrid, n: int) -> list[int]:
    """The ``n`` highest pixels that are the highest within twice the pixel size."""
    ts = np.nan_to_num(np.ravel(tsm.ts), nan=-np.inf)
    th, ph = grid.directions()
    v = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    near = np.cos(2.0 * np.radians(58.6 / grid.nside))
    picked: list[int] = []
    for i in np.argsort(ts)[::-1]:
        if not np.isfinite(ts[i]) or len(picked) >= n:
            break
        if all(v[i] @ v[j] < near for j in picked):
            picked.append(int(i))
    return picked


def localise_burst(
    counts: BurstCounts,
    background_rate: np.ndarray,
    weight: Any = None,
    *,
    energy: Any,
    model: Any = "exact",
    radius: Any = 80.0,
    nside: int | None = None,
    n_refine: int = 3,
    systematic: Any = 0.0,
    progress: ProgressArg = None,
) -> BurstPosition:
    """Localise a burst in ``counts``: coarse TS map, continuous refit, region.

    Parameters
    ----------
    counts : BurstCounts
        :func:`bin_events` of a window holding the burst.
    background_rate : ndarray, shape (n_det, n_time)
        The background rate (1/s) fitted outside the burst: the template whose level per
        detector is fitted with the burst.
    weight : array_like, shape (n_time,), optional
        The burst's light curve in the bins (default constant over the window).
    energy : float or Quantity
        Energy of the response (keV).
    model : str or ProfileModel
        Profile model of the response.
    radius : float or Quantity
        Radius of the searched cone around the pointing (deg), < 90.
    nside : int, optional
        HEALPix ``nside`` of the coarse map (default: pixels about ``b / L``).
    n_refine : int
        Local maxima of the coarse map refitted continuously, >= 1.
    systematic : float or Quantity
        Systematic error per axis added to the region (deg if plain), >= 0.
    progress : bool or callable, optional
        Progress over the coarse map's pixels.
    """
    n_refine = as_int(n_refine, "n_refine", 1)
    rad = np.degrees(as_angle_scalar(radius, "radius", lo=0.0, hi=90.0, lo_open=True,
                                     hi_open=True))
    first = counts.attitudes[int(counts.segment[0])]
    side = (coarse_nside(geometric_scale(counts.events.instrument)) if nside is None
            else as_int(nside, "nside", 1))

    def grid_for(att: Attitude) -> HealpixGrid:
        return HealpixGrid(side, first.ra, first.dec, rad, att)

    response = burst_response(counts, grid_for, energy=energy, model=model, weight=weight)
    data = counts.data(background_rate)
    fitter = SourceFitter(response, data)
    coarse = ts_map(response, data, limits=False, fitter=fitter, progress=progress)
    best: FitResult | None = None
    for pixel in _local_maxima(coarse, response.grid, n_refine):
        start = PointSource(pixel_position(response, pixel), free_position=True)
        res = fit(response, data, SkyModel((start,)), errors=False)
        if best is None or res.loglike > best.loglike:
            best = res
    if best is None:
        raise ParameterError("the coarse map has no finite TS: no counts above background")
    from_fit = fit_with(fitter, best.model, errors=True)
    region = localise(fitter, from_fit.model, 0, systematic=systematic)
    pos = from_fit.model.sources[0].position
    th, ph = first.to_instrument(pos)
    return BurstPosition(pos, float(th.to_value(u.deg)), float(ph.to_value(u.deg)), region,
                         from_fit, coarse, response)
