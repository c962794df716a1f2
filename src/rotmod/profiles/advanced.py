"""The advanced characteristic profile (the seed paper's Sec. 3), derived in our conventions.

Geometry (``docs/physics.md`` has the derivation).  With ``|s| <= a`` and ``|s| <= b`` a ray
meets at most one slat, and the shadow of a slat ``[e1, e2]`` on the mask-bottom coordinate
of the rays is its *footprint* ``[e1 - max(0, s), e2 + max(0, -s)]`` (width ``a + |s|``,
centred ``s/2`` below the slat centre): a full-thickness core of width ``a' = a - |s|``,
transmission ``e^-tau``, between two clip regions of width ``|s|`` whose transmission rises
exponentially from ``e^-tau`` at the core to 1 at the footprint's edge.  Footprints do not
overlap because ``b' = b - |s| >= 0``.  In units of the detector diameter ``c``, measured from
the low edge of the detector disc, the core of slat ``m`` ends at ::

    x*_m = ((a' + c)/2 - | |x'| mod p - (1 + 2m) p/2 |) / c,    x' = uc + s/2,   p = a + b,

with ``M = floor((a + s_max + c)/p)`` and ``s_max = h tan(theta)``.  At most ``M + 1``
consecutive slats can shadow the disc at once (the paper sums ``2M + 1``), so the code sums
``m = m0 .. m0 + M`` from the first slat ``m0`` whose footprint reaches the disc; the other
terms of the paper's sum are exactly zero.  Then, with ``F0`` the clamped disc-segment fraction
(:func:`rotmod.profiles.standard.segment_fraction`), ::

    G0_m = (1 - e^-tau) [F0(x*_m + |s|/c) - F0(x*_m - a'/c - |s|/c)]
    G1_m = e^-tau [F1(x*_m) + F1(1 - x*_m + a'/c)]
    e^-tau F1(y) = ∫_{Λ[y]}^{Λ[y + |s|/c]} (exp(-tau (y + |s|/c - x) c/|s|) - e^-tau) dF0(x)
    G1~_m = alpha [F0(x*_m + |s|/c) - F0(x*_m) + F0(x*_m - a'/c) - F0(x*_m - a'/c - |s|/c)]
    alpha = (1 - e^-tau)/tau - e^-tau
    P = 1 - Σ_m (G0_m - G1_m)

``F1``'s integral is the exact model's clip integral
(:func:`rotmod.profiles._exact_kernels._clip_integral`: Gauss–Legendre in the square root of the
distance from the disc's edge, where the disc's density is smooth), which stays accurate
and finite as ``s -> 0``.  Where the code departs from the printed equations and
why is listed in ``docs/physics.md``.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numba import njit, prange

from rotmod.errors import ModelValidityError, ParameterError
from rotmod.geometry import Instrument
from rotmod.profiles._exact_kernels import _clip_integral
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, register_model
from rotmod.profiles.standard import _FAST, segment_fraction

__all__ = ["AdvancedModel", "advanced_point", "clip_transmission"]

#: G1 variants: name -> kernel mode.
_G1_MODES = {"none": 0, "exact": 1, "approx": 2}


@njit(cache=True)
def clip_transmission(y: float, w: float, tau: float, radius: float) -> float:
    """Extra transmission of one clip region: the paper's ``exp(-tau) F1(y)``.

    The clip region spans ``[y, y + w]`` diameters from the low edge of the disc; its
    transmission rises as ``exp(-tau (y + w - x)/w)`` from ``exp(-tau)`` at ``y`` (the
    full-thickness side) to 1 at ``y + w``.  Returns
    ``∫ (exp(-tau (y + w - x)/w) - exp(-tau)) dF0(x)`` over the part inside the disc.

    Parameters
    ----------
    y : float
        Inner edge of the clip region (detector diameters, unclamped).
    w : float
        Width ``|s|/c`` of the clip region (detector diameters), >= 0.
    tau : float
        Optical depth of the full slat thickness (may be inf).
    radius : float
        Detector radius (cm); the disc is centred at 0 in the quadrature's coordinate.
    """
    if w <= 0.0 or tau == 0.0 or math.isinf(tau):
        return 0.0
    lam_lo = max(0.0, -y / w)  # fraction of the clip region below the disc
    lam_hi = min(1.0, (1.0 - y) / w)  # ... and up to the disc's upper edge
    if lam_hi <= lam_lo:
        return 0.0
    diam = 2.0 * radius
    x1 = y + lam_lo * w
    x2 = y + lam_hi * w
    e_out = math.exp(-tau)
    dF = segment_fraction(x2) - segment_fraction(x1)
    u1 = (x1 - 0.5) * diam
    u2 = (x2 - 0.5) * diam
    E1 = tau * (1.0 - lam_lo)
    E2 = tau * (1.0 - lam_hi)
    if u2 - u1 <= 1e-12 * diam:
        # Sliver (s -> 0): the quadrature's slope would overflow; the midpoint rule is exact
        # to O(width^2) and the whole term is below 2e-12 anyway.
        return (math.exp(-0.5 * (E1 + E2)) - e_out) * dF
    return _clip_integral(u1, u2, E1, E2, 0.0, radius) - e_out * dF


@njit(cache=True, inline="always")
def _f0(x: float) -> float:
    """``F0(x)`` that returns the clamped values 0 and 1 without evaluating the segment."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return segment_fraction(x)


