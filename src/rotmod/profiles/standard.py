"""The standard characteristic profile (the seed paper's Sec. 2; Durouchoux et al. 1983).

For ``a = b = c`` and thin slats the detector disc (diameter ``a``) always overlaps exactly
one slat, from one side, by a fraction ``x*`` of its diameter, ::

    x* = 1 - | |uc / a| mod 2 - 1 |,        P = 1 - (1 - T) F(x*),

where ``uc`` is the mask coordinate of the ray to the detector centre at the mask plane
(:mod:`rotmod.profiles.base`), ``F`` the fraction of a disc's area within ``x*`` diameters of
one side (:func:`segment_fraction`) and ``T`` a constant slat transmission.  The model
ignores the slat thickness ``h`` and the mask's attenuation coefficient: it is the thin-slat
limit (``h -> 0``) of the exact model with slat transmission ``T``.  It matches our
conventions with no correction (``docs/physics.md``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

from rotmod._validate import as_scalar
from rotmod.errors import ModelValidityError
from rotmod.geometry import Instrument
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, register_model

__all__ = ["StandardModel", "segment_fraction"]

# Power-series coefficients (in y = z^2, 0 <= y <= 1/4) of R(y) = (asin(z) - z) / z^3, a
# degree-12 Chebyshev fit to the exact Taylor series evaluated in 40-digit arithmetic.
# Max |error| of R: 1.4e-16 on [0, 1/4]; asin(z) = z + z y R(y) is then good to < 3e-17
# absolute for z <= 1/2.  (Generated once with mpmath; see docs/physics.md.)
_R0 = 0.16666666666666674
_R1 = 0.0749999999999661
_R2 = 0.04464285714919078
_R3 = 0.030381943940787564
_R4 = 0.02237218038968956
_R5 = 0.01735222411520712
_R6 = 0.013973655819164217
_R7 = 0.011455748493617348
_R8 = 0.010473253009552003
_R9 = 0.004817899101562862
_R10 = 0.019128408574733947
_R11 = -0.017535613226566927
_R12 = 0.03058349608909191
_HALF_PI = 0.5 * math.pi
#: Only fused multiply-add contraction: no assumptions about NaN, inf or reassociation.
_FAST = {"contract"}
_INV_PI = 1.0 / math.pi


@njit(cache=True, inline="always", fastmath=_FAST)
def segment_fraction(tau: float) -> float:
    """Fraction of a disc's area within ``tau`` diameters of one side (the paper's F, F0).

    ``F(tau) = arccos(1 - 2 tau)/pi - 2 (1 - 2 tau) sqrt(tau - tau^2)/pi`` with ``tau``
    clamped to [0, 1] (the paper's Lambda).  Same values as that closed form to ~1e-16
    (tests/profiles/test_models.py), but branch-free (so numba vectorises loops over it) and
    without ``acos``: with ``q = min(tau, 1 - tau)``,
    ``acos(1 - 2q) = 2 asin(sqrt q)`` for ``q <= 1/4`` and ``pi/2 - asin(1 - 2q)`` above,
    and ``asin`` on [0, 1/2] is a polynomial.
    """
    x = min(max(tau, 0.0), 1.0)
    q = min(x, 1.0 - x)
    v = 1.0 - 2.0 * q
    small = q <= 0.25
    y = q if small else v * v
    z = math.sqrt(q) if small else v
    # Estrin's scheme: a short dependency chain (the profile kernels are latency bound).
    y2 = y * y
    y4 = y2 * y2
    y8 = y4 * y4
    r = (
        (_R0 + _R1 * y) + (_R2 + _R3 * y) * y2
        + ((_R4 + _R5 * y) + (_R6 + _R7 * y) * y2) * y4
        + ((_R8 + _R9 * y) + (_R10 + _R11 * y) * y2 + _R12 * y4) * y8
    )
    asn = z + z * y * r
    ang = 2.0 * asn if small else _HALF_PI - asn
    f = (ang - 2.0 * v * math.sqrt(q * (1.0 - q))) * _INV_PI
    return f if x <= 0.5 else 1.0 - f


@njit(parallel=True, cache=True, fastmath=_FAST)
def _standard_grid(Xa, Ya, cos_xi, sin_xi, opacity, out):
    """``out[d, t, n] = 1 - opacity F(x*)`` with ``x* = 1 - ||uc/a| mod 2 - 1|``.

    ``Xa, Ya`` are the projected detector centres divided by ``a``.
    """
    nd, nt, nn = out.shape
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        c = cos_xi[t]
        sn = sin_xi[t]
        for n in range(nn):
            w = abs(Xa[d, n] * c - Ya[d, n] * sn)
            w = w - 2.0 * np.floor(0.5 * w)
            out[d, t, n] = 1.0 - opacity * segment_fraction(1.0 - abs(w - 1.0))


@register_model("standard")
class StandardModel(ProfileModel):
    """The paper's standard profile: thin slats, ``a = b = c``, constant transmission.

    Parameters
    ----------
    transmission : float
        Constant fraction ``T`` of the photons that pass through a slat (0 = opaque, the
        default; 1 = transparent).  The mask's own thickness and attenuation coefficient are
        ignored (thin-slat model).

    Raises
    ------
    ParameterError
        If ``transmission`` is not a number in [0, 1].

    Notes
    -----
    ``P = 1 - (1 - T) F(x*)``, ``x* = 1 - ||uc/a| mod 2 - 1|`` (module notes).  Instruments
    with ``a``, ``b``, ``c`` not all equal are refused with
    :class:`~rotmod.errors.ModelValidityError`; use ``"advanced"`` or ``"exact"`` there.
    """

    #: Relative tolerance for ``a = b = c``.
    equality_rtol = 1e-9

    def __init__(self, transmission: float = 0.0) -> None:
        self.transmission = as_scalar(transmission, "transmission", lo=0.0, hi=1.0)

    def check_validity(self, instrument: Instrument, geom: ProjectedGeometry) -> None:
        """Refuse instruments whose slat width ``a``, gap ``b`` and detector diameter ``c``
        differ (relative tolerance :attr:`equality_rtol`)."""
        a = instrument.mask.slat_width
        b = instrument.mask.slat_gap
        c = instrument.detectors.diameter
        tol = self.equality_rtol * max(a, b, c)
        if abs(a - b) > tol or abs(a - c) > tol:
            raise ModelValidityError(
                "the standard model requires slat width a = slat gap b = detector diameter c, "
                f"got a = {a:g} cm, b = {b:g} cm, c = {c:g} cm; use the 'advanced' or "
                "'exact' model for other geometries"
            )
        m = instrument.mask
        if m.thickness == 0 and np.isfinite(geom.mu):
            # Zero-thickness slats of finite attenuation stop nothing, but this model's slats
            # stop everything but `transmission`: it would describe another instrument.
            raise ModelValidityError(
                "the standard model's slats are opaque (up to its transmission), but "
                "mask.thickness = 0 cm with a finite attenuation transmits every photon; give "
                "the slats a thickness, or mu = inf for the paper's thin opaque mask"
            )

    def evaluate(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        a = instrument.mask.slat_width
        _standard_grid(geom.X / a, geom.Y / a, cos_xi, sin_xi, 1.0 - self.transmission, out)

    def describe(self) -> dict[str, Any]:
        """Parameters that identify this model (for metadata)."""
        return {"model": self.name, "transmission": self.transmission}

