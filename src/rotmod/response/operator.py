"""The response as a linear operator from sky to folded count rates.

``O[d, t] = sum_n P[d, t, n] S[n]``: ``S[n]`` is the photon rate that sky pixel ``n`` would
give on one (unobstructed) detector face, ``O[d, t]`` the expected count rate of detector
``d`` in time (mask-angle) bin ``t``.  Reconstruction algorithms see only :meth:`forward`,
:meth:`adjoint` and :meth:`sensitivity`; whether ``P`` is stored is an implementation detail.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property
from typing import Any

import numpy as np

from rotmod.errors import ParameterError

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

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_det * n_time, n_sky)``, the shape of the flattened matrix."""
        return (self.n_det * self.n_time, self.n_sky)

    def forward(self, sky: np.ndarray) -> np.ndarray:
        """``P S``: folded rates ``(n_det, n_time)`` of sky vector ``sky`` ``(n_sky,)``."""
        x = np.asarray(sky)
        if x.shape != (self.n_sky,):
            raise ParameterError(f"sky must have shape ({self.n_sky},), got {x.shape}")
        return self._forward(x)

    def adjoint(self, counts: np.ndarray) -> np.ndarray:
        """``P^T Y``: sky vector ``(n_sky,)`` of folded data ``counts`` ``(n_det, n_time)``."""
        y = np.asarray(counts)
        if y.shape != (self.n_det, self.n_time):
            raise ParameterError(
                f"counts must have shape ({self.n_det}, {self.n_time}), got {y.shape}"
            )
        return self._adjoint(y)

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

    def as_linear_operator(self) -> Any:
        """A `scipy.sparse.linalg.LinearOperator` on flattened vectors."""
        from scipy.sparse.linalg import LinearOperator

        return LinearOperator(
            self.shape,
            matvec=lambda x: self.forward(np.ravel(x)).ravel(),
            rmatvec=lambda y: self.adjoint(np.reshape(y, (self.n_det, self.n_time))),
            dtype=np.float64,
        )
