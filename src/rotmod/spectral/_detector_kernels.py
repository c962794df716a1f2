"""Numba kernels of the photon transport in one detector cylinder (see
:mod:`rotmod.spectral.detector` for the physics and its approximations).

The cylinder is ``x^2 + y^2 <= R^2``, ``-H <= z <= 0`` (top face in the plane z = 0).  A
primary photon is a ray labelled by where it crosses the plane z = 0, ``q``, travelling along
``d`` (``d_z < 0``); its path in the cylinder is the parameter interval ``[t1, t2]`` where the
``z`` slab ``[0, H / -d_z]`` and the radial interval ``|q_xy + t d_xy| <= R`` overlap.

Cross-sections are tabulated on a uniform grid in ``ln E`` (columns: coherent, incoherent,
photoelectric, pair as linear coefficients in 1/cm, then per fluorescing element the
cumulative probability that a photoabsorption emits a K x-ray of that element) and
interpolated linearly in ``ln E``.

Random numbers: the Monte Carlo's xoshiro256+ (:mod:`rotmod._rng`), one state per
chunk, seeded from :class:`numpy.random.SeedSequence` children, so results depend on the seed
and the chunking but not on the threads.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rotmod._rng import next_double as _u01

#: Electron rest energy (keV), CODATA 2018.
ME_KEV = 510.99895

#: Fine deposit histogram: counts with ``edep >= (1 - FULL_TOL) E`` are the full-energy peak.
FULL_TOL = 1e-9


@njit(cache=True, inline="always")
def _row(ln0, inv_dln, n, e):
    """Grid interval and fraction of energy ``e`` (keV) on the ``ln E`` grid."""
    x = (math.log(e) - ln0) * inv_dln
    if x <= 0.0:
        return 0, 0.0
    i = int(x)
    if i >= n - 1:
        return n - 2, 1.0
    return i, x - i


@njit(cache=True, inline="always")
def _col(table, i, f, c):
    return table[i, c] + f * (table[i + 1, c] - table[i, c])


@njit(cache=True)
def compton(st, k):
    """Klein–Nishina sample for a photon of ``k = E / m c^2``: ``(eps, cos theta)``,
    ``eps = E'/E``.

    Butcher & Messel (Nucl. Phys. 20, 15 (1960)) as in Geant4's G4KleinNishinaCompton:
    ``dsigma/deps ~ (1/eps + eps) (1 - eps sin^2 / (1 + eps^2))`` on ``[eps0, 1]``,
    ``eps0 = 1 / (1 + 2k)``; the first factor is sampled exactly as a mixture of ``1/eps``
    and ``eps``, the second (in (0, 1]) by rejection.
    """
    eps0 = 1.0 / (1.0 + 2.0 * k)
    eps0sq = eps0 * eps0
    alpha1 = -math.log(eps0)
    alpha2 = 0.5 * (1.0 - eps0sq)
    while True:
        if alpha1 / (alpha1 + alpha2) > _u01(st):
            eps = math.exp(-alpha1 * _u01(st))
            epssq = eps * eps
        else:
            epssq = eps0sq + (1.0 - eps0sq) * _u01(st)
            eps = math.sqrt(epssq)
        onecost = (1.0 - eps) / (eps * k)
        sint2 = onecost * (2.0 - onecost)
        greject = 1.0 - eps * sint2 / (1.0 + epssq)
        if greject >= _u01(st):
            return eps, 1.0 - onecost


@njit(cache=True)
def compton_many(states, k, n, eps_out, cos_out):
    """``n`` Klein–Nishina samples (for checks); one chunk per state row, sequentially."""
    m = states.shape[0]
    per = (n + m - 1) // m
    w = 0
    for j in range(m):
        st = states[j].copy()
        for _ in range(per):
            if w >= n:
                return
            e, c = compton(st, k)
            eps_out[w] = e
            cos_out[w] = c
            w += 1


@njit(cache=True, inline="always")
def _thomson_cos(st):
    """cos theta with density ``(1 + mu^2) 3/8`` on [-1, 1]: exact inversion of the cubic
    CDF, ``mu = c - 1/c``, ``c = cbrt(a + sqrt(a^2 + 1))``, ``a = 4u - 2`` (Cardano)."""
    a = 4.0 * _u01(st) - 2.0
    c = (a + math.sqrt(a * a + 1.0)) ** (1.0 / 3.0)  # the argument is > 0
    return c - 1.0 / c


@njit(cache=True, inline="always")
def _rotate(dx, dy, dz, cost, phi):
    """Direction at polar angle ``acos(cost)``, azimuth ``phi`` about ``(dx, dy, dz)``."""
    sint = math.sqrt(max(0.0, 1.0 - cost * cost))
    cp = math.cos(phi)
    sp = math.sin(phi)
    if abs(dz) > 0.99999999:
        return sint * cp, sint * sp, cost * math.copysign(1.0, dz)
    tmp = math.sqrt(1.0 - dz * dz)
    nx = dx * cost + sint * (dx * dz * cp - dy * sp) / tmp
    ny = dy * cost + sint * (dy * dz * cp + dx * sp) / tmp
    nz = dz * cost - sint * cp * tmp
    norm = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * norm, ny * norm, nz * norm


@njit(cache=True, inline="always")
def _isotropic(st):
    cost = 2.0 * _u01(st) - 1.0
    sint = math.sqrt(max(0.0, 1.0 - cost * cost))
    phi = 2.0 * math.pi * _u01(st)
    return sint * math.cos(phi), sint * math.sin(phi), cost


@njit(cache=True, inline="always")
def _exit(px, py, pz, dx, dy, dz, R, H):
    """Path length from an inside point to the cylinder's surface along ``d``."""
    t = math.inf
    if dz < 0.0:
        t = (-H - pz) / dz
    elif dz > 0.0:
        t = -pz / dz
    a = dx * dx + dy * dy
    if a > 0.0:
        b = px * dx + py * dy
        c = px * px + py * py - R * R
        disc = b * b - a * c
        tr = (-b + math.sqrt(max(disc, 0.0))) / a
        t = min(t, tr)
    return max(t, 0.0)


