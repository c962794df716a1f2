"""The response as a stored matrix ``P[d, t, n]``."""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.binning import TimeBinning
from rotmod.errors import ParameterError
from rotmod.geometry import Instrument
from rotmod.limits import check_memory
from rotmod.profiles.base import ProfileModel, get_model
from rotmod.response._plan import ResponsePlan, make_plan, repeat_half_turn
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_grid, compute_blocks, iter_blocks
from rotmod.response.spec import ResponseSpec, as_spec

__all__ = ["MaterialisedResponse", "build_response"]


class MaterialisedResponse(ResponseOperator):
    """A response held in memory as ``P[d, t, n]``.

    Parameters
    ----------
    matrix : ndarray, shape (n_det, n_time, n_sky)
        The response, float32 or float64 (other types are refused; the array is used as
        is, without a copy, when it is C-contiguous).
    spec : ResponseSpec, optional
        What the matrix was computed for (its shape and dtype must be the spec's).
    instrument, grid, time_bins, model, energy, distance : optional
        Without a spec, what is known of it (metadata only; see
        :meth:`ResponseOperator.metadata`).  ``model`` may be a registry name or instance;
        ``distance`` (cm) of a lab field's sources.

    Raises
    ------
    ParameterError
        If ``matrix`` is not a 3-D float32/float64 array, or does not fit the metadata.

    Notes
    -----
    With ``A = P.reshape(n_det * n_time, n_sky)``, ``forward(S) = (A S).reshape(n_det,
    n_time)`` and ``adjoint(Y) = Y.ravel() A``: one BLAS matrix-vector product each, in the
    matrix's dtype (inputs are cast to it).
    """

    def __init__(
        self,
        matrix: np.ndarray,
        *,
        spec: ResponseSpec | None = None,
        instrument: Any = None,
        grid: Any = None,
        time_bins: Any = None,
        model: str | ProfileModel | None = None,
        energy: float | None = None,
        distance: float | None = None,
    ) -> None:
        m = np.asarray(matrix)
        if m.ndim != 3:
            raise ParameterError(f"matrix must have shape (n_det, n_time, n_sky), got {m.shape}")
        if m.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ParameterError(f"matrix must be float32 or float64, got {m.dtype}")
        self.matrix = np.ascontiguousarray(m)
        if spec is not None:
            loose = (instrument, grid, time_bins, model, energy, distance)
            if any(v is not None for v in loose):
                raise ParameterError("pass either spec or instrument, grid, time_bins, model, "
                                     "energy, distance, not both")
            if spec.shape != m.shape or spec.dtype != m.dtype:
                raise ParameterError(f"matrix must have the spec's shape {spec.shape} and dtype "
                                     f"{spec.dtype}, got {m.shape} {m.dtype}")
            self._adopt(spec)
            return
        self.n_det, self.n_time, self.n_sky = (int(v) for v in m.shape)
        self.dtype = m.dtype
        _set_metadata(self, instrument, grid, time_bins, model, energy)
        self.distance = None if distance is None else float(distance)

    @property
    def _flat(self) -> np.ndarray:
        return self.matrix.reshape(self.n_det * self.n_time, self.n_sky)

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        x = np.asarray(sky, dtype=self.dtype)
        return (self._flat @ x).reshape(self.n_det, self.n_time)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        y = np.asarray(counts, dtype=self.dtype).ravel()
        return y @ self._flat

    def forward_detectors(self, sky: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``(P S)[detectors]``: only those detectors' rows (one product per detector)."""
        x = np.asarray(self._check_sky(sky), dtype=self.dtype)
        return np.stack([self.matrix[d] @ x for d in np.asarray(detectors).ravel()])

    def adjoint_detectors(self, counts: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``P_D^T Y`` from only those detectors' rows."""
        det = np.asarray(detectors).ravel()
        y = np.asarray(counts, dtype=self.dtype).reshape(det.size, self.n_time)
        out = np.zeros(self.n_sky, dtype=self.dtype)
        for k, d in enumerate(det):
            out += y[k] @ self.matrix[d]
        return out

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (a view of :attr:`matrix`; ``None`` = whole axis)."""
        t0, t1 = (0, self.n_time) if t is None else t
        n0, n1 = (0, self.n_sky) if n is None else n
        return self.matrix[:, t0:t1, n0:n1]

    def materialise(self) -> MaterialisedResponse:
        """This response (it is in memory already)."""
        return self


def _set_metadata(
    op: ResponseOperator,
    instrument: Any,
    grid: Any,
    time_bins: Any,
    model: Any,
    energy: Any,
) -> None:
    """Check the shapes implied by the metadata against the operator and attach it."""
    if instrument is not None:
        if not isinstance(instrument, Instrument):
            raise ParameterError(
                f"instrument must be an Instrument, got {type(instrument).__name__}"
            )
        if len(instrument.detectors) != op.n_det:
            raise ParameterError(
                f"instrument has {len(instrument.detectors)} detectors but the response has "
                f"n_det = {op.n_det}"
            )
    if grid is not None and int(grid.size) != op.n_sky:
        raise ParameterError(f"grid has {grid.size} pixels but the response has n_sky = {op.n_sky}")
    if time_bins is not None:
        time_bins = TimeBinning.coerce(time_bins)
        if time_bins.n_bins != op.n_time:
            raise ParameterError(
                f"time_bins has {time_bins.n_bins} bins but the response has "
                f"n_time = {op.n_time}"
            )
    op.instrument = instrument
    op.grid = grid
    op.time_bins = time_bins
    op.model = None if model is None else get_model(model)
    op.energy = None if energy is None else float(energy)


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