@njit(cache=True, inline="always", fastmath=_FAST)
def _first_slat(w: float, sa: float, a: float, diam: float, inv_p: float) -> float:
    """Lowest ``m`` whose footprint can reach the disc: ``|w - (m + 1/2) p| < (a+|s|+c)/2``."""
    return np.floor((w - 0.5 * (a + sa + diam)) * inv_p - 0.5) + 1.0


@njit(cache=True)
def advanced_point(
    uc: float,
    s: float,
    diam: float,
    a: float,
    b: float,
    tau: float,
    alpha: float,
    n_slats: int,
    mode: int,
) -> float:
    """Advanced profile value for one detector, source and mask angle.

    Parameters
    ----------
    uc, s : float
        Mask coordinate of the ray to the detector centre and its growth across the slab (cm).
    diam : float
        Detector diameter ``c`` (cm).
    a, b : float
        Slat width and gap (cm).
    tau, alpha : float
        Full-slat optical depth (may be inf) and the paper's ``alpha``.
    n_slats : int
        Number of consecutive slats summed, ``M + 1`` with the paper's
        ``M = floor((a + s_max + c)/(a + b))``.
    mode : int
        0: G0 only; 1: G0 - exact G1; 2: G0 - G1~.
    """
    p = a + b
    inv_p = 1.0 / p
    inv_c = 1.0 / diam
    sa = abs(s)
    ws = sa * inv_c  # |s|/c
    wa = (a - sa) * inv_c  # a'/c
    e_tau = math.exp(-tau)
    w = abs(uc + 0.5 * s)  # |x'(t)|
    w = w - p * np.floor(w * inv_p)
    m0 = _first_slat(w, sa, a, diam, inv_p)
    total = 0.0
    for j in range(n_slats):
        xs = 0.5 * (wa + 1.0) - abs(w - (0.5 + m0 + j) * p) * inv_c  # x*_m
        hi = xs + ws
        lo = xs - wa - ws
        if hi <= 0.0 or lo >= 1.0:
            continue  # the footprint misses the disc
        f_hi = _f0(hi)
        f_lo = _f0(lo)
        g = (1.0 - e_tau) * (f_hi - f_lo)
        if mode == 1:
            g -= clip_transmission(xs, ws, tau, 0.5 * diam) + clip_transmission(
                1.0 - xs + wa, ws, tau, 0.5 * diam
            )
        elif mode == 2:
            g -= alpha * (f_hi - _f0(xs) + _f0(xs - wa) - f_lo)
        total += g
    return min(max(1.0 - total, 0.0), 1.0)


@njit(parallel=True, cache=True)
def _advanced_grid(X, Y, Sx, Sy, tau, alpha, n_slats, cos_xi, sin_xi, diam, a, b, mode, out):
    """Per-point kernel (any mode; used for the exact G1, whose quadrature dominates)."""
    nd, nt, nn = out.shape
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        c = cos_xi[t]
        sn = sin_xi[t]
        for n in range(nn):
            uc = X[d, n] * c - Y[d, n] * sn
            s = Sx[n] * c - Sy[n] * sn
            out[d, t, n] = advanced_point(uc, s, diam, a, b, tau[n], alpha[n], n_slats, mode)


