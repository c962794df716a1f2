"""The response computed and held in memory: :func:`build_response`.

The in-memory operator itself, :class:`MaterialisedResponse`, lives with the other
operators in :mod:`rotmod.response.operator` (:meth:`ResponseOperator.materialise` returns
it) and is re-exported here.  The computation is
:meth:`MatrixFreeResponse.materialise <rotmod.response.MatrixFreeResponse.materialise>`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.limits import check_memory
from rotmod.profiles.base import ProfileModel
from rotmod.response.matrix_free import MatrixFreeResponse
from rotmod.response.operator import MaterialisedResponse
from rotmod.response.spec import as_spec

__all__ = ["MaterialisedResponse", "build_response"]


def build_response(
    instrument: Any,
    grid: Any = None,
    time_bins: Any = None,
    model: str | ProfileModel | None = None,
    energy: Any = None,
    *,
    dtype: Any = None,
    detectors: Any = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: bool = False,
    block_size: tuple[int, int] | None = None,
    distance: Any = None,
) -> MaterialisedResponse:
    """Compute the response ``P[d, t, n]`` of ``instrument`` on ``grid`` and hold it in memory.

    Parameters
    ----------
    instrument : Instrument or ResponseSpec
        The instrument; or a whole :class:`~rotmod.response.ResponseSpec` (then ``grid``,
        ``time_bins``, ``model``, ``energy``, ``dtype``, ``detectors`` and ``distance``
        are not given).
    grid : SkyGrid
        Sky pixels; ``n`` runs over ``grid.directions()`` (C order).
    time_bins : TimeBinning or int
        Mask-angle binning (an int means that many centre-mode bins).
    model : str or ProfileModel, optional
        Registry name (``"standard"``, ``"advanced"``, ``"advanced-approx"``,
        ``"advanced-g0"``, ``"exact"``) or an instance; default
        :data:`~rotmod.profiles.DEFAULT_MODEL` (``"exact"``).
    energy : float or Quantity, optional
        Photon energy (keV); needed unless the mask's attenuation is fixed.
    dtype : {float32, float64}, optional
        Storage type of the matrix (default float32; the kernels compute in float64).
    detectors : sequence of int, optional
        Indices of the detectors to include (default all); the response's ``instrument``
        then holds only those detectors, in that order.
    scheduler, client : optional
        Compute the blocks on a Dask cluster (address string or ``distributed.Client``);
        default: local threads.
    progress : bool
        Show a tqdm progress bar (distributed or blocked computations only).
    block_size : (int, int), optional
        ``(time bins, sky pixels)`` per block for the distributed path
        (default: chosen for ~32 MB blocks); not used locally (no blocks are walked).
    distance : float or Quantity, optional
        Sources at this distance (cm) from the origin in the pixels' directions (a lab
        field; the ``exact`` model only); default at infinity.

    Returns
    -------
    MaterialisedResponse

    Raises
    ------
    ParameterError, MaterialError, ModelValidityError, MemoryBudgetError, TimeBudgetError

    Notes
    -----
    This is ``MatrixFreeResponse(spec, ...).materialise()`` after a memory check: the one
    way to compute a whole response, :meth:`ResponsePlan.fill` locally and the block walk
    of :meth:`ResponseOperator.materialise` with ``scheduler``, ``client`` or
    ``progress``; both give the same values bit for bit.
    """
    spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype, detectors=detectors,
                   distance=distance, default_dtype=np.float32)
    local = scheduler is None and client is None and not progress
    # The one way to compute a whole response: MatrixFreeResponse.materialise (ResponsePlan
    # .fill locally, the block walk of ResponseOperator.materialise otherwise).  Locally no
    # blocks are walked, so block_size is not used (nor checked) there, as always.
    op = MatrixFreeResponse(spec, block_size=None if local else block_size,
                            scheduler=scheduler, client=client, progress=progress)
    d, t, n = spec.shape
    check_memory(float(d) * t * n * spec.dtype.itemsize,
                 f"a response matrix of {d} detectors x {t} time bins x {n} pixels "
                 f"({spec.dtype.name})",
                 hint="use MatrixFreeResponse or write_response (blocks, on disk) instead")
    return op.materialise()
