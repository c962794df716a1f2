"""Numba kernels of the analog photon transport (see :mod:`rotmod.montecarlo`).

Geometry (:mod:`rotmod.conventions`): a photon that reaches the detector plane at lab point
``(x, y, 0)`` came along the unit vector ``d = (sin t cos p, sin t sin p, cos t)`` toward its
source.  In the mask frame at mask angle ``xi`` (``u = x cos xi - y sin xi`` perpendicular to
the slats, ``v = x sin xi + y cos xi`` along them, ``z`` unchanged) the ray traced back is

    P(l) = (u0, v0, 0) + l (du, dv, dz),   l >= 0 the path length,

with ``du = sin t cos(p + xi)``, ``dz = cos t``.  Slat ``k`` is the box
``b/2 + k(a+b) <= u <= b/2 + a + k(a+b)``, ``L <= z <= L + h``, unbounded in ``v`` (the mask
is infinite; finite slat length is not modelled).  The chord through a box is the overlap of
the ray's parameter intervals in each slab (the standard slab method): the ``z`` slab gives
``[L/dz, (L+h)/dz]``, the ``u`` slab ``[(e1 - u0)/du, (e2 - u0)/du]`` (sorted), the ``v``
slab everything.  The path in material is the sum of the chords of all boxes the ray meets.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rotmod._rng import next_double, poisson

__all__ = ["slat_chord"]


@njit(cache=True, inline="always")
def slat_chord(u0: float, du: float, l_bot: float, l_top: float, a: float, b: float) -> float:
    """Total chord (cm) in slat boxes of the ray ``u(l) = u0 + du l``, ``l in [l_bot, l_top]``.

    ``l_bot = L / cos(theta)`` and ``l_top = (L + h) / cos(theta)`` are the path lengths at
    which the ray crosses the mask's bottom and top planes; ``du`` is the mask-frame ``u``
    component of the unit direction.
    """
    p = a + b
    hb = 0.5 * b
    if du == 0.0:
        # Ray parallel to the slat side planes: wholly inside one slat or in a gap.
        k = math.floor((u0 - hb) / p)
        if u0 - hb - k * p <= a:
            return l_top - l_bot
        return 0.0
    ub = u0 + du * l_bot
    ut = u0 + du * l_top
    umin = min(ub, ut)
    umax = max(ub, ut)
    k_lo = math.ceil((umin - hb - a) / p)
    k_hi = math.floor((umax - hb) / p)
    inv = 1.0 / du
    total = 0.0
    for k in range(k_lo, k_hi + 1):
        e1 = hb + k * p
        e2 = e1 + a
        l1 = (e1 - u0) * inv
        l2 = (e2 - u0) * inv
        lo = max(min(l1, l2), l_bot)
        hi = min(max(l1, l2), l_top)
        if hi > lo:
            total += hi - lo
    return total


@njit(cache=True, inline="always")
def _survives(st, u0, du, l_bot, l_top, a, b, mu, thin_opaque):
    """Sample whether the photon crosses the mask unabsorbed."""
    if thin_opaque:
        # h = 0 with mu = inf: an opaque strip in the plane z = L (the models' limit).
        ub = u0 + du * l_bot
        p = a + b
        k = math.floor((ub - 0.5 * b) / p)
        return ub - 0.5 * b - k * p > a
    chord = slat_chord(u0, du, l_bot, l_top, a, b)
    if chord <= 0.0:
        return True
    if math.isinf(mu):
        return False
    return next_double(st) < math.exp(-mu * chord)


@njit(cache=True, inline="always")
def _disc(st):
    """Uniform point in the unit disc (rejection from the square: 4/pi tries on average)."""
    while True:
        ex = 2.0 * next_double(st) - 1.0
        ey = 2.0 * next_double(st) - 1.0
        if ex * ex + ey * ey <= 1.0:
            return ex, ey


@njit(cache=True)
def chords_many(x, y, sin_t, cos_t, cos_p, sin_p, xi, a, b, height, thickness):
    """Chord (cm) in slat material of each ray (vectorised :func:`slat_chord`, for checks)."""
    n = x.size
    out = np.empty(n)
    for i in range(n):
        c = math.cos(xi[i])
        s = math.sin(xi[i])
        du = sin_t[i] * (cos_p[i] * c - sin_p[i] * s)
        u0 = x[i] * c - y[i] * s
        out[i] = slat_chord(
            u0, du, height / cos_t[i], (height + thickness) / cos_t[i], a, b
        )
    return out


@njit(parallel=True, cache=True)
def profile_kernel(
    cell_lo, cell_hi, part, nphot, states,
    det_x, det_y, radius,
    sin_t, cos_t, cos_p, sin_p, mu,
    xi_lo, xi_width, binned,
    a, b, height, thickness, thin_opaque,
    n_t, n_n, counts,
):
    """Transmitted photons per (part, cell); one chunk (own RNG state) per prange step.

    Cells are ``q = (d * n_t + t) * n_n + n``; chunk ``j`` simulates ``nphot[j]`` photons in
    each cell ``cell_lo[j] <= q < cell_hi[j]`` and adds them to ``counts[part[j], q]``.
    The parallel loop only calls :func:`_profile_chunk` (numba's parallel compilation
    analyses the loop's body: a short one compiles in a fraction of the time).
    """
    for j in prange(cell_lo.size):
        _profile_chunk(cell_lo[j], cell_hi[j], nphot[j], states[j].copy(), det_x, det_y,
                       radius, sin_t, cos_t, cos_p, sin_p, mu, xi_lo, xi_width, binned, a, b,
                       height, thickness, thin_opaque, n_t, n_n, counts[part[j]])


@njit(cache=True)
def _profile_chunk(q0, q1, nphot, st, det_x, det_y, radius, sin_t, cos_t, cos_p, sin_p, mu,
                   xi_lo, xi_width, binned, a, b, height, thickness, thin_opaque, n_t, n_n,
                   counts):
    """One chunk of :func:`profile_kernel`: cells ``q0 <= q < q1``, ``st`` its RNG state."""
    for q in range(q0, q1):
        n = q % n_n
        t = (q // n_n) % n_t
        d = q // (n_n * n_t)
        l_bot = height / cos_t[n]
        l_top = (height + thickness) / cos_t[n]
        c = math.cos(xi_lo[t])
        s = math.sin(xi_lo[t])
        du = sin_t[n] * (cos_p[n] * c - sin_p[n] * s)
        k = 0
        for _ in range(nphot):
            ex, ey = _disc(st)
            px = det_x[d] + radius * ex
            py = det_y[d] + radius * ey
            if binned:
                xi = xi_lo[t] + xi_width[t] * next_double(st)
                c = math.cos(xi)
                s = math.sin(xi)
                du = sin_t[n] * (cos_p[n] * c - sin_p[n] * s)
            u0 = px * c - py * s
            if _survives(st, u0, du, l_bot, l_top, a, b, mu[n], thin_opaque):
                k += 1
        counts[q] += k


@njit(parallel=True, cache=True)
def observation_count_kernel(t0, t1, states_n, rate, bkg, n_det, total):
    """Number of incident photons (sources and background) in each time piece."""
    for j in prange(t0.size):
        st = states_n[j].copy()
        dt = t1[j] - t0[j]
        acc = 0
        for d in range(n_det):
            for n in range(rate.size):
                acc += poisson(st, rate[n] * dt)
            acc += poisson(st, bkg[d] * dt)
        total[j] = acc


@njit(parallel=True, cache=True)
def observation_kernel(
    t0, t1, states_n, states_p, offset,
    det_x, det_y, radius,
    sin_t, cos_t, cos_p, sin_p, mu, rate, bkg,
    omega, phase0,
    a, b, height, thickness, thin_opaque,
    out_time, out_det, out_src, n_out,
):
    """Detected events of each time piece written at ``offset[j]`` (``n_out[j]`` of them).

    The incident counts are redrawn from ``states_n`` in the same order as
    :func:`observation_count_kernel`, so ``offset`` (its cumulative sums) bounds the output.
    The parallel loop only calls :func:`_observation_piece` (a short body compiles faster).
    """
    for j in prange(t0.size):
        w = _observation_piece(t0[j], t1[j], states_n[j].copy(), states_p[j].copy(),
                               offset[j], det_x, det_y, radius, sin_t, cos_t, cos_p, sin_p,
                               mu, rate, bkg, omega, phase0, a, b, height, thickness,
                               thin_opaque, out_time, out_det, out_src)
        n_out[j] = w - offset[j]


@njit(cache=True)
def _observation_piece(t0, t1, stn, st, w, det_x, det_y, radius, sin_t, cos_t, cos_p, sin_p,
                       mu, rate, bkg, omega, phase0, a, b, height, thickness, thin_opaque,
                       out_time, out_det, out_src):
    """One time piece of :func:`observation_kernel`, written from index ``w``; returns the
    index after its last event."""
    dt = t1 - t0
    for d in range(det_x.size):
        for n in range(rate.size):
            m = poisson(stn, rate[n] * dt)
            l_bot = height / cos_t[n]
            l_top = (height + thickness) / cos_t[n]
            for _ in range(m):
                tt = t0 + dt * next_double(st)
                xi = omega * tt + phase0
                c = math.cos(xi)
                s = math.sin(xi)
                du = sin_t[n] * (cos_p[n] * c - sin_p[n] * s)
                ex, ey = _disc(st)
                px = det_x[d] + radius * ex
                py = det_y[d] + radius * ey
                u0 = px * c - py * s
                if _survives(st, u0, du, l_bot, l_top, a, b, mu[n], thin_opaque):
                    out_time[w] = tt
                    out_det[w] = d
                    out_src[w] = n
                    w += 1
        m = poisson(stn, bkg[d] * dt)
        for _ in range(m):
            out_time[w] = t0 + dt * next_double(st)
            out_det[w] = d
            out_src[w] = -1
            w += 1
    return w


# --------------------------------------------------------------------------- as built
#
# The instrument as built (docs/conventions.md, "The instrument as built"): the mask in its
# own frame (tilted axis through c_m), any slat pattern, a finite outline, sources at a
# finite distance and detectors of finite thickness.  A separate kernel, so that the ideal
# instrument's photons keep the short path above (bench_montecarlo.py).


@njit(cache=True, inline="always")
def _interval_in_outline(u0, du, v0, dv, lo, hi, kind, size):
    """Sub-interval of ``[lo, hi]`` (path lengths) where the ray ``(u0 + du l, v0 + dv l)``
    lies inside the outline (0 none, 1 disc of radius ``size``, 2 square of half-width
    ``size``); ``hi <= lo`` when it misses."""
    if kind == 1:
        A = du * du + dv * dv
        B = u0 * du + v0 * dv
        C = u0 * u0 + v0 * v0 - size * size
        if A == 0.0:
            return (lo, hi) if C <= 0.0 else (0.0, -1.0)
        disc = B * B - A * C
        if disc < 0.0:
            return 0.0, -1.0
        r = math.sqrt(disc)
        return max(lo, (-B - r) / A), min(hi, (-B + r) / A)
    if kind == 2:
        for c0, dc in ((u0, du), (v0, dv)):
            if dc == 0.0:
                if abs(c0) > size:
                    return 0.0, -1.0
            else:
                l1 = (-size - c0) / dc
                l2 = (size - c0) / dc
                lo = max(lo, min(l1, l2))
                hi = min(hi, max(l1, l2))
    return lo, hi


@njit(cache=True, inline="always")
def pattern_chord(u0, du, lo, hi, e0, W, p):
    """Path length (cm) in slats of the ray ``u(l) = u0 + du l``, ``l in [lo, hi]`` (``du``
    the u component of the unit direction), for the slat pattern ``(e0, W, p)`` (slat ``j``
    of period ``k``: ``e0 + k p + [W[2j], W[2j+1]]``; unbounded along the slats)."""
    if hi <= lo:
        return 0.0
    n_s = W.size // 2
    if du == 0.0:
        r = u0 - e0 - p * math.floor((u0 - e0) / p)
        for j in range(n_s):
            if W[2 * j] <= r <= W[2 * j + 1]:
                return hi - lo
        return 0.0
    ua = u0 + du * lo
    ub = u0 + du * hi
    k_lo = math.floor((min(ua, ub) - e0) / p) - 1
    k_hi = math.floor((max(ua, ub) - e0) / p)
    inv = 1.0 / du
    total = 0.0
    for k in range(k_lo, k_hi + 1):
        base = e0 + k * p
        for j in range(n_s):
            l1 = (base + W[2 * j] - u0) * inv
            l2 = (base + W[2 * j + 1] - u0) * inv
            a = max(min(l1, l2), lo)
            b = min(max(l1, l2), hi)
            if b > a:
                total += b - a
    return total


@njit(cache=True, inline="always")
def _cylinder_path(qx, qy, dx, dy, dz, cx, cy, radius, depth):
    """Path length (cm) in the cylinder ``|xy - c| <= radius``, ``-depth <= z <= 0`` of the ray
    through ``(qx, qy, 0)`` travelling along ``-(dx, dy, dz)`` (unit, ``dz > 0``)."""
    hi = depth / dz
    A = dx * dx + dy * dy
    ex = qx - cx
    ey = qy - cy
    C = ex * ex + ey * ey - radius * radius
    if A == 0.0:
        return hi if C <= 0.0 else 0.0
    B = -(ex * dx + ey * dy)
    disc = B * B - A * C
    if disc <= 0.0:
        return 0.0
    r = math.sqrt(disc)
    lo = max(0.0, (-B - r) / A)
    hi = min(hi, (-B + r) / A)
    return max(hi - lo, 0.0)


@njit(cache=True, inline="always")
def _asbuilt_photon(st, qx, qy, dx, dy, dz, c, s, Q, cm, h, e0, W, p, kind, size, mu,
                    thin_opaque):
    """Whether the photon reaching ``(qx, qy, 0)`` along ``-(dx, dy, dz)`` crossed the mask
    at angle ``(c, s) = (cos xi, sin xi)`` unabsorbed."""
    px = qx - cm[0]
    py = qy - cm[1]
    pz = -cm[2]
    # Slat frame: rows u, v of R_z(xi) Q, and z' (Q's last row).
    x0 = Q[0, 0] * px + Q[0, 1] * py + Q[0, 2] * pz
    y0 = Q[1, 0] * px + Q[1, 1] * py + Q[1, 2] * pz
    z0 = Q[2, 0] * px + Q[2, 1] * py + Q[2, 2] * pz
    xd = Q[0, 0] * dx + Q[0, 1] * dy + Q[0, 2] * dz
    yd = Q[1, 0] * dx + Q[1, 1] * dy + Q[1, 2] * dz
    zd = Q[2, 0] * dx + Q[2, 1] * dy + Q[2, 2] * dz
    u0 = x0 * c - y0 * s
    v0 = x0 * s + y0 * c
    du = xd * c - yd * s
    dv = xd * s + yd * c
    l_bot = -z0 / zd
    l_top = (h - z0) / zd
    if thin_opaque:
        # h = 0 with mu = inf: an opaque pattern in the plane z' = 0.
        ub = u0 + du * l_bot
        vb = v0 + dv * l_bot
        lo, hi = _interval_in_outline(ub, 0.0, vb, 0.0, -1.0, 1.0, kind, size)
        if hi < lo:
            return True
        r = ub - e0 - p * math.floor((ub - e0) / p)
        for j in range(W.size // 2):
            if W[2 * j] <= r <= W[2 * j + 1]:
                return False
        return True
    lo, hi = _interval_in_outline(u0, du, v0, dv, l_bot, l_top, kind, size)
    chord = pattern_chord(u0, du, lo, hi, e0, W, p)
    if chord <= 0.0:
        return True
    if math.isinf(mu):
        return False
    return next_double(st) < math.exp(-mu * chord)


@njit(parallel=True, cache=True)
def profile_kernel_asbuilt(
    cell_lo, cell_hi, part, nphot, states, poisson_counts,
    det_x, det_y, radius, depth, mu_det,
    gen, wmax, src, finite, mu,
    xi_lo, xi_width, binned,
    Q, cm, h, e0, W, p, kind, size, thin_opaque,
    n_t, n_n, counts,
):
    """Counted photons per (part, cell) for the instrument as built.

    Photons' end points in the detector plane are uniform on the generation disc
    ``gen[d, n] = (x, y, r)`` (the detector face, or a disc containing the shadow of a
    thick detector); for a source at a finite distance (``finite[n]``, position
    ``src[n]``) a point is kept with probability ``w / wmax[d, n]``, ``w = z_s / |S - q|^3``
    the flux per unit area of the plane, so kept points are photons of the source.  A
    surviving photon counts if it reached a flat face (``depth = 0``, the generation disc
    is then the face) or interacted in the cylinder (``1 - exp(-mu_det[n] l)``).  With
    ``poisson_counts`` each chunk's number of photons is Poisson of mean ``nphot[j]``.
    """
    for j in prange(cell_lo.size):
        st = states[j].copy()
        for q in range(cell_lo[j], cell_hi[j]):
            n = q % n_n
            t = (q // n_n) % n_t
            d = q // (n_n * n_t)
            gx = gen[d, n, 0]
            gy = gen[d, n, 1]
            gr = gen[d, n, 2]
            m = poisson(st, nphot[j]) if poisson_counts else nphot[j]
            c = math.cos(xi_lo[t])
            s = math.sin(xi_lo[t])
            k = 0
            done = 0
            while done < m:
                ex, ey = _disc(st)
                qx = gx + gr * ex
                qy = gy + gr * ey
                if finite[n]:
                    rx = src[n, 0] - qx
                    ry = src[n, 1] - qy
                    rz = src[n, 2]
                    r2 = rx * rx + ry * ry + rz * rz
                    rr = math.sqrt(r2)
                    if next_double(st) * wmax[d, n] > rz / (r2 * rr):
                        continue  # not a photon of this source: draw again
                    dx = rx / rr
                    dy = ry / rr
                    dz = rz / rr
                else:
                    dx = src[n, 0]
                    dy = src[n, 1]
                    dz = src[n, 2]
                done += 1
                if binned:
                    xi = xi_lo[t] + xi_width[t] * next_double(st)
                    c = math.cos(xi)
                    s = math.sin(xi)
                if not _asbuilt_photon(st, qx, qy, dx, dy, dz, c, s, Q, cm, h, e0, W, p,
                                       kind, size, mu[n], thin_opaque):
                    continue
                if depth == 0.0:
                    k += 1
                else:
                    ell = _cylinder_path(qx, qy, dx, dy, dz, det_x[d], det_y[d], radius,
                                         depth)
                    if ell > 0.0 and next_double(st) >= math.exp(-mu_det[n] * ell):
                        k += 1
            counts[part[j], q] += k
