"""The exact model of the instrument as built (``docs/physics.md``, "The instrument as built").

The ideal instrument (an infinite mask of equal slats turning about the array's axis, flat
detector faces, sources at infinity) takes the kernels of :mod:`rotmod.profiles.exact`
unchanged.  Everything else comes here, by the same 1-D reduction:

* **Mask frame.**  The mask's faces are perpendicular to its rotation axis ``n`` (tilted by
  ``(tilt_x, tilt_y)``), its bottom face crosses the axis at ``c_m = (ox, oy, L)``.  ``Q``
  (lab -> mask frame) is the inverse of the smallest rotation taking ``z`` to ``n``; at mask
  angle ``xi`` the slat-frame coordinates of a lab point ``q`` are the rows of
  ``M = R_z(xi) Q`` applied to ``q - c_m``: ``u`` across the slats, ``v`` along them, ``z'``
  above the bottom face.
* **Parallel rays** (a source at infinity, direction ``d``): a ray ending at detector point
  ``c + delta`` crosses the bottom face at ``u_b = u_b(c) + g . delta``, an affine function
  of ``delta``, so the uniform disc maps to the chord density of a disc of radius
  ``R |g|`` in ``u_b``; ``s = h d_u / d_z`` and ``tau = mu h / d_z`` are the same for every
  ray.  The profile is the ideal kernel's with ``(u_b(c), s, R |g|, tau)`` -- exact, for any
  offset and tilt.
* **A source at a finite distance** (position ``S``): the ray from detector point ``q`` to
  ``S`` crosses the plane ``z' = zeta`` at a projective function of ``q``.  The rays whose
  crossings lie on a line of the slab along the slats (``u = e``) fill a plane through
  ``S`` containing the slats' direction ``v``, so in the detector plane their points form a
  line through the vertex ``V = S - (S_z / v_z) v`` -- for every ``zeta`` and ``e``.  The
  face is therefore labelled by the pencil of lines through ``V``: in the label frame
  (``x`` along the gradient ``g_b`` of the bottom crossing at the centre, ``V = (0, 1 /
  kap)``) the line of label ``x`` holds the points ``(x (1 - kap y), y)`` (area element
  ``(1 - kap y) dx dy``), and its crossings are ``u(0) + g x / (1 - beta x)`` exactly,
  ``beta = dP_z/dx / (S'_z - P_z)``.  No tilt: ``v_z = 0``, ``kap = beta = 0`` (parallel
  chords, affine crossings).  The path fraction in slats is a function of ``x`` alone,
  with breakpoints where a crossing meets a slat edge (the inverse map).  The slab path
  ``h |S - q| / (S'_z - q'_z)`` and the flux weight ``z_s / |S - q|^3`` (``cos(incidence)
  / r^2``) vary smoothly along each label line: 3-point Gauss–Legendre (error ~ (R/D)^6),
  and ``x`` is integrated on the pieces between breakpoints by Gauss–Legendre in ``t =
  sqrt`` (distance from the tangent labels ``-+ R / sqrt(1 - kap^2 R^2)``), sub-pieces as
  in the ideal kernel's clip integrals.  The profile is ``1 - ∫ w (1 - T) / ∫ w`` over the
  face.
* **Thick detectors**: rays are labelled by where they cross the top face's plane (the
  same pencil of label lines for a nearby source); each counts with ``ε = 1 -
  exp(-mu_det l)``, ``l`` its path in the cylinder, and ``P = (∫∫ w ε - ∫∫ w ε (1 - T)) /
  ∫∫_face w`` over the detector's shadow; the mask-independent chord integrals are
  interpolated per cell (:func:`_thick_cells`), the mask's factor integrated against them
  (:func:`_thick_lost`).
* **Slat patterns** given as edge lists take :func:`~rotmod.profiles._exact_kernels.point_edges`.
* **A finite outline** (disc or square centred on the axis, turning with the mask): rays
  that cross the slab outside it are not attenuated.  The model handles the detectors
  whose rays are all inside or all outside the outline across the whole slab (the 1-D
  reduction holds there); a ray bundle cut by the rim is a 2-D problem left to the Monte
  Carlo, and the model raises :class:`~rotmod.errors.ModelValidityError` for it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rotmod.errors import ModelValidityError
from rotmod.geometry import Instrument
from rotmod.profiles._exact_kernels import (
    _G12_W,
    _G12_X,
    _S_ZERO,
    _edge,
    _first_edge_above,
    _path_fraction,
    _point,
    n_subpieces,
    point_edges,
)
from rotmod.profiles.base import ProjectedGeometry

__all__ = ["evaluate"]

#: Outline codes of the kernels.
_OUTLINE_CODES = {None: 0, "circle": 1, "square": 2}


@njit(cache=True, inline="always")
def _rows(Q, c, s):
    """Rows ``u``, ``v`` of ``M = R_z(xi) Q`` (``c = cos xi``, ``s = sin xi``)."""
    u0 = c * Q[0, 0] - s * Q[1, 0]
    u1 = c * Q[0, 1] - s * Q[1, 1]
    u2 = c * Q[0, 2] - s * Q[1, 2]
    v0 = s * Q[0, 0] + c * Q[1, 0]
    v1 = s * Q[0, 1] + c * Q[1, 1]
    v2 = s * Q[0, 2] + c * Q[1, 2]
    return u0, u1, u2, v0, v1, v2


@njit(cache=True)
def _outline_class(kind, size, cu0, cv0, cu1, cv1, ju0, ju1, jv0, jv1, radius):
    """0: the ray bundle of a detector is inside the outline across the slab; 1: outside;
    2: cut by the rim.  ``(cu0, cv0)``, ``(cu1, cv1)``: the bundle's centre at the bottom
    and top faces; ``j``: the map from the detector plane to the faces (rows u, v)."""
    if kind == 0:
        return 0
    if kind == 1:
        # Largest singular value of J bounds the bundle's radius on a face.
        a = ju0 * ju0 + ju1 * ju1
        b = ju0 * jv0 + ju1 * jv1
        c = jv0 * jv0 + jv1 * jv1
        sig = math.sqrt(0.5 * (a + c) + math.sqrt(0.25 * (a - c) ** 2 + b * b))
        rho = radius * sig
        far = max(math.hypot(cu0, cv0), math.hypot(cu1, cv1))
        if far + rho <= size:
            return 0
        # Distance from the axis to the segment of bundle centres.
        du = cu1 - cu0
        dv = cv1 - cv0
        ll = du * du + dv * dv
        t = 0.0 if ll == 0.0 else min(max(-(cu0 * du + cv0 * dv) / ll, 0.0), 1.0)
        near = math.hypot(cu0 + t * du, cv0 + t * dv)
        return 1 if near - rho >= size else 2
    eu = radius * math.hypot(ju0, ju1)
    ev = radius * math.hypot(jv0, jv1)
    if (max(abs(cu0), abs(cu1)) + eu <= size) and (max(abs(cv0), abs(cv1)) + ev <= size):
        return 0
    if (min(cu0, cu1) - eu >= size or max(cu0, cu1) + eu <= -size
            or min(cv0, cv1) - ev >= size or max(cv0, cv1) + ev <= -size):
        return 1
    return 2


# --------------------------------------------------------------------------- general path
#
# Sources at a finite distance and thick detectors: ``P = E0 - ∫∫ w ε (1 - T) / N`` over the
# labels ``q = c + x g + y g_perp`` of the rays in the detector plane (``g`` along the
# gradient of the bottom crossing, so that ``T`` depends on ``x`` alone up to the slab
# path's slow variation), ``w`` the flux density (1 at infinity, ``z_s / r^3`` otherwise),
# ``ε`` the counting probability (1 on a flat face), ``N = ∫∫_face w`` and
# ``E0 = ∫∫ w ε / N`` (1 for a flat face).  Per-point constants are packed in ``prm``:
(_UB, _GB, _UT, _GT, _CX, _CY, _HX, _HY, _SX, _SY, _SZ, _D0, _AX, _AY, _H, _MU, _R, _FIN, _TAU,
 _DH, _MUD, _DLX, _DLY, _RH, _AIX, _AIY, _SGX, _SGY, _BETA, _KAP) = range(30)
_N_PRM = 30
# Hull of a thick detector's shadow (``hull``): the two external tangents' contact points on
# the top face's circle (a) and the bottom face's shadow (b), when they exist.
_N_HULL = 9
#: Moments ``∫ w ε δ^k dy``, ``k < _N_MOM``, of a thick detector's chords (a nearby source).
_N_MOM = 5
#: 3-point Gauss–Legendre rule of the chords of a flat face (a source at a finite distance).
_G3_X = (-math.sqrt(0.6), 0.0, math.sqrt(0.6))
_G3_W = (5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0)
#: Gauss–Legendre rule of the inner integrals along a chord of a thick detector's shadow.
_G12I_X, _G12I_W = (tuple(v) for v in np.polynomial.legendre.leggauss(12))


@njit(cache=True, inline="always")
def _mobius(x, prm):
    """``x / (1 - beta x)``: the crossings of the rays of label ``x`` are ``u = u(0) + g
    x / (1 - beta x)`` (a projective map; ``beta = 0`` for parallel rays or an untilted
    mask, where it is affine)."""
    return x / (1.0 - prm[_BETA] * x)


@njit(cache=True, inline="always")
def _label_of(du, g, prm):
    """The label ``x`` whose crossing is ``u(0) + du`` (``g`` the crossing's gradient at the
    centre): the inverse of :func:`_mobius`; ``inf`` if no ray of this branch reaches it."""
    r = du / g
    den = 1.0 + prm[_BETA] * r
    return r / den if den > 0.0 else math.inf


@njit(cache=True, inline="always")
def _fraction_at(x, prm, e0, W, cum, p):
    """Path fraction in slats of the rays labelled ``x`` (their bottom and top crossings)."""
    m = _mobius(x, prm)
    ub = prm[_UB] + prm[_GB] * m
    s = prm[_UT] + prm[_GT] * m - ub
    if abs(s) <= _S_ZERO * p:
        s = 0.0
    return _path_fraction(ub, s, abs(s), e0, W, cum, p)


@njit(cache=True, inline="always")
def _ray(x, y, f, prm):
    """Flux weight ``w`` and absorbed fraction ``1 - T`` of the ray labelled ``(x, y)`` whose
    path fraction in slats is ``f``."""
    mu = prm[_MU]
    if prm[_FIN] == 0.0:
        if f <= 0.0:
            return 1.0, 0.0
        return 1.0, 1.0 if math.isinf(prm[_TAU]) else -math.expm1(-prm[_TAU] * f)
    dx = x * prm[_HX] - y * prm[_HY]
    dy = x * prm[_HY] + y * prm[_HX]
    rx = prm[_SX] - prm[_CX] - dx
    ry = prm[_SY] - prm[_CY] - dy
    r2 = rx * rx + ry * ry + prm[_SZ] * prm[_SZ]
    r = math.sqrt(r2)
    w = prm[_SZ] / (r2 * r)
    if f <= 0.0:
        return w, 0.0
    if math.isinf(mu):
        return w, 1.0
    ell = prm[_H] * r / (prm[_D0] - prm[_AX] * dx - prm[_AY] * dy)
    return w, -math.expm1(-mu * ell * f)


@njit(cache=True, inline="always")
def _depth_path(x, y, prm):
    """Path (cm) in the detector cylinder of the ray labelled ``(x, y)`` (label frame, from
    the detector's centre): the depths ``zeta in [0, H]`` at which the ray is inside
    ``|q + A zeta| <= R``, ``A`` its horizontal displacement per unit depth, times its
    length per unit depth ``sqrt(1 + |A|^2)``."""
    if prm[_FIN] == 0.0:
        ax = prm[_AIX]
        ay = prm[_AIY]
    else:
        ax = (x - prm[_SGX]) / prm[_SZ]
        ay = (y - prm[_SGY]) / prm[_SZ]
    R = prm[_R]
    H = prm[_DH]
    aa = ax * ax + ay * ay
    bb = x * ax + y * ay
    cc = x * x + y * y - R * R
    if aa == 0.0:
        return H if cc <= 0.0 else 0.0
    disc = bb * bb - aa * cc
    if disc <= 0.0:
        return 0.0
    # Stable roots of aa z^2 + 2 bb z + cc.
    qq = -(bb + math.copysign(math.sqrt(disc), bb))
    z1 = qq / aa
    z2 = cc / qq if qq != 0.0 else z1
    lo = max(min(z1, z2), 0.0)
    hi = min(max(z1, z2), H)
    return max(hi - lo, 0.0) * math.sqrt(1.0 + aa)


@njit(cache=True, inline="always")
def _circle_cut(x, kap, cx, cy, r):
    """``(y1, y2)``, where the label line ``x`` (the points ``(x (1 - kap y), y)``) meets
    the circle of centre ``(cx, cy)`` and radius ``r``; ``y2 < y1`` if it misses it."""
    if kap == 0.0:
        dx = x - cx
        if abs(dx) > r:
            return 1.0, -1.0
        h = math.sqrt(r * r - dx * dx)
        return cy - h, cy + h
    ex = -x * kap
    px = x - cx
    aa = 1.0 + ex * ex
    bb = ex * px - cy
    cc = px * px + cy * cy - r * r
    disc = bb * bb - aa * cc
    if disc < 0.0:
        return 1.0, -1.0
    sq = math.sqrt(disc)
    return (-bb - sq) / aa, (-bb + sq) / aa


@njit(cache=True, inline="always")
def _line_cut(x, kap, ax, ay, bx, by):
    """``(y, t)``: where the label line ``x`` meets the line ``a + t (b - a)``."""
    ex = bx - ax
    ey = by - ay
    den = ex + x * kap * ey
    if den == 0.0:
        return math.nan, math.nan
    t = (x * (1.0 - kap * ay) - ax) / den
    return ay + t * ey, t


@njit(cache=True, inline="always")
def _tangent_labels(kap, cx, cy, r):
    """Labels of the two lines of the pencil tangent to the circle ``(cx, cy, r)``: the
    roots of ``(cx + x (kap cy - 1))^2 = r^2 (1 + kap^2 x^2)`` (``cx -+ r`` for ``kap =
    0``)."""
    if kap == 0.0:
        return cx - r, cx + r
    g = kap * cy - 1.0
    aa = g * g - r * r * kap * kap
    bb = cx * g
    cc = cx * cx - r * r
    sq = math.sqrt(max(bb * bb - aa * cc, 0.0))
    q = -(bb + math.copysign(sq, bb))
    x1 = q / aa
    x2 = cc / q if q != 0.0 else x1
    return min(x1, x2), max(x1, x2)


@njit(cache=True)
def _hull_chord(x, prm, hull):
    """``(y_lo, y_hi)`` of the thick detector's shadow (the convex hull of the top face's
    circle and the bottom face's shadow) along the label line ``x``; ``y_hi < y_lo``
    outside it."""
    R = prm[_R]
    lo = math.inf
    hi = -math.inf
    kap = prm[_KAP]
    if kap != 0.0:
        for cx, cy, r in ((0.0, 0.0, R), (prm[_DLX], prm[_DLY], prm[_RH])):
            y1, y2 = _circle_cut(x, kap, cx, cy, r)
            if y2 >= y1:
                lo = min(lo, y1)
                hi = max(hi, y2)
        if hull[0] > 0.0:
            for k in range(2):
                yy, t = _line_cut(x, kap, hull[1 + 4 * k], hull[2 + 4 * k], hull[3 + 4 * k],
                                  hull[4 + 4 * k])
                if 0.0 <= t <= 1.0:
                    lo = min(lo, yy)
                    hi = max(hi, yy)
        return lo, hi
    if abs(x) <= R:
        h = math.sqrt(R * R - x * x)
        lo = -h
        hi = h
    dx = x - prm[_DLX]
    if abs(dx) <= prm[_RH]:
        h = math.sqrt(prm[_RH] ** 2 - dx * dx)
        lo = min(lo, prm[_DLY] - h)
        hi = max(hi, prm[_DLY] + h)
    if hull[0] > 0.0:
        for k in range(2):
            ax = hull[1 + 4 * k]
            ay = hull[2 + 4 * k]
            bx = hull[3 + 4 * k]
            by = hull[4 + 4 * k]
            if min(ax, bx) <= x <= max(ax, bx) and ax != bx:
                yy = ay + (x - ax) * (by - ay) / (bx - ax)
                lo = min(lo, yy)
                hi = max(hi, yy)
    return lo, hi


@njit(cache=True)
def _inner(x, prm, hull):
    """Chord integrals of a thick detector's shadow along the label line ``x`` (the points
    ``(x (1 - kap y), y)``, weight ``1 - kap y``): ``∫ w ε dy`` and, for a source at a
    finite distance, the moments ``∫ w ε δ^k dy``, ``k = 1 .. 4``, with ``δ(y) = l(x, y) /
    l(x, 0) - 1`` the relative change of the slab path along the chord (~ tan(theta) y / r,
    ~1e-2), so that ``∫ w ε (1 - T) dy`` follows from ``T``'s value at ``y = 0`` by
    Taylor's formula (:func:`_cell_value`).

    Pieces between the circles' crossings; on each, 12-point Gauss–Legendre in ``b``,
    ``y = sm + sh sin(b)`` with ``[sm - sh, sm + sh]`` the chord between the grazing lines
    (the lines of the hull's tangents), where the path through the side vanishes as
    ``sqrt((y - r1) (r2 - y))``: regular in ``b`` on every piece, also on those that end
    just short of a grazing line (7.3e-8 with the pieces' own ends instead, 5 cm of NaI
    at 40 deg).  Sub-divided so that the counting exponent ``mu_det l`` changes by at most
    2.5; pieces where every ray crosses the full depth (``l`` constant) in closed form.
    """
    lo, hi = _hull_chord(x, prm, hull)
    if hi <= lo:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    cuts = np.empty(6)
    nc = 0
    cuts[nc] = lo
    nc += 1
    R = prm[_R]
    kap = prm[_KAP]
    for cx, cy, r in ((0.0, 0.0, R), (prm[_DLX], prm[_DLY], prm[_RH])):
        y1, y2 = _circle_cut(x, kap, cx, cy, r)
        if y2 > y1:
            for yy in (y1, y2):
                if lo < yy < hi:
                    cuts[nc] = yy
                    nc += 1
    cuts[nc] = hi
    nc += 1
    cuts[:nc].sort()
    mud = prm[_MUD]
    finite = prm[_FIN] != 0.0
    ell0 = _slab_path(x, 0.0, prm) if finite else 1.0
    # Where the chord meets the grazing lines (the lines of the hull's tangents).
    strip = False
    r1 = lo
    r2 = hi
    if hull[0] > 0.0:
        ya = _line_cut(x, kap, hull[1], hull[2], hull[3], hull[4])[0]
        yb = _line_cut(x, kap, hull[5], hull[6], hull[7], hull[8])[0]
        if not (math.isnan(ya) or math.isnan(yb)):
            r1 = min(min(ya, yb), lo)
            r2 = max(max(ya, yb), hi)
            strip = r2 > r1
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    f3 = 0.0
    f4 = 0.0
    for i in range(nc - 1):
        y1 = cuts[i]
        y2 = cuts[i + 1]
        if y2 <= y1:
            continue
        ya = y1 + 1e-9 * (y2 - y1)
        yb = y2 - 1e-9 * (y2 - y1)
        ym = 0.5 * (y1 + y2)
        l1 = _depth_path(x * (1.0 - kap * ya), ya, prm)
        lm = _depth_path(x * (1.0 - kap * ym), ym, prm)
        l2 = _depth_path(x * (1.0 - kap * yb), yb, prm)
        if not finite and l1 == lm == l2:
            # Every ray of the piece crosses the full depth: a constant counting probability.
            if lm > 0.0:
                f0 += (y2 - y1) * (1.0 if math.isinf(mud) else -math.expm1(-mud * lm))
            continue
        de = mud * (max(l1, lm, l2) - min(l1, lm, l2)) if not math.isinf(mud) else 0.0
        nsub = max(1, math.ceil(de / 2.5))
        # y = sm + sh sin(b): the path through the side is sqrt((y - r1) (r2 - y)) times
        # a smooth function, (r1, r2) where the chord meets the grazing lines (the hull's
        # tangents), so it is regular in b on every piece, whether or not the piece ends
        # there.  Without tangents (no grazing ray) each piece is its own [r1, r2].
        sm = 0.5 * (y1 + y2)
        sh = 0.5 * (y2 - y1)
        if strip:
            sm = 0.5 * (r1 + r2)
            sh = 0.5 * (r2 - r1)
        b1 = math.asin(min(max((y1 - sm) / sh, -1.0), 1.0))
        b2 = math.asin(min(max((y2 - sm) / sh, -1.0), 1.0))
        step = (b2 - b1) / nsub
        for j in range(nsub):
            hw = 0.5 * step
            m = b1 + j * step + hw
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            a3 = 0.0
            a4 = 0.0
            for k in range(len(_G12I_X)):
                b = m + hw * _G12I_X[k]
                yy = sm + sh * math.sin(b)
                jac = 1.0 - kap * yy
                xx = x * jac
                ell = _depth_path(xx, yy, prm)
                if ell <= 0.0:
                    continue
                v = _G12I_W[k] * math.cos(b) * (
                    1.0 if math.isinf(mud) else -math.expm1(-mud * ell))
                if finite:
                    w = _ray(xx, yy, 0.0, prm)[0] * jac
                    dl = _slab_path(xx, yy, prm) / ell0 - 1.0
                    v *= w
                    d2 = dl * dl
                    a1 += v * dl
                    a2 += v * d2
                    a3 += v * d2 * dl
                    a4 += v * d2 * d2
                a0 += v
            c = hw * sh
            f0 += a0 * c
            f1 += a1 * c
            f2 += a2 * c
            f3 += a3 * c
            f4 += a4 * c
    return f0, f1, f2, f3, f4


@njit(cache=True, inline="always")
def _slab_path(x, y, prm):
    """Path (cm) through the mask slab of the ray from label ``(x, y)`` to a source at a
    finite distance: ``h |S - q| / (S'_z - q'_z)``."""
    dx = x * prm[_HX] - y * prm[_HY]
    dy = x * prm[_HY] + y * prm[_HX]
    rx = prm[_SX] - prm[_CX] - dx
    ry = prm[_SY] - prm[_CY] - dy
    r = math.sqrt(rx * rx + ry * ry + prm[_SZ] * prm[_SZ])
    return prm[_H] * r / (prm[_D0] - prm[_AX] * dx - prm[_AY] * dy)


@njit(cache=True, inline="always")
def _chord_integral(x, f, mode, prm):
    """``∫ G dy`` along the label line ``x`` of a flat face (the pencil's line through
    ``(x, 0)``), by 3-point Gauss–Legendre (the integrand varies on the scale of the source
    distance): ``G = w (1 - T)`` (``mode`` 0) or ``w`` (1), times ``1 - kap y``."""
    R = prm[_R]
    kap = prm[_KAP]
    # The chord is the line of the pencil through (x, 0) and (0, 1 / kap): points
    # (x (1 - kap y), y), area element (1 - kap y) dx dy.
    aa = 1.0 + x * x * kap * kap
    ym = x * x * kap / aa
    half = math.sqrt(max(R * R - x * x * (1.0 - kap * kap * R * R), 0.0)) / aa
    total = 0.0
    for k in range(3):
        y = ym + half * _G3_X[k]
        jac = 1.0 - kap * y
        w, g = _ray(x * jac, y, f, prm)
        total += _G3_W[k] * jac * w * (g if mode == 0 else 1.0)
    return total * half


@njit(cache=True)
def _outer_quad(x1, x2, s_lo, s_hi, mode, prm, e0, W, cum, p):
    """``∫ F(x) dx`` over ``[x1, x2]`` inside the segment ``[s_lo, s_hi]`` between two
    sqrt-type singular points of ``F`` (a chord's ends), ``F`` of :func:`_chord_integral`.
    As the ideal kernel's clip integrals: ``y`` the distance from the nearer end in
    half-segments (so the far end is ``y = 2``, like a disc's far edge), 12-point
    Gauss–Legendre in ``t = sqrt(y)`` on the sub-pieces of
    :func:`~rotmod.profiles._exact_kernels.n_subpieces` (exponent change <= 2.5, far end outside
    every Bernstein ellipse of parameter 2)."""
    half = 0.5 * (s_hi - s_lo)
    mid = s_lo + half
    if x1 < mid < x2:
        return (_outer_quad(x1, mid, s_lo, s_hi, mode, prm, e0, W, cum, p)
                + _outer_quad(mid, x2, s_lo, s_hi, mode, prm, e0, W, cum, p))
    lower = x1 + x2 <= 2.0 * mid
    ya = max((x1 - s_lo) / half if lower else (s_hi - x2) / half, 0.0)
    yb = (x2 - s_lo) / half if lower else (s_hi - x1) / half
    if yb <= ya:
        return 0.0
    de = _exponent_change(x1, x2, prm, e0, W, cum, p) if mode == 0 else 0.0
    nsub = n_subpieces(ya, yb, de)
    step = (yb - ya) / nsub
    total = 0.0
    t1 = math.sqrt(ya)
    for i in range(nsub):
        t2 = math.sqrt(yb if i == nsub - 1 else ya + (i + 1) * step)
        tm = 0.5 * (t1 + t2)
        hw = 0.5 * (t2 - t1)
        acc = 0.0
        for k in range(len(_G12_X)):
            t = tm + hw * _G12_X[k]
            x = s_lo + t * t * half if lower else s_hi - t * t * half
            f = _fraction_at(x, prm, e0, W, cum, p) if mode == 0 else 0.0
            acc += _G12_W[k] * t * _chord_integral(x, f, mode, prm)
        total += acc * hw
        t1 = t2
    return total * 2.0 * half


@njit(cache=True, inline="always")
def _exponent(x, prm, e0, W, cum, p):
    """Slab exponent ``mu l f`` of the ray labelled ``(x, 0)``."""
    f = _fraction_at(x, prm, e0, W, cum, p)
    if prm[_FIN] == 0.0:
        return prm[_TAU] * f
    return prm[_MU] * _slab_path(x, 0.0, prm) * f


@njit(cache=True, inline="always")
def _exponent_change(x1, x2, prm, e0, W, cum, p):
    """Change of the slab exponent across a piece (monotonic on it; 0 for opaque slats)."""
    if math.isinf(prm[_MU]) or prm[_MU] == 0.0:
        return 0.0
    return abs(_exponent(x2, prm, e0, W, cum, p) - _exponent(x1, prm, e0, W, cum, p))


@njit(cache=True)
def _lost_pieces(x1, x2, c, cells, vals, prm, e0, W, cum, p):
    """``∫ (1 - T)``-weighted integrand over ``[x1, x2]``: walk the pieces between the
    breakpoints where the bottom (``u_b = e``) or top (``u_t = e``) crossing meets a slat
    edge; pieces whose rays stay in a gap (``T = 1``) add nothing.  ``c < 0``: a flat face
    (:func:`_outer_quad` over the chord ``[-R, R]``); else cell ``c`` of a thick detector
    (:func:`_cell_quad`)."""
    ub0 = prm[_UB]
    gb = prm[_GB]
    ut0 = prm[_UT]
    gt = prm[_GT]
    xr = _x_max(prm)
    m1 = _mobius(x1, prm)
    ja = _first_edge_above(ub0 + gb * m1, e0, W, p)
    xa = _label_of(_edge(ja, e0, W, p) - ub0, gb, prm)
    jb = _first_edge_above(ut0 + gt * m1, e0, W, p)
    xb = _label_of(_edge(jb, e0, W, p) - ut0, gt, prm)
    cur = x1
    total = 0.0
    while cur < x2:
        nxt = min(xa, xb, x2)
        if nxt > cur:
            if _fraction_at(0.5 * (cur + nxt), prm, e0, W, cum, p) > 0.0:
                if c < 0:
                    total += _outer_quad(cur, nxt, -xr, xr, 0, prm, e0, W, cum, p)
                else:
                    total += _cell_quad(cur, nxt, c, cells, vals, True, prm, e0, W, cum, p)
            cur = nxt
        if xa <= cur:
            ja += 1
            xa = _label_of(_edge(ja, e0, W, p) - ub0, gb, prm)
        if xb <= cur:
            jb += 1
            xb = _label_of(_edge(jb, e0, W, p) - ut0, gt, prm)
    return total


@njit(cache=True, inline="always")
def _x_max(prm):
    """Largest label of a ray of the flat face: the pencil's tangents to its rim,
    ``R / sqrt(1 - kap^2 R^2)`` (``R`` for parallel chords)."""
    R = prm[_R]
    return R / math.sqrt(1.0 - prm[_KAP] * prm[_KAP] * R * R)


#: Placeholders for the cell arguments of :func:`_lost_pieces` on a flat face.
_NO_CELLS = np.zeros((0, 7))
_NO_VALS = np.zeros((0, _N_MOM, 1))


@njit(cache=True)
def _flat_lost(prm, norm_only, e0, W, cum, p):
    """``∫∫ w (1 - T)`` over a flat face (or ``∫∫ w`` with ``norm_only``)."""
    xr = _x_max(prm)
    if norm_only:
        return _outer_quad(-xr, xr, -xr, xr, 1, prm, e0, W, cum, p)
    return _lost_pieces(-xr, xr, -1, _NO_CELLS, _NO_VALS, prm, e0, W, cum, p)


# A thick detector's chord integrals are interpolated on cells: Chebyshev points (second
# kind) in t = sqrt(distance from the nearer singular point), barycentric formula.
_M_CHEB = 16
_CHEB = np.cos(np.pi * np.arange(_M_CHEB) / (_M_CHEB - 1))
_BARY = np.array([(-1.0) ** j * (0.5 if j in (0, _M_CHEB - 1) else 1.0)
                  for j in range(_M_CHEB)])
#: At most this many cells per point (static pieces x halves x grading levels x sub-pieces;
#: the grading adds levels only next to the <= 4 singular points).
_MAX_CELLS = 512


@njit(cache=True, inline="always")
def _bary(t, t1, t2, vals, c, q):
    """Interpolant of ``vals[c, q, :]`` (values at the Chebyshev points of ``[t1, t2]``) at
    ``t``."""
    tm = 0.5 * (t1 + t2)
    hw = 0.5 * (t2 - t1)
    num = 0.0
    den = 0.0
    for j in range(_M_CHEB):
        d = t - (tm + hw * _CHEB[j])
        if d == 0.0:
            return vals[c, q, j]
        g = _BARY[j] / d
        num += g * vals[c, q, j]
        den += g
    return num / den


@njit(cache=True, inline="always")
def _cell_x(t, lower, s_lo, half, s_hi):
    return s_lo + t * t * half if lower else s_hi - t * t * half


@njit(cache=True)
def _cell_value(x, t, c, cells, vals, with_mask, prm, e0, W, cum, p):
    """``∫ w ε (1 - T) dy`` (``with_mask``) or ``∫ w ε dy`` at ``x`` from the cell's
    interpolants: with ``E = mu l(x, 0) f`` and ``T(y) = exp(-E (1 + δ(y)))``,
    ``1 - T = 1 - e^-E sum_{k<5} (-E δ)^k / k! + R5``, ``|R5| <= e^-E (E |δ|)^5 e^(E |δ|)
    / 120 <= 0.19 |δ|^5`` (2e-11 at ``|δ| = 1e-2``)."""
    t1 = cells[c, 0]
    t2 = cells[c, 1]
    F0 = _bary(t, t1, t2, vals, c, 0)
    if not with_mask:
        return F0
    f = _fraction_at(x, prm, e0, W, cum, p)
    if f <= 0.0:
        return 0.0
    mu = prm[_MU]
    if math.isinf(mu):
        return F0
    if prm[_FIN] == 0.0:
        return -math.expm1(-prm[_TAU] * f) * F0
    E = mu * _slab_path(x, 0.0, prm) * f
    eE = math.exp(-E)
    acc = -math.expm1(-E) * F0
    term = 1.0
    for k in range(1, _N_MOM):
        term *= -E / k
        acc -= eE * term * _bary(t, t1, t2, vals, c, k)
    return acc


@njit(cache=True)
def _cell_quad(x1, x2, c, cells, vals, with_mask, prm, e0, W, cum, p):
    """``∫ G dx`` over ``[x1, x2]`` inside cell ``c`` (``G`` of :func:`_cell_value`):
    12-point Gauss–Legendre in the cell's ``t``, sub-divided by the slab exponent's change
    (where it exceeds 36 on the whole piece ``1 - T = 1`` to 2e-16 and none is needed)."""
    lower = cells[c, 2] > 0.0
    s_lo = cells[c, 3]
    s_hi = cells[c, 4]
    half = 0.5 * (s_hi - s_lo)
    ta = math.sqrt(max((x1 - s_lo) / half if lower else (s_hi - x2) / half, 0.0))
    tb = math.sqrt(max((x2 - s_lo) / half if lower else (s_hi - x1) / half, 0.0))
    if tb <= ta:
        return 0.0
    nsub = 1
    if with_mask:
        e1 = _exponent(x1, prm, e0, W, cum, p)
        e2 = _exponent(x2, prm, e0, W, cum, p)
        if min(e1, e2) < 36.0:
            nsub = max(1, math.ceil(_exponent_change(x1, x2, prm, e0, W, cum, p) / 2.5))
    step = (tb - ta) / nsub
    total = 0.0
    for i in range(nsub):
        tm = ta + (i + 0.5) * step
        hw = 0.5 * step
        acc = 0.0
        for k in range(len(_G12_X)):
            t = tm + hw * _G12_X[k]
            x = _cell_x(t, lower, s_lo, half, s_hi)
            acc += _G12_W[k] * t * _cell_value(x, t, c, cells, vals, with_mask, prm, e0, W,
                                                cum, p)
        total += acc * hw
    return total * 2.0 * half


@njit(cache=True)
def _thick_cells(prm, hull):
    """The cells of a thick detector's shadow and the interpolated chord integrals on them;
    returns ``(cells, vals, ∫∫ w ε)``.

    The shadow ``x in [min(-R, dx - R_H), max(R, dx + R_H)]`` is cut at the chords' sqrt-type
    singular points (``x = const`` touching a circle) into segments, at kinks (tangents'
    contact points, the circles' intersections) and at segment middles, and each piece
    into sub-pieces whose far singular point stays outside a Bernstein ellipse of parameter
    2.  On each cell the chord integrals of :func:`_inner` are interpolated at 16 Chebyshev
    points in ``t`` (the mask plays no part: for a source at infinity the cells serve every
    detector, the shadow being the same around each).
    """
    R = prm[_R]
    dlx = prm[_DLX]
    dly = prm[_DLY]
    rh = prm[_RH]
    kap = prm[_KAP]
    t1, t2 = _tangent_labels(kap, 0.0, 0.0, R)
    t3, t4 = _tangent_labels(kap, dlx, dly, rh)
    sing = np.array((t1, t2, t3, t4))
    sing.sort()
    pts = np.empty(10)
    pts[:4] = sing
    npt = 4
    # Kinks: the labels x / (1 - kap y) of the tangents' contact points and of the
    # circles' intersections.
    if hull[0] > 0.0:
        for k in range(2):
            pts[npt] = hull[1 + 4 * k] / (1.0 - kap * hull[2 + 4 * k])
            pts[npt + 1] = hull[3 + 4 * k] / (1.0 - kap * hull[4 + 4 * k])
            npt += 2
    ll = math.hypot(dlx, dly)
    if ll > 0.0:
        s0 = (R * R - rh * rh + ll * ll) / (2.0 * ll)
        if R * R > s0 * s0:
            h0 = math.sqrt(R * R - s0 * s0)
            pts[npt] = (s0 * dlx + h0 * dly) / ll / (1.0 - kap * (s0 * dly - h0 * dlx) / ll)
            pts[npt + 1] = (s0 * dlx - h0 * dly) / ll / (1.0 - kap * (s0 * dly + h0 * dlx) / ll)
            npt += 2
    pts[:npt].sort()
    # Cells, in increasing x: (t1, t2, lower, s_lo, s_hi, x1, x2).
    cells = np.empty((_MAX_CELLS, 7))
    nc = 0
    js = 1
    for i in range(npt - 1):
        a = max(pts[i], sing[0])
        b = min(pts[i + 1], sing[3])
        if b <= a:
            continue
        while js < 3 and sing[js] <= a:
            js += 1
        s_lo = sing[js - 1]
        s_hi = sing[js]
        half = 0.5 * (s_hi - s_lo)
        mid = s_lo + half
        for part in range(2):
            x1 = a if part == 0 else max(a, mid)
            x2 = min(b, mid) if part == 0 else b
            if x2 <= x1:
                continue
            lower = x1 + x2 <= 2.0 * mid
            ya = max((x1 - s_lo) / half if lower else (s_hi - x2) / half, 0.0)
            yb = (x2 - s_lo) / half if lower else (s_hi - x1) / half
            # A singular point just outside the near end (the two circles' tangencies
            # are H tan(theta) apart) sits at y = -yo: grade the cells geometrically
            # (ratio 4 in y, 2 in t) from y = yo, so that it stays outside each cell's
            # Bernstein ellipse (at most 38 levels: 4^-38 = 1e-23 of a half-segment).
            yo = math.inf
            for q in range(4):
                gap = (s_lo - sing[q]) if lower else (sing[q] - s_hi)
                if gap > 1e-22 * half:
                    yo = min(yo, gap / half)
            nb = 0
            ybr = np.empty(40)
            y = ya
            if yo < yb:
                y = max(ya, yo)
                if y > ya:
                    ybr[nb] = y
                    nb += 1
                while 4.0 * y < yb and nb < 38:
                    y *= 4.0
                    ybr[nb] = y
                    nb += 1
            ybr[nb] = yb
            nb += 1
            # Cells in increasing x: increasing y in the lower half, decreasing above.
            for jb in range(nb):
                kb = jb if lower else nb - 1 - jb
                g1 = ya if kb == 0 else ybr[kb - 1]
                g2 = ybr[kb]
                nsub = n_subpieces(g1, g2, 0.0)
                step = (g2 - g1) / nsub
                if nc + nsub > _MAX_CELLS:
                    raise ValueError("thick-detector quadrature: too many cells")
                for j in range(nsub):
                    jj = j if lower else nsub - 1 - j
                    y1 = g1 + jj * step
                    y2 = g2 if jj == nsub - 1 else g1 + (jj + 1) * step
                    t1 = math.sqrt(y1)
                    t2 = math.sqrt(y2)
                    cells[nc, 0] = t1
                    cells[nc, 1] = t2
                    cells[nc, 2] = 1.0 if lower else 0.0
                    cells[nc, 3] = s_lo
                    cells[nc, 4] = s_hi
                    cells[nc, 5] = _cell_x(t1 if lower else t2, lower, s_lo, half, s_hi)
                    cells[nc, 6] = _cell_x(t2 if lower else t1, lower, s_lo, half, s_hi)
                    nc += 1
    vals = np.empty((nc, _N_MOM, _M_CHEB))
    for c in range(nc):
        lower = cells[c, 2] > 0.0
        half = 0.5 * (cells[c, 4] - cells[c, 3])
        tm = 0.5 * (cells[c, 0] + cells[c, 1])
        hw = 0.5 * (cells[c, 1] - cells[c, 0])
        for j in range(_M_CHEB):
            x = _cell_x(tm + hw * _CHEB[j], lower, cells[c, 3], half, cells[c, 4])
            (vals[c, 0, j], vals[c, 1, j], vals[c, 2, j], vals[c, 3, j],
             vals[c, 4, j]) = _inner(x, prm, hull)
    total = 0.0
    for c in range(nc):
        total += _cell_quad(cells[c, 5], cells[c, 6], c, cells, vals, False, prm, 0.0,
                            _NO_W, _NO_W, 1.0)
    return cells[:nc], vals, total


#: A placeholder slat pattern for integrals that do not involve the mask.
_NO_W = np.zeros(2)


@njit(cache=True)
def _thick_lost(prm, cells, vals, e0, W, cum, p):
    """``∫∫ w ε (1 - T)`` over a thick detector's shadow, cell by cell."""
    if prm[_MU] == 0.0:
        return 0.0
    lost = 0.0
    for c in range(cells.shape[0]):
        lost += _lost_pieces(cells[c, 5], cells[c, 6], c, cells, vals, prm, e0, W, cum, p)
    return lost


@njit(cache=True)
def _thick_point(prm, hull, e0, W, cum, p):
    """``P = (∫∫ w ε - ∫∫ w ε (1 - T)) / ∫∫_face w`` for a thick detector (module notes)."""
    norm = _flat_lost(prm, True, e0, W, cum, p)
    cells, vals, total = _thick_cells(prm, hull)
    return max(total - _thick_lost(prm, cells, vals, e0, W, cum, p), 0.0) / norm


@njit(cache=True)
def _general_point(prm, hull, e0, W, cum, p):
    """``P = E0 - ∫∫ w ε (1 - T) / N`` (module notes) for one detector, source and angle."""
    if prm[_DH] > 0.0:
        return _thick_point(prm, hull, e0, W, cum, p)
    norm = _flat_lost(prm, True, e0, W, cum, p)
    lost = _flat_lost(prm, False, e0, W, cum, p)
    return min(max(1.0 - lost / norm, 0.0), 1.0)


@njit(cache=True, inline="always")
def _crossing(Pu, Pz, Su, Sz, Au0, Au1, Az0, Az1, zeta):
    """Crossing coordinate with the plane ``z' = zeta`` of the ray from the detector centre
    (``Pu``, ``Pz``) to the source (``Su``, ``Sz``), and its gradient with the lab ``(x, y)``
    of the detector point (``A``: the point's frame coordinates per unit x and y)."""
    D = Sz - Pz
    uz = (Pu * (Sz - zeta) + (zeta - Pz) * Su) / D
    g0 = (Au0 * (Sz - zeta) - Az0 * (Su - uz)) / D
    g1 = (Au1 * (Sz - zeta) - Az1 * (Su - uz)) / D
    return uz, g0, g1


@njit(parallel=True, cache=True)
def _grid(det, radius, depth, mu_det, src, finite, mu, h, Q, cm, uniform, a, b, e0, W, cum, p,
          kind, size, cos_xi, sin_xi, out):
    """``out[d, t, n]``: sources at infinity (``src[n]`` the unit direction toward the
    source) or at a finite distance (``finite[n]``, ``src[n]`` the position), through a mask
    in the frame ``(Q, cm)``, onto flat faces or cylinders of ``depth``; NaN where a finite
    outline cuts a detector's ray bundle.  Flat faces and parallel rays take the ideal
    kernel's arguments (module notes), everything else :func:`_general_point`."""
    nd, nt, nn = out.shape
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        u0, u1, u2, v0, v1, v2 = _rows(Q, cos_xi[t], sin_xi[t])
        px = det[d, 0] - cm[0]
        py = det[d, 1] - cm[1]
        pz = -cm[2]
        Pu = u0 * px + u1 * py + u2 * pz
        Pv = v0 * px + v1 * py + v2 * pz
        Pz = Q[2, 0] * px + Q[2, 1] * py + Q[2, 2] * pz
        prm = np.empty(_N_PRM)
        hull = np.empty(_N_HULL)
        for n in range(nn):
            if depth > 0.0 and not finite[n]:
                continue  # thick detectors, parallel rays: _thick_parallel_grid
            m = mu[n]
            if finite[n]:
                S = src[n]
                sx = S[0] - cm[0]
                sy = S[1] - cm[1]
                sz = S[2] - cm[2]
                Su = u0 * sx + u1 * sy + u2 * sz
                Sv = v0 * sx + v1 * sy + v2 * sz
                Sz = Q[2, 0] * sx + Q[2, 1] * sy + Q[2, 2] * sz
                ub, gu0, gu1 = _crossing(Pu, Pz, Su, Sz, u0, u1, Q[2, 0], Q[2, 1], 0.0)
                ut, gt0, gt1 = _crossing(Pu, Pz, Su, Sz, u0, u1, Q[2, 0], Q[2, 1], h)
                vb, gv0, gv1 = _crossing(Pv, Pz, Sv, Sz, v0, v1, Q[2, 0], Q[2, 1], 0.0)
                vt = _crossing(Pv, Pz, Sv, Sz, v0, v1, Q[2, 0], Q[2, 1], h)[0]
                dz = 1.0
            else:
                dx = src[n, 0]
                dy = src[n, 1]
                dzl = src[n, 2]
                du = u0 * dx + u1 * dy + u2 * dzl
                dv = v0 * dx + v1 * dy + v2 * dzl
                dz = Q[2, 0] * dx + Q[2, 1] * dy + Q[2, 2] * dzl
                ru = du / dz
                rv = dv / dz
                # Crossings of the centre's ray and their gradients with the lab (x, y) of
                # the detector point (exact: an affine map).
                ub = Pu - Pz * ru
                ut = ub + h * ru
                gu0 = u0 - Q[2, 0] * ru
                gu1 = u1 - Q[2, 1] * ru
                gt0 = gu0
                gt1 = gu1
                vb = Pv - Pz * rv
                vt = vb + h * rv
                gv0 = v0 - Q[2, 0] * rv
                gv1 = v1 - Q[2, 1] * rv
            gn = math.hypot(gu0, gu1)
            hx = gu0 / gn
            hy = gu1 / gn
            # The thick detector's shadow lies within R + |shift| of the centre (below).
            shift = 0.0
            if depth > 0.0:
                if finite[n]:
                    shift = depth * math.hypot(src[n, 0] - det[d, 0], src[n, 1] - det[d, 1]) / (
                        src[n, 2] + depth)
                else:
                    shift = depth * math.hypot(src[n, 0], src[n, 1]) / src[n, 2]
            outside = False
            if kind != 0:
                rb = radius + shift
                if finite[n]:
                    # The bundle's crossings are the projective map of the labels: within
                    # the linear map's image of a disc of radius rb (1 + eps), eps the
                    # largest relative change of the denominator S'_z - P_z over the disc.
                    az = math.hypot(Q[2, 0], Q[2, 1]) * rb
                    rb *= 1.0 + az / (Sz - Pz - az)
                cls = _outline_class(kind, size, ub, vb, ut, vt, gu0, gu1, gv0, gv1, rb)
                if cls == 2:
                    out[d, t, n] = np.nan
                    continue
                outside = cls == 1
            if depth == 0.0 and (outside or m == 0.0 or a == 0.0):
                out[d, t, n] = 1.0
                continue
            if depth == 0.0 and not finite[n]:
                r_eff = radius * gn
                s = ut - ub
                tau = math.inf if math.isinf(m) else m * h / dz
                if uniform:
                    et = 0.0 if math.isinf(tau) else math.exp(-tau)
                    out[d, t, n] = _point(ub, s, r_eff, a, b, tau, et)
                else:
                    out[d, t, n] = point_edges(ub, s, r_eff, e0, W, cum, p, tau)
                continue
            prm[_UB] = ub
            prm[_GB] = gn
            prm[_UT] = ut
            prm[_GT] = gt0 * hx + gt1 * hy
            prm[_CX] = det[d, 0]
            prm[_CY] = det[d, 1]
            prm[_HX] = hx
            prm[_HY] = hy
            prm[_SX] = src[n, 0]
            prm[_SY] = src[n, 1]
            prm[_SZ] = src[n, 2]
            prm[_H] = h
            # Rays outside the outline, or slats of no material, absorb nothing.
            prm[_MU] = 0.0 if (outside or a == 0.0) else m
            prm[_R] = radius
            prm[_DH] = depth
            prm[_MUD] = mu_det[n]
            prm[_BETA] = 0.0
            prm[_KAP] = 0.0
            if finite[n]:
                prm[_FIN] = 1.0
                prm[_D0] = Sz - Pz
                prm[_AX] = Q[2, 0]
                prm[_AY] = Q[2, 1]
                prm[_TAU] = 0.0
                # The exact (projective) map of a tilted mask: the rays whose crossings
                # meet a line of the slab along the slats lie in a plane through the
                # source and the slats' direction v, so their labels form a pencil of
                # lines through the vertex V = S - (S_z / v_z) v of the detector plane,
                # (0, 1 / kap) in the label frame; along the label x (the pencil line
                # through (x, 0)) the crossings are u(0) + g x / (1 - beta x), beta =
                # dP_z/dx / (S'_z - P_z).  No tilt: v_z = 0, kap = beta = 0.
                prm[_BETA] = (Q[2, 0] * hx + Q[2, 1] * hy) / (Sz - Pz)
                vy = -v0 * hy + v1 * hx
                sy = -(src[n, 0] - det[d, 0]) * hy + (src[n, 1] - det[d, 1]) * hx
                prm[_KAP] = v2 / (v2 * sy - src[n, 2] * vy)
                # Source foot relative to the centre in the label frame; the bottom face's
                # shadow: centre sigma H / (z_s + H), radius R z_s / (z_s + H).
                fx = src[n, 0] - det[d, 0]
                fy = src[n, 1] - det[d, 1]
                prm[_SGX] = fx * hx + fy * hy
                prm[_SGY] = -fx * hy + fy * hx
                k = depth / (src[n, 2] + depth)
                prm[_DLX] = prm[_SGX] * k
                prm[_DLY] = prm[_SGY] * k
                prm[_RH] = radius * src[n, 2] / (src[n, 2] + depth)
            else:
                prm[_FIN] = 0.0
                prm[_TAU] = math.inf if math.isinf(prm[_MU]) else prm[_MU] * h / dz
                # Horizontal displacement per unit depth of the descending ray.
                ax = -src[n, 0] / src[n, 2]
                ay = -src[n, 1] / src[n, 2]
                prm[_AIX] = ax * hx + ay * hy
                prm[_AIY] = -ax * hy + ay * hx
                prm[_DLX] = -prm[_AIX] * depth
                prm[_DLY] = -prm[_AIY] * depth
                prm[_RH] = radius
            if depth > 0.0:
                _hull_tangents(prm, hull)
            out[d, t, n] = _general_point(prm, hull, e0, W, cum, p)


@njit(parallel=True, cache=True)
def _thick_parallel_grid(det, radius, depth, mu_det, src, finite, mu, h, Q, cm, a, e0, W, cum,
                         p, kind, size, cos_xi, sin_xi, out):
    """``out[:, t, n]`` of thick detectors for the sources at infinity: the shadow's cells
    (:func:`_thick_cells`) depend on the angle and the source only, so they are built once
    per (angle, source) and serve every detector."""
    nd, nt, nn = out.shape
    norm = math.pi * radius * radius
    for idx in prange(nt * nn):
        t = idx // nn
        n = idx % nn
        if finite[n]:
            continue
        u0, u1, u2, v0, v1, v2 = _rows(Q, cos_xi[t], sin_xi[t])
        dx = src[n, 0]
        dy = src[n, 1]
        dzl = src[n, 2]
        du = u0 * dx + u1 * dy + u2 * dzl
        dv = v0 * dx + v1 * dy + v2 * dzl
        dz = Q[2, 0] * dx + Q[2, 1] * dy + Q[2, 2] * dzl
        ru = du / dz
        rv = dv / dz
        gu0 = u0 - Q[2, 0] * ru
        gu1 = u1 - Q[2, 1] * ru
        gv0 = v0 - Q[2, 0] * rv
        gv1 = v1 - Q[2, 1] * rv
        gn = math.hypot(gu0, gu1)
        hx = gu0 / gn
        hy = gu1 / gn
        prm = np.zeros(_N_PRM)
        hull = np.empty(_N_HULL)
        prm[_GB] = gn
        prm[_GT] = gn
        prm[_HX] = hx
        prm[_HY] = hy
        prm[_H] = h
        prm[_R] = radius
        prm[_DH] = depth
        prm[_MUD] = mu_det[n]
        prm[_FIN] = 0.0
        m = 0.0 if a == 0.0 else mu[n]
        tau = math.inf if math.isinf(m) else m * h / dz
        # Horizontal displacement per unit depth of the descending ray, in the label frame;
        # the bottom face's shadow is the top face's moved by -A H.
        ax = -dx / dzl
        ay = -dy / dzl
        prm[_AIX] = ax * hx + ay * hy
        prm[_AIY] = -ax * hy + ay * hx
        prm[_DLX] = -prm[_AIX] * depth
        prm[_DLY] = -prm[_AIY] * depth
        prm[_RH] = radius
        _hull_tangents(prm, hull)
        cells, vals, total = _thick_cells(prm, hull)
        shift = depth * math.hypot(dx, dy) / dzl
        for d in range(nd):
            px = det[d, 0] - cm[0]
            py = det[d, 1] - cm[1]
            pz = -cm[2]
            Pu = u0 * px + u1 * py + u2 * pz
            Pv = v0 * px + v1 * py + v2 * pz
            Pz = Q[2, 0] * px + Q[2, 1] * py + Q[2, 2] * pz
            ub = Pu - Pz * ru
            vb = Pv - Pz * rv
            mm = m
            if kind != 0:
                cls = _outline_class(kind, size, ub, vb, ub + h * ru, vb + h * rv, gu0, gu1,
                                     gv0, gv1, radius + shift)
                if cls == 2:
                    out[d, t, n] = np.nan
                    continue
                if cls == 1:
                    mm = 0.0
            prm[_UB] = ub
            prm[_UT] = ub + h * ru
            prm[_MU] = mm
            prm[_TAU] = 0.0 if mm == 0.0 else tau
            lost = _thick_lost(prm, cells, vals, e0, W, cum, p)
            out[d, t, n] = max(total - lost, 0.0) / norm


@njit(cache=True)
def _hull_tangents(prm, hull):
    """Contact points of the external common tangents of the top face's circle (centre 0,
    radius R) and the bottom face's shadow (centre (DLX, DLY), radius RH <= R); ``hull[0]``
    is 0 when one circle holds the other (no tangent)."""
    R = prm[_R]
    rh = prm[_RH]
    dx = prm[_DLX]
    dy = prm[_DLY]
    ll = math.hypot(dx, dy)
    hull[0] = 0.0
    if ll <= (R - rh) * (1.0 + 1e-12):
        return
    hull[0] = 1.0
    c = (rh - R) / ll
    sn = math.sqrt(max(1.0 - c * c, 0.0))
    ex = dx / ll
    ey = dy / ll
    for k in range(2):
        sg = 1.0 if k == 0 else -1.0
        # Unit normal n of the tangent, pointing from the line to the centres:
        # n . delta = rh - R.
        nx = c * ex - sg * sn * ey
        ny = c * ey + sg * sn * ex
        hull[1 + 4 * k] = -R * nx
        hull[2 + 4 * k] = -R * ny
        hull[3 + 4 * k] = dx - rh * nx
        hull[4 + 4 * k] = dy - rh * ny


def _sources(instrument: Instrument, geom: ProjectedGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Per source: the unit direction toward it (at infinity) or its lab position, and
    which are at a finite distance."""
    st = np.sin(geom.theta)
    dirs = np.stack([st * np.cos(geom.phi), st * np.sin(geom.phi), np.cos(geom.theta)], axis=1)
    dist = np.full(geom.theta.size, np.inf) if geom.distance is None else geom.distance
    finite = np.isfinite(dist)
    if finite.any():
        S = instrument.source_positions(geom.theta, geom.phi, dist)
        dirs[finite] = S[finite]
    return np.ascontiguousarray(dirs), finite


def evaluate(
    instrument: Instrument,
    geom: ProjectedGeometry,
    cos_xi: np.ndarray,
    sin_xi: np.ndarray,
    out: np.ndarray,
) -> None:
    """Fill ``out[d, t, n]`` with the exact profile of an as-built instrument.

    Raises
    ------
    ModelValidityError
        A finite outline cuts some detector's ray bundle at a requested angle.
    """
    m = instrument.mask
    Q, cm = m.frame()
    e0, W, cum, p = m.pattern()
    mu = np.full(geom.theta.size, geom.mu)
    kind = _OUTLINE_CODES[m.outline]
    size = 0.0 if m.outline_size is None else m.outline_size
    det = np.ascontiguousarray(geom.positions)
    src, finite = _sources(instrument, geom)
    dets = instrument.detectors
    mu_det = np.full(geom.theta.size, geom.mu_det)
    cx = np.ascontiguousarray(cos_xi)
    sx = np.ascontiguousarray(sin_xi)
    _grid(det, dets.radius, dets.thickness, mu_det, src, finite, mu, m.thickness, Q, cm,
          m.slat_edges is None, m.slat_width, m.slat_gap, e0, W, cum, p, kind, size, cx, sx,
          out)
    if dets.thickness > 0 and not finite.all():
        _thick_parallel_grid(det, dets.radius, dets.thickness, mu_det, src, finite, mu,
                             m.thickness, Q, cm, m.slat_width, e0, W, cum, p, kind, size, cx,
                             sx, out)
    if kind and np.isnan(out).any():
        d, t, n = (int(i[0]) for i in np.nonzero(np.isnan(out)))
        raise ModelValidityError(
            f"the exact model handles a finite mask (mask.outline = {m.outline!r}, "
            f"outline_size = {size:g} cm) where each detector's rays are all inside or all "
            f"outside it, but the rim cuts the rays of detector {d} from source {n} "
            f"(theta = {np.degrees(geom.theta[n]):.6g} deg) at mask angle "
            f"{np.degrees(np.arctan2(sin_xi[t], cos_xi[t])):.6g} deg; use the Monte Carlo "
            "(rotmod.montecarlo.simulate_profiles) there"
        )
