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
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_angle, as_angle_scalar, as_array, as_int, as_scalar
from rotmod.errors import ParameterError
from rotmod.events.eventlist import EventList
from rotmod.events.gti import check_gti
from rotmod.geometry import Instrument
from rotmod.limits import check_memory

__all__ = ["FoldedProfiles", "exposure_per_bin", "fold"]

log = logging.getLogger(__name__)


def _check_n_bins(n_bins: Any) -> int:
    return as_int(n_bins, "n_bins", 1)


def _rotations(t: np.ndarray, period: float, start_phase: float) -> np.ndarray:
    return np.asarray(t, dtype=float) / period + start_phase / (2 * np.pi)


def exposure_per_bin(
    gti: Any, n_bins: int, rotation_period: Any, start_phase: Any = 0.0
) -> np.ndarray:
    """Seconds of good time with the mask angle in each of ``n_bins`` phase bins.

    Parameters
    ----------
    gti : array_like or Quantity, shape (k, 2)
        Good-time intervals (s).
    n_bins : int
        Number of mask-angle bins over one turn (>= 1).
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
    n = _check_n_bins(n_bins)
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


@dataclass(frozen=True, eq=False)
class FoldedProfiles:
    """Count profiles per detector folded modulo the rotation period.

    Attributes
    ----------
    counts : ndarray of int64, shape (n_det, n_bins)
        Events per detector and mask-angle bin.
    exposure : ndarray, shape (n_bins,) or (n_det, n_bins)
        Good time (s) in each bin (common to all detectors unless 2-D).
    bin_edges : Quantity, shape (n_bins + 1,)
        Mask-angle bin edges, ``0 .. 360 deg`` (deg if plain numbers; held in rad).
    instrument : Instrument
    gti : ndarray, shape (k, 2)
        Good-time intervals of the folded data (s).
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if a plain number; held as a Quantity in rad).
    meta : dict
        Free-form metadata (e.g. the event file's header values).
    """

    counts: np.ndarray
    exposure: np.ndarray
    bin_edges: Any
    instrument: Instrument
    gti: np.ndarray
    start_phase: Any = 0.0
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = np.asarray(self.counts)
        if c.ndim != 2:
            raise ParameterError(f"counts must have shape (n_det, n_bins), got {c.shape}")
        if np.any(c < 0) or not np.all(c == np.round(c)):
            raise ParameterError("counts must be non-negative integers")
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
        edges = as_angle(self.bin_edges, "bin_edges")
        if edges.shape != (n_bins + 1,) or np.any(np.diff(edges) <= 0):
            raise ParameterError(
                f"bin_edges must be {n_bins + 1} increasing mask angles, got shape {edges.shape}"
            )
        for name, val in (
            ("counts", c.astype(np.int64)), ("exposure", ex),
            ("gti", check_gti(self.gti)),
        ):
            val = np.array(val)
            val.flags.writeable = False
            object.__setattr__(self, name, val)
        edges = np.array(edges) * u.rad
        edges.flags.writeable = False
        object.__setattr__(self, "bin_edges", edges)
        phase = as_angle_scalar(self.start_phase, "start_phase") * u.rad
        object.__setattr__(self, "start_phase", phase)
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
        return self.counts.shape[1]

    @property
    def bin_centers(self) -> np.ndarray:
        """Mask angle at the centre of each bin (Quantity, rad)."""
        return 0.5 * (self.bin_edges[1:] + self.bin_edges[:-1])

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


def fold(events: EventList, n_bins: int, energy_band: Any = None) -> FoldedProfiles:
    """Fold an event list modulo the rotation period into ``n_bins`` mask-angle bins.

    Parameters
    ----------
    events : EventList
        The events; those outside every good-time interval are dropped (and logged).
    n_bins : int
        Number of mask-angle bins over one turn (>= 1).
    energy_band : (float, float) or Quantity, optional
        Keep only events with ``lo <= ENERGY <= hi`` (keV), e.g. a photopeak window.  Default:
        every event, and the band recorded is the range of their energies.

    Returns
    -------
    FoldedProfiles
        Counts per detector and bin, with the exact exposure per bin; ``meta["e_min"]`` and
        ``meta["e_max"]`` (keV) record the energy band, which a reconstruction checks against
        the response's energy.
    """
    if not isinstance(events, EventList):
        raise ParameterError(f"events must be an EventList, got {type(events)}")
    n = _check_n_bins(n_bins)
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
        band = (float(e[good].min()), float(e[good].max())) if good.any() else (0.0, 0.0)
    else:
        band = tuple(as_array(energy_band, "energy_band", u.keV, lo=0.0, ndim=1).tolist())
        if len(band) != 2 or not band[0] < band[1]:
            raise ParameterError(f"energy_band must be (lo, hi) keV with lo < hi, got {band}")
        # float32 energies: compare at float32 precision so a line at the edge is kept.
        good &= (e >= np.float32(band[0])) & (e <= np.float32(band[1]))
    phase = events.start_phase.to_value(u.rad)
    q = _rotations(t[good], inst.rotation_period, phase)
    k = np.minimum(((q - np.floor(q)) * n).astype(np.int64), n - 1)
    n_det = len(inst.detectors)
    counts = np.bincount(events.detector[good].astype(np.int64) * n + k, minlength=n_det * n)
    exposure = exposure_per_bin(g, n, inst.rotation_period, events.start_phase)
    return FoldedProfiles(
        counts.reshape(n_det, n),
        exposure,
        np.linspace(0.0, 2 * np.pi, n + 1) * u.rad,
        inst,
        g,
        events.start_phase,
        {**events.meta, "e_min": band[0], "e_max": band[1]},
    )
