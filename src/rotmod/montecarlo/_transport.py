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

from rotmod.montecarlo._rng import next_double, poisson

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
    """
    for j in prange(cell_lo.size):
        st = states[j].copy()
        for q in range(cell_lo[j], cell_hi[j]):
            n = q % n_n
            t = (q // n_n) % n_t
            d = q // (n_n * n_t)
            l_bot = height / cos_t[n]
            l_top = (height + thickness) / cos_t[n]
            c = math.cos(xi_lo[t])
            s = math.sin(xi_lo[t])
            du = sin_t[n] * (cos_p[n] * c - sin_p[n] * s)
            k = 0
            for _ in range(nphot[j]):
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
            counts[part[j], q] += k


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
    """
    for j in prange(t0.size):
        stn = states_n[j].copy()
        st = states_p[j].copy()
        dt = t1[j] - t0[j]
        w = offset[j]
        for d in range(det_x.size):
            for n in range(rate.size):
                m = poisson(stn, rate[n] * dt)
                l_bot = height / cos_t[n]
                l_top = (height + thickness) / cos_t[n]
                for _ in range(m):
                    tt = t0[j] + dt * next_double(st)
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
                out_time[w] = t0[j] + dt * next_double(st)
                out_det[w] = d
                out_src[w] = -1
                w += 1
        n_out[j] = w - offset[j]
