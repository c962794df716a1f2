"""Where a burst is: its unfolded counts searched on the whole visible sky, then fitted.

The counts of a window around the burst are kept in time bins aligned with the mask-angle
bins (:func:`bin_events`); the model of bin ``k`` of detector ``d`` is

    mu[d, k] = E_k (F w_k P_j(k)[d, t(k), n] + beta_d B_d(t_k)),

with ``E_k`` the bin's good time, ``w_k`` the burst's light curve (pulses fitted to
the detector-summed counts where the Bayesian blocks of :mod:`rotmod.bursts.measure` put
the burst, :mod:`rotmod.bursts.pulses`), ``P_j`` the folded response of the
attitude segment ``j`` the bin falls in, ``B_d`` the background rate fitted outside the
burst and ``beta_d`` a free level per detector (the background's normalisation during the
burst is fitted with the burst, as in the source fits).  The response is an
:class:`~rotmod.response.UnfoldedResponse`, so the source layer does the rest:

1. **search**: the score map (:func:`search_map`) of a HEALPix cone over the visible sky,
   pixels a quarter of ``b / L``: the slope of ``ln L`` in a source's flux at flux 0 over
   its noise, for every pixel from two adjoint products (of ``P`` and of ``P**2``, through
   the Radon factorisation) -- the matched filter of the burst's excess, which peaks at the
   burst (Cauchy-Schwarz); with pulses, a second map weighted by the pulses seen from the
   first map's likeliest peak adds its own peaks;
2. **fits**: the exact likelihood at the maps' best distinct peaks, and Nelder-Mead climbs
   from the most likely of them in bins that resolve the modulation at their off-axis
   angles, the light curve fitted again as seen from each start; the highest likelihood is
   kept and the others are reported as alternatives;
3. **region**: :func:`rotmod.sources.localise` -- the likelihood surface around the best
   and every other mode within :data:`MODE_DTS`, each weighted by its probability
   (:class:`~rotmod.bursts.posterior.Posterior`), every TS divided by the dispersion of the
   light curve's misfit (:func:`pulse_misfit`), with a settable systematic term, 68 %
   and 90 % contours and a HEALPix probability map.

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
from rotmod.bursts.posterior import Posterior, tempered
from rotmod.bursts.pulses import PulseLightCurve, fit_pulses, inflation, misfit
from rotmod.conventions import source_direction
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.io.regions import HealpixProbability
from rotmod.profiles import get_model
from rotmod.progress import ProgressArg
from rotmod.reconstruction.data import PoissonData
from rotmod.response import ResponseOperator, UnfoldedResponse, aligned_edges, build_response
from rotmod.response.columns import columns_at
from rotmod.response.operator import MaterialisedResponse
from rotmod.response.radon import RadonResponse
from rotmod.sky.attitude import Attitude, AttitudeTable
from rotmod.sky.geometry import SkyGeometry
from rotmod.sky.healpix import HealpixGrid
from rotmod.sky.points import PositionList
from rotmod.sources.fitting import FitResult, SourceFitter, fit_with, geometric_scale
from rotmod.sources.localisation import Region, localise
from rotmod.sources.model import PointSource, SkyModel, positions_of

__all__ = ["BurstCounts", "BurstPosition", "ScoreMap", "bin_events", "burst_pulses",
           "burst_response", "localise_burst", "pulse_misfit", "search_map"]

#: Attitude segments of at most this many seconds (a balloon's pointing moves by well under
#: the instrument's scale in that time; a fast slew can pass a shorter step).
MAX_ATTITUDE_STEP = 10.0
#: Off-axis margin (deg) beyond the candidates for the fine bins' sampling: the
#: search map's pixels are b/(4L) across, and a fit moves by a few of them at most.
FINE_MARGIN = 5.0
#: Pixels of the score map: at most a quarter of ``b / L``, so that the likelihood's core
#: (narrower than its fringes, ~``p cos^2(theta) / L`` apart) is sampled.
SEARCH_PIXEL = 0.25
#: Tolerance of the Radon table of the score map (profile values): it ranks candidates,
#: which the exact likelihood then decides between.
SEARCH_TOLERANCE = 1e-3
#: Distinct peaks of the score map whose exact likelihood is computed, and how many of the
#: most likely are refitted with a continuous position.
SCORE_PEAKS = 16
FINE_FITS = 3
#: Modes within this TS of the best are part of the region (their probability relative to
#: the best's is at least ~exp(-MODE_DTS / 2)); peaks of the map within MODE_DTS +
#: CLIMB_MARGIN at their pixel centre are climbed, at most MAX_CLIMBS of them.
MODE_DTS = 12.0
CLIMB_MARGIN = 6.0
MAX_CLIMBS = 5
#: Final simplex of the climbs, as a fraction of their first step (half a search pixel,
#: b/(8L)): 1e-2 is 0.002 deg on the survey instrument, a tenth of the smallest 90 %
#: radius measured (0.02 deg at sqrt TS 170); the region's surface is scanned around the
#: climb's end in any case.
CLIMB_PRECISION = 1e-2
#: Points per side of the best mode's square and of a secondary mode's: the square is
#: scanned until the 90 % region holds >= 25 points and its edge is 13.8 in TS below the
#: peak (:func:`rotmod.sources.localise`), so 31 points put ~250 in a Gaussian 90 %
#: region (r90 within 2.2 % of 41 points' on four calibration bursts, at 0.6 of the cost).
BEST_SIDE = 31
MODE_SIDE = 21


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

    @property
    def first_attitude(self) -> Attitude:
        """The attitude of the window's first time bin (the searched cone's centre)."""
        return self.attitudes[int(self.segment[0])]

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
        seconds, each with its own attitude; it must cover the good time of the widened
        window (:meth:`~rotmod.sky.AttitudeTable.covers`).
    max_step : float
        Longest attitude segment (s), > 0.

    Raises
    ------
    ParameterError
        No good time in the window; an attitude table that does not cover its good time.
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
        # The attitude is needed where there is good time: the bins' edges widen the window
        # to mask-angle boundaries, past the data (and a table covering them) at its ends.
        good = hi > lo
        g0, g1 = float(lo[good].min()), float(hi[good].max())
        try:
            pieces = att.intervals(g0, g1, max_step)
        except ParameterError as exc:
            raise ParameterError(
                f"attitude: the window's good time, widened to whole mask-angle bins "
                f"({g0:.12g} .. {g1:.12g} s), needs the attitude: {exc}") from None
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
        key = _key("folded", counts, att, grid, model, energy)
        if key not in cache:
            cache[key] = build_response(inst, grid, counts.time_bins, model=model,
                                        energy=energy, dtype=np.float64)
        parts.append(cache[key])
    return UnfoldedResponse(parts, counts.segment, counts.phase, weight, counts.edges)


def _key(kind: str, counts: BurstCounts, att: Attitude, grid: SkyGeometry, model: Any,
         energy: Any) -> tuple[Any, ...]:
    """What a cached response depends on: the attitude, grid, binning, model, energy and
    instrument."""
    return (kind, att.ra, att.dec, att.roll,
            json.dumps(grid.to_dict(), sort_keys=True, default=str),
            tuple(counts.time_bins.to_dict().items()), str(model), float(energy),
            json.dumps(counts.events.instrument.to_dict(), sort_keys=True, default=str))


@dataclass(frozen=True, eq=False)
class ScoreMap:
    """The score map of a burst's counts on a HEALPix cone (:func:`search_map`).

    Attributes
    ----------
    grid : HealpixGrid
        The cone, at the attitude of the window's first time bin.
    score : ndarray, shape (n_pix,)
        ``U / sqrt(I)`` per pixel: the derivative of ``ln L`` in a source's flux at flux 0
        (the background fitted alone) over its noise.  Its square is Rao's score statistic
        (``chi^2_1`` without a source, as the TS); with a source, its expectation is
        largest at the source's position (Cauchy-Schwarz), which is what the search uses.
    """

    grid: HealpixGrid
    score: np.ndarray


def _search_operators(counts: BurstCounts, grid: SkyGeometry, model: Any, energy: Any
                      ) -> tuple[ResponseOperator, ResponseOperator]:
    """The response ``P`` of one attitude on ``grid`` and the operator of ``P**2``.

    The ideal instrument's exact model through the Radon factorisation (its table and the
    table's square: the mean of squared sub-samples, as the information wants); otherwise
    the materialised response and its square.
    """
    inst, bins = counts.events.instrument, counts.time_bins
    if inst.is_ideal and get_model(model).name == "exact":
        r = RadonResponse(inst, grid, bins, energy, tolerance=SEARCH_TOLERANCE,
                          dtype=np.float64)
        return r, RadonResponse(inst, grid, bins, energy, tolerance=SEARCH_TOLERANCE,
                                dtype=np.float64, table=r.table ** 2)
    m = build_response(inst, grid, bins, model=model, energy=energy, dtype=np.float64)
    return m, MaterialisedResponse(m.matrix ** 2)


def search_map(counts: BurstCounts, fitter: SourceFitter, nside: int, radius: float,
               weight: np.ndarray | None, *, energy: Any, model: Any = "exact",
               cache: dict[Any, Any] | None = None) -> ScoreMap:
    """The score map of a point source over the cone of ``radius`` (deg) around the first
    pointing, on HEALPix pixels of ``nside``.

    With ``mu0`` the background fitted alone (``fitter``'s null model), ``E`` the bins'
    exposure and ``w`` the light curve ``weight``, the score of pixel ``n`` is

        U_n = sum_{d,k} E_k w_k P[d, k, n] (y[d, k] / mu0[d, k] - 1),
        I_n = sum_{d,k} (E_k w_k P[d, k, n])^2 / mu0[d, k],

    two adjoint products (of ``P`` and of ``P**2``), whatever the number of pixels: with
    the Radon factorisation a cone of 10^5 pixels in ~1 s, where the TS of each pixel would
    evaluate each pixel's column.
    """
    cache = {} if cache is None else cache
    first = counts.first_attitude
    mu0 = fitter.expected(fitter.maximise(SkyModel(()))[0])
    e = counts.exposure[None, :]
    safe = np.where(mu0 > 0, mu0, 1.0)
    resid = np.where(mu0 > 0, e * (counts.counts / safe - 1.0), 0.0)
    info = np.where(mu0 > 0, e ** 2 / safe, 0.0)
    ops = []
    grids = [HealpixGrid(nside, first.ra, first.dec, radius, att) for att in counts.attitudes]
    for att, grid in zip(counts.attitudes, grids, strict=True):
        key = _key("search", counts, att, grid, model, energy)
        if key not in cache:
            cache[key] = _search_operators(counts, grid, model, energy)
        ops.append(cache[key])
    w = np.ones(counts.edges.size - 1) if weight is None else np.asarray(weight, float)
    u_n = UnfoldedResponse([o[0] for o in ops], counts.segment, counts.phase, w,
                           counts.edges).adjoint(resid)
    i_n = UnfoldedResponse([o[1] for o in ops], counts.segment, counts.phase, w ** 2,
                           counts.edges).adjoint(info)
    score = np.where(i_n > 0, u_n / np.sqrt(np.where(i_n > 0, i_n, 1.0)), np.nan)
    return ScoreMap(grids[int(counts.segment[0])], score)


def search_nside(response_scale: float) -> int:
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
        The likelihood surface with the systematic term, its TS divided by
        :attr:`dispersion`: 68 % and 90 % contours, radii, areas, the probability map.
    fit : FitResult
        The fitted model (burst flux, background levels) with the burst's TS and flux
        errors.
    score : ScoreMap
        The score map of the visible sky the search started from, with the light curve
        (with pulses: the second map, weighted by the pulses seen from the first map's
        likeliest peak).
    response : UnfoldedResponse
        The response of the fit (its light curve weights).
    counts : BurstCounts
        The counts of the fit.
    alternatives : tuple of (SkyCoord, float)
        Other local maxima refitted, with their TS below the best (``delta TS``): a mode
        within a few units of TS (the mirror image of a symmetric array, a short burst's
        partial turn) is a real ambiguity, stated in the summary.
    posterior : Posterior
        The position's probability: the surfaces of the best position and of every other
        refitted mode within :data:`MODE_DTS` (nothing outside their squares).
        :meth:`contains` and :meth:`probability_map` use it.
    pulses : PulseLightCurve or None
        The light curve of the fit, seen from the best position (``None`` without pulses).
    misfit : (float, int) or None
        Pearson's ``chi^2`` and degrees of freedom of :attr:`pulses` over the burst
        (:func:`pulse_misfit`); ``None`` without pulses or with ``inflate=False``.
    dispersion : float
        The factor the regions' TS surfaces (``region.ts``, every square of
        :attr:`posterior`) were divided by: :func:`rotmod.bursts.pulses.inflation` of
        :attr:`misfit`, 1 without it.
    """

    position: SkyCoord
    theta: float
    phi: float
    region: Region
    fit: FitResult
    score: ScoreMap
    response: UnfoldedResponse
    counts: BurstCounts
    alternatives: tuple[tuple[SkyCoord, float], ...] = ()
    posterior: Posterior | None = None
    pulses: PulseLightCurve | None = None
    misfit: tuple[float, int] | None = None
    dispersion: float = 1.0

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

    def contains(self, position: SkyCoord, containment: float = 0.9) -> bool:
        """Whether ``position`` lies in the region of ``containment`` (every refitted mode
        included: :attr:`posterior`)."""
        return self.posterior.contains(position, containment)

    def probability_map(self, nside: int | None = None) -> HealpixProbability:
        """The position's probability on HEALPix pixels (ICRS), every mode included."""
        return self.posterior.probability_map(nside)


def _peaks(theta: np.ndarray, phi: np.ndarray, values: np.ndarray, apart: float, n: int
           ) -> np.ndarray:
    """Indices of the ``n`` highest values that are the highest within ``apart`` (rad)."""
    v = source_direction(theta, phi)
    near = np.cos(apart)
    t = np.nan_to_num(values, nan=-np.inf)
    picked: list[int] = []
    for i in np.argsort(t)[::-1]:
        if not np.isfinite(t[i]) or len(picked) >= n:
            break
        if not picked or np.all(v[picked] @ v[i] < near):
            picked.append(int(i))
    return np.array(picked, dtype=np.int64)


def _summed(counts: BurstCounts, background: Background, unit: UnfoldedResponse | None,
            source: PointSource | None) -> tuple[np.ndarray, ...]:
    """The detector-summed counts of ``counts`` as :func:`fit_pulses` takes them: edges,
    counts, background counts, good time and the summed rate of a unit flux at ``source``
    (``None`` without one)."""
    rates = _background_rates(background, counts)
    e = counts.exposure
    r = None
    if unit is not None and source is not None:
        r = columns_at(unit, positions_of([source]))[:, :, 0].sum(axis=0)
    return counts.edges, counts.counts.sum(axis=0), (rates * e).sum(axis=0), e, r


def burst_pulses(light_curve: BurstLightCurve, counts: BurstCounts, background: Background,
                 unit: UnfoldedResponse | None = None, source: PointSource | None = None,
                 start: PulseLightCurve | None = None) -> PulseLightCurve:
    """The burst's light curve in the bins of ``counts``: pulses fitted to the
    detector-summed counts (:func:`rotmod.bursts.pulses.fit_pulses`, its default family),
    seen from ``source`` through ``unit`` (weight 1) when given, refined from ``start``
    when given.

    Seen from a position, the summed rate of a unit flux there (the response summed over
    the detectors) carries the mask's modulation of the summed transmission -- its rms is
    0.2-1.3 of its mean from 20 to 57 deg off axis on the survey instrument -- and the
    pulses fitted without it take part of that modulation and put it in the model twice
    (measured with the blocks' net rates as the light curve: a burst of sqrt(TS) 136
    placed 68 deg away).
    """
    edges, y, b, e, r = _summed(counts, background, unit, source)
    return fit_pulses(edges, y, b, e, light_curve, r, start)


def pulse_misfit(light_curve: BurstLightCurve, counts: BurstCounts, background: Background,
                 pulses: PulseLightCurve, unit: UnfoldedResponse | None = None,
                 source: PointSource | None = None) -> tuple[float, int]:
    """Pearson's ``chi^2`` and degrees of freedom of ``pulses`` (fitted by
    :func:`burst_pulses` with the same arguments) over the burst's extent
    (``light_curve.interval``): :func:`rotmod.bursts.pulses.misfit`."""
    edges, y, b, e, r = _summed(counts, background, unit, source)
    return misfit(edges, y, b, e, pulses, light_curve.interval, r)


def periods_per_turn(instrument: Any, theta_deg: float) -> float:
    """The most mask periods that pass over a detector in one turn, for a source up to
    ``theta_deg`` off axis.

    The ray from a source at ``t = tan(theta) (cos phi, sin phi)`` to detector ``d`` at
    ``(x_d, y_d)`` crosses the mask at ``u = delta_d(xi) + L w(xi)`` across the slats
    (``docs/physics.md``), with ``delta_d = x_d cos xi - y_d sin xi`` and ``w = t_x cos xi -
    t_y sin xi``: it moves by at most ``|r_d| + L tan(theta)`` per radian of mask angle, the
    detector's own distance from the axis included (an outer detector is modulated even by
    a source on the axis).
    """
    mask = instrument.mask
    r_max = float(np.max(np.hypot(*instrument.detectors.positions.T)))
    return 2.0 * np.pi * (r_max + mask.height * np.tan(np.radians(theta_deg))) / mask.period


def default_time_bins(instrument: Any, radius_deg: float) -> TimeBinning:
    """Mask-angle bins that resolve the modulation out to ``radius_deg`` off axis.

    Eight samples per mask period passing over a detector (:func:`periods_per_turn`, up to
    60 deg off axis, beyond which the effective area is small) fix the number of samples per
    turn, taken as bins of two sub-samples each (``"average"`` mode: a bin's response is its
    mean, as its counts are).  With four (bins of half a period) the midpoint rule's error
    in a bin's mean biased positions by more than their 90 % radius at 25 deg off axis
    (measured); with eight the calibration's positions show no bias (docs/bursts.md).
    """
    samples = 8.0 * periods_per_turn(instrument, min(radius_deg, 60.0))
    n = int(2 ** np.ceil(np.log2(max(samples, 64.0))))
    return TimeBinning(n // 2, "average", 2)


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
    n_refine: int = FINE_FITS,
    systematic: Any = 0.0,
    inflate: bool = True,
    progress: ProgressArg = None,
    cache: dict[Any, ResponseOperator] | None = None,
) -> BurstPosition:
    """Localise a burst: score map of the visible sky, exact refits of its peaks, region.

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
        The burst's Bayesian blocks (:func:`rotmod.bursts.burst_light_curve`): pulses
        are fitted to the summed counts there (:func:`burst_pulses`), as seen from
        each candidate position, and weight the response bin by bin.  Or any function of
        the bins' edges giving their weights; ``None``: a constant source over the window.
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
        HEALPix ``nside`` of the search map (default: pixels at most a quarter of ``b / L``,
        :data:`SEARCH_PIXEL`).
    time_bins : TimeBinning, optional
        Mask-angle bins of the continuous fits (default :func:`default_time_bins` out to
        the starting peaks' off-axis angle plus :data:`FINE_MARGIN`); the search map's bins
        are :func:`default_time_bins` at ``radius``.
    n_refine : int
        The most likely peaks of the search map refitted with a continuous position, at
        least (others within reach of a mode too, up to :data:`MAX_CLIMBS`), >= 1.
    systematic : float or Quantity
        Systematic error per axis added to the region (deg if plain), >= 0.
    inflate : bool
        With pulses, divide the regions' TS by the dispersion of the pulses' misfit at the
        best position (:func:`pulse_misfit`, :func:`rotmod.bursts.pulses.inflation`;
        ``False``: the likelihood's own regions).
    progress : bool or callable, optional
        Progress over each map's pixels.
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
    fine_bins = None if time_bins is None else TimeBinning.coerce(time_bins)
    side = (search_nside(SEARCH_PIXEL * geometric_scale(inst)) if nside is None
            else as_int(nside, "nside", 1))
    cache = {} if cache is None else cache

    def weights(c: BurstCounts) -> np.ndarray | None:
        """A light curve given as a function of the bins (or none)."""
        return None if light_curve is None else np.asarray(light_curve(c.edges), dtype=float)

    # 1. The score map of the cone: the matched filter of the counts' excess over the
    # background, normalised by its noise, for every pixel at once (search_map), in bins
    # that resolve the modulation out to the cone's edge.
    def binned(bins: TimeBinning) -> tuple[BurstCounts, UnfoldedResponse, PoissonData]:
        c = bin_events(events, t0, t1, time_bins=bins, attitude=attitude, max_step=max_step)
        pointing = c.first_attitude.pointing
        unit = burst_response(c, lambda att: PositionList.from_coords(pointing, att),
                              energy=energy, model=model, cache=cache)
        return c, unit, c.data(_background_rates(background, c))

    search_bins = default_time_bins(inst, rad)
    counts, unit, data = binned(search_bins)
    first = counts.first_attitude
    # The light curve of the blocks as pulses (seen from no position in particular; each
    # candidate position below fits them again as seen from there).
    pulses = (burst_pulses(light_curve, counts, background)
              if isinstance(light_curve, BurstLightCurve) else None)
    w = weights(counts) if pulses is None else pulses.shape(counts.edges)
    null_fitter = SourceFitter(unit.with_weight(w), data)
    score = search_map(counts, null_fitter, side, rad, w, energy=energy, model=model,
                       cache=cache)
    # 2. The exact likelihood at the score map's best distinct peaks, then continuous fits
    # from the most likely of them, in bins that resolve the modulation out to their
    # off-axis angles (a burst near the axis needs a fraction of the samples of one at the
    # cone's edge).
    pixel = np.radians(58.6 / side)
    th, ph = score.grid.directions()
    peaks = _peaks(th.to_value(u.rad), ph.to_value(u.rad), score.score, 2.0 * pixel,
                   SCORE_PEAKS)
    if peaks.size == 0:
        raise ParameterError("the score map has no finite value: no exposure in the window")
    coords = score.grid.sky_coords()[peaks]

    def seen_from(src: PointSource, c: BurstCounts, u_c: UnfoldedResponse,
                  d_c: PoissonData, start: PulseLightCurve | None = None
                  ) -> tuple[SourceFitter, PulseLightCurve | None]:
        """The fitter of a source at ``src``, its light curve seen from there (refined
        from ``start``, default the search's pulses), and those pulses (a given light
        curve is the same from everywhere: the search's fitter and its columns are
        shared)."""
        if pulses is None:
            return (null_fitter if c is counts
                    else SourceFitter(u_c.with_weight(weights(c)), d_c)), None
        lc = burst_pulses(light_curve, c, background, u_c, src,
                          pulses if start is None else start)
        return SourceFitter(u_c.with_weight(lc.shape(c.edges)), d_c), lc

    def peak_loglike(c: SkyCoord) -> float:
        return seen_from(PointSource(c), counts, unit, data)[0].maximise(
            SkyModel((PointSource(c),)))[1].loglike

    peak_ll = np.array([peak_loglike(c) for c in coords])
    if pulses is not None:
        # The map weighs the pixels with the pulses seen from no position; a position's
        # own modulation of the summed rate changes them.  Weighted with the pulses seen
        # from the likeliest peak, a second map ranks that peak's neighbourhood better
        # (measured in the calibration: a truth on the next fringe ranked 1314th, then
        # 13th) and its new peaks are added.
        seen = burst_pulses(light_curve, counts, background, unit,
                            PointSource(coords[int(np.argmax(peak_ll))]), pulses)
        w = seen.shape(counts.edges)
        score = search_map(counts, SourceFitter(unit.with_weight(w), data), side, rad, w,
                           energy=energy, model=model, cache=cache)
        # On the first map's grid (the same cone and nside), so its directions serve.
        more = _peaks(th.to_value(u.rad), ph.to_value(u.rad), score.score, 2.0 * pixel,
                      SCORE_PEAKS)
        coords = np.concatenate([coords, score.grid.sky_coords()[more]])
        peak_ll = np.append(peak_ll, [peak_loglike(c) for c in coords[peaks.size:]])
        # Of the two maps' peaks, the likeliest within two pixels of each other.
        keep: list[int] = []
        for k in np.argsort(peak_ll)[::-1]:
            if np.all(coords[k].separation(coords[keep]).rad > 2.0 * pixel):
                keep.append(int(k))
        coords, peak_ll = coords[keep], peak_ll[keep]
    # Climb the n_refine most likely, and any other within reach of being a mode of the
    # region (a pixel centre is below its peak by up to the pixel's own loss).
    order = np.argsort(peak_ll)[::-1]
    near = 2.0 * (peak_ll[order[0]] - peak_ll[order]) <= MODE_DTS + CLIMB_MARGIN
    starts = [coords[k] for j, k in enumerate(order)
              if j < n_refine or (near[j] and j < MAX_CLIMBS)]
    if time_bins is None:
        reach = max(float(first.to_instrument(p)[0].to_value(u.deg)) for p in starts)
        fine_bins = default_time_bins(inst, min(reach + FINE_MARGIN, rad))
    fine, fine_unit, fine_data = ((counts, unit, data) if fine_bins == search_bins
                                  else binned(fine_bins))

    def climb(src: PointSource
              ) -> tuple[SkyModel, float, SourceFitter, PulseLightCurve | None]:
        """Nelder-Mead from ``src``, with the light curve seen from there; then, with
        pulses, the light curve seen from where the climb ended and a second climb (the
        pulses held during a climb are those of its start, a pixel or more away)."""
        f, lc = seen_from(src, fine, fine_unit, fine_data)
        m = f.maximise(SkyModel((dataclasses.replace(src, free_position=True),)))[0]
        m = f.fit_positions(m, scale=0.5 * pixel, precision=CLIMB_PRECISION)
        if lc is not None:
            # The pulse fit is not convex: refined from the start's pulses it can stay in
            # another optimum than refined from the search's (measured in the calibration:
            # the truth, within 0.22 deg of the best fit, above it by 1.5-1535 in TS in 7
            # of 34 bursts), so both are tried where the climb ended and the likelier kept.
            tries = []
            for begin in (lc, None):
                f_s, lc_s = seen_from(m.sources[0], fine, fine_unit, fine_data, begin)
                tries.append((f_s.maximise(m), f_s, lc_s))
            (fitted, _), f, lc = max(tries, key=lambda t: t[0][1].loglike)
            m = f.fit_positions(fitted, scale=0.5 * pixel, precision=CLIMB_PRECISION)
        return m, f.maximise(m)[1].loglike, f, lc

    fits = sorted((climb(PointSource(p)) for p in starts), key=lambda fit: -fit[1])
    # Distinct modes (climbs that met on one peak are one mode), best first.
    distinct: list[tuple[SkyModel, float, SourceFitter, PulseLightCurve | None]] = []
    for fit in fits:
        if all(fit[0].sources[0].separation(d[0].sources[0]) > np.degrees(1.5 * pixel)
               for d in distinct):
            distinct.append(fit)
    best, best_ll, fitter, best_lc = distinct[0]
    result = fit_with(fitter, best, errors=True)
    # Other modes (e.g. the mirror image through the axis of a symmetric array): their TS
    # below the best.
    others = tuple((m.sources[0].position, 2.0 * (best_ll - ll))
                   for m, ll, _, _ in distinct[1:])
    # 3. The region: the likelihood surface around each mode within MODE_DTS of the best,
    # weighted by its probability (its peak likelihood times its surface's integral), every
    # TS divided by the dispersion of the light curve's misfit at the best position (1
    # when the pulses fit the summed counts; the misfit is read as modulation).
    misfit_stat = (None if best_lc is None or not inflate else
                   pulse_misfit(light_curve, fine, background, best_lc,
                                fine_unit, result.model.sources[0]))
    factor = 1.0 if misfit_stat is None else inflation(*misfit_stat)
    # Each square sized for the tempered surface (so its edge falls by EDGE_DROP too), and
    # the modes kept by their tempered TS.
    region = tempered(localise(fitter, result.model, 0, systematic=systematic,
                               n_side=BEST_SIDE, dispersion=factor), factor)
    regions = [region] + [tempered(localise(f, m, 0, systematic=systematic, n_side=MODE_SIDE,
                                            dispersion=factor), factor)
                          for m, ll, f, _ in distinct[1:]
                          if 2.0 * (best_ll - ll) <= MODE_DTS * factor]
    posterior = Posterior(tuple(regions))
    pos = result.model.sources[0].position
    th, ph = first.to_instrument(pos)
    return BurstPosition(pos, float(th.to_value(u.deg)), float(ph.to_value(u.deg)), region,
                         result, score, fitter.response, fine, others, posterior, best_lc,
                         misfit_stat, factor)
