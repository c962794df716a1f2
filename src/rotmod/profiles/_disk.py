"""Numba kernels shared by the profile models: the disc's cumulative area and the mask's
cumulative slat measure."""

from __future__ import annotations

import math

from numba import njit

__all__ = ["disk_fraction", "segment_fraction", "slat_measure"]


@njit(cache=True, fastmath=False)
def segment_fraction(tau: float) -> float:
    """Fraction of a disc's area lying within ``tau`` diameters of one side (the paper's F).

    ``F(tau) = arccos(1 - 2 tau)/pi - 2 (1 - 2 tau) sqrt(tau - tau^2)/pi``, clamped to
    ``tau in [0, 1]`` (the paper's Lambda constraint).
    """
    if tau <= 0.0:
        return 0.0
    if tau >= 1.0:
        return 1.0
    t = 2.0 * tau - 1.0  # coordinate in radii, -1..1
    return (math.acos(-t) + t * math.sqrt(1.0 - t * t)) / math.pi


@njit(cache=True)
def disk_fraction(u: float, uc: float, radius: float) -> float:
    """Fraction of the disc of ``radius`` centred at ``uc`` with coordinate below ``u``."""
    return segment_fraction(0.5 * ((u - uc) / radius + 1.0))


@njit(cache=True)
def slat_measure(u: float, a: float, b: float) -> float:
    """Signed measure of slat material on the mask-coordinate interval ``[0, u]``.

    Slats occupy ``b/2 + k(a+b) <= u <= b/2 + a + k(a+b)``; the measure of slat material in
    ``[u1, u2]`` is ``slat_measure(u2) - slat_measure(u1)``.
    """
    p = a + b
    k = math.floor(u / p)
    r = u - k * p
    return k * a + min(max(r - 0.5 * b, 0.0), a)
