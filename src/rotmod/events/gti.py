"""Good-time intervals."""

from __future__ import annotations

from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_scalar
from rotmod.errors import ParameterError

__all__ = ["check_gti", "join_touching"]


def check_gti(gti: Any, t_start: Any = None, t_stop: Any = None) -> np.ndarray:
    """Validate good-time intervals; returns a float array of shape (k, 2) in s.

    Parameters
    ----------
    gti : array_like or Quantity, shape (k, 2), or None
        ``[start, stop]`` rows, sorted, non-overlapping, each ``start < stop``.  ``None``
        means one interval ``[t_start, t_stop]``.
    t_start, t_stop : float or Quantity, optional
        Exposure bounds (s); when given, every interval must lie within them.

    Raises
    ------
    ParameterError
        Empty, unsorted, overlapping, zero-length or out-of-bounds intervals.
    """
    t0 = None if t_start is None else as_scalar(t_start, "t_start", u.s)
    t1 = None if t_stop is None else as_scalar(t_stop, "t_stop", u.s)
    if t0 is not None and t1 is not None and not t1 > t0:
        raise ParameterError(f"t_stop must be > t_start ({t0:g} s), got {t1:g} s")
    if gti is None:
        if t0 is None or t1 is None:
            raise ParameterError("gti is required unless both t_start and t_stop are given")
        return np.array([[t0, t1]])
    g = as_array(gti, "gti", u.s)
    if g.ndim == 1 and g.shape == (2,):
        g = g[None, :]
    if g.ndim != 2 or g.shape[1] != 2:
        raise ParameterError(f"gti must have shape (k, 2), got {g.shape}")
    if g.shape[0] == 0:
        raise ParameterError("gti must contain at least one interval, got none")
    if np.any(g[:, 1] <= g[:, 0]):
        i = int(np.argmax(g[:, 1] <= g[:, 0]))
        raise ParameterError(
            f"gti intervals must have start < stop, got [{g[i, 0]:g}, {g[i, 1]:g}] s (row {i})"
        )
    if np.any(g[1:, 0] < g[:-1, 1]):
        i = int(np.argmax(g[1:, 0] < g[:-1, 1])) + 1
        raise ParameterError(
            f"gti intervals must be sorted and non-overlapping, row {i} starts at "
            f"{g[i, 0]:g} s before row {i - 1} ends at {g[i - 1, 1]:g} s"
        )
    if t0 is not None and g[0, 0] < t0:
        raise ParameterError(f"gti must start at or after t_start = {t0:g} s, got {g[0, 0]:g} s")
    if t1 is not None and g[-1, 1] > t1:
        raise ParameterError(f"gti must end at or before t_stop = {t1:g} s, got {g[-1, 1]:g} s")
    return np.array(g, dtype=float)


def join_touching(gti: np.ndarray) -> np.ndarray:
    """Checked GTIs ``(k, 2)`` with touching or overlapping rows joined (``[0, 10], [10,
    20]`` -> ``[0, 20]``): the stretches of data without a gap."""
    rows = [list(gti[0])]
    for a, b in gti[1:]:
        if a <= rows[-1][1]:
            rows[-1][1] = max(rows[-1][1], b)
        else:
            rows.append([a, b])
    return np.array(rows, dtype=float)
