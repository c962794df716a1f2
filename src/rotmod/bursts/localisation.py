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

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod._validate import as_angle_scalar, as_int
from rotmod.binning import TimeBinning
from rotmod.bursts.measure import Background, BurstLightCurve
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.progress import ProgressArg
from rotmod.reconstruction.data import PoissonData
from rotmod.response import ResponseOperator, UnfoldedResponse, aligned_edges, build_response
from rotmod.response.columns import columns_at
from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.geometry import SkyGeometry
from rotmod.sky.healpix import HealpixGrid
from rotmod.sky.points import PositionList
from rotmod.sources.detection import pixel_position
from rotmod.sources.fitting import FitResult, SourceFitter, fit_with, geometric_scale
from rotmod.sources.localisation import Region, localise, vectors_to_positions
from rotmod.sources.model import PointSource, SkyModel, tangent_basis
from rotmod.sources.tsmap import TSMap, null_state, scan_test_source, ts_map

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
                   energy: Any, model: Any = "exact", weight: Any = None,
                   cache: dict[Any, ResponseOperator] | None = None) -> UnfoldedResponse:
    """The unfolded response of ``counts``: one folded response per attitude segment on
    the grid ``grid_for(attitude)``, read per time bin and weighted by the light curve
    ``weight`` ``(n_time,)`` (default constant).

    ``cache`` (a dict the caller keeps) holds the folded responses already computed, by
    attitude, grid, binning, model and energy: they depend on the attitude only, not on the
    burst, so a flight system computes them ahead of the trigger.
    """
    inst = counts.events.instrument
    cache = {} if cache is None else cache
    parts = []
    for att in counts.attitudes:
        grid = grid_for(att)
        key = (att.ra, att.dec, att.roll, json.dumps(grid.to_dict(), sort_keys=True,
                                                     default=str),
               tuple(counts.time_bins.to_dict().items()), str(model), float(energy),
               json.dumps(inst.to_dict(), sort_keys=True, default=str))
        if key not in cache:
            cache[key] = build_response(inst, grid, counts.time_bins, model=model,
                                        energy=energy, dtype=np.float64)
        parts.append(cache[key])
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
    counts : BurstCounts
        The counts of the fit.
    alternatives : tuple of (SkyCoord, float)
        Other local maxima refitted, with their TS below the best (``delta TS``): a mode
        within a few units of TS (the mirror image of a symmetric array, a short burst's
        partial turn) is a real ambiguity, stated in the summary.
    """

    position: SkyCoord
    theta: float
    phi: float
    region: Region
    fit: FitResult
    coarse: TSMap
    response: UnfoldedResponse
    counts: BurstCounts
    alternatives: tuple[tuple[SkyCoord, float], ...] = ()

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


def _best_near(fitter: SourceFitter, null: tuple[np.ndarray, ...], source: PointSource,
               half: float, n: int) -> PointSource:
    """The point of highest TS on an ``n x n`` tangent-plane grid of half-width ``half``
    (rad) around ``source``."""
    v0 = source.vector()
    e1, e2 = tangent_basis(v0)
    o = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(o, o)
    v = v0[None, :] + xx.ravel()[:, None] * e1 + yy.ravel()[:, None] * e2
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    cols = columns_at(fitter.response, vectors_to_positions(source.frame, v))
    ts = np.nan_to_num(scan_test_source(fitter, null, cols, 0.0, 0.0)[:, 0], nan=-np.inf)
    return source.at_vector(v[int(np.argmax(ts))])


def default_time_bins(instrument: Any, radius_deg: float) -> TimeBinning:
    """Mask-angle bins that resolve the modulation out to ``radius_deg`` off axis.

    The slats' shadow moves across a detector at up to ``L tan(theta)`` per radian of
    mask angle, so one period ``p = a + b`` of the mask passes in ``p / (L tan theta)``
    rad; four samples per period (up to 60 deg off axis, beyond which the effective area
    is small) fix the number of samples per turn, taken as bins of two sub-samples each
    (``"average"`` mode: a bin's response is its mean, as its counts are).
    """
    mask = instrument.mask
    theta = np.radians(min(radius_deg, 60.0))
    samples = 4.0 * 2.0 * np.pi * mask.height * np.tan(theta) / mask.period
    n = int(2 ** np.ceil(np.log2(max(samples, 64.0))))
    return TimeBinning(n // 2, "average", 2)


def coarse_time_bins(fine: TimeBinning) -> TimeBinning:
    """The coarse map's bins: 16 times wider (the same samples per turn), so that the
    modulation faster than the coarse pixels is averaged out and the map's peak is as
    broad as a pixel, not narrower (a narrow peak falls between pixel centres)."""
    n = max(fine.n_bins // 16, 8)
    return TimeBinning(n, "average", max(fine.n_bins * fine.n_sub // n, 1))


def _background_rates(background: Background, counts: BurstCounts) -> np.ndarray:
    widths = np.diff(counts.edges)
    return background.counts(counts.edges) / widths[None, :]


def localise_burst(
    events: EventList,
    window: Any,
    background: Background,
    light_curve: BurstLightCurve | None = None,
    *,
    energy: Any,
    model: Any = "exact",
    attitude: Any = None,
    radius: Any = 80.0,
    nside: int | None = None,
    time_bins: TimeBinning | None = None,
    n_refine: int = 3,
    systematic: Any = 0.0,
    progress: ProgressArg = None,
    cache: dict[Any, ResponseOperator] | None = None,
) -> BurstPosition:
    """Localise a burst: coarse TS map of the visible sky, continuous refit, region.

    Parameters
    ----------
    events : EventList
    window : (float, float)
        The time window of the fit (s): the burst with some background around it.
    background : Background
        The background fitted outside the burst (:func:`rotmod.bursts.fit_background`):
        its rate in each bin is the template whose level per detector is fitted with the
        burst.
    light_curve : BurstLightCurve, optional
        The burst's light curve (:func:`rotmod.bursts.burst_light_curve`), whose shape
        weights the response bin by bin; ``None``: a constant source over the window (the
        light curve ignored).
    energy : float or Quantity
        Energy of the response (keV).
    model : str or ProfileModel
        Profile model of the response.
    attitude : Attitude or AttitudeTable, optional
        Default the events' attitude.
    radius : float or Quantity
        Radius of the searched cone around the pointing (deg), < 90.
    nside : int, optional
        HEALPix ``nside`` of the coarse map (default: pixels about ``b / L``).
    time_bins : TimeBinning, optional
        Mask-angle bins of the fine fit (default :func:`default_time_bins`); the coarse map
        uses :func:`coarse_time_bins` of them.
    n_refine : int
        Local maxima of the coarse map refitted continuously, >= 1.
    systematic : float or Quantity
        Systematic error per axis added to the region (deg if plain), >= 0.
    progress : bool or callable, optional
        Progress over the coarse map's pixels.
    cache : dict, optional
        Folded responses computed before, by attitude (:func:`burst_response`).
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    if not isinstance(background, Background):
        raise ParameterError(f"background must be a Background (fit_background), got "
                             f"{type(background)}")
    if light_curve is not None and not isinstance(light_curve, BurstLightCurve):
        raise ParameterError(f"light_curve must be a BurstLightCurve or None, got "
                             f"{type(light_curve)}")
    try:
        t0, t1 = (float(v) for v in window)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"window must be a pair (start, stop) in s, got {window!r}") \
            from exc
    n_refine = as_int(n_refine, "n_refine", 1)
    rad = float(np.degrees(as_angle_scalar(radius, "radius", lo=0.0, hi=90.0, lo_open=True,
                                           hi_open=True)))
    inst = events.instrument
    fine_bins = default_time_bins(inst, rad) if time_bins is None else \
        TimeBinning.coerce(time_bins)
    side = (coarse_nside(geometric_scale(inst)) if nside is None
            else as_int(nside, "nside", 1))
    cache = {} if cache is None else cache

    def weights(c: BurstCounts) -> np.ndarray | None:
        return None if light_curve is None else light_curve.shape(c.edges)

    # 1. Coarse: a TS map of the cone, in wide mask-angle bins.
    coarse = bin_events(events, t0, t1, time_bins=coarse_time_bins(fine_bins),
                        attitude=attitude)
    first = coarse.attitudes[int(coarse.segment[0])]

    def cone(att: Attitude) -> HealpixGrid:
        return HealpixGrid(side, first.ra, first.dec, rad, att)

    response = burst_response(coarse, cone, energy=energy, model=model,
                              weight=weights(coarse), cache=cache)
    data = coarse.data(_background_rates(background, coarse))
    tsm = ts_map(response, data, limits=False, progress=progress)
    starts = [pixel_position(response, p) for p in _local_maxima(tsm, response.grid, n_refine)]
    if not starts:
        raise ParameterError("the coarse map has no finite TS: no counts above background")
    # 2. Fine: continuous fits from the best local maxima, in the fine bins.
    fine = bin_events(events, t0, t1, time_bins=fine_bins, attitude=attitude)

    def pointing(att: Attitude) -> PositionList:
        return PositionList.from_coords(first.pointing, att)

    fine_response = burst_response(fine, pointing, energy=energy, model=model,
                                   weight=weights(fine), cache=cache)
    fine_data = fine.data(_background_rates(background, fine))
    fitter = SourceFitter(fine_response, fine_data)
    best: SkyModel | None = None
    best_ll = -np.inf
    null = null_state(fitter, SkyModel())
    pixel = np.radians(58.6 / side)
    modes: list[tuple[SkyModel, float]] = []
    for start in starts:
        # The fine likelihood has fringes (one mask period of shadow shift, ~p cos^2(theta)
        # / L apart) finer than the coarse pixels: scan the pixel's neighbourhood on a grid
        # finer than them, then climb from the best point.
        start = _best_near(fitter, null, PointSource(start), 1.5 * pixel, 13)
        m = fitter.maximise(SkyModel((dataclasses.replace(start, free_position=True),)))[0]
        m = fitter.fit_positions(m)
        ll = fitter.maximise(m)[1].loglike
        modes.append((m, ll))
        if ll > best_ll:
            best, best_ll = m, ll
    result = fit_with(fitter, best, errors=True)
    # Other modes (e.g. the mirror image through the axis of a symmetric array): their TS
    # below the best, at least a pixel and a half away.
    others = tuple(sorted(
        ((m.sources[0].position, 2.0 * (best_ll - ll)) for m, ll in modes
         if m.sources[0].separation(best.sources[0]) > np.degrees(1.5 * pixel)),
        key=lambda pair: pair[1]))
    # 3. The region: the likelihood surface around the best fit.
    region = localise(fitter, result.model, 0, systematic=systematic)
    pos = result.model.sources[0].position
    th, ph = first.to_instrument(pos)
    return BurstPosition(pos, float(th.to_value(u.deg)), float(ph.to_value(u.deg)), region,
                         result, tsm, fine_response, fine, others)
