"""Folding event lists modulo the rotation period into count profiles.

Phase bins are bins of the mask angle ``xi mod 2 pi``: bin ``k`` of ``N`` covers
``[2 pi k / N, 2 pi (k + 1) / N)``, so folded profiles line up with the profile models'
``P[d, t, n]`` evaluated at the bin centres (or averaged over the bins).

Exposure per bin is exact: with ``q(t) = t / T + xi0 / (2 pi)`` (rotations since the mask
angle zero), the time a good interval ``[t1, t2]`` spends in bin ``k`` is
``T (G_k(q(t2)) - G_k(q(t1)))`` with
``G_k(q) = floor(q) / N + clip(frac(q) - k / N, 0, 1 / N)``, the measure of the set of
``q' in [0, q)`` whose fractional part lies in the bin.  This handles a non-integer number of
rotations, a start phase and any gaps.

The bins are a :class:`~rotmod.binning.TimeBinning` (the one binning shared with responses)
and the energy window an :class:`~rotmod.binning.EnergyBand`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_angle_scalar, as_integers, as_scalar
from rotmod.binning import EnergyBand, TimeBinning
from rotmod.errors import ParameterError
from rotmod.events.eventlist import EventList
from rotmod.events.gti import check_gti
from rotmod.geometry import Instrument
from rotmod.limits import check_memory

__all__ = ["FoldedProfiles", "exposure_per_bin", "fold"]

log = logging.getLogger(__name__)


def _rotations(t: np.ndarray, period: float, start_phase: float) -> np.ndarray:
    return np.asarray(t, dtype=float) / period + start_phase / (2 * np.pi)


def exposure_per_bin(
    gti: Any, time_bins: TimeBinning | int, rotation_period: Any, start_phase: Any = 0.0
) -> np.ndarray:
    """Seconds of good time with the mask angle in each of ``n_bins`` phase bins.

    Parameters
    ----------
    gti : array_like or Quantity, shape (k, 2)
        Good-time intervals (s).
    time_bins : TimeBinning or int
        The mask-angle bins (an integer: that many equal bins over one turn, >= 1).
    rotation_period : float or Quantity
        Mask rotation period (s), > 0.
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if a plain number).

    Returns
    -------
    numpy.ndarray, shape (n_bins,)
        Exposure (s); sums to the total good time.
    """
    g = check_gti(gti)
    n = TimeBinning.coerce(time_bins).n_bins
    T = as_scalar(rotation_period, "rotation_period", u.s, lo=0.0, lo_open=True)
    phase = as_angle_scalar(start_phase, "start_phase")
    check_memory(8.0 * 4 * g.shape[0] * n, f"the exposure of {g.shape[0]} good-time intervals "
                 f"in {n} bins", hint="fold into fewer bins")
    q = _rotations(g, T, phase)  # (k, 2)
    lo = np.arange(n) / n

    def measure(qq: np.ndarray) -> np.ndarray:
        whole = np.floor(qq)
        frac = qq - whole
        return whole[..., None] / n + np.clip(frac[..., None] - lo, 0.0, 1.0 / n)

    return T * np.sum(measure(q[:, 1]) - measure(q[:, 0]), axis=0)


#: Keys of :meth:`EnergyBand.to_dict`: the band has one owner, ``FoldedProfiles.energy_band``.
_BAND_KEYS = ("e_min", "e_max")


@dataclass(frozen=True, eq=False)
class FoldedProfiles:
    """Count profiles per detector folded modulo the rotation period.

    Attributes
    ----------
    counts : ndarray of int64, shape (n_det, n_bins)
        Events per detector and mask-angle bin.
    exposure : ndarray, shape (n_bins,) or (n_det, n_bins)
        Good time (s) in each bin (common to all detectors unless 2-D).
    time_bins : TimeBinning
        The mask-angle bins (an integer ``n`` is taken as ``TimeBinning(n)``); edges of
        another origin become one with :meth:`TimeBinning.from_edges`.
    instrument : Instrument
    gti : ndarray, shape (k, 2)
        Good-time intervals of the folded data (s).
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if a plain number; held as a Quantity in rad).
    energy_band : EnergyBand, optional
        Energies of the folded events (a ``(lo, hi)`` pair in keV is accepted); a
        reconstruction checks the response's energy against it.  ``None``: not known (no
        check).
    meta : dict
        Free-form metadata (e.g. the event file's header values), without ``e_min``/``e_max``
        keys: the band of the counts is :attr:`energy_band` (:func:`fold` leaves out an
        event file's ``e_min``/``e_max``, which describe the event file, not the folded
        window).
    """

    counts: np.ndarray
    exposure: np.ndarray
    time_bins: TimeBinning
    instrument: Instrument
    gti: np.ndarray
    start_phase: Any = 0.0
    energy_band: EnergyBand | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = np.asarray(self.counts)
        if c.ndim != 2:
            raise ParameterError(f"counts must have shape (n_det, n_bins), got {c.shape}")
        # Counts are integers >= 0: a float count is accepted only when exactly integral.
        c = as_integers(c, "counts", lo=0)
        n_det, n_bins = c.shape
        if n_det != len(self.instrument.detectors):
            raise ParameterError(
                f"counts must have one row per detector ({len(self.instrument.detectors)}), "
                f"got {n_det}"
            )
        ex = np.asarray(self.exposure, dtype=float)
        if ex.shape not in ((n_bins,), (n_det, n_bins)):
            raise ParameterError(
                f"exposure must have shape ({n_bins},) or ({n_det}, {n_bins}), got {ex.shape}"
            )
        if np.any(ex < 0) or not np.all(np.isfinite(ex)):
            raise ParameterError("exposure must be finite and >= 0 s")
        tb = TimeBinning.coerce(self.time_bins)
        if tb.n_bins != n_bins:
            raise ParameterError(
                f"time_bins must have one bin per counts column ({n_bins}), got {tb.n_bins}"
            )
        for name, val in (
            ("counts", c.astype(np.int64)), ("exposure", ex),
            ("gti", check_gti(self.gti)),
        ):
            val = np.array(val)
            val.flags.writeable = False
            object.__setattr__(self, name, val)
        object.__setattr__(self, "time_bins", tb)
        phase = as_angle_scalar(self.start_phase, "start_phase") * u.rad
        object.__setattr__(self, "start_phase", phase)
        if self.energy_band is not None:
            object.__setattr__(self, "energy_band", EnergyBand.coerce(self.energy_band))
        given = sorted(k for k in _BAND_KEYS if k in self.meta)
        if given:
            # The band of the counts has one owner; a key here would be ignored by the fits,
            # which check the response's energy against energy_band only.
            raise ParameterError(
                f"meta must not hold {', '.join(given)}: give the band of the folded counts "
                "as energy_band=EnergyBand(e_min, e_max)"
            )
        object.__setattr__(self, "meta", dict(self.meta))

    def __repr__(self) -> str:
        good = float(np.sum(self.gti[:, 1] - self.gti[:, 0]))
        return (
            f"<FoldedProfiles {self.counts.shape[0]} detectors x {self.n_bins} bins, "
            f"{int(self.counts.sum())} counts, {good:g} s good time>"
        )

    @property
    def n_bins(self) -> int:
        """Number of mask-angle bins."""
        return self.time_bins.n_bins

    @property
    def bin_edges(self) -> u.Quantity:
        """Mask-angle bin edges ``(n_bins + 1,)``, 0 to 360 deg (Quantity, rad)."""
        return self.time_bins.edges() * u.rad

    @property
    def bin_centers(self) -> u.Quantity:
        """Mask angle at the centre of each bin (Quantity, rad)."""
        return self.time_bins.angles() * u.rad

    @property
    def rate(self) -> np.ndarray:
        """Count rate (1/s) per detector and bin; NaN where a bin has no exposure."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.exposure > 0, self.counts / self.exposure, np.nan)

    @property
    def error(self) -> np.ndarray:
        """Poisson 1-sigma error of :attr:`rate`, ``sqrt(counts) / exposure`` (1/s).

        Zero for empty bins; fit against a model's expected counts instead when counts are
        small.
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.exposure > 0, np.sqrt(self.counts) / self.exposure, np.nan)


def fold(
    events: EventList, time_bins: TimeBinning | int, energy_band: Any = None
) -> FoldedProfiles:
    """Fold an event list modulo the rotation period into mask-angle bins.

    Parameters
    ----------
    events : EventList
        The events; those outside every good-time interval are dropped (and logged).
    time_bins : TimeBinning or int
        The mask-angle bins, e.g. a response's ``time_bins`` (an integer: that many equal
        bins over one turn, >= 1).
    energy_band : EnergyBand or (float, float) or Quantity, optional
        Keep only events with ``lo <= ENERGY <= hi`` (keV), e.g. a photopeak window.  Default:
        every event, and the band recorded is the range of their energies (``None`` when no
        event lies in a good-time interval).

    Returns
    -------
    FoldedProfiles
        Counts per detector and bin, with the exact exposure per bin; ``energy_band`` records
        the band, which a reconstruction checks against the response's energy.
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    tb = TimeBinning.coerce(time_bins)
    n = tb.n_bins
    inst = events.instrument
    check_memory(8.0 * (len(inst.detectors) + 4) * n, f"folding into {n} bins",
                 hint="fold into fewer bins")
    t = events.time
    g = events.gti
    # Events in a GTI: index of the last GTI starting at or before t.
    i = np.searchsorted(g[:, 0], t, side="right") - 1
    good = (i >= 0) & (t <= g[np.maximum(i, 0), 1])
    if not np.all(good):
        log.warning("fold: dropped %d events outside the good-time intervals", int((~good).sum()))
    e = np.asarray(events.energy, dtype=float)
    if energy_band is None:
        band = EnergyBand(float(e[good].min()), float(e[good].max())) if good.any() else None
    else:
        band = EnergyBand.coerce(energy_band)
        in_time = good.copy()
        good &= band.contains(e)
        if in_time.any() and not good.any():
            # Not an error (a band may be empty), but all-zero counts are worth a word.
            log.warning("fold: no event has an energy in the band %g-%g keV (the events in "
                        "the good-time intervals span %g-%g keV); the folded counts are all 0",
                        band.e_min, band.e_max, e[in_time].min(), e[in_time].max())
    phase = events.start_phase.to_value(u.rad)
    q = _rotations(t[good], inst.rotation_period, phase)
    k = np.minimum(((q - np.floor(q)) * n).astype(np.int64), n - 1)
    n_det = len(inst.detectors)
    counts = np.bincount(events.detector[good].astype(np.int64) * n + k, minlength=n_det * n)
    exposure = exposure_per_bin(g, tb, inst.rotation_period, events.start_phase)
    return FoldedProfiles(
        counts.reshape(n_det, n), exposure, tb, inst, g, events.start_phase, band,
        {k: v for k, v in events.meta.items() if k not in _BAND_KEYS}
    )