@njit(cache=True, inline="always", fastmath=_FAST)
def _slat_term(xs, ws, wa, opac, alpha, mode):
    """One slat's ``G0 - G1~`` (mode 2) or ``G0`` (mode 0) at footprint position ``xs``."""
    g = (opac - alpha) * (segment_fraction(xs + ws) - segment_fraction(xs - wa - ws))
    if mode == 2:
        g += alpha * (segment_fraction(xs) - segment_fraction(xs - wa))
    return g


@njit(parallel=True, cache=True)
def _advanced_rows(X, Y, Sx, Sy, opac, alpha, n_slats, cos_xi, sin_xi, diam, a, b, mode, out):
    """Branch-free kernel for G0 and G0 - G1~ (modes 0 and 2), vectorised over sources:
    :func:`_advanced_row` for every (detector, angle) row, in parallel.

    The parallel loop only calls the row kernel: numba's parallel compilation analyses the
    loop's body, and with the row inlined it took twice as long to compile (a newcomer's
    first run waits for it).
    """
    nd, nt = out.shape[:2]
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        _advanced_row(X[d], Y[d], Sx, Sy, opac, alpha, n_slats, cos_xi[t], sin_xi[t], diam,
                      a, b, mode, out[d, t])


@njit(cache=True, fastmath=_FAST)
def _advanced_row(X, Y, Sx, Sy, opac, alpha, n_slats, c, sn, diam, a, b, mode, out):
    """One (detector, angle) row ``out[n]`` of :func:`_advanced_rows`.

    With ``w = |x'|`` reduced to one period, the footprint nearest the disc is always slat
    ``m = 0`` (centre ``p/2``), so pass 1 evaluates it for every source, branch-free.  The
    other candidates (``m0 .. m0 + n_slats - 1``) reach the disc only when their centre is
    within ``(a + |s| + c)/2`` of the disc's: on the paper's masks about 1 source in 25, so
    pass 2 collects just those and evaluates them in a compact loop.  A footprint that
    misses the disc contributes exactly 0 (all its F0 arguments clamp alike), so the sum
    equals the sum over all candidates.
    """
    nn = out.shape[0]
    p = a + b
    inv_p = 1.0 / p
    inv_c = 1.0 / diam
    g0_only = 0.0 if mode == 2 else 1.0  # mode 0: alpha does not enter
    ws = np.empty(nn)  # |s|/c
    wa = np.empty(nn)  # a'/c
    wr = np.empty(nn)  # |x'(t)| reduced to [0, p)
    reach = np.empty(nn)  # (a + |s| + c)/2: footprints with centres nearer meet the disc
    first = np.empty(nn)  # first candidate slat m0
    acc = np.empty(nn)
    for n in range(nn):
        uc = X[n] * c - Y[n] * sn
        s = Sx[n] * c - Sy[n] * sn
        sa = abs(s)
        w = abs(uc + 0.5 * s)
        w = w - p * np.floor(w * inv_p)
        ws[n] = sa * inv_c
        wa[n] = (a - sa) * inv_c
        wr[n] = w
        reach[n] = 0.5 * (a + sa + diam)
        first[n] = _first_slat(w, sa, a, diam, inv_p)
        xs = 0.5 * (wa[n] + 1.0) - abs(w - 0.5 * p) * inv_c
        al = alpha[n] * (1.0 - g0_only)
        acc[n] = _slat_term(xs, ws[n], wa[n], opac[n], al, mode)
    # Pass 2: the other candidates that reach the disc.
    own = np.empty(nn * n_slats, dtype=np.int64)
    pos = np.empty(nn * n_slats)
    k = 0
    for n in range(nn):
        for j in range(n_slats):
            m = first[n] + j
            if m != 0.0:
                dist = abs(wr[n] - (m + 0.5) * p)
                if dist < reach[n]:
                    own[k] = n
                    pos[k] = 0.5 * (wa[n] + 1.0) - dist * inv_c
                    k += 1
    for i in range(k):
        n = own[i]
        al = alpha[n] * (1.0 - g0_only)
        acc[n] += _slat_term(pos[i], ws[n], wa[n], opac[n], al, mode)
    for n in range(nn):
        out[n] = min(max(1.0 - acc[n], 0.0), 1.0)


