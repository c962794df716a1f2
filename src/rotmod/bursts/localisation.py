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
   sky, with pixels about the instrument's scale ``b / L``, in wide mask-angle bins;
2. **fine**: the neighbourhoods of the best local maxima scanned in narrower bins, then in
   the fine bins (which resolve the modulation at the candidates' off-axis angles), and
   the best peaks refitted with a continuous position; the highest likelihood is kept and
   the others are reported as alternatives;
3. **region**: :func:`rotmod.sources.localise` -- the likelihood surface, with a settable
   systematic term, its 68 % and 90 % contours and a HEALPix probability map.

``docs/bursts.md`` derives the bin widths and says why each stage is there.
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
from rotmod.sources.localisation import Region, localise
from rotmod.sources.model import PointSource, SkyModel, positions_of
from rotmod.sources.tsmap import TSMap, ts_map

__all__ = ["BurstCounts", "BurstPosition", "bin_events", "burst_response", "localise_burst"]

#: Attitude segments of at most this many seconds (a balloon's pointing moves by well under
#: the instrument's scale in that time; a fast slew can pass a shorter step).
MAX_ATTITUDE_STEP = 10.0
#: Off-axis margin (deg) beyond the coarse candidates for the fine bins' sampling: the
#: coarse pixels are ~b/L across, and a fit moves by a few of them at most.
FINE_MARGIN = 5.0
#: Mask-angle bins per turn of the coarse map (11 deg each).  With pixels of ~b/L, 32 bins
#: found the burst's basin at 10-35 deg off axis on the survey instrument where 64 missed
#: it at 35 deg (its peak narrower than a pixel), in single injections during development;
#: benchmarks/bursts_calibration.py measures the whole chain.
COARSE_BINS = 32
#: Positions passed on from the coarse to the medium bins, and from the medium to the fine.
MEDIUM_CANDIDATES = 4
FINE_FITS = 3


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
        The TS map of the visible sky the search started from (with the light curve).
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


def _light_curve_from(light_curve: BurstLightCurve, counts: BurstCounts,
                      unit: UnfoldedResponse, source: PointSource) -> np.ndarray:
    """The light curve's weights in the bins of ``counts``, seen from ``source``.

    Each block's net counts over the counts a unit flux at ``source`` gives in it (the
    response summed over the detectors, weight 1): the block's flux.  The summed rate of a
    bright burst carries the mask's modulation of the summed transmission; the blocks'
    net rates taken as the light curve would put it in the model twice (measured: a burst
    of sqrt(TS) 136 placed 68 deg away, its TS 1100 above the truth's in the coarse map).
    """
    col = columns_at(unit, positions_of([source]))[:, :, 0].sum(axis=0) * counts.exposure
    edges = light_curve.edges
    n = light_curve.counts.size
    inside = (counts.centres >= edges[0]) & (counts.centres < edges[-1])
    block = np.clip(np.searchsorted(edges, counts.centres, side="right") - 1, 0, n - 1)
    per_flux = np.bincount(block[inside], weights=col[inside], minlength=n)
    net = np.where(light_curve.burst,
                   np.maximum(light_curve.counts - light_curve.background, 0.0), 0.0)
    flux = np.where(per_flux > 0, net / np.where(per_flux > 0, per_flux, 1.0), 0.0)
    w = np.where(inside, flux[block], 0.0)
    return w / w.max() if w.max() > 0 else light_curve.shape(counts.edges)


def default_time_bins(instrument: Any, radius_deg: float) -> TimeBinning:
    """Mask-angle bins that resolve the modulation out to ``radius_deg`` off axis.

    The slats' shadow moves across a detector at up to ``L tan(theta)`` per radian of
    mask angle, so one period ``p = a + b`` of the mask passes in ``p / (L tan theta)``
    rad; eight samples per period (up to 60 deg off axis, beyond which the effective area
    is small) fix the number of samples per turn, taken as bins of two sub-samples each
    (``"average"`` mode: a bin's response is its mean, as its counts are).  With four
    (bins of half a period) the midpoint rule's error in a bin's mean biased positions by
    more than their 90 % radius at 25 deg off axis (measured); with eight it did not.
    """
    mask = instrument.mask
    theta = np.radians(min(radius_deg, 60.0))
    samples = 8.0 * 2.0 * np.pi * mask.height * np.tan(theta) / mask.period
    n = int(2 ** np.ceil(np.log2(max(samples, 64.0))))
    return TimeBinning(n // 2, "average", 2)


def coarse_time_bins(fine: TimeBinning) -> TimeBinning:
    """The coarse map's bins: :data:`COARSE_BINS` per turn, each the mean of as many
    samples as the fine bins take, so that the modulation faster than the coarse pixels is
    averaged out and the map's peak is as broad as a pixel (a narrow peak falls between
    pixel centres, and the map then peaks on a sidelobe)."""
    n = min(COARSE_BINS, fine.n_bins)
    return TimeBinning(n, "average", max(fine.n_bins * fine.n_sub // n, 1))


def _background_rates(background: Background, counts: BurstCounts) -> np.ndarray:
    widths = np.diff(counts.edges)
    return background.counts(counts.edges) / widths[None, :]


def localise_burst(
    events: EventList,
    window: Any,
    background: Background,
    light_curve: BurstLightCurve | Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    energy: Any,
    model: Any = "exact",
    attitude: Any = None,
    max_step: float = MAX_ATTITUDE_STEP,
    radius: Any = 80.0,
    nside: int | None = None,
    time_bins: TimeBinning | None = None,
    n_refine: int = 4,
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
    light_curve : BurstLightCurve or callable, optional
        The burst's light curve (:func:`rotmod.bursts.burst_light_curve`), whose shape
        weights the response bin by bin (or any function of the bins' edges giving their
        weights); ``None``: a constant source over the window.
    energy : float or Quantity
        Energy of the response (keV).
    model : str or ProfileModel
        Profile model of the response.
    attitude : Attitude or AttitudeTable, optional
        Default the events' attitude.
    max_step : float
        Longest attitude segment (s) of a table, > 0.
    radius : float or Quantity
        Radius of the searched cone around the pointing (deg), < 90.
    nside : int, optional
        HEALPix ``nside`` of the coarse map (default: pixels about ``b / L``).
    time_bins : TimeBinning, optional
        Mask-angle bins of the fine fit (default :func:`default_time_bins` out to the
        coarse candidates' off-axis angle plus :data:`FINE_MARGIN`); the coarse map uses
        :func:`coarse_time_bins` of :func:`default_time_bins` at ``radius``.
    n_refine : int
        Local maxima of each coarse map (with the light curve, and with the burst's extent
        weighted evenly) refined, >= 1.
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
    if light_curve is not None and not (isinstance(light_curve, BurstLightCurve)
                                        or callable(light_curve)):
        raise ParameterError(f"light_curve must be a BurstLightCurve (or a function of the "
                             f"bin edges giving the weights) or None, got {type(light_curve)}")
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
        if light_curve is None:
            return None
        shape = light_curve.shape if isinstance(light_curve, BurstLightCurve) else light_curve
        return np.asarray(shape(c.edges), dtype=float)

    # 1. Coarse: a TS map of the cone, in wide mask-angle bins.
    coarse = bin_events(events, t0, t1, time_bins=coarse_time_bins(fine_bins),
                        attitude=attitude, max_step=max_step)
    first = coarse.attitudes[int(coarse.segment[0])]

    def cone(att: Attitude) -> HealpixGrid:
        return HealpixGrid(side, first.ra, first.dec, rad, att)

    # Two coarse maps: with the light curve, and with the burst's extent weighted evenly.
    # The shape sharpens a map's peak, which can then fall between pixels and leave the map
    # peaking on a sidelobe (a burst 55 deg off axis was missed with the shape alone, one 18
    # deg off axis without it), so the local maxima of both are refined.
    data = coarse.data(_background_rates(background, coarse))
    w = weights(coarse)
    starts: list[Any] = []
    tsm: TSMap | None = None
    for weight in ([w, (w > 0).astype(float)] if w is not None else [None]):
        response = burst_response(coarse, cone, energy=energy, model=model, weight=weight,
                                  cache=cache)
        m = ts_map(response, data, limits=False, progress=progress)
        tsm = m if tsm is None else tsm
        for p in _local_maxima(m, response.grid, n_refine):
            new = PointSource(pixel_position(response, p))
            if all(new.separation(PointSource(s)) > 2.0 * 58.6 / side for s in starts):
                starts.append(new.position)
    if not starts:
        raise ParameterError("the coarse map has no finite TS: no counts above background")
    # 2. Fine: continuous fits in ever finer mask-angle bins, each stage climbing from the
    # best positions of the one before.  The likelihood in fine bins has fringes (a shadow
    # shifted by one mask period, ~p cos^2(theta) / L apart) around a core far narrower
    # than a coarse pixel: a climb there from a pixel away stops on a fringe.  In bins 16x
    # and 4x wider the core is broader and the fringes washed out, so the coarse and medium
    # climbs bring the start within reach of the core.  The fine bins resolve the
    # modulation at the candidates' own off-axis angles (a burst near the axis needs a
    # fraction of the samples of one at the cone's edge).
    if time_bins is None:
        reach = max(float(first.to_instrument(p)[0].to_value(u.deg)) for p in starts)
        fine_bins = default_time_bins(inst, min(reach + FINE_MARGIN, rad))
    medium_bins = TimeBinning(max(fine_bins.n_bins // 4, 8), "average",
                              max(fine_bins.n_bins * fine_bins.n_sub // max(
                                  fine_bins.n_bins // 4, 8), 1))

    def pointing(att: Attitude) -> PositionList:
        return PositionList.from_coords(first.pointing, att)

    def stage(bins: TimeBinning) -> tuple[BurstCounts, UnfoldedResponse, PoissonData]:
        c = bin_events(events, t0, t1, time_bins=bins, attitude=attitude, max_step=max_step)
        return c, burst_response(c, pointing, energy=energy, model=model, cache=cache), \
            c.data(_background_rates(background, c))

    def fitter_at(c: BurstCounts, unit: UnfoldedResponse, data: PoissonData,
                  src: PointSource) -> SourceFitter:
        """The fitter of a candidate position, with the light curve seen from there."""
        return SourceFitter(unit.with_weight(_light_curve_from(light_curve, c, unit, src)
                                             if isinstance(light_curve, BurstLightCurve)
                                             else weights(c)), data)

    coarse_unit = burst_response(coarse, cone, energy=energy, model=model, cache=cache)
    stages = [(coarse, coarse_unit, data), stage(medium_bins), stage(fine_bins)]
    pixel = np.radians(58.6 / side)

    def climb(c: BurstCounts, unit: UnfoldedResponse, d: PoissonData, src: PointSource,
              step: float) -> tuple[SkyModel, float, SourceFitter]:
        f = fitter_at(c, unit, d, src)
        m = f.maximise(SkyModel((dataclasses.replace(src, free_position=True),)))[0]
        m = f.fit_positions(m, scale=step)
        return m, f.maximise(m)[1].loglike, f

    def best_of(fits: list[tuple[SkyModel, float, SourceFitter]], n: int
                ) -> list[PointSource]:
        """The ``n`` most likely distinct positions (a pixel apart at least)."""
        out: list[PointSource] = []
        for m, _, _ in sorted(fits, key=lambda fit: -fit[1]):
            src = m.sources[0]
            if all(src.separation(o) > np.degrees(pixel) for o in out):
                out.append(src)
        return out[:n]

    # Each stage climbs (Nelder-Mead) from the last one's best positions on its own
    # likelihood, smooth enough at its bin width for a climb from a pixel away to reach the
    # right peak, and passes on fewer of them.
    fits = [climb(*stages[0], PointSource(p), 0.5 * pixel) for p in starts]
    fits = [climb(*stages[1], src, 0.25 * pixel) for src in best_of(fits, MEDIUM_CANDIDATES)]
    modes = [climb(*stages[2], src, 0.125 * pixel) for src in best_of(fits, FINE_FITS)]
    best, best_ll, fitter = max(modes, key=lambda fit: fit[1])
    fine = stages[2][0]
    result = fit_with(fitter, best, errors=True)
    # Other modes (e.g. the mirror image through the axis of a symmetric array): their TS
    # below the best, at least a pixel and a half away.
    others = tuple(sorted(
        ((m.sources[0].position, 2.0 * (best_ll - ll)) for m, ll, _ in modes
         if m.sources[0].separation(best.sources[0]) > np.degrees(1.5 * pixel)),
        key=lambda pair: pair[1]))
    # 3. The region: the likelihood surface around the best fit.
    region = localise(fitter, result.model, 0, systematic=systematic)
    pos = result.model.sources[0].position
    th, ph = first.to_instrument(pos)
    return BurstPosition(pos, float(th.to_value(u.deg)), float(ph.to_value(u.deg)), region,
                         result, tsm, fitter.response, fine, others)
