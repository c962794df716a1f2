"""Evaluation of blocks of the response ``P[d, t, n]`` with the per-source geometry reused.

A :class:`ResponsePlan` is a :class:`~rotmod.response.ResponseSpec` (model, instrument,
grid, time binning, energy, distance, dtype) plus the projected geometry of every sky pixel:
everything a block needs, picklable, so Dask workers can evaluate blocks from it.  The
half-turn symmetry (:attr:`ResponsePlan.n_distinct`) is applied by :func:`repeat_half_turn`
and :func:`fold_half_turn`, the one copy and its adjoint.  The profile kernels fill
``out[d, t, n]`` of whatever shape they are given, so a block over detectors ``d0:d1``, bins
``t0:t1`` and pixels ``n0:n1`` is one kernel call on the sliced geometry (``n_sub`` calls in
``"average"`` mode).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rotmod.binning import TimeBinning
from rotmod.geometry import Instrument
from rotmod.limits import check_memory, check_time, measure_rate
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, project
from rotmod.response.parallel import block_grid, block_ranges, iter_blocks
from rotmod.response.spec import ResponseSpec

__all__ = ["ResponsePlan", "check_plan_memory", "distinct_bins", "fold_half_turn", "make_plan",
           "repeat_half_turn"]


def distinct_bins(n_bins: int, symmetric: bool = True) -> int:
    """Number of leading time bins that determine all ``n_bins``: ``n_bins / 2`` when a half
    turn maps the instrument and the model onto themselves and ``n_bins`` is even (bin
    ``t + N/2`` is then bin ``t`` turned by exactly half a turn), else ``n_bins``."""
    return n_bins // 2 if n_bins % 2 == 0 and symmetric else n_bins


def repeat_half_turn(out: np.ndarray, n_distinct: int) -> np.ndarray:
    """Fill the bins (axis 1) after the first ``n_distinct`` with copies of the first ones,
    ``out[:, t + N/2] = out[:, t]`` (a response ``P[d, t, n]`` or forward rates ``[d, t]``);
    in place, returned for convenience.  Nothing to do when every bin is distinct."""
    nt = out.shape[1]
    if n_distinct < nt:
        out[:, n_distinct:] = out[:, : nt - n_distinct]
    return out


def fold_half_turn(counts: np.ndarray, n_distinct: int) -> np.ndarray:
    """The adjoint of :func:`repeat_half_turn` on data ``(n_det, n_time)``: bins ``t`` and
    ``t + N/2`` share a response, so ``P^T Y = P_h^T (Y[:, :h] + Y[:, h:])``."""
    if n_distinct < counts.shape[1]:
        return counts[:, :n_distinct] + counts[:, n_distinct:]
    return counts


@dataclass(frozen=True)
class ResponsePlan:
    """A :class:`~rotmod.response.ResponseSpec` with every sky pixel projected once;
    :meth:`block` evaluates any sub-block of ``P``.

    Build with :func:`make_plan`.
    """

    spec: ResponseSpec
    geom: ProjectedGeometry

    @property
    def model(self) -> ProfileModel:
        return self.spec.model

    @property
    def instrument(self) -> Instrument:
        return self.spec.instrument

    @property
    def time_bins(self) -> TimeBinning:
        return self.spec.time_bins

    @property
    def dtype(self) -> np.dtype:
        return self.spec.dtype

    @property
    def distance(self) -> float | None:
        return self.spec.distance

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
        symmetric = self.model.half_turn_symmetric and self.instrument.mask.half_turn_symmetric
        return distinct_bins(self.time_bins.n_bins, symmetric)

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
        (t0, t1), (n0, n1) = block_ranges(t, n, nt, nn)
        geom = self._sub_geometry(d0, d1, n0, n1)
        shape = (d1 - d0, t1 - t0, n1 - n0)
        if out is None:
            out = np.empty(shape, dtype=self.dtype)
        xi = self.time_bins.sub_angles(t0, t1)
        if xi.shape[0] == 1:
            self.model.evaluate_into(self.instrument, geom, np.cos(xi[0]), np.sin(xi[0]), out)
            return out
        # Bin average: accumulate the sub-samples in float64, then scale and cast once.
        acc = np.zeros(shape)
        tmp = np.empty(shape)
        for row in xi:
            self.model.evaluate_into(self.instrument, geom, np.cos(row), np.sin(row), tmp)
            acc += tmp
        np.multiply(acc, 1.0 / xi.shape[0], out=out, casting="unsafe")
        return out

    def check_time(self, overhead: float = 1.0) -> float:
        """Refuse computing every value of this plan (a stored or materialised response)
        when it would take longer than the time budget; return the estimate (s).

        The rate is measured on up to 8000 pixels of one detector and bin (every
        sub-sample; :func:`rotmod.limits.measure_rate`, ~10 ms): a value's cost depends on
        the model, the instrument and where the pixels are.  ``overhead`` multiplies the
        computing time (a store's writing, checksums and read-back).

        Raises
        ------
        rotmod.limits.TimeBudgetError
            With the estimate, naming the response's sizes.
        """
        nd, nt, nn = self.shape
        k = min(nn, 8000)
        n_sub = self.time_bins.n_sub
        per_s = measure_rate(lambda: self.block(d=(0, 1), t=(0, 1), n=(0, k)), k * n_sub)
        return check_time(
            float(nd) * self.n_distinct * nn * n_sub, per_s / overhead,
            f"a response of {nd} detector(s) x {nt} time bins x {nn} pixels "
            f"({self.model.name} model, {n_sub} sub-sample(s) per bin)", unit="profile values",
            hint="use larger pixels or a smaller field, fewer bins or detectors, or the Radon "
            "operator (the exact model through one table)")

    def fill(self, out: np.ndarray, *, max_block_bytes: int = 64 << 20) -> np.ndarray:
        """Fill ``out = P`` locally (numba threads inside each kernel call): the one local
        way to compute the whole response (``MatrixFreeResponse.materialise``, and so
        ``build_response``).

        Parameters
        ----------
        out : ndarray
            C-contiguous, of :attr:`shape` and :attr:`dtype`; returned.
        max_block_bytes : int
            Bound of the float64 temporaries of average mode.

        Notes
        -----
        Centre mode writes straight into ``out``, one detector at a time (``out[d]`` is
        C-contiguous), so the only memory is the matrix itself; average mode keeps two
        float64 temporaries per block of time bins.  The distinct bins
        (:attr:`n_distinct`) are computed and :func:`repeat_half_turn` copies them.
        """
        nd, nt, nn = self.shape
        half = self.n_distinct
        if half == nt and self.time_bins.n_sub == 1:
            return self.block(out=out)
        if self.time_bins.n_sub == 1:
            # Not a walk over (t, n) blocks, which would need a temporary per block.
            for d in range(nd):
                self.block(d=(d, d + 1), t=(0, half), out=out[d : d + 1, :half])
        else:
            step = max(1, max_block_bytes // max(16 * nd * nn, 1))
            for _, ((t0, t1), _), p in iter_blocks(self, block_grid((nd, half, nn), (step, nn))):
                out[:, t0:t1, :] = p
        return repeat_half_turn(out, half)


def check_plan_memory(spec: ResponseSpec) -> None:
    """Refuse a plan of ``spec`` larger than the memory budget (before any work: the writer
    asks this first, then whether its store fits on the disk, then makes the plan).

    Raises
    ------
    MemoryBudgetError
    """
    inst, grid = spec.instrument, spec.grid
    # Pixel directions and the projected geometry: ~(2 n_det + 6) float64 per pixel.
    check_memory(8.0 * grid.size * (2 * len(inst.detectors) + 6),
                 f"projecting {grid.size} sky pixels for {len(inst.detectors)} detectors",
                 hint="use larger pixels or a smaller field")


def make_plan(spec: ResponseSpec) -> ResponsePlan:
    """Project every sky pixel of ``spec`` once and check the model's domain.

    Raises
    ------
    MaterialError, ModelValidityError, MemoryBudgetError
    """
    check_plan_memory(spec)
    inst, grid = spec.instrument, spec.grid
    theta, phi = grid.directions()
    geom = project(inst, theta, phi, spec.energy, spec.distance)
    spec.model.validate(inst, geom)
    return ResponsePlan(spec, geom)