@njit(cache=True, inline="always")
def _entry(qx, qy, dx, dy, dz, R, H):
    """``(t1, t2)`` of the ray ``(qx, qy, 0) + t d`` (``dz < 0``) inside the cylinder
    (``t2 <= t1`` if it misses)."""
    t1 = 0.0
    t2 = H / -dz
    a = dx * dx + dy * dy
    c = qx * qx + qy * qy - R * R
    if a == 0.0:
        if c > 0.0:
            return 0.0, -1.0
        return t1, t2
    b = qx * dx + qy * dy
    disc = b * b - a * c
    if disc < 0.0:
        return 0.0, -1.0
    r = math.sqrt(disc)
    return max(t1, (-b - r) / a), min(t2, (-b + r) / a)


@njit(cache=True)
def _history(st, px, py, pz, dx, dy, dz, e, s_first, R, H, table, ln0, inv_dln, n_grid,
             n_fl, lines, e_cut, thomson, stack):
    """Energy (keV) deposited by one primary photon and its secondaries.

    The primary is at ``p`` (on the cylinder's surface) moving along ``d`` and interacts
    after the path ``s_first`` (sampled by the caller).  Photoabsorption deposits ``E``
    minus an escaping-or-not K x-ray (the x-ray is then transported), Compton scattering
    deposits the electron's energy, pair production ``E - 2 m c^2`` plus two back-to-back
    isotropic 511 keV photons from the interaction point, Rayleigh scattering only turns the
    photon (Thomson angular law; or, ``thomson`` False, not at all: the two bracket the
    form-factor-peaked truth).  Photons below ``e_cut`` deposit their energy where they
    are.
    """
    edep = 0.0
    ns = 0
    first = True
    while True:
        while True:
            i, f = _row(ln0, inv_dln, n_grid, e)
            mu_c = _col(table, i, f, 0)
            mu_i = _col(table, i, f, 1)
            mu_p = _col(table, i, f, 2)
            mu_pp = _col(table, i, f, 3)
            mu_t = mu_c + mu_i + mu_p + mu_pp
            if first:
                s = s_first
                first = False
            else:
                s = -math.log(1.0 - _u01(st)) / mu_t
                if s >= _exit(px, py, pz, dx, dy, dz, R, H):
                    break  # escapes
            px += s * dx
            py += s * dy
            pz += s * dz
            r = _u01(st) * mu_t
            if r < mu_p:
                # Photoabsorption; a K x-ray of fluorescing element j with probability
                # table[:, 4 + j] - table[:, 3 + j] (cumulative columns).
                v = _u01(st)
                line = -1
                for j in range(n_fl):
                    if v < _col(table, i, f, 4 + j):
                        line = j
                        break
                if line < 0:
                    edep += e
                    break
                # Its line: ``lines[j, 2k]`` energies, ``lines[j, 2k + 1]`` cumulative
                # probabilities (the last 1).
                w = _u01(st)
                k = 0
                while w >= lines[line, 2 * k + 1] and 2 * k + 3 < lines.shape[1]:
                    k += 1
                ex = lines[line, 2 * k]
                edep += e - ex
                e = ex
                dx, dy, dz = _isotropic(st)
            elif r < mu_p + mu_i:
                eps, cost = compton(st, e / ME_KEV)
                edep += e * (1.0 - eps)
                e *= eps
                dx, dy, dz = _rotate(dx, dy, dz, cost, 2.0 * math.pi * _u01(st))
                if e < e_cut:
                    edep += e
                    break
            elif r < mu_p + mu_i + mu_pp:
                edep += e - 2.0 * ME_KEV
                e = ME_KEV
                dx, dy, dz = _isotropic(st)
                if ns < stack.shape[0]:
                    stack[ns, 0] = px
                    stack[ns, 1] = py
                    stack[ns, 2] = pz
                    stack[ns, 3] = -dx
                    stack[ns, 4] = -dy
                    stack[ns, 5] = -dz
                    ns += 1
                else:  # never reached (one pair per history at most matters)
                    edep += ME_KEV
            elif thomson:
                cost = _thomson_cos(st)
                dx, dy, dz = _rotate(dx, dy, dz, cost, 2.0 * math.pi * _u01(st))
        if ns == 0:
            return edep
        ns -= 1
        px = stack[ns, 0]
        py = stack[ns, 1]
        pz = stack[ns, 2]
        dx = stack[ns, 3]
        dy = stack[ns, 4]
        dz = stack[ns, 5]
        e = ME_KEV


