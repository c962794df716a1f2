"""The response as a linear operator from sky to folded count rates.

``O[d, t] = sum_n P[d, t, n] S[n]``: ``S[n]`` is the photon rate that sky pixel ``n`` would
give on one (unobstructed) detector face, ``O[d, t]`` the expected count rate of detector
``d`` in time (mask-angle) bin ``t``.  Reconstruction algorithms see only :meth:`forward`,
:meth:`adjoint` and :meth:`sensitivity`; whether ``P`` is stored is an implementation detail.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from rotmod.errors import ParameterError

if TYPE_CHECKING:
    from scipy.sparse.linalg import LinearOperator

__all__ = ["ResponseOperator"]


class ResponseOperator(ABC):
    """Abstract response ``P``: sky vectors ``(n_sky,)`` to folded rates ``(n_det, n_time)``.

    Subclasses set :attr:`n_det`, :attr:`n_time`, :attr:`n_sky` and implement
    :meth:`_forward` and :meth:`_adjoint`.

    Notes
    -----
    ``forward(S)[d, t] = sum_n P[d, t, n] S[n]`` and
    ``adjoint(Y)[n] = sum_{d, t} P[d, t, n] Y[d, t]``; every implementation passes the dot
    test ``<P x, y> = <x, P^T y>``.
    """

    n_det: int
    n_time: int
    n_sky: int
    #: Floating type of the products (float32 or float64).
    dtype: np.dtype = np.dtype(np.float64)
    #: Optional metadata: the instrument, sky grid, time binning, profile model and energy
    #: the response was computed for (``None`` when unknown, e.g. a matrix from elsewhere).
    instrument: Any = None
    grid: Any = None
    time_bins: Any = None
    model: Any = None
    energy: float | None = None
    #: Distance of the sources (cm) for a lab field; ``None``: at infinity.
    distance: float | None = None

    def __repr__(self) -> str:
        model = self.model.name if hasattr(self.model, "name") else self.model
        extra = "" if model is None else f", model {model!r}"
        if self.energy is not None:
            extra += f", {self.energy:g} keV"
        if self.distance is not None:
            extra += f", sources at {self.distance:g} cm"
        return (
            f"<{type(self).__name__} {self.n_det} detectors x {self.n_time} time bins x "
            f"{self.n_sky} sky pixels, {np.dtype(self.dtype).name}{extra}>"
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_det * n_time, n_sky)``, the shape of the flattened matrix."""
        return (self.n_det * self.n_time, self.n_sky)

    def _check_sky(self, sky: Any) -> np.ndarray:
        x = np.asarray(sky)
        if x.shape != (self.n_sky,):
            raise ParameterError(f"sky must have shape ({self.n_sky},), got {x.shape}")
        return x

    def _check_counts(self, counts: Any) -> np.ndarray:
        y = np.asarray(counts)
        if y.shape != (self.n_det, self.n_time):
            raise ParameterError(
                f"counts must have shape ({self.n_det}, {self.n_time}), got {y.shape}"
            )
        return y

    def forward(self, sky: np.ndarray) -> np.ndarray:
        """``P S``: folded rates ``(n_det, n_time)`` of sky vector ``sky`` ``(n_sky,)``."""
        return self._forward(self._check_sky(sky))

    def adjoint(self, counts: np.ndarray) -> np.ndarray:
        """``P^T Y``: sky vector ``(n_sky,)`` of folded data ``counts`` ``(n_det, n_time)``."""
        return self._adjoint(self._check_counts(counts))

    def forward_detectors(self, sky: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``(P S)[detectors]``: folded rates ``(len(detectors), n_time)`` of some detectors.

        For block-iterative solvers (ordered subsets).  The default computes the whole
        product and keeps the rows; operators that can do less work override it.
        """
        return self.forward(sky)[np.asarray(detectors)]

    def adjoint_detectors(self, counts: np.ndarray, detectors: np.ndarray) -> np.ndarray:
        """``P_D^T Y``: sky vector ``(n_sky,)`` of data ``(len(detectors), n_time)`` of some
        detectors ``D`` (the others taken as 0).  Default: the full adjoint, zero-padded."""
        det = np.asarray(detectors)
        full = np.zeros((self.n_det, self.n_time), dtype=np.result_type(counts, np.float32))
        full[det] = counts
        return self.adjoint(full)

    @cached_property
    def _sensitivity(self) -> np.ndarray:
        return self._adjoint(np.ones((self.n_det, self.n_time)))

    def sensitivity(self) -> np.ndarray:
        """``P^T 1``: summed response of every sky pixel ``(n_sky,)``."""
        return self._sensitivity

    @abstractmethod
    def _forward(self, sky: np.ndarray) -> np.ndarray: ...

    @abstractmethod
    def _adjoint(self, counts: np.ndarray) -> np.ndarray: ...

    def as_linear_operator(self) -> LinearOperator:
        """A `scipy.sparse.linalg.LinearOperator` on flattened vectors.

        The operator is declared float64 and returns float64 vectors (products of a float32
        response are computed in float32 and then widened), which is what scipy's iterative
        solvers (``lsqr``, ``cg``, ...) expect.
        """
        from scipy.sparse.linalg import LinearOperator

        return LinearOperator(
            self.shape,
            matvec=lambda x: self.forward(np.ravel(x)).ravel().astype(np.float64, copy=False),
            rmatvec=lambda y: self.adjoint(np.reshape(y, (self.n_det, self.n_time))).astype(
                np.float64, copy=False
            ),
            dtype=np.float64,
        )

    def metadata(self) -> dict[str, Any]:
        """Everything needed to reproduce this response, as plain (JSON-able) values.

        Keys: ``instrument`` (:meth:`Instrument.to_dict`), ``grid`` (:meth:`SkyGrid.to_dict`),
        ``time_bins`` (:meth:`TimeBinning.to_dict`), ``model`` (``ProfileModel.describe()``),
        ``energy`` (keV or ``None``), ``dtype``, ``shape`` ``[n_det, n_time, n_sky]`` and
        ``rotmod_version``; unknown entries are ``None``.  A response for sources at a finite
        distance adds ``distance`` (cm).
        """
        import rotmod

        def _d(obj: Any) -> Any:
            return None if obj is None else obj.to_dict()

        model = self.model
        return {
            "instrument": _d(self.instrument),
            "grid": _d(self.grid),
            "time_bins": _d(self.time_bins),
            "model": None if model is None else model.describe(),
            "energy": None if self.energy is None else float(self.energy),
            "dtype": np.dtype(self.dtype).name,
            "shape": [int(self.n_det), int(self.n_time), int(self.n_sky)],
            "rotmod_version": rotmod.__version__,
            # Only when finite, so that responses at infinity describe themselves as before.
            **({} if self.distance is None else {"distance": float(self.distance)}),
        }
