"""The exact characteristic profile, valid for every geometry.

Derivation (``docs/physics.md``): a ray that reaches the detector plane crosses the mask
bottom at mask coordinate ``u`` and its top at ``u + s``.  Because the coordinate is linear
in height, the ray's path in slat material is ``(h / cos theta) g(u) / |s|`` with
``g(u) = |[u, u + s] ∩ slats|`` (for ``s = 0`` the path is ``h/cos theta`` inside a slat and
0 in a gap).  Its transmission is ``T(u) = exp(-tau g(u) / |s|)``, ``tau = mu h / cos theta``,
and the profile is ``T`` averaged over the detector disc,

    P = ∫ T(u) dΦ(u),    Φ(u) = fraction of the disc (centre uc, radius R) below u.

``g`` is piecewise linear with slopes -1, 0, +1 between breakpoints at the slat edges ``e``
and at ``e - s``; the kernel walks those pieces in order (any number of slats, rays crossing
several slats, detectors wider than many periods).  On a piece where ``g`` is constant the
contribution is ``T ΔΦ`` in closed form.  Where ``g`` varies, ``T`` is an exponential in
``u``; substituting ``u = uc - R cos(phi)`` makes ``dΦ = (2/π) sin²(phi) dphi`` smooth even at
the disc's edge, and the piece is integrated by Gauss–Legendre on sub-pieces over which the
exponent changes by at most ``_EXP_STEP``.  Parts where the exponent exceeds ``_EXP_CUT``
(``T < 1e-19``) are dropped.  The result is accurate to better than 1e-12 (tested against
adaptive quadrature in ``tests/test_exact.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, prange

from rotmod.geometry import Instrument
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, register_model
from rotmod.profiles.standard import segment_fraction

__all__ = ["ExactModel", "exact_point"]

_GL_N = 12
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_N)
#: Largest change of the exponent over one Gauss–Legendre sub-piece.
_EXP_STEP = 2.0
#: Exponent beyond which transmission (< 2e-19) is dropped.
_EXP_CUT = 43.0
#: Largest angular width (rad) of one sub-piece, so sin² is resolved on wide pieces.
_PHI_STEP = 0.6
#: |s| / (a + b) below which the ray is taken as parallel to the slat walls (s = 0).
_S_ZERO = 1e-13


@njit(cache=True)
def _edge(j: int, a: float, b: float) -> float:
    """Slat edge number ``j`` in increasing order: even = slat start, odd = slat end."""
    k = j // 2
    e = 0.5 * b + k * (a + b)
    if j % 2 == 1:
        e += a
    return e


@njit(cache=True)
def _first_edge_above(x: float, a: float, b: float) -> int:
    j = 2 * math.floor((x - 0.5 * b) / (a + b))
    while _edge(j, a, b) > x:
        j -= 1
    while _edge(j, a, b) <= x:
        j += 1
    return j


@njit(cache=True)
def _transmission(frac: float, tau: float) -> float:
    """``exp(-tau frac)`` for path fraction ``frac`` (0..1), with the opaque limit tau = inf."""
    if frac <= 0.0:
        return 1.0
    if math.isinf(tau):
        return 0.0
    return math.exp(-tau * frac)


@njit(cache=True)
def _in_slat(x: float, a: float, b: float) -> bool:
    """Whether mask coordinate ``x`` lies in a slat (``b/2 <= x mod p <= b/2 + a``)."""
    p = a + b
    r = x - 0.5 * b
    r -= p * math.floor(r / p)
    return r <= a


@njit(cache=True)
def _path_fraction(x: float, s: float, s_abs: float, a: float, b: float) -> float:
    """Fraction ``|[x, x + s] ∩ slats| / |s|`` of a ray's path through the slab in slats.

    Both ends are located in their period cell ``k`` (cell coordinate ``r`` in ``[0, p)``,
    slat at ``0 <= r <= a``), and the measure is ``(k2 - k1) a + min(r2, a) - min(r1, a)``:
    exactly 0 for two ends in one gap, exactly 1 for two ends in one slat, so no rounding
    noise of order eps |x| / |s| survives when |s| is small.
    """
    p = a + b
    lo = min(x, x + s) - 0.5 * b
    hi = max(x, x + s) - 0.5 * b
    k1 = math.floor(lo / p)
    k2 = math.floor(hi / p)
    r1 = lo - k1 * p
    r2 = hi - k2 * p
    if k1 == k2:
        if r2 <= a:
            return 1.0  # both ends in one slat
        if r1 > a:
            return 0.0  # both ends in one gap
    g = (k2 - k1) * a + min(r2, a) - min(r1, a)
    return min(max(g / s_abs, 0.0), 1.0)


@njit(cache=True)
def _exp_piece(u1, u2, e1, e2, uc, radius, gl_x, gl_w):
    """∫_{u1}^{u2} exp(-E(u)) dΦ(u) for E linear from e1 at u1 to e2 at u2."""
    # Drop the part with E > _EXP_CUT (E is monotonic on the piece).
    if e1 >= _EXP_CUT and e2 >= _EXP_CUT:
        return 0.0
    if e1 > _EXP_CUT:
        u1 = u1 + (e1 - _EXP_CUT) / (e1 - e2) * (u2 - u1)
        e1 = _EXP_CUT
    elif e2 > _EXP_CUT:
        u2 = u1 + (_EXP_CUT - e1) / (e2 - e1) * (u2 - u1)
        e2 = _EXP_CUT
    if u2 <= u1:
        return 0.0
    slope = (e2 - e1) / (u2 - u1)
    c1 = min(max((uc - u1) / radius, -1.0), 1.0)
    c2 = min(max((uc - u2) / radius, -1.0), 1.0)
    f1 = math.acos(c1)
    f2 = math.acos(c2)
    nsub = max(
        math.ceil(abs(e2 - e1) / _EXP_STEP), math.ceil((f2 - f1) / _PHI_STEP), 1
    )
    total = 0.0
    for i in range(nsub):
        # Sub-pieces uniform in u (the exponent is linear in u).
        v1 = u1 + (u2 - u1) * i / nsub
        v2 = u1 + (u2 - u1) * (i + 1) / nsub
        g1 = math.acos(min(max((uc - v1) / radius, -1.0), 1.0))
        g2 = math.acos(min(max((uc - v2) / radius, -1.0), 1.0))
        half = 0.5 * (g2 - g1)
        mid = 0.5 * (g2 + g1)
        acc = 0.0
        for k in range(gl_x.size):
            ph = mid + half * gl_x[k]
            uu = uc - radius * math.cos(ph)
            sn = math.sin(ph)
            acc += gl_w[k] * math.exp(-(e1 + slope * (uu - u1))) * sn * sn
        total += acc * half * (2.0 / math.pi)
    return total


@njit(cache=True)
def _exp_piece_fast(u1, u2, e1, e2, uc, radius, dphi):
    """Two-moment closed form of ∫_{u1}^{u2} exp(-E(u)) dΦ(u), E linear from e1 to e2.

    The disc's density on the piece is replaced by the linear density with the same mass
    ``dphi = Φ(u2) - Φ(u1)`` and the same first moment (both exact, in closed form), and
    the exponential is integrated against it exactly.  Exact for a density linear in ``u``;
    the error comes from the curvature of the density (largest next to the disc's edge).
    """
    half = 0.5 * (u2 - u1)
    if dphi <= 0.0 or half <= 0.0:
        return 0.0
    mid = 0.5 * (u1 + u2)
    v1 = min(max((u1 - uc) / radius, -1.0), 1.0)
    v2 = min(max((u2 - uc) / radius, -1.0), 1.0)
    q1 = 1.0 - v1 * v1
    q2 = 1.0 - v2 * v2
    # ∫ (u - mid) dΦ / half: first moment in z = (u - mid)/half, |m1| <= dphi.
    c1 = radius * (2.0 / (3.0 * math.pi))
    m1 = ((uc - mid) * dphi + c1 * (q1 * math.sqrt(q1) - q2 * math.sqrt(q2))) / half
    m1 = min(max(m1, -dphi), dphi)
    # Density A + B z on [-1, 1]: 2A = dphi, (2/3) B = m1.
    A = 0.5 * dphi
    B = 1.5 * m1
    kap = 0.5 * (e2 - e1)
    if abs(kap) < 0.2:
        em = math.exp(-0.5 * (e1 + e2))
        k2 = kap * kap
        i0 = 2.0 * (1.0 + k2 / 6.0 * (1.0 + k2 / 20.0 * (1.0 + k2 / 42.0 * (1.0 + k2 / 72.0))))
        i1 = -2.0 * kap * (
            1.0 / 3.0 + k2 * (1.0 / 30.0 + k2 * (1.0 / 840.0 + k2 / 45360.0))
        )
        return em * (A * i0 + B * i1)
    x1 = math.exp(-e1)
    x2 = math.exp(-e2)
    i0 = (x1 - x2) / kap
    i1 = -(kap * (x1 + x2) - (x1 - x2)) / (kap * kap)
    return A * i0 + B * i1


@njit(cache=True)
def exact_point(
    uc: float, s: float, radius: float, a: float, b: float, tau: float, fast: bool = False
) -> float:
    """Exact profile value for one detector, source and mask angle.

    Parameters
    ----------
    uc : float
        Mask coordinate of the ray to the detector centre at the mask bottom (cm).
    s : float
        Growth of the ray's mask coordinate from mask bottom to top (cm).
    radius : float
        Detector radius (cm).
    a, b : float
        Slat width and gap (cm).
    tau : float
        Optical depth of a full slat along the ray, ``mu h / cos theta`` (may be inf).
    fast : bool
        Integrate the exponential (clip) pieces with the two-moment closed form
        (:func:`_exp_piece_fast`) instead of Gauss–Legendre quadrature; see
        :class:`ExactModel` for its accuracy.
    """
    if tau == 0.0 or a == 0.0:
        return 1.0
    p = a + b
    # The mask is periodic: work near the origin so that no rounding error of size
    # eps * |uc| can swamp a small |s| (far-off-axis detectors, wide fields).
    uc = uc - p * math.floor(uc / p + 0.5)
    s_abs = abs(s)
    if s_abs <= _S_ZERO * p:
        # |s| this small moves P by O(|s| / radius) < 1e-12: use the s = 0 limit, whose
        # pieces are exact, rather than dividing rounding noise by |s|.
        s = 0.0
        s_abs = 0.0
    lo = uc - radius
    hi = uc + radius
    ja = _first_edge_above(lo, a, b)
    ea = _edge(ja, a, b)
    jb = _first_edge_above(lo + s, a, b)
    eb = _edge(jb, a, b) - s
    cur = lo
    phi_cur = 0.0
    total = 0.0
    while cur < hi:
        nxt = min(ea, eb, hi)
        if nxt > cur:
            # Disc fraction below nxt (acos-free polynomial form, ~1e-16).
            phi_nxt = segment_fraction(0.5 * ((nxt - uc) / radius + 1.0)) if nxt < hi else 1.0
            um = 0.5 * (cur + nxt)
            if s_abs == 0.0:
                # Thin or vertical-ray limit: pieces lie between slat edges, so each is
                # wholly slat or wholly gap.
                if _in_slat(um, a, b):
                    tr = 0.0 if math.isinf(tau) else math.exp(-tau)
                else:
                    tr = 1.0
                total += tr * (phi_nxt - phi_cur)
            else:
                g1 = _path_fraction(cur, s, s_abs, a, b)
                g2 = _path_fraction(nxt, s, s_abs, a, b)
                if abs(g2 - g1) * s_abs <= 1e-12 * (nxt - cur + s_abs):
                    gm = _path_fraction(um, s, s_abs, a, b)
                    total += _transmission(gm, tau) * (phi_nxt - phi_cur)
                elif not math.isinf(tau):
                    if fast:
                        total += _exp_piece_fast(
                            cur, nxt, tau * g1, tau * g2, uc, radius, phi_nxt - phi_cur
                        )
                    else:
                        total += _exp_piece(cur, nxt, tau * g1, tau * g2, uc, radius, _GL_X, _GL_W)
            cur = nxt
            phi_cur = phi_nxt
        if ea <= cur:
            ja += 1
            ea = _edge(ja, a, b)
        if eb <= cur:
            jb += 1
            eb = _edge(jb, a, b) - s
    return min(max(total, 0.0), 1.0)


@njit(parallel=True, cache=True)
def _exact_grid(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, fast, out):
    nd, nt, nn = out.shape
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        c = cos_xi[t]
        sn = sin_xi[t]
        for n in range(nn):
            uc = X[d, n] * c - Y[d, n] * sn
            s = Sx[n] * c - Sy[n] * sn
            out[d, t, n] = exact_point(uc, s, radius, a, b, tau[n], fast)


class ExactModel(ProfileModel):
    """Exact profile from first principles, valid for every geometry (see module notes).

    Parameters
    ----------
    fast : bool
        False (default, registry name ``"exact"``): clip pieces by Gauss–Legendre
        quadrature, accurate to better than 1e-12.  True (``"exact-fast"``): clip pieces by
        a two-moment closed form (:func:`_exp_piece_fast`), several times faster; its error
        is stated in ``docs/response.md`` (measured against the accurate path).
    """

    name = "exact"

    def __init__(self, fast: bool = False) -> None:
        self.fast = bool(fast)
        self.name = "exact-fast" if self.fast else "exact"

    def _evaluate(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        m = instrument.mask
        _exact_grid(
            geom.X, geom.Y, geom.Sx, geom.Sy, geom.tau, cos_xi, sin_xi,
            instrument.detectors.radius, m.slat_width, m.slat_gap, self.fast, out,
        )

    def describe(self) -> dict[str, Any]:
        """Parameters that identify this model (for metadata)."""
        return {"model": self.name, "fast": self.fast}


register_model("exact", ExactModel)
register_model("exact-fast", lambda: ExactModel(fast=True))
