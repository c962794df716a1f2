"""Where the instrument points: from celestial coordinates to the instrument frame and back.

An :class:`Attitude` is the pointing of the rotation axis (RA, Dec) and the *roll*, the
position angle (east of north) of the instrument's +y axis on the sky.  The instrument frame
is rotmod's lab frame (:mod:`rotmod.conventions`): +z along the rotation axis toward the sky,
and, seen by an observer looking out along +z, +x toward the east when the roll is 0 (x, y, z
= east, north, up is right-handed).  A source at zenith ``theta`` and azimuth ``phi`` then lies
``theta`` from the pointing at position angle

    PA = roll + 90 deg - phi        (equivalently phi = roll + 90 deg - PA).

Every transformation goes through :class:`astropy.coordinates.SkyOffsetFrame` (origin = the
pointing, ``rotation`` = the roll), which is exact everywhere, the celestial poles included.
"""

from __future__ import annotations

import itertools
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import ICRS, CartesianRepresentation, SkyCoord, SkyOffsetFrame
from scipy.spatial.transform import Rotation, Slerp

from rotmod._validate import as_angle, as_angle_scalar, as_array, as_scalar
from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.limits import check_memory, check_time

__all__ = ["COVER_ABSOLUTE", "COVER_ROUND_OFF", "Attitude", "attitude_rotations"]

#: How far beyond its first and last samples a time still counts as covered by an
#: :class:`AttitudeTable`: float round-off only, the larger of COVER_ROUND_OFF times the
#: table's largest ``|time|`` and COVER_ABSOLUTE seconds.  The spacing of floats at ``|t|``
#: is 2.2e-16 ``|t|``, so 1e-12 allows ~4500 units in the last place of the times'
#: arithmetic; 1 us allows a time stamp that went through a double MJD (spacing 0.63 us
#: at MJD 6e4), which a relative tolerance alone refuses for times counted from 0.  At a
#: mission elapsed time of 1e9 s it is 1 ms, in which a gondola swinging at 3 deg/s turns
#: 0.003 deg, far below the instrument's resolution.  Not half a sample step: that would
#: hold the end attitude for half a step (30 s of a 60 s aspect) without a word, and the
#: command line's ``--attitude`` check allowed nothing past the samples.
COVER_ROUND_OFF = 1e-12
COVER_ABSOLUTE = 1e-6


@dataclass(frozen=True)
class Attitude:
    """A fixed pointing and roll of the instrument.

    Parameters
    ----------
    ra, dec : float or Quantity
        Direction of the rotation axis (ICRS; deg if plain numbers), ``-90 <= dec <= 90``.
    roll : float or Quantity
        Position angle (east of north) of the instrument's +y axis (deg if plain).

    Examples
    --------
    >>> att = Attitude(ra=83.63, dec=22.01, roll=30.0)
    >>> theta, phi = att.to_instrument(SkyCoord(84.0 * u.deg, 23.0 * u.deg))
    """

    ra: Any
    dec: Any
    roll: Any = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "ra", np.degrees(as_angle_scalar(self.ra, "attitude.ra")))
        object.__setattr__(
            self, "dec", np.degrees(as_angle_scalar(self.dec, "attitude.dec", lo=-90, hi=90))
        )
        object.__setattr__(self, "roll", np.degrees(as_angle_scalar(self.roll, "attitude.roll")))

    @property
    def pointing(self) -> SkyCoord:
        """The rotation axis on the sky (ICRS)."""
        return SkyCoord(self.ra * u.deg, self.dec * u.deg, frame="icrs")

    @property
    def frame(self) -> SkyOffsetFrame:
        """The sky frame centred on the pointing with its latitude axis along instrument +y."""
        return SkyOffsetFrame(origin=self.pointing.frame, rotation=self.roll * u.deg)

    def to_instrument(self, coords: SkyCoord) -> tuple[u.Quantity, u.Quantity]:
        """Zenith and azimuth (Quantities, rad) of sky positions in the instrument frame.

        Raises
        ------
        ParameterError
            ``coords`` is not a SkyCoord.
        """
        if not isinstance(coords, SkyCoord):
            raise ParameterError(f"coords must be an astropy SkyCoord, got {type(coords)}")
        c = coords.transform_to(self.frame).cartesian
        # Offset frame: x toward the pointing, y toward +longitude (east at roll 0), z toward
        # +latitude (the roll's direction).  Instrument (x, y, z) = offset (y, z, x): a cyclic
        # permutation, so both are right-handed.
        theta, phi = source_angles(np.stack([c.y.value, c.z.value, c.x.value], axis=-1))
        return theta * u.rad, phi * u.rad

    def to_sky(self, theta: Any, phi: Any) -> SkyCoord:
        """Sky positions (ICRS) of instrument directions ``(theta, phi)`` (deg if plain)."""
        th = as_angle(theta, "theta", lo=0.0, hi=180.0)
        ph = as_angle(phi, "phi")
        d = source_direction(*np.broadcast_arrays(th, ph))
        # Offset (x, y, z) = instrument (z, x, y): see to_instrument.
        offset = SkyCoord(x=d[..., 2], y=d[..., 0], z=d[..., 1], representation_type="cartesian",
                          frame=self.frame)
        out = offset.transform_to(ICRS())
        return SkyCoord(out.ra, out.dec, frame="icrs")


