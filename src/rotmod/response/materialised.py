"""The response computed and held in memory: :func:`build_response`.

The in-memory operator itself, :class:`MaterialisedResponse`, lives with the other
operators in :mod:`rotmod.response.operator` (:meth:`ResponseOperator.materialise` returns
it) and is re-exported here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.limits import check_memory
from rotmod.profiles.base import ProfileModel
from rotmod.response._plan import ResponsePlan, make_plan, repeat_half_turn
from rotmod.response.operator import MaterialisedResponse
from rotmod.response.parallel import block_grid, compute_blocks, iter_blocks
from rotmod.response.spec import as_spec

__all__ = ["MaterialisedResponse", "build_response"]


def _fill(plan: ResponsePlan, out: np.ndarray, *, max_block_bytes: int = 64 << 20) -> None:
    """Fill ``out = P`` from ``plan`` locally (numba threads inside each kernel call)."""
    nd, nt, nn = plan.shape
    half = plan.n_distinct
    if half == nt and plan.time_bins.n_sub == 1:
        plan.block(out=out)
        return
    if plan.time_bins.n_sub == 1:
        # One detector at a time straight into ``out`` (out[d] is C-contiguous), so the
        # only memory is the matrix itself: not a walk over (t, n) blocks, which would
        # need a temporary per block.
        for d in range(nd):
            plan.block(d=(d, d + 1), t=(0, half), out=out[d : d + 1, :half])
    else:
        # Average mode keeps two float64 temporaries per block: bound them by time blocks.
        step = max(1, max_block_bytes // max(16 * nd * nn, 1))
        for _, ((t0, t1), _), p in iter_blocks(plan, block_grid((nd, half, nn), (step, nn))):
            out[:, t0:t1, :] = p
    repeat_half_turn(out, half)


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
        (default: chosen for ~32 MB blocks).
    distance : float or Quantity, optional
        Sources at this distance (cm) from the origin in the pixels' directions (a lab
        field; the ``exact`` model only); default at infinity.

    Returns
    -------
    MaterialisedResponse

    Raises
    ------
    ParameterError, MaterialError, ModelValidityError
    """
    spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype, detectors=detectors,
                   distance=distance, default_dtype=np.float32)
    plan = make_plan(spec)
    d, t, n = plan.shape
    check_memory(float(d) * t * n * plan.dtype.itemsize,
                 f"a response matrix of {d} detectors x {t} time bins x {n} pixels "
                 f"({plan.dtype.name})",
                 hint="use MatrixFreeResponse or write_response (blocks, on disk) instead")
    out = np.empty(plan.shape, dtype=plan.dtype)
    if scheduler is None and client is None and not progress:
        _fill(plan, out)
    else:
        compute_blocks(
            plan, out, scheduler=scheduler, client=client, progress=progress,
            block_size=block_size,
        )
    return MaterialisedResponse(out, spec=spec)
