"""The response restricted to some sky pixels, held as their columns.

A solve whose image is known to vanish outside a set of pixels (coarse-to-fine
reconstruction, :mod:`rotmod.reconstruction.multires`) needs only those columns of ``P``:
:class:`PixelSubset` evaluates them once with the parent's own :meth:`columns` (the same
values its products use) and keeps only the bins that are distinct under the half turn, so
a product is one BLAS matrix-vector product of ``n_det n_distinct`` rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.errors import ParameterError
from rotmod.limits import check_memory
from rotmod.response._plan import fold_half_turn, repeat_half_turn
from rotmod.response.operator import ResponseOperator

__all__ = ["PixelSubset"]

#: Columns evaluated per call of the parent's ``columns`` (bounds the transient copy of the
#: repeated half turn).
_CHUNK = 256


class PixelSubset(ResponseOperator):
    """``P[:, :, pixels]`` of a parent response, as an operator on those pixels.

    Parameters
    ----------
    parent : ResponseOperator
        The response restricted.
    pixels : sequence of int
        Sky pixel indices of ``parent`` (flattened grid order), distinct.
    reuse : PixelSubset, optional
        A subset of the same parent whose columns are reused for the pixels it holds (a
        support that grows computes only its new columns).

    Raises
    ------
    ParameterError
        Indices that are not distinct integers in ``[0, parent.n_sky)``.
    MemoryBudgetError
        If the columns do not fit the memory budget.

    Notes
    -----
    ``forward(S) = P[:, :, pixels] S`` and ``adjoint(Y) = P[:, :, pixels]^T Y`` exactly (the
    parent's values, in its dtype), so the dot test holds to rounding; the half turn is
    folded as in the parent (``n_distinct``).
    """

    def __init__(self, parent: ResponseOperator, pixels: Any,
                 reuse: PixelSubset | None = None) -> None:
        idx = parent._check_pixels(pixels)
        if np.unique(idx).size != idx.size:
            raise ParameterError("pixels must be distinct indices")
        self.parent = parent
        self.pixels = idx
        self.n_det, self.n_time, self.n_sky = parent.n_det, parent.n_time, int(idx.size)
        self.dtype = np.dtype(parent.dtype)
        self.instrument, self.time_bins = parent.instrument, parent.time_bins
        self.model, self.energy, self.distance = parent.model, parent.energy, parent.distance
        h = parent.n_distinct
        self._h = h
        check_memory(float(self.n_det) * h * idx.size * self.dtype.itemsize,
                     f"the columns of {idx.size} pixels ({self.n_det} x {h} each)",
                     hint="refine fewer pixels (a larger coarse factor or a higher ts_cut)")
        cols = np.empty((self.n_det, h, idx.size), dtype=self.dtype)
        todo = np.arange(idx.size)
        if reuse is not None and reuse.parent is parent:
            where = {int(p): k for k, p in enumerate(reuse.pixels)}
            old = np.array([where.get(int(p), -1) for p in idx], dtype=np.int64)
            have = old >= 0
            cols[:, :, have] = reuse._cols[:, :, old[have]]
            todo = np.flatnonzero(~have)
        for k0 in range(0, todo.size, _CHUNK):
            part = todo[k0:k0 + _CHUNK]
            cols[:, :, part] = parent.columns(idx[part])[:, :h]
        self._cols = cols

    @property
    def n_distinct(self) -> int:
        """As the parent's (the half turn's bins repeat)."""
        return self._h

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        x = np.asarray(sky, dtype=self.dtype)
        out = np.empty((self.n_det, self.n_time), dtype=self.dtype)
        out[:, : self._h] = (self._cols.reshape(-1, self.n_sky) @ x).reshape(self.n_det, -1)
        return repeat_half_turn(out, self._h)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        y = fold_half_turn(np.asarray(counts, dtype=self.dtype), self._h)
        return np.ascontiguousarray(y).ravel() @ self._cols.reshape(-1, self.n_sky)

    def columns(self, pixels: Any) -> np.ndarray:
        """``P[:, :, self.pixels[pixels]]`` (``pixels`` index this subset)."""
        idx = self._check_pixels(pixels)
        out = np.empty((self.n_det, self.n_time, idx.size), dtype=self.dtype)
        out[:, : self._h] = self._cols[:, :, idx]
        return repeat_half_turn(out, self._h)
