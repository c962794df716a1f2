"""The response to time-tagged counts that are not folded: a transient's likelihood.

Folding assumes a sky that is constant over many rotations.  A burst lasts a few rotations
or less and its brightness changes within one, so its counts are kept in short time bins
``k`` of a window, and the expected rate of detector ``d`` in bin ``k`` is

    O[d, k] = w_k sum_n P_j(k)[d, t(k), n] S[n],

with ``t(k)`` the mask-angle bin the mask is in during bin ``k`` (the bins are aligned with
the mask-angle bins, :func:`aligned_edges`), ``j(k)`` the attitude segment it belongs to
(``P_j`` the folded response of that attitude) and ``w_k`` the burst's relative light curve
``L(t)`` in the bin.  This is the model ``F L(t) A_d P_d(xi(t), direction, attitude(t))`` of
a source with time profile ``L`` and flux ``F``: the folded response supplies ``P_d`` at
every mask angle and attitude, the weights supply ``L``.  The operator is linear in the
sky, so fits, TS maps and localisation regions (:mod:`rotmod.sources`) take it unchanged:
it is one more :class:`~rotmod.response.ResponseOperator`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import astropy.units as u
import numpy as np
from scipy import sparse

from rotmod._validate import as_angle_scalar, as_scalar
from rotmod.binning import TimeBinning
from rotmod.errors import ParameterError
from rotmod.limits import check_memory
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_ranges

__all__ = ["UnfoldedResponse", "aligned_edges"]


def aligned_edges(t_start: Any, t_stop: Any, time_bins: TimeBinning | int,
                  rotation_period: Any, start_phase: Any = 0.0) -> np.ndarray:
    """Time-bin edges (s) covering ``[t_start, t_stop]`` on the mask-angle bin boundaries.

    Bin ``k`` then spends all its time in one mask-angle bin, so its response is exactly
    that bin's (no mixing of two angles).  The first and last edges are the boundaries at or
    before ``t_start`` and at or after ``t_stop``.

    Parameters
    ----------
    t_start, t_stop : float or Quantity
        The window (s), ``t_stop > t_start``.
    time_bins : TimeBinning or int
        The mask-angle bins per rotation.
    rotation_period : float or Quantity
        Mask rotation period (s), > 0.
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if a plain number).
    """
    t0 = as_scalar(t_start, "t_start", u.s)
    t1 = as_scalar(t_stop, "t_stop", u.s)
    if not t1 > t0:
        raise ParameterError(f"t_stop must be > t_start ({t0:g} s), got {t1:g} s")
    n = TimeBinning.coerce(time_bins).n_bins
    period = as_scalar(rotation_period, "rotation_period", u.s, lo=0.0, lo_open=True)
    phase = as_angle_scalar(start_phase, "start_phase")
    # Bin boundaries are where q = n (t / T + phase / 2 pi) is an integer.
    offset = n * phase / (2.0 * np.pi)
    q0 = np.floor(n * t0 / period + offset + 1e-9)
    q1 = np.ceil(n * t1 / period + offset - 1e-9)
    check_memory(8.0 * (q1 - q0 + 1), f"{int(q1 - q0)} time bins of {period / n:g} s",
                 hint="use a shorter window or fewer mask-angle bins")
    return (np.arange(q0, q1 + 1) - offset) * period / n


class UnfoldedResponse(ResponseOperator):
    """Sky to count rates in the time bins of a window (see the module notes).

    Parameters
    ----------
    parts : sequence of ResponseOperator
        The folded response of each attitude segment: all on one sky geometry (the same
        pixels), with the same detectors and mask-angle bins.
    segment : array_like of int, shape (n_time,)
        The part each time bin belongs to.
    phase : array_like of int, shape (n_time,)
        The mask-angle bin of each time bin (``0 <= t < parts[0].n_time``).
    weight : array_like, shape (n_time,), optional
        The light curve ``w_k >= 0`` (default 1: a constant source).
    edges : array_like, shape (n_time + 1,), optional
        The time bins' edges (s): metadata, for the products.
    """

    def __init__(self, parts: Sequence[ResponseOperator], segment: Any, phase: Any,
                 weight: Any = None, edges: Any = None) -> None:
        parts = list(parts)
        if not parts or not all(isinstance(p, ResponseOperator) for p in parts):
            raise ParameterError("parts must be one or more ResponseOperators")
        first = parts[0]
        for j, p in enumerate(parts[1:], 1):
            if (p.n_det, p.n_time, p.n_sky) != (first.n_det, first.n_time, first.n_sky):
                raise ParameterError(
                    f"parts[{j}] must have the shape of parts[0] "
                    f"{(first.n_det, first.n_time, first.n_sky)}, got "
                    f"{(p.n_det, p.n_time, p.n_sky)}")
        seg = np.asarray(segment)
        ph = np.asarray(phase)
        if seg.ndim != 1 or seg.size == 0 or ph.shape != seg.shape:
            raise ParameterError(f"segment and phase must be 1-D of one length >= 1, got "
                                 f"shapes {seg.shape} and {ph.shape}")
        for name, v, hi in (("segment", seg, len(parts)), ("phase", ph, first.n_time)):
            if not np.issubdtype(v.dtype, np.integer) or v.min() < 0 or v.max() >= hi:
                raise ParameterError(f"{name} must hold integers in 0..{hi - 1}")
        w = np.ones(seg.size) if weight is None else np.asarray(weight, dtype=float)
        if w.shape != seg.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ParameterError(f"weight must be {seg.size} finite values >= 0")
        self.parts = parts
        self.segment = seg.astype(np.int64)
        self.phase = ph.astype(np.int64)
        self.weight = w
        self.edges = None if edges is None else np.asarray(edges, dtype=float)
        if self.edges is not None and self.edges.shape != (seg.size + 1,):
            raise ParameterError(f"edges must have {seg.size + 1} values, got {self.edges.shape}")
        self.n_det, self.n_time, self.n_sky = first.n_det, seg.size, first.n_sky
        self.dtype = np.dtype(np.float64)
        self.instrument, self.grid = first.instrument, first.grid
        self.model, self.energy, self.distance = first.model, first.energy, first.distance
        # Per part: its time bins and the sparse map from its mask-angle bins to them.
        self._rows = [np.flatnonzero(self.segment == j) for j in range(len(parts))]
        self._maps = [sparse.csr_matrix(
            (w[rows], (self.phase[rows], rows)), shape=(first.n_time, self.n_time))
            for rows in self._rows]

    def with_weight(self, weight: Any) -> UnfoldedResponse:
        """The same response with another light curve ``weight`` (the parts are shared)."""
        return UnfoldedResponse(self.parts, self.segment, self.phase, weight, self.edges)

    def components(self) -> list[Any]:
        """Not a sum of folded responses: its columns come from :meth:`gather`."""
        raise ParameterError("an unfolded response is not a sum of folded ones; evaluate "
                             "it at other positions with rotmod.response.columns_at")

    def gather(self, folded: Sequence[np.ndarray]) -> np.ndarray:
        """Unfold per-part folded values ``(n_det, n_phase, m)`` to ``(n_det, n_time, m)``."""
        m = folded[0].shape[2]
        check_memory(8.0 * self.n_det * self.n_time * m,
                     f"{m} unfolded columns of {self.n_det} x {self.n_time} bins",
                     hint="evaluate fewer positions at a time")
        out = np.zeros((self.n_det, self.n_time, m))
        for rows, p in zip(self._rows, folded, strict=True):
            out[:, rows, :] = p[:, self.phase[rows], :] * self.weight[rows][None, :, None]
        return out

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n_det, self.n_time))
        for part, rows in zip(self.parts, self._rows, strict=True):
            if rows.size:
                out[:, rows] = part.forward(sky)[:, self.phase[rows]] * self.weight[rows]
        return out

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n_sky)
        y = np.asarray(counts, dtype=float)
        for part, rows, gmap in zip(self.parts, self._rows, self._maps, strict=True):
            if rows.size:
                # Each mask-angle bin collects the weighted counts of the time bins in it.
                out += part.adjoint(np.asarray((gmap @ y.T).T))
        return out

    def block(self, t: tuple[int, int] | None = None,
              n: tuple[int, int] | None = None) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]``, gathered from the parts' blocks of pixels."""
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        full = self.gather([p.block(n=(n0, n1)) for p in self.parts])
        return np.ascontiguousarray(full[:, t0:t1, :])