def attitude_rotations(attitudes: list[Any]) -> np.ndarray:
    """Rotation matrices ``(k, 3, 3)`` from ICRS unit vectors to each attitude's instrument
    frame: rows the instrument's +x, +y and +z axes in ICRS.

    +z is the pointing, +y lies at position angle ``roll`` (east of north) and +x = y × z
    (east at roll 0), as :class:`~rotmod.sky.Attitude` defines them; so ``M s`` is the
    instrument direction of the sky direction ``s``, exactly as
    :meth:`~rotmod.sky.Attitude.to_instrument` gives it (to rounding).
    """
    a, d, r = (np.radians(np.array([getattr(att, name) for att in attitudes], dtype=float))
               for name in ("ra", "dec", "roll"))
    z = np.stack([np.cos(d) * np.cos(a), np.cos(d) * np.sin(a), np.sin(d)], axis=-1)
    east = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], axis=-1)
    north = np.stack([-np.sin(d) * np.cos(a), -np.sin(d) * np.sin(a), np.cos(d)], axis=-1)
    y = np.cos(r)[:, None] * north + np.sin(r)[:, None] * east
    return np.stack([np.cross(y, z), y, z], axis=1)


def _from_axes(z: np.ndarray, y: np.ndarray) -> Attitude:
    """The attitude whose pointing is ``z`` and whose +y axis is ``y`` (ICRS unit vectors)."""
    z = z / np.linalg.norm(z)
    y = y - np.dot(y, z) * z  # Gram-Schmidt: exactly perpendicular to the pointing
    y /= np.linalg.norm(y)
    pointing = SkyCoord(ICRS(CartesianRepresentation(*z)))
    # +y seen from the pointing: a direction 90 deg away at the roll's position angle.
    roll = pointing.position_angle(SkyCoord(ICRS(CartesianRepresentation(*y))))
    return Attitude(pointing.ra, pointing.dec, roll)


