"""The response of an observation whose pointing drifts: the exposure-weighted sum.

A balloon gondola drifts and turns; over an attitude interval ``k`` (short enough for the
attitude to be constant) a sky pixel ``n`` lies at its own instrument direction, so its
profile is ``P_k[d, t, n]``.  The counts folded over the whole observation are, bin by bin,
the sum over intervals of ``exposure_k[t] P_k[d, t, n] S[n]``, so the response the folded
data see is

    P[d, t, n] = sum_k exposure_k[t] P_k[d, t, n] / sum_k exposure_k[t],

with ``exposure_k[t]`` the time interval ``k`` spends in mask-angle bin ``t`` (the same exact
per-bin exposure that folding uses).  It is a response like any other (a
:class:`~rotmod.response.MaterialisedResponse`), on a celestial grid.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rotmod.events.folding import exposure_per_bin
from rotmod.limits import check_memory
from rotmod.profiles.base import DEFAULT_MODEL
from rotmod.response.binning import TimeBinning
from rotmod.response.materialised import MaterialisedResponse, build_response

__all__ = ["drift_response"]


def drift_response(
    instrument: Any,
    grid: Any,
    time_bins: Any,
    intervals: list[tuple[float, float, Any]],
    model: Any = DEFAULT_MODEL,
    energy: Any = None,
    *,
    start_phase: Any = 0.0,
    dtype: Any = np.float64,
) -> MaterialisedResponse:
    """Exposure-weighted response over attitude ``intervals`` (see the module notes).

    Parameters
    ----------
    instrument : Instrument
    grid : CelestialGrid
        The image grid; its attitude is replaced by each interval's.
    time_bins : int or TimeBinning
    intervals : list of (t_lo, t_hi, Attitude)
        E.g. :meth:`rotmod.sky.AttitudeTable.intervals`; times in s.
    model, energy, dtype
        As for :func:`~rotmod.response.build_response`.
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if plain), as in the event list.

    Returns
    -------
    MaterialisedResponse
    """
    import dataclasses

    tb = TimeBinning.coerce(time_bins)
    n_det = len(instrument.detectors)
    check_memory(2 * 8.0 * n_det * tb.n_bins * grid.size,
                 f"a drift response of {n_det} x {tb.n_bins} x {grid.size}",
                 hint="use fewer pixels or time bins")
    total = np.zeros(tb.n_bins)
    acc = np.zeros((n_det, tb.n_bins, grid.size))
    for lo, hi, att in intervals:
        w = exposure_per_bin([[lo, hi]], tb.n_bins, instrument.rotation_period, start_phase)
        part = build_response(instrument, dataclasses.replace(grid, attitude=att), tb, model,
                              energy, dtype=np.float64)
        acc += w[None, :, None] * part.matrix
        total += w
    with np.errstate(invalid="ignore", divide="ignore"):
        matrix = np.where(total[None, :, None] > 0, acc / total[None, :, None], 0.0)
    return MaterialisedResponse(matrix.astype(dtype), instrument=instrument, grid=grid,
                                time_bins=tb, model=part.model, energy=part.energy)
