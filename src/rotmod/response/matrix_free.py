"""The response computed block by block on the fly, never stored."""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.profiles.base import ProfileModel
from rotmod.response._plan import ResponsePlan, make_plan
from rotmod.response.operator import BlockwiseResponse, MaterialisedResponse
from rotmod.response.parallel import Block, block_grid, block_ranges
from rotmod.response.spec import as_spec

__all__ = ["MatrixFreeResponse"]


class MatrixFreeResponse(BlockwiseResponse):
    """The response of a profile model, evaluated in blocks on every product.

    Memory is bounded by one block (default ~32 MB) plus the vectors, so the sky grid, the
    number of time bins and of detectors can be far larger than a stored matrix allows.
    The per-pixel projected geometry is computed once in the constructor.

    Parameters
    ----------
    instrument, grid, time_bins, model, energy, dtype, detectors, distance
        As :func:`~rotmod.response.build_response` (``instrument`` may be a whole
        :class:`~rotmod.response.ResponseSpec`); ``dtype`` (default float64) is the type
        of the blocks and of the products; ``distance`` (cm) makes a lab field.
    block_size : (int, int), optional
        ``(time bins, sky pixels)`` per block (all detectors are in every block); default
        as many whole-sky time bins as fit ~32 MB.  Also the blocks of a distributed
        :meth:`materialise`.
    scheduler, client : optional
        Evaluate the blocks on a Dask cluster (address or ``distributed.Client``); default
        local threads.
    progress : bool
        tqdm progress bar over the blocks of each product.

    Raises
    ------
    ParameterError, MaterialError, ModelValidityError

    Notes
    -----
    Products as :class:`~rotmod.response.operator.BlockwiseResponse`; the blocks cover the
    distinct bins only (``ResponsePlan.n_distinct``), the others repeat them.
    """

    def __init__(
        self,
        instrument: Any,
        grid: Any = None,
        time_bins: Any = None,
        model: str | ProfileModel | None = None,
        energy: Any = None,
        *,
        dtype: Any = None,
        detectors: Any = None,
        block_size: tuple[int, int] | None = None,
        scheduler: str | None = None,
        client: Any = None,
        progress: bool = False,
        distance: Any = None,
    ) -> None:
        spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype,
                       detectors=detectors, distance=distance, default_dtype=np.float64)
        self.plan: ResponsePlan = make_plan(spec)
        self._adopt(spec)
        self.block_size = block_size
        self.blocks = block_grid(
            (self.n_det, self.n_distinct, self.n_sky), block_size, itemsize=self.dtype.itemsize
        )
        self.scheduler = scheduler
        self.client = client
        self.progress = progress

    @property
    def n_distinct(self) -> int:
        """Leading time bins that determine all (``ResponsePlan.n_distinct``)."""
        return self.plan.n_distinct

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (``None`` = whole axis), evaluated now."""
        t, n = block_ranges(t, n, self.n_time, self.n_sky)
        return self.plan.block(t=t, n=n)

    def materialise(self) -> MaterialisedResponse:
        """The whole matrix ``P`` in memory, with this operator's :attr:`spec`.

        Locally (no ``scheduler``, ``client`` or ``progress``) :meth:`ResponsePlan.fill`
        writes it straight into the result; otherwise the blocks of
        :meth:`ResponseOperator.materialise` (``block_size``, default ~32 MB of float64)
        run on the cluster (or locally, with a progress bar).  Either way every value is
        the same kernel's: :func:`~rotmod.response.build_response` is this method.

        Raises
        ------
        rotmod.limits.TimeBudgetError
            Every value would take longer than the time budget
            (:meth:`ResponsePlan.check_time`, before any is computed; computed here, not on
            a Dask cluster, whose rate a local sample does not give).
        """
        if self.scheduler is None and self.client is None:  # a cluster's rate is not ours
            self.plan.check_time()
        if self.scheduler is None and self.client is None and not self.progress:
            out = np.empty((self.n_det, self.n_time, self.n_sky), dtype=self.dtype)
            return MaterialisedResponse(self.plan.fill(out), spec=self.spec)
        return super().materialise()

    def _materialise_blocks(self) -> list[Block]:
        # ``block_size`` (or ~32 MB counted in float64, whatever the dtype) over the
        # distinct bins.
        return block_grid((self.n_det, self.n_distinct, self.n_sky), self.block_size)

    @property
    def _source(self) -> ResponsePlan:
        # The plan, not the operator: it is what a Dask worker receives (picklable, without
        # the client).
        return self.plan

    def _run_options(self) -> dict[str, Any]:
        return {"scheduler": self.scheduler, "client": self.client, "progress": self.progress}