@njit(cache=True, inline="always")
def _label(st, mode, sin_t, cos_t, shift, dist, cos_max, R):
    """A primary ray: where it crosses the plane z = 0 and its direction ``(qx, qy, dx, dy,
    dz)``.  Parallel beam (``mode`` 0): labels uniform in the cylinder's shadow (hull of the
    top circle and the bottom circle's shadow, centre ``(shift, 0)``, ``shift = H tan
    theta``), by rejection from its box.  Point source on the axis at height ``dist`` (mode
    1): directions in the cone that covers the top face (every such ray enters through
    it)."""
    if mode == 0:
        while True:
            qx = -R + (2.0 * R + shift) * _u01(st)
            qy = R * (2.0 * _u01(st) - 1.0)
            if abs(qy) <= R and 0.0 <= qx <= shift:
                break
            if qx * qx + qy * qy <= R * R:
                break
            if (qx - shift) ** 2 + qy * qy <= R * R:
                break
        return qx, qy, -sin_t, 0.0, -cos_t
    cost = 1.0 - (1.0 - cos_max) * _u01(st)
    sint = math.sqrt(max(0.0, 1.0 - cost * cost))
    phi = 2.0 * math.pi * _u01(st)
    dx = sint * math.cos(phi)
    dy = sint * math.sin(phi)
    tz = dist / cost
    return tz * dx, tz * dy, dx, dy, -cost


@njit(cache=True, inline="always")
def _mu_total(table, ln0, inv_dln, n_grid, e):
    i, f = _row(ln0, inv_dln, n_grid, e)
    return (_col(table, i, f, 0) + _col(table, i, f, 1) + _col(table, i, f, 2)
            + _col(table, i, f, 3))


