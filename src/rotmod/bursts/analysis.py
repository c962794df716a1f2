"""A burst from trigger to summary: background, light curve, durations, position, fluence.

:func:`analyse_burst` takes the events and a burst's interval (a search
:class:`~rotmod.bursts.search.Candidate`, or a pair of times) and runs, in order,

1. the background per detector, a polynomial fitted by Poisson likelihood to the data
   before and after the burst (:func:`~rotmod.bursts.measure.fit_background`);
2. the light curve ``L(t)``: Bayesian blocks of the detector-summed counts against that
   background (:func:`~rotmod.bursts.measure.burst_light_curve`), which also fixes the
   burst's extent;
3. T90, T50, net counts and peak rate (:func:`~rotmod.bursts.measure.durations`);
4. the position (:func:`~rotmod.bursts.localisation.localise_burst`), with the light curve
   in the model;
5. the flux in physical units: the fitted ``F`` is photons/s on one unobstructed detector
   face at ``L = 1`` (the brightest block), so the photon flux is ``F / (pi R^2 cos
   theta)`` and the fluence that times ``integral of L dt`` (at the response's energy).

The result, :class:`Burst`, writes a GCN-circular-style text (:meth:`Burst.summary`), a
table row (:meth:`Burst.to_table`) and, through :mod:`rotmod.io`, a FITS product.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import astropy.units as u
import numpy as np
from astropy.table import Table
from astropy.time import Time

from rotmod._validate import as_angle_scalar, as_energy_scalar, as_scalar
from rotmod.bursts.localisation import MAX_ATTITUDE_STEP, BurstPosition, localise_burst
from rotmod.bursts.measure import (
    Background,
    BurstLightCurve,
    Durations,
    burst_light_curve,
    durations,
    fit_background,
)
from rotmod.bursts.search import Candidate
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.progress import ProgressArg, progress_callbacks
from rotmod.response import ResponseOperator

__all__ = ["Burst", "analyse_burst"]

#: Seconds of background fitted on each side of the burst, and the gap left between them
#: and the burst (a tail below the blocks' threshold stays out of the background).
BACKGROUND_SPAN = 100.0
BACKGROUND_GAP = 10.0
#: Background (s) kept on each side of the burst in the fit window, at least: the burst's
#: own length if longer.
WINDOW_MARGIN = 5.0
#: Background kept on each side of the burst in the durations' window, in units of the
#: burst's length (at least WINDOW_MARGIN).
DURATION_MARGIN = 2.0
#: How far (s) beyond the trigger the first pass looks for more of the burst: a burst of
#: several pulses triggers on one of them.
REACH = 30.0


@dataclass(frozen=True)
class Burst:
    """A burst measured and localised.

    Attributes
    ----------
    interval : (float, float)
        The burst's extent from the light curve (s): first to last block above background.
    window : (float, float)
        The window of the position fit (s).
    background : Background
    light_curve : BurstLightCurve
    durations : Durations
    position : BurstPosition
    energy : float
        Energy of the response (keV): the physical fluxes are photons at this energy.
    photon_flux, photon_flux_err : float
        Peak photon flux (photons/cm^2/s) over ``durations.peak_timescale``, and its error.
    fluence, fluence_err : float
        Photon fluence (photons/cm^2) of the burst, and its error.
    mjdref : float
        MJD of ``t = 0`` of the events.
    durations_window : (float, float)
        The window of the durations (s): wider than :attr:`window` (see
        :func:`analyse_burst`).
    """

    interval: tuple[float, float]
    window: tuple[float, float]
    background: Background
    light_curve: BurstLightCurve
    durations: Durations
    position: BurstPosition
    energy: float
    photon_flux: float
    photon_flux_err: float
    fluence: float
    fluence_err: float
    mjdref: float
    durations_window: tuple[float, float]

    @property
    def trigger_time(self) -> Time:
        """The start of the burst (first block above background) as a Time (TT)."""
        return Time(self.mjdref, format="mjd", scale="tt") + self.interval[0] * u.s

    def summary(self, name: str = "") -> str:
        """A short text in the style of a GCN circular."""
        p = self.position
        d = self.durations
        c = p.position.icrs
        r90, r68 = p.region.radius(0.9), p.region.radius(0.68)
        sys_note = (f"including a systematic {p.region.systematic:g} deg"
                    if p.region.systematic > 0 else "statistical only")
        lines = [
            f"{name or 'Burst'}: rotmod rotating-modulator detection and localisation",
            "",
            f"At {self.trigger_time.utc.isot} UT (t = {self.interval[0]:.3f} s) the RM "
            f"detected a burst with sqrt(TS) = {p.sqrt_ts:.1f}.",
            f"Position: RA, Dec = {c.ra.deg:.3f}, {c.dec.deg:+.3f} deg (J2000), 90 % region "
            f"radius {r90:.2f} deg (68 %: {r68:.2f} deg; {sys_note}); "
            f"{p.theta:.1f} deg off axis (azimuth {p.phi:.1f} deg).",
        ]
        post = p.posterior
        if post is not None and len(post.squares) > 1:
            lines.append(f"  This position holds {post.best_probability:.0%} of the probability; "
                         f"the 90 % region ({post.area(0.9):.2g} deg2) also includes:")
            for r, prob in zip(post.squares[1:], post.square_probability[1:], strict=True):
                a = r.source.position.icrs
                dts = 2.0 * (np.nanmax(post.squares[0].ts) - np.nanmax(r.ts))
                lines.append(f"  RA, Dec = {a.ra.deg:.3f}, {a.dec.deg:+.3f} deg "
                             f"(probability {prob:.0%}, TS {dts:.1f} below).")
        lines += [
            f"T90 = {d.t90:.2f} +/- {d.t90_err:.2f} s from t = {d.t90_start:.3f} s; "
            f"T50 = {d.t50:.2f} +/- {d.t50_err:.2f} s.",
            f"Net counts {d.net_counts:.0f} +/- {d.net_counts_err:.0f}; peak rate "
            f"{d.peak_rate:.1f} +/- {d.peak_rate_err:.1f} counts/s ({d.peak_timescale:g} s).",
            f"At {self.energy:g} keV: fluence {self.fluence:.3g} +/- {self.fluence_err:.2g} "
            f"photons/cm2, peak flux {self.photon_flux:.3g} +/- {self.photon_flux_err:.2g} "
            f"photons/cm2/s ({d.peak_timescale:g} s).",
            "Errors are 1 sigma, statistical.",
        ]
        return "\n".join(lines)

    def to_table(self) -> Table:
        """One row: time, position, region radii, significance, durations, fluxes."""
        p = self.position
        c = p.position.icrs
        d = self.durations
        t = Table()
        t["t_start"] = [self.interval[0]] * u.s
        t["t_stop"] = [self.interval[1]] * u.s
        t["ra"] = [c.ra.deg] * u.deg
        t["dec"] = [c.dec.deg] * u.deg
        t["theta"] = [p.theta] * u.deg
        t["phi"] = [p.phi] * u.deg
        t["r68"] = [p.region.radius(0.68)] * u.deg
        t["r90"] = [p.region.radius(0.9)] * u.deg
        t["sqrt_ts"] = [p.sqrt_ts]
        for key in ("t90", "t90_err", "t50", "t50_err", "t90_start", "t50_start"):
            t[key] = [getattr(d, key)] * u.s
        t["net_counts"] = [d.net_counts]
        t["net_counts_err"] = [d.net_counts_err]
        t["peak_rate"] = [d.peak_rate] * u.Unit("1/s")
        t["peak_rate_err"] = [d.peak_rate_err] * u.Unit("1/s")
        t["photon_flux"] = [self.photon_flux] * u.Unit("cm-2 s-1")
        t["photon_flux_err"] = [self.photon_flux_err] * u.Unit("cm-2 s-1")
        t["fluence"] = [self.fluence] * u.Unit("cm-2")
        t["fluence_err"] = [self.fluence_err] * u.Unit("cm-2")
        # FITS keywords: the response's energy, the time zero, the systematic of the region.
        t.meta.update({"ENERGY": self.energy, "MJDREF": self.mjdref,
                       "SYSERR": p.region.systematic})
        return t


def _interval(interval: Any) -> tuple[float, float]:
    if isinstance(interval, Candidate):
        return interval.interval
    try:
        t0, t1 = (as_scalar(v, "interval", u.s) for v in interval)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"interval must be a Candidate or a pair (start, stop) in s, got "
                             f"{interval!r}") from exc
    if not t1 > t0:
        raise ParameterError(f"interval must have stop > start, got {t0:g}..{t1:g} s")
    return t0, t1


def _background_and_light_curve(events: EventList, a: float, b: float,
                                pads: tuple[float, ...], degree: int
                                ) -> tuple[Background, BurstLightCurve]:
    """The background fitted on up to :data:`BACKGROUND_SPAN` s each side of ``[a - pad, b +
    pad]``, and the light curve inside that span (its blocks above the background), for the
    first of ``pads`` that leaves background within the data."""
    lo, hi = events.t_start, events.t_stop
    for pad in pads:
        sides = [(max(lo, a - pad - BACKGROUND_SPAN), a - pad),
                 (b + pad, min(hi, b + pad + BACKGROUND_SPAN))]
        sides = [s for s in sides if s[1] - s[0] >= 1.0]
        if sides:
            break
    else:
        raise ParameterError(
            f"interval {a:g}..{b:g} s leaves no background on either side within the data "
            f"({lo:g}..{hi:g} s): at least 1 s is needed {pad:g} s before or after it")
    bkg = fit_background(events, sides, degree=degree)
    lc = burst_light_curve(events, (max(lo, a - pad + 1.0), min(hi, b + pad - 1.0)), bkg)
    if not np.all(np.isfinite(lc.interval)):
        raise ParameterError(f"no block of the light curve in {a:g}..{b:g} s is above the "
                             "background: no burst to localise")
    return bkg, lc


def _boxcar(t0: float, t1: float) -> Callable[[np.ndarray], np.ndarray]:
    """Weights of a constant source over ``[t0, t1]``: each bin's fraction inside it (the
    light curve ignored, for comparison)."""
    def weights(edges: np.ndarray) -> np.ndarray:
        lo, hi = np.maximum(edges[:-1], t0), np.minimum(edges[1:], t1)
        return np.clip(hi - lo, 0.0, None) / np.diff(edges)
    return weights


def _peak_weight(weight: np.ndarray, edges: np.ndarray, timescale: float) -> float:
    """The highest mean over ``timescale`` seconds of the light curve ``weight`` of the fit
    (1 at its peak) in its bins of ``edges`` (equal widths: the mask-angle bins)."""
    n = max(round(timescale / float(edges[1] - edges[0])), 1)
    w = np.asarray(weight, dtype=float)
    if w.size <= n:
        return float(w.mean())
    c = np.concatenate([[0.0], np.cumsum(w)])
    return float(np.max(c[n:] - c[:-n]) / n)


def _measurements(events: EventList, a: float, b: float, degree: int,
                  update: Callable[[int, int], None] | None = None
                  ) -> tuple[Background, BurstLightCurve, tuple[float, float], Durations,
                             tuple[float, float]]:
    """Steps 1-3 of :func:`analyse_burst` for the burst triggered in ``[a, b]``: the
    background, the light curve, the window of the fits, the durations and their window."""
    def step(k: int) -> None:
        if update is not None:
            update(k, 5)

    # Two passes.  First the background on each side, away from the trigger by the gap,
    # its length and REACH (later pulses of a burst that triggered on one; without REACH
    # where the data are too short), and the light curve in between; then both again
    # around the burst's extent so found.
    pad = BACKGROUND_GAP + (b - a)
    bkg, lc = _background_and_light_curve(events, a, b, (pad + REACH, pad), degree)
    step(1)
    bkg, lc = _background_and_light_curve(events, *lc.interval, (BACKGROUND_GAP,), degree)
    s0, s1 = lc.interval
    step(2)
    # The window of the position fit: the burst with background on both sides, which pins
    # each detector's background level (free in the fit) where the burst is not, so that
    # the burst's TS counts its whole excess, not only its modulation.
    t0, t1 = events.t_start, events.t_stop
    margin = max(WINDOW_MARGIN, s1 - s0)
    window = (max(t0, s0 - margin), min(t1, s1 + margin))
    # The durations' window is wider, so that a long pulse's tail below the blocks'
    # threshold counts in T90 (measured: T90 of decays of 10-15 s short by 20-25 % in the
    # fit window).  Beyond BACKGROUND_GAP it overlaps the background's own data, where a
    # tail is partly absorbed by the polynomial.  Where the wider window fails durations'
    # checks (its excess too faint, or no background at its ends), the fit window.
    reach = max(WINDOW_MARGIN, DURATION_MARGIN * (s1 - s0))
    wide = (max(t0, s0 - reach), min(t1, s1 + reach))
    try:
        dur, dur_window = durations(events, wide, bkg, light_curve=lc), wide
    except ParameterError:
        dur, dur_window = durations(events, window, bkg, light_curve=lc), window
    step(3)
    return bkg, lc, window, dur, dur_window


def analyse_burst(
    events: EventList,
    interval: Any,
    *,
    energy: Any,
    model: Any = "exact",
    attitude: Any = None,
    max_step: float = MAX_ATTITUDE_STEP,
    radius: Any = 80.0,
    systematic: Any = 0.0,
    light_curve: bool = True,
    background_degree: int = 1,
    nside: int | None = None,
    progress: ProgressArg = None,
    cache: dict[Any, ResponseOperator] | None = None,
) -> Burst:
    """Measure and localise the burst in ``interval`` (see the module notes).

    Parameters
    ----------
    events : EventList
        Time-tagged events with the burst and background on both sides (or one side, at
        the edge of the data).
    interval : Candidate or (float, float)
        Where the burst is (a search candidate's window, or times in s); the light curve
        finds its extent from there.
    energy : float or Quantity
        Energy of the response (keV).
    model : str or ProfileModel
        Profile model of the response.
    attitude : Attitude or AttitudeTable, optional
        Default the events' attitude.
    max_step : float
        Longest attitude segment (s) of a table, > 0.
    radius : float or Quantity
        Searched cone around the pointing (deg), < 90.
    systematic : float or Quantity
        Systematic error per axis of the position (deg if plain), >= 0.
    light_curve : bool
        Weight the response with the burst's light curve (``False``: a constant source over
        the burst's extent, for comparison).
    background_degree : int
        Degree of the background polynomials, >= 0.
    nside : int, optional
        HEALPix ``nside`` of the search map (default: pixels a quarter of ``b / L``).
    progress : bool or callable, optional
        Progress over the steps.
    cache : dict, optional
        Folded responses computed before, by attitude.

    Returns
    -------
    Burst

    Raises
    ------
    ParameterError
        No background on either side of the burst, no significant block in the interval,
        an interval outside the data, no attitude.
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    e_kev = as_energy_scalar(energy, "energy")
    as_angle_scalar(systematic, "systematic", lo=0.0)
    a, b = _interval(interval)
    lo, hi = events.t_start, events.t_stop
    if b <= lo or a >= hi:
        raise ParameterError(f"interval {a:g}..{b:g} s lies outside the data ({lo:g}..{hi:g} s)")
    update, close = progress_callbacks(progress, 5, "burst", "step")
    try:
        bkg, lc, window, dur, dur_window = _measurements(events, a, b, background_degree,
                                                         update)
        s0, s1 = lc.interval
        pos = localise_burst(events, window, bkg, lc if light_curve else _boxcar(s0, s1),
                             energy=e_kev, model=model, attitude=attitude,
                             max_step=max_step, radius=radius,
                             nside=nside, systematic=systematic, cache=cache)
        update(4, 5)
    finally:
        close()
    # Photons/s on one face at L = 1 -> photons/cm^2/s: the face's projected area.
    inst = events.instrument
    area = np.pi * (0.5 * inst.detectors.diameter) ** 2 * np.cos(np.radians(pos.theta))
    flux = pos.flux / area
    lower, upper = pos.fit.flux_err[0]
    flux_err = 0.5 * (lower + upper) / area
    c = pos.counts
    w = pos.response.weight
    exposure_weight = float(np.sum(w * c.exposure))
    peak = _peak_weight(w, c.edges, dur.peak_timescale)
    return Burst((float(s0), float(s1)), window, bkg, lc, dur, pos, e_kev, flux * peak,
                 flux_err * peak, flux * exposure_weight, flux_err * exposure_weight,
                 float(events.meta.get("mjdref", 0.0)), dur_window)