@dataclass(frozen=True)
class AttitudeTable:
    """A time-dependent attitude (a balloon's aspect solution): samples interpolated.

    Between samples the instrument turns as a rigid body at a constant rate about one axis
    (spherical linear interpolation of the rotations, scipy's ``Slerp``): a roll from 0 to
    180 deg is at 90 deg midway, a slew from RA 0 to 170 deg at RA 85, and the poles are
    not special.  Two consecutive samples exactly opposite (a half turn apart) have no
    unique path between them and are refused.

    The table covers the times from its first sample to its last: :meth:`at` and
    :meth:`intervals` refuse times outside them (beyond round-off, :attr:`tolerance`),
    where the attitude is unknown; a single sample covers its own instant only.

    Parameters
    ----------
    time : array_like, shape (k,)
        Sample times (s, increasing, k >= 1).
    ra, dec, roll : array_like, shape (k,)
        Pointing and roll at each sample (deg if plain numbers).
    max_gap : float, optional
        The longest time between samples (s) interpolated without a warning (a longer one
        is a dropout of the aspect solution); default 10 times the median spacing.

    Warns
    -----
    UserWarning
        Gaps longer than ``max_gap``, with the longest and where it is.
    """

    time: Any
    ra: Any
    dec: Any
    roll: Any
    max_gap: Any = None

    def __post_init__(self) -> None:
        t = as_array(self.time, "attitude.time", u.s, ndim=1)
        if t.size == 0 or np.any(np.diff(t) <= 0):
            raise ParameterError("attitude.time must hold at least one time, increasing")
        cols = [np.degrees(as_angle(v, f"attitude.{n}", ndim=1))
                for v, n in ((self.ra, "ra"), (self.dec, "dec"), (self.roll, "roll"))]
        if any(c.shape != t.shape for c in cols):
            raise ParameterError("attitude.ra, dec and roll must have one value per time")
        for name, arr in zip(("time", "ra", "dec", "roll"), (t, *cols), strict=True):
            arr = np.array(arr, dtype=float)
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        samples = [Attitude(r, d, o) for r, d, o in zip(*cols, strict=True)]
        rot = Rotation.from_matrix(attitude_rotations(samples))
        if t.size > 1:
            turn = (rot[:-1].inv() * rot[1:]).magnitude()
            bad = np.flatnonzero(turn > np.pi - 1e-9)
            if bad.size:
                k = int(bad[0])
                raise ParameterError(
                    f"attitude: the samples at {t[k]:g} s and {t[k + 1]:g} s are a half turn "
                    "apart, so no path between them is defined; add a sample in between")
        if t.size > 2:
            gaps = np.diff(t)
            limit = (10.0 * float(np.median(gaps)) if self.max_gap is None
                     else as_scalar(self.max_gap, "attitude.max_gap", u.s, lo=0.0,
                                    lo_open=True))
            long = np.flatnonzero(gaps > limit)
            if long.size:
                k = int(long[np.argmax(gaps[long])])
                warnings.warn(
                    f"attitude: {long.size} gap(s) in the aspect longer than {limit:g} s, the "
                    f"longest {gaps[k]:g} s after t = {t[k]:g} s; the attitude is "
                    "interpolated across them (set max_gap to accept them)", stacklevel=3)
        object.__setattr__(self, "_slerp", Slerp(t, rot) if t.size > 1 else None)
        object.__setattr__(self, "_first", rot[0])

    @property
    def span(self) -> tuple[float, float]:
        """The first and last sample times (s): the times the table covers."""
        return float(self.time[0]), float(self.time[-1])

    @property
    def tolerance(self) -> float:
        """How far (s) beyond its end samples a time still counts as covered: round-off,
        :data:`COVER_ROUND_OFF` times the largest ``|time|``, at least
        :data:`COVER_ABSOLUTE`."""
        return max(COVER_ABSOLUTE,
                   COVER_ROUND_OFF * float(max(abs(self.time[0]), abs(self.time[-1]))))

    def covers(self, t_start: float, t_stop: float | None = None) -> bool:
        """Whether the samples span the time ``t_start`` or the times ``[t_start, t_stop]``
        (s), to :attr:`tolerance`: the one test of :meth:`at`, :meth:`intervals` and the
        command line's ``--attitude``.

        Raises
        ------
        ParameterError
            A time not finite, or ``t_stop < t_start``.
        """
        lo, hi = self.span
        t0 = as_scalar(t_start, "t_start", u.s)
        t1 = t0 if t_stop is None else as_scalar(t_stop, "t_stop", u.s)
        if t1 < t0:
            raise ParameterError(f"t_stop must be >= t_start, got {t0:g} .. {t1:g} s")
        return bool(t0 >= lo - self.tolerance and t1 <= hi + self.tolerance)

    def _check_covers(self, name: str, t_start: float, t_stop: float) -> None:
        """Refuse times outside the samples (:meth:`covers`), naming ``name``."""
        if self.covers(t_start, t_stop):
            return
        lo, hi = self.span
        one, tol = t_stop == t_start, self.tolerance
        asked = f"{t_start:.12g} s" if one else f"{t_start:.12g} .. {t_stop:.12g} s"
        early = f"{lo - t_start:.3g} s before its first sample"
        late = f"{t_stop - hi:.3g} s after its last sample"
        if one:
            past = f"is {early if t_start < lo else late}"
        else:
            past = " and ".join([*([f"starts {early}"] if t_start < lo - tol else []),
                                 *([f"ends {late}"] if t_stop > hi + tol else [])])
        raise ParameterError(
            f"{name}: the attitude table covers {lo:.12g} .. {hi:.12g} s, but {name} = {asked} "
            f"{past} (round-off of {tol:.3g} s is allowed); outside its samples "
            "the attitude is unknown (holding the end one would freeze the drift silently): "
            "give a table that covers these times")

    def at(self, t: float) -> Attitude:
        """The attitude at time ``t`` (s), within the samples.

        Raises
        ------
        ParameterError
            ``t`` not finite, or outside the samples (beyond :attr:`tolerance`).
        """
        t = as_scalar(t, "t", u.s)
        self._check_covers("t", t, t)
        return self._at(t)

    def _at(self, t: float) -> Attitude:
        """The attitude at ``t``, covered (clipped onto the samples: round-off)."""
        if self._slerp is None:
            m = self._first.as_matrix()
        else:
            m = self._slerp(float(np.clip(t, self.time[0], self.time[-1]))).as_matrix()
        return _from_axes(m[2], m[1])  # rows: the instrument's axes in ICRS

    def intervals(self, t_start: float, t_stop: float, max_step: float
                  ) -> list[tuple[float, float, Attitude]]:
        """``(lo, hi, attitude at the middle)`` pieces of at most ``max_step`` s.

        Raises
        ------
        ParameterError
            Times not finite or not increasing, outside the samples (beyond
            :attr:`tolerance`), ``max_step <= 0``.
        rotmod.limits.MemoryBudgetError, rotmod.limits.TimeBudgetError
            More pieces than the memory or time budget allows (before any is made).
        """
        t0 = as_scalar(t_start, "t_start", u.s)
        t1 = as_scalar(t_stop, "t_stop", u.s)
        step = as_scalar(max_step, "max_step", u.s, lo=0.0, lo_open=True)
        if not t1 > t0:
            raise ParameterError(f"t_stop must be > t_start, got {t0:g} .. {t1:g} s")
        self._check_covers("t_start .. t_stop", t0, t1)
        n = (t1 - t0) / step  # inf for a step below 1e-308 of the span: refused below
        n = math.ceil(n) if math.isfinite(n) else n
        what = (f"(t_stop - t_start) / max_step = {t1 - t0:g} s / {step:g} s = {n:.6g} "
                "attitude pieces")
        hint = "use a longer max_step or a shorter time span"
        # Each piece is a tuple of two floats and an Attitude: ~340 B measured (tracemalloc).
        check_memory(400.0 * n, what, hint=hint)
        check_time(n, "attitude_pieces", what, hint=hint)
        edges = np.linspace(t0, t1, int(n) + 1)
        return [(float(a), float(b), self._at(0.5 * (a + b)))
                for a, b in itertools.pairwise(edges)]

    def write(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the samples as an ECSV table (time in s, angles in deg), atomically
        (:func:`rotmod.io.tables.write_attitude_table`, the one writer).

        Raises
        ------
        ParameterError
            ``path`` exists and ``overwrite`` is false.
        """
        # Function-local: the file formats live in rotmod.io, which builds on this module.
        from rotmod.io.tables import write_attitude_table

        return write_attitude_table(self, path, overwrite=overwrite)

    @classmethod
    def read(cls, path: str | os.PathLike) -> AttitudeTable:
        """Read an attitude table (ECSV or FITS with columns time, ra, dec, roll + units;
        :func:`rotmod.io.tables.read_attitude_table`, the one reader)."""
        from rotmod.io.tables import read_attitude_table  # see write

        return read_attitude_table(path)