@njit(cache=True)
def _chunk(st, n, e, mode, sin_t, cos_t, dist, R, H, forced, table, ln0, inv_dln, n_grid,
           n_fl, lines, e_cut, thomson, hist, tally):
    """``n`` primaries of one chunk; adds to ``hist`` (weighted deposits in ``n_fine``
    bins of ``[0, e]``) and ``tally`` (sum of weights, of squared weights, full-energy
    weight, no-deposit weight, weight of deposits above ``e``)."""
    n_fine = hist.size
    stack = np.empty((4, 6))
    mu_t = _mu_total(table, ln0, inv_dln, n_grid, e)
    shift = H * sin_t / cos_t
    cos_max = dist / math.sqrt(dist * dist + R * R)
    for _ in range(n):
        qx, qy, dx, dy, dz = _label(st, mode, sin_t, cos_t, shift, dist, cos_max, R)
        t1, t2 = _entry(qx, qy, dx, dy, dz, R, H)
        length = t2 - t1
        if length <= 0.0:
            continue
        if forced:
            # Forced first collision: the interaction depth from the exponential truncated
            # to the chord, the history weighted by its probability.
            pint = -math.expm1(-mu_t * length)
            s = -math.log1p(-_u01(st) * pint) / mu_t
            wgt = pint
        else:
            s = -math.log(1.0 - _u01(st)) / mu_t
            if s >= length:
                continue
            wgt = 1.0
        edep = _history(st, qx + t1 * dx, qy + t1 * dy, t1 * dz, dx, dy, dz, e, s, R, H,
                        table, ln0, inv_dln, n_grid, n_fl, lines, e_cut, thomson, stack)
        tally[0] += wgt
        tally[1] += wgt * wgt
        if edep > e * (1.0 + FULL_TOL):
            tally[4] += wgt  # more than the photon brought: must never happen
        elif edep >= e * (1.0 - FULL_TOL):
            tally[2] += wgt
        elif edep <= 0.0:
            tally[3] += wgt
        else:
            k = int(edep / e * n_fine)
            hist[min(k, n_fine - 1)] += wgt


@njit(cache=True)
def _draw_chunk(st, energies, lo, hi, sin_t, cos_t, R, H, table, ln0, inv_dln, n_grid, n_fl,
                lines, e_cut, thomson, out):
    """Photons ``lo <= i < hi`` of :func:`draw_kernel`: for each, analog primaries of energy
    ``energies[i]`` in a parallel beam until one interacts; ``out[i]`` its deposit."""
    stack = np.empty((4, 6))
    shift = H * sin_t / cos_t
    for i in range(lo, hi):
        e = energies[i]
        mu_t = _mu_total(table, ln0, inv_dln, n_grid, e)
        while True:
            qx, qy, dx, dy, dz = _label(st, 0, sin_t, cos_t, shift, 1.0, 0.0, R)
            t1, t2 = _entry(qx, qy, dx, dy, dz, R, H)
            s = -math.log(1.0 - _u01(st)) / mu_t
            if s < t2 - t1:
                break
        out[i] = _history(st, qx + t1 * dx, qy + t1 * dy, t1 * dz, dx, dy, dz, e, s, R, H,
                          table, ln0, inv_dln, n_grid, n_fl, lines, e_cut, thomson, stack)


@njit(parallel=True, cache=True)
def draw_kernel(states, bounds, energies, sin_t, cos_t, R, H, table, ln0, inv_dln, n_fl,
                lines, e_cut, thomson, out):
    """Chunk ``j`` (own RNG state ``states[j]``) draws the deposits of photons
    ``bounds[j] <= i < bounds[j + 1]``, each given that it interacts (analog: primaries are
    drawn until one does, so the deposits follow the redistribution given an interaction of
    a uniformly lit face); the parallel loop only calls :func:`_draw_chunk`."""
    for j in prange(states.shape[0]):
        _draw_chunk(states[j].copy(), energies, bounds[j], bounds[j + 1], sin_t, cos_t, R, H,
                    table, ln0, inv_dln, table.shape[0], n_fl, lines, e_cut, thomson, out)


@njit(parallel=True, cache=True)
def deposit_kernel(states, nphot, e, mode, sin_t, cos_t, dist, R, H, forced, table, ln0,
                   inv_dln, n_fl, lines, e_cut, thomson, hist, tally):
    """Chunk ``j`` (own RNG state ``states[j]``) simulates ``nphot[j]`` primaries into
    ``hist[j]`` and ``tally[j]``; the parallel loop only calls :func:`_chunk`."""
    for j in prange(states.shape[0]):
        _chunk(states[j].copy(), nphot[j], e, mode, sin_t, cos_t, dist, R, H, forced, table,
               ln0, inv_dln, table.shape[0], n_fl, lines, e_cut, thomson, hist[j], tally[j])
