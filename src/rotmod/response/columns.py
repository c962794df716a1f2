"""The response at positions of one's choosing: the columns of point sources between pixels.

A point source at a continuous position contributes ``F c[d, t]`` to the folded rates, with
``c`` the response's column for its direction.  :func:`columns_at` evaluates the columns of
any response (one spec, or a sum over attitude intervals, :meth:`ResponseOperator.components`)
at a list of positions with the response's own model, energy and binning, by building the
response of a one-pixel-per-position sky geometry (:mod:`rotmod.sky.points`).  The exact
model gives a column in one profile evaluation per detector and bin; a Radon response's
columns are those of the exact model it factorises (within its tolerance).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import astropy.units as u
import numba
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod.errors import ParameterError
from rotmod.response.materialised import build_response
from rotmod.response.operator import ResponseOperator
from rotmod.response.unfolded import UnfoldedResponse
from rotmod.sky.geometry import SkyGeometry
from rotmod.sky.points import DirectionList, PositionList

__all__ = ["columns_at", "component_columns", "position_grid"]

#: Profile values below which a column is evaluated on one thread: a fit evaluates a few
#: columns at a time, ~1 ms of work, and a parallel launch on a loaded machine can wait a
#: scheduler slice (measured: 0.6 ms -> 100 ms per column with other processes running).
SERIAL_BELOW = 200_000


@contextmanager
def _threads_for(n_values: int) -> Iterator[None]:
    """One numba thread for small evaluations (thread-local; restored after)."""
    if n_values >= SERIAL_BELOW:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def position_grid(grid: SkyGeometry, positions: Any) -> SkyGeometry:
    """``positions`` as a sky geometry in the frame of ``grid``.

    Parameters
    ----------
    grid : SkyGeometry
        A grid of the response (its frame, and for the celestial frame its attitude).
    positions : SkyCoord or (theta, phi)
        Sky positions (celestial frame) or instrument directions (deg if plain numbers).

    Raises
    ------
    ParameterError
        Positions of the wrong kind for the grid's frame, or out of view.
    """
    if grid.frame == "celestial":
        if not isinstance(positions, SkyCoord):
            raise ParameterError(
                f"positions must be an astropy SkyCoord for a response on the sky (grid "
                f"kind {grid.kind!r}), got {type(positions).__name__}")
        return PositionList.from_coords(positions, grid.attitude)
    if isinstance(positions, SkyCoord):
        raise ParameterError(
            f"positions must be instrument directions (theta, phi) for a response in the "
            f"instrument frame (grid kind {grid.kind!r}), got a SkyCoord")
    try:
        theta, phi = positions
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"positions must be a pair (theta, phi), got {positions!r}") \
            from exc
    return DirectionList(np.atleast_1d(theta), np.atleast_1d(phi))


def columns_at(response: ResponseOperator, positions: Any, *, energy: Any = None
               ) -> np.ndarray:
    """Response columns ``c[d, t, k]`` (float64) at ``positions``.

    Parameters
    ----------
    response : ResponseOperator
        Any response with a spec (every operator rotmod builds or stores).
    positions : SkyCoord or (theta, phi)
        See :func:`position_grid`.
    energy : float or Quantity, optional
        Photon energy (keV) of the columns; default the response's own (an energy-resolved
        response evaluates them at every true energy, :mod:`rotmod.sources.spectra`).

    Returns
    -------
    ndarray, shape (n_det, n_time, n_positions)
        ``forward`` of a unit source at each position, in the response's units.
    """
    if isinstance(response, UnfoldedResponse):
        # Its rows are the folded responses' rows, picked per time bin and weighted.
        return response.gather([columns_at(p, positions, energy=energy)
                                for p in response.parts])
    out = np.zeros((response.n_det, response.n_time, 0))
    for part in component_columns(response, positions, energy=energy):
        out = part if out.shape[2] == 0 else out + part
    return np.asarray(out, dtype=np.float64)


def component_columns(response: ResponseOperator, positions: Any, *, energy: Any = None
                      ) -> Iterator[np.ndarray]:
    """The columns of each of the response's components (:meth:`ResponseOperator.components`,
    one per attitude interval of a drifting observation), each times its weights: their sum
    is :func:`columns_at`.  Yielded one by one, so that a consumer summing them holds one
    interval's columns at a time (a day's flight has thousands of intervals).

    Parameters
    ----------
    response, positions, energy
        As :func:`columns_at` (a response that is a sum of folded ones: not an
        :class:`~rotmod.response.UnfoldedResponse`).

    Yields
    ------
    ndarray, shape (n_det, n_time, n_positions)
        In the order of ``response.components()``.
    """
    for weights, spec in response.components():
        points = position_grid(spec.grid, positions)
        with _threads_for(response.n_det * response.n_time * points.size):
            at = spec.replace(grid=points, dtype=np.float64)
            if energy is not None:
                at = at.replace(energy=energy)
            part = build_response(at).matrix
        if weights is not None:
            part = part * np.asarray(weights, dtype=float)[None, :, None]
        yield np.asarray(part, dtype=np.float64)


def _deg(q: Any) -> np.ndarray:
    return np.asarray(q.to_value(u.deg) if isinstance(q, u.Quantity) else q, dtype=float)