def alpha_factor(tau: np.ndarray) -> np.ndarray:
    """The paper's ``alpha = (1 - e^-tau)/tau - e^-tau``: mean extra clip transmission.

    Finite for ``tau = 0`` (0) and ``tau = inf`` (0).
    """
    tau = np.asarray(tau, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(tau > 0, -np.expm1(-tau) / np.where(tau > 0, tau, 1.0), 1.0)
    return np.where(np.isinf(tau), 0.0, mean - np.exp(-tau))


@register_model("advanced-g0", g1="none")
@register_model("advanced-approx", g1="approx")
@register_model("advanced")
class AdvancedModel(ProfileModel):
    """The paper's advanced profile (Sec. 3) in our conventions.

    Parameters
    ----------
    g1 : {"exact", "approx", "none"}
        Clip-region transmission term: the exact ``G1`` (integral by quadrature), the
        approximation ``G1~`` with the constant ``alpha``, or none (``G0`` only).
        Registered as ``"advanced"``, ``"advanced-approx"`` and ``"advanced-g0"``.

    Raises
    ------
    ParameterError
        Unknown ``g1``.

    Notes
    -----
    Valid only while no ray meets two slats or both faces of one slat's sides:
    ``a >= h tan(theta)`` and ``b >= h tan(theta)`` for every requested source (the minima
    over a rotation of ``a'(t)`` and ``b'(t)``); :meth:`check_validity` refuses other sources.
    With ``g1="exact"`` it equals the exact model there (to ~1e-12).
    """

    _NAMES: ClassVar[dict[str, str]] = {
        "exact": "advanced",
        "approx": "advanced-approx",
        "none": "advanced-g0",
    }

    def __init__(self, g1: str = "exact") -> None:
        if g1 not in _G1_MODES:
            raise ParameterError(f"g1 must be one of {sorted(_G1_MODES)}, got {g1!r}")
        self.g1 = g1
        self.name = self._NAMES[g1]

    def check_validity(self, instrument: Instrument, geom: ProjectedGeometry) -> None:
        """Refuse sources with ``min a'(t) = a - h tan(theta) < 0`` or ``min b'(t) < 0``.

        The minima over a full rotation (``|s| = h tan(theta)`` at some angle), so the check
        does not depend on the requested mask angles.
        """
        m = instrument.mask
        a, b, h = m.slat_width, m.slat_gap, m.thickness
        smax = h * np.tan(geom.theta)
        for width, sym, label in ((a, "a", "slat width"), (b, "b", "slat gap")):
            # 1e-12 relative slack: tan(atan(a/h)) * h may exceed a by an ulp.
            bad = np.flatnonzero(smax > width * (1.0 + 1e-12))
            if bad.size:
                i = int(bad[0])
                raise ModelValidityError(
                    f"the advanced model needs min {sym}'(t) = {sym} - h tan(theta) >= 0 for "
                    f"every source, but {bad.size} source(s) break it, e.g. source {i} at "
                    f"theta = {np.degrees(geom.theta[i]):.6g} deg: {sym} = {width:g} cm "
                    f"({label}) < h tan(theta) = {smax[i]:.6g} cm (h = {h:g} cm); "
                    "use the 'exact' model for this geometry"
                )

    def evaluate(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        m = instrument.mask
        a, b, c = m.slat_width, m.slat_gap, instrument.detectors.diameter
        smax = m.thickness * float(np.max(np.tan(geom.theta), initial=0.0))
        # The paper's M = floor((a + s_max + c)/(a + b)); at most M + 1 slats shadow the disc.
        n_slats = int(np.floor((a + smax + c) / (a + b))) + 1
        tau = geom.tau
        args = (geom.X, geom.Y, geom.Sx, geom.Sy)
        mode = _G1_MODES[self.g1]
        if mode == 1:
            _advanced_grid(*args, tau, alpha_factor(tau), n_slats, cos_xi, sin_xi, c, a, b,
                           mode, out)
        else:
            _advanced_rows(*args, -np.expm1(-tau), alpha_factor(tau), n_slats, cos_xi, sin_xi,
                           c, a, b, mode, out)

    def describe(self) -> dict[str, Any]:
        """Parameters that identify this model (for metadata)."""
        return {"model": self.name, "g1": self.g1}

