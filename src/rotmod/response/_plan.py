"""Evaluation of blocks of the response ``P[d, t, n]`` with the per-source geometry reused.

A :class:`ResponsePlan` holds everything a block needs (model, instrument, projected
geometry of every sky pixel, time binning, dtype) and is picklable, so Dask workers can
evaluate blocks from it.  The profile kernels fill ``out[d, t, n]`` of whatever shape they
are given, so a block over detectors ``d0:d1``, bins ``t0:t1`` and pixels ``n0:n1`` is one
kernel call on the sliced geometry (``n_sub`` calls in ``"average"`` mode).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rotmod._validate import as_distance, as_float_dtype, as_scalar
from rotmod.errors import ParameterError
from rotmod.geometry import Instrument
from rotmod.limits import check_memory
from rotmod.profiles.base import (
    DEFAULT_MODEL,
    ProfileModel,
    ProjectedGeometry,
    get_model,
    project,
)
from rotmod.binning import TimeBinning

__all__ = ["ResponsePlan", "check_response_inputs", "make_plan"]


def _select_detectors(instrument: Instrument, detectors: Any) -> Instrument:
    if detectors is None:
        return instrument
    idx = np.atleast_1d(np.asarray(detectors))
    n = len(instrument.detectors)
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ParameterError(f"detectors must be a non-empty list of indices, got {detectors!r}")
    if np.any(idx < 0) or np.any(idx >= n):
        raise ParameterError(f"detectors must be indices in [0, {n - 1}], got {idx.tolist()}")
    det = instrument.detectors.with_positions(instrument.detectors.positions[idx])
    return Instrument(instrument.mask, det, instrument.rotation_period)


@dataclass(frozen=True)
class ResponsePlan:
    """Inputs of a response computation; :meth:`block` evaluates any sub-block of ``P``.

    Build with :func:`make_plan`.
    """

    model: ProfileModel
    instrument: Instrument
    grid: Any
    time_bins: TimeBinning
    energy: float | None
    dtype: np.dtype
    geom: ProjectedGeometry
    distance: float | None = None

    @property
    def p_max(self) -> float:
        """Largest value a profile can take: 1, or for thick detectors the effective-area
        ratio of a black cylinder, ``1 + 2 H s / (pi R)``, ``s`` the steepest ray's
        horizontal-to-vertical slope (+1 %: a bound, used to refuse damaged stores)."""
        det = self.instrument.detectors
        if det.is_flat:
            return 1.0
        slope = float(np.max(np.tan(self.geom.theta), initial=0.0))
        if self.distance is not None:
            reach = np.hypot(*det.positions.T).max() + det.radius
            slope = max(slope, (self.distance * float(np.max(np.sin(self.geom.theta),
                                                               initial=0.0)) + reach)
                        / (self.distance * float(np.min(np.cos(self.geom.theta)))))
        return 1.0 + 1.01 * 2.0 * det.thickness * slope / (np.pi * det.radius)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n_det, n_time, n_sky)``."""
        return (self.geom.X.shape[0], self.time_bins.n_bins, self.geom.X.shape[1])

    @property
    def n_distinct(self) -> int:
        """Number of leading time bins that determine the whole response.

        With an even number of bins ``N``, a half-turn-symmetric model and a mask that a half
        turn maps onto itself (:attr:`Mask.half_turn_symmetric`: every mask but an
        asymmetric slat pattern; an offset or tilted axis keeps the symmetry), bin
        ``t + N/2`` is bin ``t`` turned by exactly half a turn (sub-samples included), so
        ``P[:, t + N/2] = P[:, t]`` and only the first ``N/2`` bins are computed.
        """
        n = self.time_bins.n_bins
        symmetric = self.model.half_turn_symmetric and self.instrument.mask.half_turn_symmetric
        return n // 2 if n % 2 == 0 and symmetric else n

    def _sub_geometry(self, d0: int, d1: int, n0: int, n1: int) -> ProjectedGeometry:
        g = self.geom
        c = np.ascontiguousarray
        if (d0, d1, n0, n1) == (0, g.X.shape[0], 0, g.X.shape[1]):
            return g
        return replace(
            g,
            X=c(g.X[d0:d1, n0:n1]),
            Y=c(g.Y[d0:d1, n0:n1]),
            Sx=c(g.Sx[n0:n1]),
            Sy=c(g.Sy[n0:n1]),
            tau=c(g.tau[n0:n1]),
            theta=c(g.theta[n0:n1]),
            phi=c(g.phi[n0:n1]),
            positions=c(g.positions[d0:d1]),
            distance=c(g.distance[n0:n1]),
        )

    def block(
        self,
        d: tuple[int, int] | None = None,
        t: tuple[int, int] | None = None,
        n: tuple[int, int] | None = None,
        *,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """``P[d0:d1, t0:t1, n0:n1]`` in :attr:`dtype` (``None`` = the whole axis).

        ``out``, if given, must be a C-contiguous array of the block's shape and dtype.
        """
        nd, nt, nn = self.shape
        d0, d1 = (0, nd) if d is None else d
        t0, t1 = (0, nt) if t is None else t
        n0, n1 = (0, nn) if n is None else n
        geom = self._sub_geometry(d0, d1, n0, n1)
        shape = (d1 - d0, t1 - t0, n1 - n0)
        if out is None:
            out = np.empty(shape, dtype=self.dtype)
        xi = self.time_bins.sub_angles(t0, t1)
        if xi.shape[0] == 1:
            self.model.evaluate(self.instrument, geom, np.cos(xi[0]), np.sin(xi[0]), out)
            return out
        # Bin average: accumulate the sub-samples in float64, then scale and cast once.
        acc = np.zeros(shape)
        tmp = np.empty(shape)
        for row in xi:
            self.model.evaluate(self.instrument, geom, np.cos(row), np.sin(row), tmp)
            acc += tmp
        np.multiply(acc, 1.0 / xi.shape[0], out=out, casting="unsafe")
        return out


def check_response_inputs(
    instrument: Instrument,
    grid: Any,
    time_bins: Any,
    energy: Any,
    *,
    dtype: Any,
    detectors: Any,
) -> tuple[Instrument, TimeBinning, float | None, np.dtype]:
    """Validate what every response operator is computed from.

    Returns the instrument (restricted to ``detectors``), the time binning, the energy (keV
    or ``None``) and the dtype.

    Raises
    ------
    ParameterError
    """
    if not isinstance(instrument, Instrument):
        raise ParameterError(f"instrument must be an Instrument, got {type(instrument).__name__}")
    if not hasattr(grid, "directions") or not hasattr(grid, "size"):
        raise ParameterError(
            f"grid must be a sky grid (e.g. SkyGrid) with directions(), got {type(grid).__name__}"
        )
    tb = TimeBinning.coerce(time_bins)
    dt = as_float_dtype(dtype)
    inst = _select_detectors(instrument, detectors)
    e = None if energy is None else as_scalar(energy, "energy", _kev(), lo=0.0, lo_open=True)
    return inst, tb, e, dt


def make_plan(
    instrument: Instrument,
    grid: Any,
    time_bins: Any,
    model: str | ProfileModel = DEFAULT_MODEL,
    energy: Any = None,
    *,
    dtype: Any = np.float32,
    detectors: Any = None,
    distance: Any = None,
) -> ResponsePlan:
    """Validate the inputs of a response and project every sky pixel once.

    Parameters are those of :func:`rotmod.response.build_response`; ``distance`` (cm, one
    value) puts every pixel's source at that distance from the origin (a lab field),
    ``None`` at infinity.

    Raises
    ------
    ParameterError, MaterialError, ModelValidityError
    """
    inst, tb, e, dt = check_response_inputs(
        instrument, grid, time_bins, energy, dtype=dtype, detectors=detectors
    )
    mdl = get_model(model)
    # Pixel directions and the projected geometry: ~(2 n_det + 6) float64 per pixel.
    check_memory(8.0 * grid.size * (2 * len(inst.detectors) + 6),
                 f"projecting {grid.size} sky pixels for {len(inst.detectors)} detectors",
                 hint="use larger pixels or a smaller field")
    dist = None
    if distance is not None:
        d = as_distance(distance, 1)
        dist = None if np.isinf(d[0]) else float(d[0])
    theta, phi = grid.directions()
    geom = project(inst, theta, phi, e, dist)
    mdl.validate(inst, geom)
    return ResponsePlan(mdl, inst, grid, tb, e, dt, geom, dist)


def _kev() -> Any:
    from rotmod.conventions import ENERGY_UNIT

    return ENERGY_UNIT
