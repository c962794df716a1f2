"""Time (mask-angle) binning of the folded data.

One rotation of the mask is split into ``n_bins`` equal bins; bin ``t`` covers mask angles
``[2 pi t / N, 2 pi (t + 1) / N)`` (rad, see :mod:`rotmod.conventions`).  The response of a
bin is either the profile at the bin centre (``mode="center"``) or its mean over the bin,
estimated by the midpoint rule on ``n_sub`` equal sub-intervals (``mode="average"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ParameterError
from rotmod.limits import check_memory

__all__ = ["TimeBinning"]

_MODES = ("center", "average")


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

    def to_dict(self) -> dict[str, Any]:
        """Plain description for metadata (round-trips :meth:`from_dict`)."""
        return {"n_bins": self.n_bins, "mode": self.mode, "n_sub": self.n_sub}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TimeBinning:
        """Inverse of :meth:`to_dict`."""
        return cls(int(d["n_bins"]), str(d["mode"]), int(d["n_sub"]))

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
