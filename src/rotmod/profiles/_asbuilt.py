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
from rotmod.profiles.exact import _point, point_edges

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


@njit(parallel=True, cache=True)
def _parallel_grid(det, radius, dirs, mu, h, Q, cm, uniform, a, b, e0, W, cum, p,
                   kind, size, cos_xi, sin_xi, out):
    """``out[d, t, n]`` for sources at infinity (directions ``dirs[n]``, unit, toward the
    source) through a mask in the frame ``(Q, cm)``; NaN where a finite outline cuts a
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
        for n in range(nn):
            dx = dirs[n, 0]
            dy = dirs[n, 1]
            dzl = dirs[n, 2]
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


def _directions(geom: ProjectedGeometry) -> np.ndarray:
    st = np.sin(geom.theta)
    return np.ascontiguousarray(np.stack(
        [st * np.cos(geom.phi), st * np.sin(geom.phi), np.cos(geom.theta)], axis=1))


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
    work = out if out.dtype == np.float64 else np.empty(out.shape)
    _parallel_grid(det, instrument.detectors.radius, _directions(geom), mu, m.thickness, Q, cm,
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
