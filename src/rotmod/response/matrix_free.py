"""The response computed block by block on the fly, never stored."""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.profiles.base import ProfileModel
from rotmod.response._plan import ResponsePlan, make_plan
from rotmod.response.operator import BlockwiseResponse
from rotmod.response.parallel import block_grid
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
        as many whole-sky time bins as fit ~32 MB.
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
        return self.plan.block(t=t, n=n)

    @property
    def _source(self) -> ResponsePlan:
        # The plan, not the operator: it is what a Dask worker receives (picklable, without
        # the client).
        return self.plan

    def _run_options(self) -> dict[str, Any]:
        return {"scheduler": self.scheduler, "client": self.client, "progress": self.progress}
