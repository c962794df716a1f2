"""Time (mask-angle) binning and energy band of the folded data.

:class:`TimeBinning` is the one description of the mask-angle bins, shared by folding
(:func:`rotmod.events.fold`) and responses; :class:`EnergyBand` is the energy window of the
folded counts.

One rotation of the mask is split into ``n_bins`` equal bins; bin ``t`` covers mask angles
``[2 pi t / N, 2 pi (t + 1) / N)`` (rad, see :mod:`rotmod.conventions`).  The response of a
bin is either the profile at the bin centre (``mode="center"``) or its mean over the bin,
estimated by the midpoint rule on ``n_sub`` equal sub-intervals (``mode="average"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rotmod._validate import as_angle, as_energy, as_energy_scalar, as_int
from rotmod.errors import ParameterError
from rotmod.limits import check_memory

__all__ = ["EnergyBand", "TimeBinning"]

_MODES = ("center", "average")

#: How far (rad) edges read back may lie from equal bins over a turn.  Folded files store
#: the edges in degrees: rad -> deg -> rad moves them by a few ulp (~1e-15 rad); 1e-9 rad
#: (0.2 milli-arcsec) is far above that and far below any bin width a file can hold.
EDGE_TOLERANCE = 1e-9


@dataclass(frozen=True)
class TimeBinning:
    """``n_bins`` equal mask-angle bins per rotation.

    Parameters
    ----------
    n_bins : int
        Number of bins per rotation, >= 1.
    mode : {"center", "average"}
        Response of a bin: the profile at the bin centre, or its mean over the bin.
    n_sub : int
        Sub-samples per bin in ``"average"`` mode (midpoint rule), >= 1.  Ignored (and
        stored as 1) in ``"center"`` mode.

    Raises
    ------
    ParameterError
        Bad ``n_bins``, ``mode`` or ``n_sub``.

    Notes
    -----
    Bin ``t`` covers ``[2 pi t/N, 2 pi (t+1)/N)``.  In ``"average"`` mode sub-sample ``k`` of
    bin ``t`` sits at ``2 pi (t + (k + 1/2)/n_sub)/N``; the mean converges as ``n_sub^-2``
    for a smooth profile (midpoint rule) and ``n_sub = 1`` equals ``"center"``.
    """

    n_bins: int
    mode: str = "center"
    n_sub: int = 4

    def __post_init__(self) -> None:
        n = as_int(self.n_bins, "time_bins.n_bins", 1)
        if self.mode not in _MODES:
            raise ParameterError(f"time_bins.mode must be one of {_MODES}, got {self.mode!r}")
        n_sub = as_int(self.n_sub, "time_bins.n_sub", 1) if self.mode == "average" else 1
        # Edges, centres and sub-sample angles are held as float64 arrays.
        check_memory(8.0 * 3 * n * n_sub, f"{n} time bins x {n_sub} sub-samples",
                     hint="use fewer time bins")
        object.__setattr__(self, "n_bins", n)
        object.__setattr__(self, "n_sub", n_sub)

    @property
    def width(self) -> float:
        """Bin width ``2 pi / n_bins`` (rad)."""
        return 2.0 * np.pi / self.n_bins

    def edges(self) -> np.ndarray:
        """Bin edges ``(n_bins + 1,)`` (rad), from 0 to ``2 pi``."""
        return self.width * np.arange(self.n_bins + 1)

    def angles(self) -> np.ndarray:
        """Bin-centre mask angles ``(n_bins,)`` (rad)."""
        return self.width * (np.arange(self.n_bins) + 0.5)

    def sub_angles(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Sample angles ``(n_sub, stop - start)`` (rad) of bins ``start:stop``.

        Row ``k`` holds sub-sample ``k`` of every bin; the response of a bin is the mean over
        the rows (a single row, the centres, in ``"center"`` mode).
        """
        stop = self.n_bins if stop is None else stop
        t = np.arange(start, stop)
        k = (np.arange(self.n_sub) + 0.5) / self.n_sub
        return self.width * (t[None, :] + k[:, None])

    def bin_of(self, xi: Any) -> np.ndarray:
        """Index of the bin containing mask angle(s) ``xi`` (rad, any real value)."""
        x = np.mod(np.asarray(xi, dtype=float), 2.0 * np.pi)
        return np.minimum((x / self.width).astype(np.int64), self.n_bins - 1)

    def same_bins(self, other: TimeBinning) -> bool:
        """Whether ``other`` has the same bins (the same number of equal bins over a turn).

        ``mode`` and ``n_sub`` say how a response averages a bin, not which bins there are:
        folded counts match a response when the bins agree, whatever the response's mode.
        """
        return self.n_bins == other.n_bins

    def to_dict(self) -> dict[str, Any]:
        """Plain description for metadata (round-trips :meth:`from_dict`)."""
        return {"n_bins": self.n_bins, "mode": self.mode, "n_sub": self.n_sub}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TimeBinning:
        """Inverse of :meth:`to_dict`."""
        return cls(int(d["n_bins"]), str(d["mode"]), int(d["n_sub"]))

    @classmethod
    def from_edges(cls, edges: Any, mode: str = "center", n_sub: int = 4) -> TimeBinning:
        """The binning whose edges are ``edges``, which must be equal bins over a turn.

        The one place where edges (e.g. the ``BIN_LO``/``BIN_HI`` columns of a folded file)
        become a :class:`TimeBinning`: each edge may differ from ``2 pi k / N`` by
        :data:`EDGE_TOLERANCE` (rad), the round-off of storing it in degrees.

        Parameters
        ----------
        edges : array_like or Quantity, shape (n_bins + 1,)
            Bin edges (deg if plain numbers), from 0 to 360 deg.
        mode, n_sub
            As for the class.

        Raises
        ------
        ParameterError
            Fewer than two edges, or edges that are not ``n_bins`` equal bins from 0 to
            360 deg (shifted, unequal or not covering one turn).
        """
        e = as_angle(edges, "bin_edges", ndim=1)
        if e.size < 2:
            raise ParameterError(f"bin_edges must hold at least 2 edges, got {e.size}")
        tb = cls(e.size - 1, mode, n_sub)
        if not np.allclose(e, tb.edges(), rtol=0.0, atol=EDGE_TOLERANCE):
            raise ParameterError(
                f"bin_edges must be {tb.n_bins} equal bins over a turn (0 to 360 deg, within "
                f"{EDGE_TOLERANCE:g} rad), got edges {np.degrees(e[:3]).round(6).tolist()}... deg"
            )
        return tb

    @classmethod
    def coerce(cls, value: Any) -> TimeBinning:
        """A :class:`TimeBinning` from an instance or a number of (centre-mode) bins."""
        if isinstance(value, cls):
            return value
        if isinstance(value, int | np.integer) and not isinstance(value, bool):
            return cls(int(value))
        raise ParameterError(
            f"time_bins must be a TimeBinning or an integer number of bins, got {value!r}"
        )


