"""The response of an observation whose pointing drifts: the exposure-weighted sum.

A balloon gondola drifts and turns; over an attitude interval ``k`` (short enough for the
attitude to be constant) a sky pixel ``n`` lies at its own instrument direction, so its
profile is ``P_k[d, t, n]``.  The counts folded over the whole observation are, bin by bin,
the sum over intervals of ``exposure_k[t] P_k[d, t, n] S[n]``, so the response the folded
data see is

    P[d, t, n] = sum_k exposure_k[t] P_k[d, t, n] / sum_k exposure_k[t],

with ``exposure_k[t]`` the time interval ``k`` spends in mask-angle bin ``t`` (the same exact
per-bin exposure that folding uses).  It is a response like any other, on a celestial grid:
with ``operator="matrix"`` the sum is computed and held (a
:class:`~rotmod.response.MaterialisedResponse`); with ``operator="radon"`` it stays a sum of
per-interval :class:`~rotmod.response.RadonResponse` operators (:class:`DriftResponse`),
which is what a wide field needs: no ``n_det n_time n_sky`` matrix, and products that cost
one Radon product per interval.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rotmod.errors import ParameterError
from rotmod.events.folding import exposure_per_bin
from rotmod.limits import check_memory
from rotmod.response.materialised import MaterialisedResponse, build_response
from rotmod.response.operator import ResponseOperator
from rotmod.response.radon import RadonResponse
from rotmod.response.spec import ResponseSpec, as_spec

__all__ = ["DriftResponse", "drift_response"]


class DriftResponse(ResponseOperator):
    """``P = sum_k W_k P_k``: operators ``P_k`` weighted bin by bin (``W_k = diag_t(w_k)``).

    Parameters
    ----------
    parts : list of ResponseOperator
        One per attitude interval, all of the same shape.
    weights : ndarray, shape (n_parts, n_time)
        ``exposure_k[t] / sum_k exposure_k[t]`` (0 where a bin has no exposure).
    spec : ResponseSpec, optional
        What the sum is the response of (the image grid); default: the first part's
        metadata, without a grid.

    Notes
    -----
    ``forward(S) = sum_k w_k[t] P_k S`` and ``adjoint(Y) = sum_k P_k^T (w_k[t] Y)``.
    """

    def __init__(self, parts: list[ResponseOperator], weights: np.ndarray,
                 spec: ResponseSpec | None = None) -> None:
        if not parts:
            raise ParameterError("parts must hold at least one response operator")
        first = parts[0]
        self.parts = parts
        self.weights = np.asarray(weights, dtype=np.float64)
        if spec is not None:
            self._adopt(spec)
            return
        self.n_det, self.n_time, self.n_sky = first.n_det, first.n_time, first.n_sky
        self.dtype = first.dtype
        self.instrument, self.time_bins = first.instrument, first.time_bins
        self.model, self.energy = first.model, first.energy
        self.grid = None

    def components(self) -> list[tuple[np.ndarray | None, ResponseSpec]]:
        """One ``(weights, spec)`` per attitude interval (see the base class)."""
        return [(w * pw if pw is not None else w, ps)
                for w, part in zip(self.weights, self.parts, strict=True)
                for pw, ps in part.components()]

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n_det, self.n_time))
        for w, part in zip(self.weights, self.parts, strict=True):
            out += w[None, :] * part.forward(sky)
        return out.astype(self.dtype, copy=False)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n_sky)
        y = np.asarray(counts, dtype=np.float64)
        for w, part in zip(self.weights, self.parts, strict=True):
            out += part.adjoint(w[None, :] * y)
        return out.astype(self.dtype, copy=False)


def drift_response(
    instrument: Any,
    grid: Any = None,
    time_bins: Any = None,
    intervals: list[tuple[float, float, Any]] | None = None,
    model: Any = None,
    energy: Any = None,
    *,
    start_phase: Any = 0.0,
    dtype: Any = None,
    operator: str = "matrix",
    tolerance: float = 1e-4,
) -> ResponseOperator:
    """Exposure-weighted response over attitude ``intervals`` (see the module notes).

    Parameters
    ----------
    instrument : Instrument or ResponseSpec
        The instrument, or a whole :class:`~rotmod.response.ResponseSpec` (on the image
        grid; then give ``intervals`` by name and no other field).
    grid : CelestialGrid
        The image grid; its attitude is replaced by each interval's.
    time_bins : int or TimeBinning
    intervals : list of (t_lo, t_hi, Attitude)
        E.g. :meth:`rotmod.sky.AttitudeTable.intervals`; times in s.
    model, energy, dtype
        As for :func:`~rotmod.response.build_response` (``dtype`` default float64).
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if plain), as in the event list.
    operator : {"matrix", "radon"}
        Hold the summed matrix, or keep a :class:`DriftResponse` of per-interval
        :class:`~rotmod.response.RadonResponse` operators (the exact model within
        ``tolerance``; ``model`` must be ``"exact"``).
    tolerance : float
        With ``operator="radon"``: the largest error of any profile value.

    Returns
    -------
    MaterialisedResponse or DriftResponse
    """
    spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype,
                   default_dtype=np.float64)
    tb, grid, inst = spec.time_bins, spec.grid, spec.instrument
    if operator not in ("matrix", "radon"):
        raise ParameterError(f"operator must be 'matrix' or 'radon', got {operator!r}")
    if not intervals:
        raise ParameterError("intervals must hold at least one attitude interval")
    weights = np.array([exposure_per_bin([[lo, hi]], tb.n_bins, inst.rotation_period,
                                         start_phase) for lo, hi, _ in intervals])
    total = weights.sum(axis=0)

    def at(att: Any, **changes: Any) -> ResponseSpec:
        """The spec of one interval: the grid at its attitude."""
        return spec.replace(grid=dataclasses.replace(grid, attitude=att), **changes)

    if operator == "radon":
        if spec.model.name != "exact":
            raise ParameterError(f"model: operator 'radon' factorises the exact model, got "
                                 f"{spec.model.name!r}")
        with np.errstate(invalid="ignore", divide="ignore"):
            norm = np.where(total > 0, weights / total, 0.0)
        parts: list[ResponseOperator] = [RadonResponse(at(att), tolerance=tolerance)
                                         for _, _, att in intervals]
        return DriftResponse(parts, norm, spec)
    n_det = len(inst.detectors)
    check_memory(2 * 8.0 * n_det * tb.n_bins * grid.size,
                 f"a drift response of {n_det} x {tb.n_bins} x {grid.size}",
                 hint="use fewer pixels or time bins")
    acc = np.zeros((n_det, tb.n_bins, grid.size))
    for w, (_, _, att) in zip(weights, intervals, strict=True):
        part = build_response(at(att, dtype=np.float64))
        acc += w[None, :, None] * part.matrix
    with np.errstate(invalid="ignore", divide="ignore"):
        matrix = np.where(total[None, :, None] > 0, acc / total[None, :, None], 0.0)
        norm = np.where(total > 0, weights / total, 0.0)
    # The matrix remembers its intervals: a source between pixels is evaluated at each
    # interval's attitude, as the matrix was (columns_at).
    return MaterialisedResponse(matrix.astype(spec.dtype), spec=spec,
                                sum_of=[(w, at(att)) for w, (_, _, att)
                                        in zip(norm, intervals, strict=True)])
