"""The response computed block by block on the fly, never stored."""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.profiles.base import DEFAULT_MODEL, ProfileModel
from rotmod.response._plan import ResponsePlan, make_plan
from rotmod.response.materialised import MaterialisedResponse
from rotmod.response.operator import ResponseOperator

__all__ = ["MatrixFreeResponse"]

Block = tuple[tuple[int, int], tuple[int, int]]


def _products(
    blk: Block, plan: ResponsePlan, sky: np.ndarray | None, counts: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Partial ``P_b S_b`` (n_det, bt) and ``P_b^T Y_b`` (bn,) of one block."""
    (t0, t1), (n0, n1) = blk
    p = plan.block(t=(t0, t1), n=(n0, n1))
    flat = p.reshape(-1, n1 - n0)
    fwd = None if sky is None else (flat @ sky[n0:n1]).reshape(p.shape[0], t1 - t0)
    adj = None if counts is None else counts[:, t0:t1].ravel() @ flat
    return fwd, adj


class MatrixFreeResponse(ResponseOperator):
    """The response of a profile model, evaluated in blocks on every product.

    Memory is bounded by one block (default ~32 MB) plus the vectors, so the sky grid, the
    number of time bins and of detectors can be far larger than a stored matrix allows.
    The per-pixel projected geometry is computed once in the constructor.

    Parameters
    ----------
    instrument, grid, time_bins, model, energy, dtype, detectors
        As :func:`~rotmod.response.build_response`; ``dtype`` (default float64) is the
        type of the blocks and of the products.
    block_size : (int, int), optional
        ``(time bins, sky pixels)`` per block (all detectors are in every block); default
        as many whole-sky time bins as fit ~32 MB.
    scheduler, client : optional
        Evaluate the blocks on a Dask cluster (address or ``distributed.Client``); default
        local threads.
    progress : bool
        tqdm progress bar over the blocks of each product.
    distance : float or Quantity, optional
        Sources at this distance (cm): a lab field (see
        :func:`~rotmod.response.build_response`).

    Raises
    ------
    ParameterError, MaterialError, ModelValidityError

    Notes
    -----
    With blocks ``b = (t-range, n-range)``,
    ``forward(S)[:, t_b] += P_b S[n_b]`` and ``adjoint(Y)[n_b] += P_b^T Y[:, t_b]``; the
    partial sums are added in block order, so the result does not depend on where the
    blocks ran.  :meth:`forward_adjoint` computes ``P S`` and ``P^T Y`` in one sweep (one
    evaluation of every block) for algorithms that need both for independent vectors.
    """

    def __init__(
        self,
        instrument: Any,
        grid: Any,
        time_bins: Any,
        model: str | ProfileModel = DEFAULT_MODEL,
        energy: Any = None,
        *,
        dtype: Any = np.float64,
        detectors: Any = None,
        block_size: tuple[int, int] | None = None,
        scheduler: str | None = None,
        client: Any = None,
        progress: bool = False,
        distance: Any = None,
    ) -> None:
        from rotmod.response.parallel import block_grid

        self.plan = make_plan(
            instrument, grid, time_bins, model, energy, dtype=dtype, detectors=detectors,
            distance=distance,
        )
        self.distance = self.plan.distance
        self.n_det, self.n_time, self.n_sky = self.plan.shape
        self.dtype = self.plan.dtype
        self.instrument = self.plan.instrument
        self.grid = grid
        self.time_bins = self.plan.time_bins
        self.model = self.plan.model
        self.energy = self.plan.energy
        # Blocks cover the distinct bins only; the others repeat them (plan.n_distinct).
        self.n_distinct = self.plan.n_distinct
        self.blocks = block_grid(
            (self.n_det, self.n_distinct, self.n_sky), block_size, itemsize=self.dtype.itemsize
        )
        self.scheduler = scheduler
        self.client = client
        self.progress = progress

    def _sweep(
        self, sky: np.ndarray | None, counts: np.ndarray | None
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        from rotmod.response.parallel import map_blocks

        h = self.n_distinct
        x = None if sky is None else np.ascontiguousarray(sky, dtype=self.dtype)
        y = None if counts is None else np.ascontiguousarray(counts, dtype=self.dtype)
        if y is not None and h < self.n_time:
            # Bins t and t + h share a response: P^T Y = P_h^T (Y[:, :h] + Y[:, h:]).
            y = y[:, :h] + y[:, h:]
        parts: list[Any] = [None] * len(self.blocks)
        for i, res in map_blocks(
            _products, self.blocks, self.plan, x, y,
            scheduler=self.scheduler, client=self.client, progress=self.progress,
        ):
            parts[i] = res
        fwd = None if x is None else np.zeros((self.n_det, h), dtype=self.dtype)
        adj = None if y is None else np.zeros(self.n_sky, dtype=self.dtype)
        for ((t0, t1), (n0, n1)), (f, a) in zip(self.blocks, parts, strict=True):
            if fwd is not None:
                fwd[:, t0:t1] += f
            if adj is not None:
                adj[n0:n1] += a
        if fwd is not None and h < self.n_time:
            fwd = np.concatenate([fwd, fwd], axis=1)
        return fwd, adj

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        return self._sweep(sky, None)[0]

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        return self._sweep(None, counts)[1]

    def forward_adjoint(self, sky: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(P S, P^T Y)`` in one sweep over the blocks (each block evaluated once).

        Parameters
        ----------
        sky : ndarray, shape (n_sky,)
        counts : ndarray, shape (n_det, n_time)

        Returns
        -------
        (ndarray, ndarray)
            ``forward(sky)`` and ``adjoint(counts)``.
        """
        x = self._check_sky(sky)
        y = self._check_counts(counts)
        fwd, adj = self._sweep(x, y)
        assert fwd is not None and adj is not None
        return fwd, adj

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (``None`` = whole axis)."""
        return self.plan.block(t=t, n=n)

    def materialise(self) -> MaterialisedResponse:
        """Compute the whole matrix (with this operator's scheduler) and store it in memory."""
        from rotmod.response.parallel import compute_blocks

        out = np.empty(self.plan.shape, dtype=self.dtype)
        compute_blocks(
            self.plan, out, scheduler=self.scheduler, client=self.client,
            progress=self.progress,
        )
        return MaterialisedResponse(
            out, instrument=self.instrument, grid=self.grid, time_bins=self.time_bins,
            model=self.model, energy=self.energy, distance=self.distance,
        )
