"""Tools for tests and benchmarks, ours and a user's.

A user who writes a response operator, an algorithm or a benchmark needs the same few
things rotmod's own tests need, so they live here, public and documented, rather than as
copies in every test file:

* :func:`dot_test` checks that an operator's adjoint is the transpose of its forward
  product (``<P x, y> = <x, P^T y>``), the one property every reconstruction algorithm relies
  on;
* :class:`MatrixOperator` is a response held as a plain array that only implements the two
  products and counts them: an algorithm run on it sees nothing but ``forward`` and
  ``adjoint`` (no spec, no fast paths), and the counters tell what it cost;
* :func:`tiny_instrument` and :func:`tiny_grid` build a small instrument and sky grid
  quickly: the attenuation is fixed, so no cross-section database is read.

Nothing in rotmod imports this module; it imports rotmod's layers.

Examples
--------
>>> import numpy as np
>>> from rotmod.testing import MatrixOperator, dot_test
>>> op = MatrixOperator(np.random.default_rng(0).random((2, 6, 5)))
>>> dot_test(op, rng=1, rtol=1e-12) < 1e-12
True
>>> op.n_forward, op.n_adjoint
(1, 1)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import Material
from rotmod.response.operator import ResponseOperator
from rotmod.sky.geometry import SkyGeometry
from rotmod.sky.grid import SkyGrid

__all__ = ["MatrixOperator", "dot_test", "tiny_grid", "tiny_instrument"]

#: The paper's lead at 662 keV: density (g/cm^3) and mass attenuation (cm^2/g) fixed, so
#: building the instrument needs no database lookup.
_LEAD_DENSITY = 11.34
_LEAD_SIGMA_662 = 0.103


def dot_test(
    op: ResponseOperator,
    *,
    rng: np.random.Generator | int | None = None,
    rtol: float | None = None,
) -> float:
    """Relative mismatch of ``<P x, y>`` and ``<x, P^T y>`` for random positive ``x``, ``y``.

    The adjoint of a response must be the transpose of its forward product; an algorithm
    that uses both (all of rotmod's do) silently converges to a wrong image otherwise.

    Parameters
    ----------
    op : ResponseOperator
        Anything with ``n_sky``, ``n_det``, ``n_time``, ``forward`` and ``adjoint``.
    rng : numpy.random.Generator or int, optional
        Source of ``x`` (drawn first, ``(n_sky,)``) and ``y`` (``(n_det, n_time)``), uniform
        on ``[0, 1)`` in float64; an int seeds a new generator, ``None`` an unseeded one.
    rtol : float, optional
        If given, raise :class:`AssertionError` when the mismatch exceeds it.

    Returns
    -------
    float
        ``|lhs - rhs| / min(|lhs|, |rhs|)`` with ``lhs = <P x, y>``, ``rhs = <x, P^T y>``,
        both summed in float64 (products of a float32 operator are widened first): the
        larger of the two relative differences.  ``0.0`` when both sides are 0.

    Raises
    ------
    AssertionError
        With ``rtol``, when the mismatch exceeds it; the message gives both sides.

    Notes
    -----
    Positive vectors make ``<P x, y>`` a sum of non-negative terms for a non-negative
    response, so the relative mismatch measures round-off rather than cancellation.  The
    pattern is that of PyLops' ``dottest``.
    """
    if rtol is not None and not rtol >= 0:
        raise ParameterError(f"rtol must be >= 0 (or None), got {rtol!r}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    x = gen.random(op.n_sky)
    y = gen.random((op.n_det, op.n_time))
    lhs = float(np.vdot(op.forward(x).astype(np.float64), y))
    rhs = float(np.vdot(x, op.adjoint(y).astype(np.float64)))
    scale = min(abs(lhs), abs(rhs))
    if lhs == rhs:
        mismatch = 0.0
    elif scale == 0.0:
        mismatch = float("inf")
    else:
        mismatch = abs(lhs - rhs) / scale
    if rtol is not None and not mismatch <= rtol:
        raise AssertionError(
            f"dot test failed: <P x, y> = {lhs!r} but <x, P^T y> = {rhs!r} "
            f"(relative mismatch {mismatch:.3g} > rtol {rtol:g}) for {op!r}"
        )
    return mismatch


class MatrixOperator(ResponseOperator):
    """A response held as a plain float64 array, which counts its products.

    It implements only :meth:`_forward` and :meth:`_adjoint` (everything else is the
    defaults of :class:`~rotmod.response.ResponseOperator`, built on them), so an algorithm
    run on it uses nothing but the two products.  On purpose it is not a
    :class:`~rotmod.response.MaterialisedResponse`: it has no ``spec`` and no fast paths.

    Parameters
    ----------
    P : array_like, shape (n_det, n_time, n_sky)
        The response values; converted to float64.
    grid : SkyGeometry, optional
        The sky grid of the columns (reconstructions shape their images with it).

    Attributes
    ----------
    P : numpy.ndarray
        The float64 matrix.
    n_forward, n_adjoint : int
        How many forward and adjoint products were computed (the sensitivity ``P^T 1`` is
        one adjoint); set them to 0 (or call :meth:`reset_counts`) to start counting anew.

    Examples
    --------
    >>> import numpy as np
    >>> op = MatrixOperator(np.ones((1, 2, 3)))
    >>> op.forward(np.arange(3.0))
    array([[3., 3.]])
    >>> op.calls
    1
    """

    def __init__(self, P: Any, grid: SkyGeometry | None = None) -> None:
        self.P = np.asarray(P, dtype=np.float64)
        if self.P.ndim != 3:
            raise ParameterError(
                f"P must have shape (n_det, n_time, n_sky), got shape {self.P.shape}"
            )
        self.n_det, self.n_time, self.n_sky = self.P.shape
        if grid is not None and (not isinstance(grid, SkyGeometry) or grid.size != self.n_sky):
            raise ParameterError(
                f"grid must be a sky grid of {self.n_sky} pixels (P's last axis), got {grid!r}"
            )
        self.grid = grid
        self.n_forward = 0
        self.n_adjoint = 0

    @property
    def calls(self) -> int:
        """Products computed so far, forward and adjoint together."""
        return self.n_forward + self.n_adjoint

    def reset_counts(self) -> None:
        """Set :attr:`n_forward` and :attr:`n_adjoint` to 0."""
        self.n_forward = 0
        self.n_adjoint = 0

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        self.n_forward += 1
        return self.P @ sky

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        self.n_adjoint += 1
        return np.einsum("dtn,dt->n", self.P, counts)


def tiny_instrument(
    *,
    thickness: float = 2.0,
    rings: int = 1,
    diameter: float = 4.0,
    rotation_period: float = 60.0,
) -> Instrument:
    """A small instrument whose lead slats have a fixed attenuation (no database lookup).

    Lead slats and gaps of 4 cm at ``L = 100`` cm above a hexagonal detector array, with the
    paper's 662 keV attenuation ``sigma = 0.103`` cm^2/g at ``rho = 11.34`` g/cm^3 at every
    energy.

    Parameters
    ----------
    thickness : float
        Slat thickness ``h`` (cm).
    rings : int
        Hexagonal rings around the centre detector: 0 gives one detector, 1 seven, 2 nineteen.
    diameter : float
        Detector diameter ``c`` (cm).
    rotation_period : float
        Mask rotation period (s).

    Returns
    -------
    Instrument
    """
    lead = Material("Pb", density=_LEAD_DENSITY, mass_attenuation=_LEAD_SIGMA_662)
    return Instrument(
        Mask(4.0, 4.0, thickness, 100.0, lead),
        DetectorArray.hexagonal(diameter, rings=rings),
        rotation_period,
    )


def tiny_grid(
    shape: tuple[int, int] = (11, 11),
    pixel_size: float = 0.6,
    center: tuple[float, float] = (0.0, 0.0),
) -> SkyGrid:
    """A small tangent-plane sky grid (default 11 x 11 pixels of 0.6 deg on the axis).

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` pixels.
    pixel_size : float
        Pixel side (deg).
    center : (float, float)
        Field centre (deg) in tangent-plane coordinates.

    Returns
    -------
    SkyGrid
    """
    return SkyGrid(shape, pixel_size, center)
