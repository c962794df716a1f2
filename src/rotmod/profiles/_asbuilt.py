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
* **A source at a finite distance** (position ``S``): the ray from detector point
  ``c + delta`` to ``S`` crosses the plane ``z' = zeta`` at a projective function of
  ``delta``, linearised at the detector's centre (exact without tilt; the remainder is
  ``O(tilt R^2 / D)``, < 1e-4 cm for the prototype).  With ``x`` along the gradient ``g_b``
  of the bottom crossing, ``u_b = u_b0 + |g_b| x`` and ``u_t = u_t0 + g_t x``: the disc maps
  to a scaled disc, the growth ``s = u_t - u_b`` is linear in ``x``, and the path fraction
  in slats is a ratio of linear functions between the breakpoints ``u_b = e`` and
  ``u_t = e``.  The slab path ``h |S - q| / (S'_z - q'_z)`` and the flux weight
  ``z_s / |S - q|^3`` (``cos(incidence) / r^2``) vary smoothly across the disc: each chord is
  averaged by 2-point Gauss–Legendre (exact to third order in ``y / D``), and ``x`` is
  integrated on the pieces between breakpoints by Gauss–Legendre in ``t = sqrt`` (distance
  from the disc's edge), sub-pieces as in the ideal kernel's clip integrals.  The profile
  is ``1 - ∫ w (1 - T) / ∫ w`` over the face.
* **Slat patterns** given as edge lists take :func:`~rotmod.profiles.exact.point_edges`.
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
from rotmod.profiles.base import ProjectedGeometry
from rotmod.profiles.exact import (
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


# --------------------------------------------------------------------------- finite distance
#
# Per-point constants of a source at a finite distance, packed in ``prm`` (so that the
# quadrature's integrand takes one array):
_UB, _GB, _UT, _GT, _CX, _CY, _HX, _HY, _SX, _SY, _SZ, _D0, _AX, _AY, _H, _MU, _R = range(17)
_N_PRM = 17
_INV_SQRT3 = 1.0 / math.sqrt(3.0)


@njit(cache=True, inline="always")
def _fraction_at(x, prm, e0, W, cum, p):
    """Path fraction in slats of the ray labelled ``x`` (its bottom and top crossings)."""
    ub = prm[_UB] + prm[_GB] * x
    s = prm[_UT] + prm[_GT] * x - ub
    if abs(s) <= _S_ZERO * p:
        s = 0.0
    return _path_fraction(ub, s, abs(s), e0, W, cum, p)


@njit(cache=True, inline="always")
def _chord_terms(x, f, prm):
    """Chord averages (2-point Gauss–Legendre along the chord at ``x``) of the flux weight
    ``w`` and of ``w (1 - T)``, ``T`` the transmission at path fraction ``f``."""
    R = prm[_R]
    half = math.sqrt(max(R * R - x * x, 0.0)) * _INV_SQRT3
    wsum = 0.0
    gsum = 0.0
    for k in range(2):
        y = half if k == 0 else -half
        dx = x * prm[_HX] - y * prm[_HY]
        dy = x * prm[_HY] + y * prm[_HX]
        rx = prm[_SX] - prm[_CX] - dx
        ry = prm[_SY] - prm[_CY] - dy
        r2 = rx * rx + ry * ry + prm[_SZ] * prm[_SZ]
        r = math.sqrt(r2)
        w = prm[_SZ] / (r2 * r)
        wsum += w
        if f > 0.0:
            mu = prm[_MU]
            if math.isinf(mu):
                gsum += w
            else:
                ell = prm[_H] * r / (prm[_D0] - prm[_AX] * dx - prm[_AY] * dy)
                gsum += w * -math.expm1(-mu * ell * f)
    return 0.5 * wsum, 0.5 * gsum


@njit(cache=True)
def _disc_quad(x1, x2, norm, prm, e0, W, cum, p):
    """``∫ G(x) dΦ(x)`` over ``[x1, x2]`` (``|x| <= R``, ``Φ`` the disc's chord measure of
    total 1): ``G = w (1 - T)``, or ``G = w`` with ``norm``.  Gauss–Legendre (12 nodes) in
    ``t = sqrt(y)``, ``y`` the distance from the disc's nearer edge in radii, on the
    sub-pieces of :func:`~rotmod.profiles.exact.n_subpieces` (exponent change at most 2.5,
    the far edge outside each Bernstein ellipse)."""
    R = prm[_R]
    if x1 < 0.0 < x2:
        return (_disc_quad(x1, 0.0, norm, prm, e0, W, cum, p)
                + _disc_quad(0.0, x2, norm, prm, e0, W, cum, p))
    lower = x1 + x2 <= 0.0
    ya = (x1 + R) / R if lower else (R - x2) / R
    yb = (x2 + R) / R if lower else (R - x1) / R
    ya = max(ya, 0.0)
    if yb <= ya:
        return 0.0
    de = 0.0
    if not norm and not math.isinf(prm[_MU]):
        # Change of the exponent mu l f across the piece (f is monotonic on it).
        ell = prm[_H] * math.sqrt(prm[_SX] ** 2 + prm[_SY] ** 2 + prm[_SZ] ** 2) / prm[_D0]
        de = prm[_MU] * ell * abs(_fraction_at(x2, prm, e0, W, cum, p)
                                  - _fraction_at(x1, prm, e0, W, cum, p))
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
            y = t * t
            x = -R + y * R if lower else R - y * R
            wbar, g = _chord_terms(x, _fraction_at(x, prm, e0, W, cum, p) if not norm
                                   else 0.0, prm)
            acc += _G12_W[k] * y * math.sqrt(2.0 - y) * (wbar if norm else g)
        total += acc * hw
        t1 = t2
    return total * (4.0 / math.pi)


@njit(cache=True)
def _finite_point(prm, e0, W, cum, p):
    """Profile value of a flat detector for a source at a finite distance (module notes):
    ``1 - ∫ w (1 - T) dΦ / ∫ w dΦ``, walking the pieces of ``x in [-R, R]`` between the
    breakpoints of the bottom (``u_b = e``) and top (``u_t = e``) crossings; pieces whose
    rays stay in a gap (``T = 1``) add nothing."""
    R = prm[_R]
    ub0 = prm[_UB]
    gb = prm[_GB]
    ut0 = prm[_UT]
    gt = prm[_GT]
    ja = _first_edge_above(ub0 - gb * R, e0, W, p)
    xa = (_edge(ja, e0, W, p) - ub0) / gb
    jb = _first_edge_above(ut0 - gt * R, e0, W, p)
    xb = (_edge(jb, e0, W, p) - ut0) / gt
    cur = -R
    total = 0.0
    while cur < R:
        nxt = min(xa, xb, R)
        if nxt > cur:
            if _fraction_at(0.5 * (cur + nxt), prm, e0, W, cum, p) > 0.0:
                total += _disc_quad(cur, nxt, False, prm, e0, W, cum, p)
            cur = nxt
        if xa <= cur:
            ja += 1
            xa = (_edge(ja, e0, W, p) - ub0) / gb
        if xb <= cur:
            jb += 1
            xb = (_edge(jb, e0, W, p) - ut0) / gt
    norm = _disc_quad(-R, R, True, prm, e0, W, cum, p)
    return min(max(1.0 - total / norm, 0.0), 1.0)


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
def _flat_grid(det, radius, src, finite, mu, h, Q, cm, uniform, a, b, e0, W, cum, p,
               kind, size, cos_xi, sin_xi, out):
    """``out[d, t, n]`` of flat detectors: sources at infinity (``src[n]`` the unit
    direction toward the source) or at a finite distance (``finite[n]``, ``src[n]`` the
    position), through a mask in the frame ``(Q, cm)``; NaN where a finite outline cuts a
    detector's ray bundle."""
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
        for n in range(nn):
            if finite[n]:
                out[d, t, n] = _finite_value(
                    prm, det[d, 0], det[d, 1], radius, src[n], mu[n], h, Q, cm, u0, u1, u2,
                    v0, v1, v2, Pu, Pv, Pz, a, e0, W, cum, p, kind, size)
                continue
            dx = src[n, 0]
            dy = src[n, 1]
            dzl = src[n, 2]
            du = u0 * dx + u1 * dy + u2 * dzl
            dv = v0 * dx + v1 * dy + v2 * dzl
            dz = Q[2, 0] * dx + Q[2, 1] * dy + Q[2, 2] * dzl
            ru = du / dz
            rv = dv / dz
            ub = Pu - Pz * ru
            # Gradient of the bottom crossing with the lab (x, y) of the detector point.
            gu0 = u0 - Q[2, 0] * ru
            gu1 = u1 - Q[2, 1] * ru
            if kind != 0:
                cls = _outline_class(
                    kind, size, ub, Pv - Pz * rv, ub + h * ru, Pv + (h - Pz) * rv,
                    gu0, gu1, v0 - Q[2, 0] * rv, v1 - Q[2, 1] * rv, radius)
                if cls == 1:
                    out[d, t, n] = 1.0
                    continue
                if cls == 2:
                    out[d, t, n] = np.nan
                    continue
            r_eff = radius * math.hypot(gu0, gu1)
            s = h * ru
            m = mu[n]
            if m == 0.0 or a == 0.0:
                out[d, t, n] = 1.0
                continue
            tau = math.inf if math.isinf(m) else m * h / dz
            if uniform:
                et = 0.0 if math.isinf(tau) else math.exp(-tau)
                out[d, t, n] = _point(ub, s, r_eff, a, b, tau, et)
            else:
                out[d, t, n] = point_edges(ub, s, r_eff, e0, W, cum, p, tau)


@njit(cache=True)
def _finite_value(prm, cx, cy, radius, S, mu, h, Q, cm, u0, u1, u2, v0, v1, v2, Pu, Pv, Pz,
                  a, e0, W, cum, p, kind, size):
    """Profile value of one flat detector (centre ``(cx, cy)``) for a source at ``S``."""
    sx = S[0] - cm[0]
    sy = S[1] - cm[1]
    sz = S[2] - cm[2]
    Su = u0 * sx + u1 * sy + u2 * sz
    Sv = v0 * sx + v1 * sy + v2 * sz
    Sz = Q[2, 0] * sx + Q[2, 1] * sy + Q[2, 2] * sz
    ub, gb0, gb1 = _crossing(Pu, Pz, Su, Sz, u0, u1, Q[2, 0], Q[2, 1], 0.0)
    ut, gt0, gt1 = _crossing(Pu, Pz, Su, Sz, u0, u1, Q[2, 0], Q[2, 1], h)
    if kind != 0:
        vb, gv0, gv1 = _crossing(Pv, Pz, Sv, Sz, v0, v1, Q[2, 0], Q[2, 1], 0.0)
        vt, _, _ = _crossing(Pv, Pz, Sv, Sz, v0, v1, Q[2, 0], Q[2, 1], h)
        # The bottom face's map is the wider (the rays converge toward the source).
        cls = _outline_class(kind, size, ub, vb, ut, vt, gb0, gb1, gv0, gv1, radius)
        if cls == 1:
            return 1.0
        if cls == 2:
            return np.nan
    if mu == 0.0 or a == 0.0:
        return 1.0
    gn = math.hypot(gb0, gb1)
    hx = gb0 / gn
    hy = gb1 / gn
    prm[_UB] = ub
    prm[_GB] = gn
    prm[_UT] = ut
    prm[_GT] = gt0 * hx + gt1 * hy
    prm[_CX] = cx
    prm[_CY] = cy
    prm[_HX] = hx
    prm[_HY] = hy
    prm[_SX] = S[0]
    prm[_SY] = S[1]
    prm[_SZ] = S[2]
    prm[_D0] = Sz - Pz
    prm[_AX] = Q[2, 0]
    prm[_AY] = Q[2, 1]
    prm[_H] = h
    prm[_MU] = mu
    prm[_R] = radius
    return _finite_point(prm, e0, W, cum, p)


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
    if not instrument.detectors.is_flat:
        raise ModelValidityError("thick detectors are not modelled yet; use the Monte Carlo")
    Q, cm = m.frame()
    e0, W, cum, p = m.pattern()
    mu = np.full(geom.theta.size, geom.mu)
    kind = _OUTLINE_CODES[m.outline]
    size = 0.0 if m.outline_size is None else m.outline_size
    det = np.ascontiguousarray(geom.positions)
    src, finite = _sources(instrument, geom)
    work = out if out.dtype == np.float64 else np.empty(out.shape)
    _flat_grid(det, instrument.detectors.radius, src, finite, mu, m.thickness, Q, cm,
               m.slat_edges is None, m.slat_width, m.slat_gap, e0, W, cum, p, kind, size,
               np.ascontiguousarray(cos_xi), np.ascontiguousarray(sin_xi), work)
    if kind and np.isnan(work).any():
        d, t, n = (int(i[0]) for i in np.nonzero(np.isnan(work)))
        raise ModelValidityError(
            f"the exact model handles a finite mask (mask.outline = {m.outline!r}, "
            f"outline_size = {size:g} cm) where each detector's rays are all inside or all "
            f"outside it, but the rim cuts the rays of detector {d} from source {n} "
            f"(theta = {np.degrees(geom.theta[n]):.6g} deg) at mask angle "
            f"{np.degrees(np.arctan2(sin_xi[t], cos_xi[t])):.6g} deg; use the Monte Carlo "
            "(rotmod.montecarlo.simulate_profiles) there"
        )
    if work is not out:
        out[...] = work
