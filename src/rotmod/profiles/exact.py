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

import numpy as np
from numba import njit, prange

from rotmod.geometry import Instrument
from rotmod.profiles._disk import disk_fraction, slat_measure
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, register_model

__all__ = ["ExactModel", "exact_point"]

_GL_N = 12
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_N)
#: Largest change of the exponent over one Gauss–Legendre sub-piece.
_EXP_STEP = 2.0
#: Exponent beyond which transmission (< 2e-19) is dropped.
_EXP_CUT = 43.0
#: Largest angular width (rad) of one sub-piece, so sin² is resolved on wide pieces.
_PHI_STEP = 0.6


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
    j = 2 * int(math.floor((x - 0.5 * b) / (a + b)))
    while _edge(j, a, b) > x:
        j -= 1
    while _edge(j, a, b) <= x:
        j += 1
    return j


@njit(cache=True)
def _transmission(g: float, s_abs: float, tau: float) -> float:
    """``exp(-tau g / |s|)`` with the limits of opaque (tau = inf) and clear (g = 0) paths."""
    if g <= 0.0:
        return 1.0
    if math.isinf(tau):
        return 0.0
    return math.exp(-tau * g / s_abs)


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
    slope = (e2 - e1) / (u2 - u1)
    c1 = min(max((uc - u1) / radius, -1.0), 1.0)
    c2 = min(max((uc - u2) / radius, -1.0), 1.0)
    f1 = math.acos(c1)
    f2 = math.acos(c2)
    nsub = max(
        int(math.ceil(abs(e2 - e1) / _EXP_STEP)), int(math.ceil((f2 - f1) / _PHI_STEP)), 1
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
def exact_point(uc: float, s: float, radius: float, a: float, b: float, tau: float) -> float:
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
    """
    if tau == 0.0 or a == 0.0:
        return 1.0
    lo = uc - radius
    hi = uc + radius
    s_abs = abs(s)
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
            phi_nxt = disk_fraction(nxt, uc, radius) if nxt < hi else 1.0
            um = 0.5 * (cur + nxt)
            if s_abs == 0.0:
                # Thin or vertical-ray limit: the ray is either wholly in a slat or not.
                # Pieces lie between slat edges, so each is wholly slat (w = 0) or gap (w = 1).
                w = 1.0 - (slat_measure(nxt, a, b) - slat_measure(cur, a, b)) / (nxt - cur)
                tr = w + (1.0 - w) * (0.0 if math.isinf(tau) else math.exp(-tau))
                total += tr * (phi_nxt - phi_cur)
            else:
                g1 = abs(slat_measure(cur + s, a, b) - slat_measure(cur, a, b))
                g2 = abs(slat_measure(nxt + s, a, b) - slat_measure(nxt, a, b))
                if abs(g2 - g1) <= 1e-12 * (nxt - cur + s_abs):
                    gm = abs(slat_measure(um + s, a, b) - slat_measure(um, a, b))
                    total += _transmission(gm, s_abs, tau) * (phi_nxt - phi_cur)
                elif not math.isinf(tau):
                    k = tau / s_abs
                    total += _exp_piece(cur, nxt, k * g1, k * g2, uc, radius, _GL_X, _GL_W)
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
def _exact_grid(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out):
    nd, nt, nn = out.shape
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        c = cos_xi[t]
        sn = sin_xi[t]
        for n in range(nn):
            uc = X[d, n] * c - Y[d, n] * sn
            s = Sx[n] * c - Sy[n] * sn
            out[d, t, n] = exact_point(uc, s, radius, a, b, tau[n])


class ExactModel(ProfileModel):
    """Exact profile from first principles, valid for every geometry (see module notes)."""

    name = "exact"

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
            instrument.detectors.radius, m.slat_width, m.slat_gap, out,
        )


register_model("exact", ExactModel)