@dataclass(frozen=True)
class EnergyBand:
    """The energy window ``[e_min, e_max]`` (keV) of folded counts.

    Parameters
    ----------
    e_min, e_max : float or Quantity
        Band edges (keV if plain numbers), finite, ``0 <= e_min <= e_max``.  The band is
        closed: ``e_min == e_max`` is the band of a single line (what :func:`~rotmod.events.fold`
        records for a monochromatic simulation folded without a window).

    Raises
    ------
    ParameterError
        A negative, non-finite or non-energy edge, or ``e_min > e_max``.
    """

    e_min: Any
    e_max: Any

    def __post_init__(self) -> None:
        lo = as_energy_scalar(self.e_min, "energy_band.e_min", lo=0.0, lo_open=False)
        hi = as_energy_scalar(self.e_max, "energy_band.e_max", lo=0.0, lo_open=False)
        if not lo <= hi:
            raise ParameterError(
                f"energy_band must be (lo, hi) keV with lo <= hi, got ({lo:g}, {hi:g}) keV"
            )
        object.__setattr__(self, "e_min", lo)
        object.__setattr__(self, "e_max", hi)

    def __repr__(self) -> str:
        return f"EnergyBand({self.e_min:g}-{self.e_max:g} keV)"

    def contains(self, energies: Any) -> np.ndarray:
        """Boolean mask of ``energies`` (keV or Quantity) with ``e_min <= E <= e_max``.

        The edges are rounded to float32 first: event files hold energies as float32, so a
        line exactly at an edge (e.g. ``energy=122`` with a band ending at 122 keV) is kept.
        """
        e = as_energy(energies, "energies", lo=None)
        return (e >= np.float32(self.e_min)) & (e <= np.float32(self.e_max))

    def to_dict(self) -> dict[str, float]:
        """``{"e_min": ..., "e_max": ...}`` (keV); round-trips :meth:`from_dict`."""
        return {"e_min": self.e_min, "e_max": self.e_max}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EnergyBand:
        """Inverse of :meth:`to_dict`."""
        return cls(d["e_min"], d["e_max"])

    @classmethod
    def coerce(cls, value: Any) -> EnergyBand:
        """An :class:`EnergyBand` from an instance or a ``(lo, hi)`` pair (keV or Quantity)."""
        if isinstance(value, cls):
            return value
        pair = as_energy(value, "energy_band", lo=None, ndim=1)
        if pair.shape != (2,):
            raise ParameterError(
                f"energy_band must be (lo, hi) keV or an EnergyBand, got {pair.size} values"
            )
        return cls(float(pair[0]), float(pair[1]))
