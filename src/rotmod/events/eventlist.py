"""Time-tagged event lists."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_angle_scalar, as_array, as_energy, as_integers, as_scalar
from rotmod.errors import ParameterError
from rotmod.events.gti import check_gti
from rotmod.geometry import Instrument
from rotmod.sky.attitude import Attitude

if TYPE_CHECKING:
    from rotmod.sky.sources import PointSources

__all__ = ["EventList"]

#: Default header metadata of an event list (see :mod:`rotmod.io.events`).
DEFAULT_META: dict[str, Any] = {
    "telescop": "ROTMOD",
    "instrume": "RM",
    "timesys": "TT",
    "mjdref": 51544.0,  # 2000-01-01 00:00 TT; arbitrary for simulations
    "timezero": 0.0,
    "creator": "rotmod",
}


@dataclass(frozen=True, eq=False)
class EventList:
    """Photon events recorded by a rotating modulator.

    Parameters
    ----------
    time : array_like, shape (n,)
        Arrival times (s since ``meta['mjdref']``), sorted.
    detector : array_like of int, shape (n,)
        Detector index ``0 <= id < n_det`` (rows of ``instrument.detectors.positions``).
    energy : array_like, shape (n,)
        Energy (keV), stored as float32.
    instrument : Instrument
        The instrument, including its rotation period.
    gti : array_like, shape (k, 2)
        Good-time intervals (s); every event lies in one.
    start_phase : float or Quantity
        Mask angle at ``time = 0`` (deg if a plain number; held as a Quantity in rad):
        ``xi(t) = 2 pi t / rotation_period + start_phase``.
    t_start, t_stop : float, optional
        Exposure bounds (s); default the first GTI start and the last GTI stop.
    source : array_like of int, shape (n,), optional
        Monte Carlo truth: index of the emitting source, -1 for background.
    sources : PointSources, optional
        The simulated sources (metadata).
    meta : dict
        Header metadata (``telescop``, ``instrume``, ``timesys``, ``mjdref``, ``timezero``,
        ...); missing keys take :data:`DEFAULT_META` values.
    attitude : Attitude, optional
        Where the instrument pointed (:class:`rotmod.sky.Attitude`); event files then carry
        the pointing and sky columns that astronomy tools (gammapy) expect.
    """

    time: np.ndarray
    detector: np.ndarray
    energy: np.ndarray
    instrument: Instrument
    gti: np.ndarray
    start_phase: Any = 0.0
    t_start: float | None = None
    t_stop: float | None = None
    source: np.ndarray | None = None
    sources: PointSources | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    attitude: Any = None

    def __post_init__(self) -> None:
        if self.attitude is not None and not isinstance(self.attitude, Attitude):
            raise ParameterError(f"events.attitude must be an Attitude, got {type(self.attitude)}")
        if not isinstance(self.instrument, Instrument):
            raise ParameterError(
                f"events.instrument must be an Instrument, got {type(self.instrument)}"
            )
        t = as_array(self.time, "events.time", u.s, ndim=1)
        n = t.size
        det = np.asarray(self.detector)
        if det.shape != (n,):
            raise ParameterError(f"events.detector must have shape ({n},), got {det.shape}")
        # Detector ids are integers: a float id is accepted only when exactly integral.
        det = as_integers(det, "events.detector")
        n_det = len(self.instrument.detectors)
        if n and (det.min() < 0 or det.max() >= n_det):  # before the cast: no wrap-around
            bad = det[(det < 0) | (det >= n_det)][0]
            raise ParameterError(
                f"events.detector must lie in 0..{n_det - 1} (the instrument's detectors), "
                f"got {bad}"
            )
        det = det.astype(np.int32)
        # Any finite energy is kept (no lower bound): events are selected by the energy
        # window of a fold, not when they are read.
        e = as_energy(self.energy, "events.energy", lo=None, ndim=1).astype(np.float32)
        if e.shape != (n,):
            raise ParameterError(f"events.energy must have shape ({n},), got {e.shape}")
        if n > 1 and np.any(np.diff(t) < 0):
            raise ParameterError("events.time must be sorted in increasing order")
        phase = as_angle_scalar(self.start_phase, "start_phase") * u.rad
        gti = check_gti(self.gti, self.t_start, self.t_stop)
        t0 = float(gti[0, 0]) if self.t_start is None else as_scalar(self.t_start, "t_start", u.s)
        t1 = float(gti[-1, 1]) if self.t_stop is None else as_scalar(self.t_stop, "t_stop", u.s)
        src = None
        if self.source is not None:
            src = np.asarray(self.source).astype(np.int32)
            if src.shape != (n,):
                raise ParameterError(f"events.source must have shape ({n},), got {src.shape}")
        meta = {**DEFAULT_META, **dict(self.meta)}
        for name, val in (
            ("time", t), ("detector", det), ("energy", e), ("gti", gti), ("source", src)
        ):
            if val is not None:
                val = np.array(val)
                val.flags.writeable = False
            object.__setattr__(self, name, val)
        object.__setattr__(self, "start_phase", phase)
        object.__setattr__(self, "t_start", t0)
        object.__setattr__(self, "t_stop", t1)
        object.__setattr__(self, "meta", meta)

    def __len__(self) -> int:
        return self.time.size

    def __repr__(self) -> str:
        span = f"{self.t_start:g}..{self.t_stop:g} s"
        return (
            f"<EventList {len(self)} events, {len(self.instrument.detectors)} detectors, {span}, "
            f"{self.exposure:g} s good time>"
        )

    @property
    def exposure(self) -> float:
        """Total good time (s): the sum of the GTI lengths (no dead time is modelled)."""
        return float(np.sum(self.gti[:, 1] - self.gti[:, 0]))

    def mask_angle(self) -> u.Quantity:
        """Mask angle ``xi`` (Quantity in rad, not wrapped) of every event."""
        return self.instrument.mask_angle(self.time) + self.start_phase

    def within(self, t_start: Any, t_stop: Any) -> EventList | None:
        """The events and good time in ``[t_start, t_stop)`` (s); ``None`` when no good
        time falls there (an interval without exposure)."""
        t0 = as_scalar(t_start, "t_start", u.s)
        t1 = as_scalar(t_stop, "t_stop", u.s)
        if not t1 > t0:
            raise ParameterError(f"t_stop must be > t_start ({t0:g} s), got {t1:g} s")
        g = np.clip(self.gti, t0, t1)
        g = g[g[:, 1] > g[:, 0]]
        if g.size == 0:
            return None
        keep = (self.time >= t0) & (self.time < t1)
        return EventList(
            self.time[keep], self.detector[keep], self.energy[keep], self.instrument, g,
            self.start_phase, float(g[0, 0]), float(g[-1, 1]),
            None if self.source is None else self.source[keep], self.sources,
            dict(self.meta), self.attitude,
        )

    def select(self, mask: np.ndarray) -> EventList:
        """A new event list holding the events where boolean ``mask`` is true."""
        mask = np.asarray(mask, dtype=bool)
        return EventList(
            self.time[mask], self.detector[mask], self.energy[mask], self.instrument,
            self.gti, self.start_phase, self.t_start, self.t_stop,
            None if self.source is None else self.source[mask], self.sources, dict(self.meta),
            self.attitude,
        )
